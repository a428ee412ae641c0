"""Concealed effects on the 3-DOF example arm, diagnosed (docs/diagnosis.md, "n joints").

    python tests/benchmarks/diagnose_urdf_catalogue.py [--duration 10] [--out DIR]

One effect-free `virtual-robot simulate --robot cicese3 --experiment cicese3-excitation` run,
then each effect written into a copy of it (tests/urdf_effect_recordings.py) and
`hil diagnose --robot cicese3` of each: the truth next to what was found, and the held-out
torque and simulated-position NRMSE of the effect's joint before and after. About a minute of
CPU per case.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from urdf_effect_recordings import with_effect

# (name, kind, joint, size, extra): the truth
CASES = [
    ("null", None, 0, 0.0, {}),
    ("gain +7 % j3", "gain", 3, 0.07, {}),
    ("gain -5 % j2", "gain", 2, -0.05, {}),
    ("angle 0.02 rad j2", "angle", 2, 0.02, {}),
    ("angle 0.02 rad j3", "angle", 3, 0.02, {}),
    ("cogging 0.1 Nm x 24 j3", "cogging", 3, 0.1, {"periods_per_rev": 24, "phase_rad": 0.3}),
]


def _run(cmd: list[str]) -> str:
    return subprocess.run(cmd, check=True, capture_output=True, text=True).stdout


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--out", default=None, help="keep the recordings here")
    args = ap.parse_args()
    root = Path(args.out or tempfile.mkdtemp(prefix="diag-urdf-"))
    null = root / "null"
    if not (null / "signals.csv").exists():
        _run(
            [sys.executable, "-m", "virtual_robot.cli", "simulate", "--robot", "cicese3",
             "--experiment", "cicese3-excitation", "--duration", str(args.duration),
             "--out", str(null), "--no-plot"]
        )  # fmt: skip
    print("| case | found | held-out torque / simulated position NRMSE, effect's joint |")
    print("|---|---|---|")
    for name, kind, joint, size, extra in CASES:
        path = null
        if kind is not None:
            path = root / name.replace(" ", "_").replace("%", "pc")
            if not path.exists():
                with_effect(null, path, kind, joint, size, **extra)
        doc = json.loads(
            _run(
                [
                    sys.executable,
                    "-m",
                    "hil.entry",
                    "diagnose",
                    str(path),
                    "--robot",
                    "cicese3",
                    "--json",
                    "--no-plots",
                ]
            )
        )
        found = "; ".join(
            f"{f['effect']} j{f['joint']}: "
            + ", ".join(f"{k} {v}" for k, v in f["estimate"].items() if k != "symmetric_model_Nm")
            for f in doc["findings"]
        )
        j = (joint or 1) - 1
        fit = doc["fit"]

        def pct(x: float | None) -> str:
            return "n/a" if x is None else f"{100 * x:.2f} %"

        tq = f"{pct(fit['before']['torque_nrmse'][j])} → {pct(fit['after']['torque_nrmse'][j])}"
        pos_b, pos_a = fit["before"]["position_nrmse"], fit["after"]["position_nrmse"]
        pos = f"{pct(pos_b[j])} → {pct(pos_a[j])}" if pos_b and pos_a else "n/a"
        print(f"| {name} | {found or 'nothing'} | {tq} / {pos} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
