"""Benchmark: `hil diagnose` on a 20 s recording at 400 Hz (target: under 30 s on this machine).

    python tests/benchmarks/bench_diagnose.py [--repeat 3]

Records the diagnosis excitation on the default virtual robot (joint 1's direction-dependent
Coulomb friction) and on the null robot (symmetric friction), then times the whole diagnosis
(nominal fit, 12 candidates with blocked cross-validation, refit, before/after simulations), the
same call `hil diagnose` makes, without plots.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from diagnose_cases import CASES, make_recording

from drivers.recording import read_signals
from hil.diagnose_report import diagnose
from hil.params import robot_params

TARGET_S = 30.0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    reference = robot_params("cicese").theta
    with tempfile.TemporaryDirectory() as tmp:
        for name, effects in (("default robot", None), ("null", CASES["null"].effects)):
            path = make_recording(Path(tmp) / name.replace(" ", "_"), "diagnosis", effects)
            rec = read_signals(path)
            times = []
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                doc = diagnose([rec], reference).document
                times.append(time.perf_counter() - t0)
            found = ", ".join(f"{f['effect']}:{f['joint']}" for f in doc["findings"]) or "none"
            med = statistics.median(times)
            print(
                f"diagnose, {name}: {len(rec)} rows ({len(rec) * rec.period_s:.0f} s at "
                f"{1 / rec.period_s:.0f} Hz): median {med:.1f} s of {args.repeat} "
                f"(min {min(times):.1f}, max {max(times):.1f}); target < {TARGET_S:.0f} s "
                f"{'met' if med < TARGET_S else 'MISSED'}; findings: {found}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
