"""Benchmark (issue 26): time and peak memory of ``hil diagnose A.csv --reference B.csv
--robot panda``, the drift stage against a reference on a 7-joint arm (target: ≤ 30 s of CPU
and ≤ 1 GB of peak resident memory for two 60 s recordings).

    python tests/benchmarks/bench_diagnose_reference.py [--seed 0] [--profile FILE]

The pair is case 1 of ``make_real_effect_set.py --robot panda`` (the Panda recording of Gaz et
al. (2019), GPL-3, read from ../shared/realdata and written to a temporary directory only),
diagnosed in a child process; its CPU time and ru_maxrss are printed as JSON. The CPU time is
the figure judged: on the shared machine the wall time measures the neighbours. Skipped with a
message when the Panda recording is absent. ``--profile FILE``: the child runs under cProfile
and writes its statistics there (``python -m pstats FILE``; the CPU time then includes the
profiler's own).

Measured (seed 0, the shared machine, this tree): 26–27 s CPU over three runs (26.7 s beside
two busy loops) and 0.65 GB: both targets met; where the time goes: docs/diagnosis.md, "Cost".
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/, for realdata

from realdata import realdata

HERE = Path(__file__).resolve().parent
PANDA = "panda-gaz2019"
TARGET_CPU_S, TARGET_RSS_MB = 30.0, 1024.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0, help="seed of the effect set's draws")
    parser.add_argument("--profile", metavar="FILE", help="write the child's cProfile here")
    args = parser.parse_args()
    if not realdata(PANDA).is_dir():
        print(json.dumps({"skipped": f"../shared/realdata/{PANDA} is absent"}))
        return
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "set"
        subprocess.run(
            [sys.executable, str(HERE / "make_real_effect_set.py"), "--out", str(out),
             "--robot", "panda", "--only", "1", "--seed", str(args.seed)],
            check=True, stdout=subprocess.DEVNULL,
        )  # fmt: skip
        case = out / "case-01"
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        profile = (
            ["-m", "cProfile", "-o", str(Path(args.profile).resolve())] if args.profile else []
        )
        subprocess.run(
            [sys.executable, *profile, "-m", "hil.entry", "diagnose", str(case / "recording.csv"),
             "--reference", str(case / "reference.csv"), "--robot", "panda"],
            check=True, stdout=subprocess.DEVNULL,
        )  # fmt: skip
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    rss_mb = after.ru_maxrss / 1024  # kB on Linux; the largest child's peak
    print(json.dumps({
        "benchmark": "diagnose_reference_panda", "wall_s": round(wall, 1),
        "cpu_s": round(cpu, 1), "peak_rss_mb": round(rss_mb),
        "target_cpu_s": TARGET_CPU_S, "target_rss_mb": TARGET_RSS_MB,
        "meets_target": cpu <= TARGET_CPU_S and rss_mb <= TARGET_RSS_MB,
    }))  # fmt: skip


if __name__ == "__main__":
    main()
