"""The KUKA LWR4+ (FloBaRoID, LGPL-3; issue 27): identified from one run, validated on the other,
side by side with the owners' identified model on the same held-out rows and filter.

    python tests/benchmarks/kuka_identify.py            # about 30 s

Converts measurements_1.npz and measurements_3.npz of ../shared/realdata/kuka-lwr4-flobaroid to
the standard CSV in a temporary directory (tests/realdata.py: the data never enters the tree,
with the files' targets converted as kuka_csv says), runs ``hil identify --from RUN_A --validate
RUN_B --robot kuka-lwr4 --json`` (plain weighted least squares with ``--instruments target``,
which also fits by IV on the reference; and ``--consistent``), both ways, and evaluates on the
held-out rows that command validates on (hil.identify.urdf.regression_rows at the fit's
smoothing cutoff, the fit's friction steps left out): our θ, the profile's (FloBaRoID's a priori
URDF) and the owners' identified model (model/kuka_lwr4_identified.urdf with its <dynamics>
viscous and Coulomb friction, mapped to the same base parameters: same kinematics). Prints a
markdown table of the held-out torque NRMSE per joint (docs/real-data.md, "KUKA LWR4+"), then
the friction parameters by least squares and by IV. Says so and exits when the data is absent.
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from realdata import KUKA, kuka_csv, realdata  # tests/realdata.py

from drivers.recording import read_signals
from hil.cli import main as hil_main
from hil.identify.urdf import regression_rows, torque_nrmse
from hil.model.urdf import UrdfArmModel

OWNERS = "kuka_lwr4_identified.urdf"


def owners_theta(model: UrdfArmModel) -> np.ndarray:
    """The owners' identified URDF as base parameters of ``model`` (the same kinematics): its
    links' inertial parameters and each joint's <dynamics damping friction> (FloBaRoID's
    τ_f = f_v q̇ + f_c sgn q̇, Coulomb as identified, negative on joints 4-7)."""
    path = realdata(KUKA) / OWNERS
    tree = ET.parse(path)
    dyn = {
        j.get("name"): j.find("dynamics")
        for j in tree.getroot().iter("joint")
        if j.get("type") == "revolute"
    }
    names = model.joint_names
    viscous = [float(dyn[n].get("damping")) for n in names]
    coulomb = [float(dyn[n].get("friction")) for n in names]
    # Pinocchio refuses a negative dry friction in a URDF: the friction is given to the model
    # here, so a copy without it is what Pinocchio reads
    for d in dyn.values():
        d.attrib.pop("friction", None)
    with tempfile.TemporaryDirectory() as tmp:
        tree.write(Path(tmp) / OWNERS)
        owners = UrdfArmModel(Path(tmp) / OWNERS, gravity_m_s2=9.81, viscous=viscous,
                              coulomb=coulomb, terms=model.terms)  # fmt: skip
    theta = owners.base_theta()
    # the same base: both models' torques agree for the owners' θ on random states
    rng = np.random.default_rng(0)
    q, dq, ddq = rng.normal(size=(3, 20, model.n_joints))
    if not np.allclose(owners.torque(theta, q, dq, ddq), model.torque(theta, q, dq, ddq)):
        raise SystemExit(f"{path}: not the kinematics of {model.urdf}")
    return theta


def identify(fit: Path, val: Path, out: Path, consistent: bool) -> dict:
    """``hil identify`` of run ``fit`` validated on ``val``; the least-squares call also fits
    by instrumental variables on the reference (``--instruments target``)."""
    argv = ["identify", "--from", str(fit), "--validate", str(val), "--robot", "kuka-lwr4",
            "--schemes", "filtered_dynamic", "--out", str(out), "--overwrite",
            "--json"]  # fmt: skip
    argv += ["--consistent"] if consistent else ["--instruments", "target"]
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        hil_main(argv)  # exit 1 when held-out validation fails: the report is written anyway
    return json.loads(buf.getvalue())


def main() -> int:
    if not (realdata(KUKA) / "measurements_1.npz").is_file():
        print(f"{realdata(KUKA)} not present (LGPL-3 data, kept out of the tree): nothing to do")
        return 0
    model = UrdfArmModel.from_profile("kuka-lwr4")
    theta_owners = owners_theta(model)
    head = " | ".join(f"j{j + 1}" for j in range(model.n_joints))
    print(f"| fit → held out | model | {head} | better than owners |")
    print("|---|---|" + "---|" * model.n_joints + "---|")
    with tempfile.TemporaryDirectory() as tmp:
        csv = {r: kuka_csv(r, tmp, targets=True) for r in (1, 3)}
        friction = []
        for a, b in ((1, 3), (3, 1)):
            val = read_signals(csv[b])
            rows_owners = None
            lines = []
            for consistent in (False, True):
                report = identify(csv[a], csv[b], Path(tmp) / "out", consistent)
                entry = report["schemes"]["filtered_dynamic"]
                rows = regression_rows(model, val, cutoff_hz=report["smoothing_cutoff_hz"])
                rows = rows.leaving_out(np.asarray(entry["friction_steps_left_out"], bool))
                # least squares' own θ: `hil identify` offers the consistent fit when least
                # squares is not physical, and keeps least squares' as theta_least_squares
                ours = torque_nrmse(
                    np.asarray(entry.get("theta_least_squares", entry["theta"])), rows
                )
                owners = torque_nrmse(theta_owners, rows)
                if rows_owners is None:
                    rows_owners = owners
                    lines.append(("owners' identified URDF", owners, None))
                    lines.append(("profile (a priori URDF)", torque_nrmse(model.base_theta(), rows),
                                  owners))  # fmt: skip
                label = "ours, consistent" if consistent else "ours, least squares"
                passed = "" if entry["validation"]["passed"] else " (failed held-out check)"
                if not consistent and "theta_least_squares" in entry:
                    passed = " (not physical)"
                lines.append((label + passed, ours, owners))
                if not consistent:  # IV on the reference, on the same rows
                    iv = report["schemes"]["filtered_dynamic_iv"]
                    passed = "" if iv["validation"]["passed"] else " (failed held-out check)"
                    lines.append(("ours, IV on the reference" + passed,
                                  torque_nrmse(np.asarray(iv["theta"]), rows), owners))  # fmt: skip
                    friction.append((a, b, report, iv["reference"]))
            for label, e, ref in lines:
                cells = " | ".join(f"{x:.3f}" for x in e)
                better = "" if ref is None else f"{int(np.sum(e < ref))} of {len(e)}"
                print(f"| {a} → {b} | {label} | {cells} | {better} |")
    # the friction parameters by least squares and by IV, ± blocked-bootstrap SE
    print("\n| fit | reference delay, tracking | parameter | " + head + " |")
    print("|---|---|---|" + "---|" * model.n_joints)
    for a, _, report, ref in friction:
        track = f"{ref['delay_s']:+.3f} s, ≤ {max(ref['relative_error']):.1%}"
        for kind in ("fv", "fc"):
            for scheme, label in (("filtered_dynamic", "LS"), ("filtered_dynamic_iv", "IV")):
                entry = report["schemes"][scheme]
                theta = entry.get("theta_least_squares", entry["theta"])
                se = entry["uncertainty"]["se_blocked_bootstrap"]
                cells = []
                for j in range(model.n_joints):
                    i = model.meanings.index(f"{kind}{j + 1}")
                    cells.append(f"{theta[i]:.3g} ± {se[i]:.2g}")
                print(f"| {a} | {track} | {kind} {label} | " + " | ".join(cells) + " |")
        n_id = {s: sum(report["schemes"][s]["uncertainty"]["identified"])
                for s in ("filtered_dynamic", "filtered_dynamic_iv")}  # fmt: skip
        print(
            f"| {a} | | identified of {model.n_params} | LS {n_id['filtered_dynamic']}, "
            f"IV {n_id['filtered_dynamic_iv']} |" + " |" * (model.n_joints - 1)
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
