"""Benchmark: peak memory of `hil identify --from` on a long 2-DOF recording (issue 13).

Simulates ``--seconds`` of the default experiment with `virtual-robot simulate` (400 Hz rows,
a physical recording: identification and open-loop validation run end to end), then runs
`hil identify --from` on it in a fresh process under ``/usr/bin/time`` and prints its peak RSS,
the bytes per recording row, and the wall time.

    python tests/benchmarks/bench_identify_memory.py --seconds 850   # 340 000 rows, ~1.5 min

The recording is kept in ``--dir`` (default: a temporary directory, removed at the end).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=850.0, help="simulated duration")
    p.add_argument("--dir", default=None, help="where to write (default: a temporary dir)")
    args = p.parse_args()
    if not args.seconds > 0:
        p.error(f"--seconds must be > 0, got {args.seconds}")
    with tempfile.TemporaryDirectory(prefix="bench-idmem-") as tmp:
        run = Path(args.dir or tmp) / f"sim-{args.seconds:g}s"
        subprocess.run(
            [sys.executable, "-m", "virtual_robot.cli", "simulate", "--duration",
             str(args.seconds), "--out", str(run), "--no-plot", "-q"],
            check=True, capture_output=True,
        )  # fmt: skip
        with open(run / "signals.csv") as f:
            rows = sum(1 for _ in f) - 1
        t0 = time.perf_counter()
        proc = subprocess.run(
            ["/usr/bin/time", "-f", "%M", sys.executable, "-m", "hil.cli", "identify", "--from",
             str(run), "--out", str(Path(args.dir or tmp) / "identify"), "--overwrite",
             "--no-plot", "--json"],
            capture_output=True, text=True, check=False,
        )  # fmt: skip
        seconds = time.perf_counter() - t0
        if proc.returncode != 0:
            print(proc.stderr.strip(), file=sys.stderr)
            return 1
        peak = int(proc.stderr.strip().splitlines()[-1]) * 1024
        print(
            f"hil identify --from ({rows} rows, {args.seconds:g} s at 400 Hz): {seconds:.0f} s, "
            f"peak RSS {peak / 1e6:.0f} MB ({peak / rows:.0f} B a row)"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
