"""The DFKI simple pendulum (one AK80-6; BSD-3; issue 27): identified from each controller's
recording, validated on every other one, side by side with the owners' identified model on the
same held-out rows and filter; the identified J, m·cx, Fv, Fc next to the owners'.

    python tests/benchmarks/pendulum_identify.py        # about 10 s

For each fit recording A and held-out recording B of ../shared/realdata/dfki-simple-pendulum/
records: ``hil identify --from A --validate B --robot dfki-pendulum --columns
t=time,q1=position,tau1=torque --json``, then on the rows that command validates on
(hil.identify.urdf.regression_rows at the fit's cutoff, the fit's friction steps left out) the
held-out torque NRMSE of our θ, of the profile's (the owners' CAD URDF) and of the owners'
identified model τ = J q̈ + m·cx·g·sin q + Fv q̇ + Fc atan(100 q̇) + offset, written in the same
base parameters (Fc atan(100 q̇) as the Coulomb level Fc·π/2, as the profile does). Prints two
markdown tables (docs/real-data.md, "DFKI simple pendulum"). Exits with a message when the data
is absent.
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from realdata import realdata  # tests/realdata.py

from drivers.recording import read_signals
from hil.cli import main as hil_main
from hil.identify.urdf import regression_rows, torque_nrmse
from hil.model.urdf import UrdfArmModel

PENDULUM = "dfki-simple-pendulum"
COLUMNS = "t=time,q1=position,tau1=torque"
# results/control_method_pd/system_identification/system_identification.txt
OWNERS = {"J": 6.259e-02, "m*cx": 1.022e-01, "Fv": 4.707e-02, "Fc": 1.839e-01, "offset": -7.586e-02}


def owners_theta(model: UrdfArmModel) -> np.ndarray:
    """The owners' model in the profile's base parameters: m·cx (first moment along the rod),
    0 across it, J about the axis, Fv, the Coulomb level Fc·π/2, the offset."""
    if model.n_params != 6:
        raise SystemExit(f"expected 6 base parameters, {model.name} has {model.n_params}")
    o = OWNERS
    return np.array([o["m*cx"], 0.0, o["J"], o["Fv"], o["Fc"] * np.pi / 2, o["offset"]])


def identify(fit: Path, val: Path, out: Path) -> dict:
    argv = ["identify", "--from", str(fit), "--validate", str(val), "--robot", "dfki-pendulum",
            "--columns", COLUMNS, "--schemes", "filtered_dynamic", "--out", str(out),
            "--overwrite", "--no-plot", "--json"]  # fmt: skip
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(io.StringIO()):
        hil_main(argv)  # exit 1 when held-out validation fails: the report is written anyway
    return json.loads(buf.getvalue())


def short(path: Path) -> str:
    return path.name.removeprefix("control_method_").split("__")[0]


def main() -> int:
    folder = realdata(PENDULUM) / "records"
    if not folder.is_dir():
        print(f"{folder} not present: nothing to do")
        return 0
    files = sorted(folder.glob("*.csv"))
    model = UrdfArmModel.from_profile("dfki-pendulum")
    theta_owners = owners_theta(model)
    table, params = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for a in files:
            wins, mean = [], {"ours": [], "owners": [], "profile": []}
            theta = None
            for b in files:
                if a == b:
                    continue
                report = identify(a, b, Path(tmp) / "out")
                entry = report["schemes"]["filtered_dynamic"]
                theta = np.asarray(entry["theta"])
                val = read_signals(b, columns=COLUMNS)
                rows = regression_rows(model, val, cutoff_hz=report["smoothing_cutoff_hz"])
                rows = rows.leaving_out(np.asarray(entry["friction_steps_left_out"], bool))
                e = {
                    "ours": torque_nrmse(theta, rows)[0],
                    "owners": torque_nrmse(theta_owners, rows)[0],
                    "profile": torque_nrmse(model.base_theta(), rows)[0],
                }
                for k, v in e.items():
                    mean[k].append(v)
                wins.append(e["ours"] < e["owners"])
            table.append((short(a), {k: np.median(v) for k, v in mean.items()}, sum(wins)))
            se = report["schemes"]["filtered_dynamic"]["uncertainty"]["se_blocked_bootstrap"]
            params.append((short(a), theta, se))
    n_other = len(files) - 1
    print("| fit recording | held-out torque NRMSE (median): ours | owners' model | profile "
          "(CAD URDF) | ours better than owners |")  # fmt: skip
    print("|---|---|---|---|---|")
    for name, m, wins in table:
        print(f"| {name} | {m['ours']:.3f} | {m['owners']:.3f} | {m['profile']:.3f} | "
              f"{wins} of {n_other} |")  # fmt: skip
    print()
    print("| fit recording | J kg m² | m·cx kg m | Fv Nm s | Fc Nm (atan) | offset Nm |")
    print("|---|---|---|---|---|---|")
    o = OWNERS
    print(f"| owners | {o['J']:.4f} | {o['m*cx']:.4f} | {o['Fv']:.4f} | {o['Fc']:.4f} | "
          f"{o['offset']:.4f} |")  # fmt: skip
    p = model.base_theta()
    print(f"| profile (CAD URDF + owners' friction) | {p[2]:.4f} | {p[0]:.4f} | {p[3]:.4f} | "
          f"{p[4] * 2 / np.pi:.4f} | {p[5]:.4f} |")  # fmt: skip
    for name, th, se in params:
        cells = [(th[2], se[2]), (th[0], se[0]), (th[3], se[3]),
                 (th[4] * 2 / np.pi, se[4] * 2 / np.pi), (th[5], se[5])]  # fmt: skip
        print(f"| {name} | " + " | ".join(f"{v:.4f} ± {s:.4f}" for v, s in cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
