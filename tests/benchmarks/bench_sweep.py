"""Benchmark: the headline timing study, serial against a local process pool (`make bench`).

Runs `hil jitter --sweep latency=0:2ms:9 --scheme ct` (9 levels; a fixed latency is
deterministic, so one run per level: 9 points, the baseline being the 0 ms level), each point a
lockstep CT tracking run of 6 s and an identification run of 10 s over the bench, once with
:class:`SerialExecutor` and once with :class:`LocalProcessExecutor` (``--workers``, default one
per CPU), and prints the wall times and the speed-up. Also checks that both give the same
numbers (lockstep is deterministic). ``--json`` prints one JSON document. No target: a report.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time

from hil.executors import LocalProcessExecutor, SerialExecutor
from hil.jitter_sweep import add_sweep_arguments, sweep


def sweep_args(bench: str, out: str, sweep_spec: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    p.add_argument("--bench", default=bench)
    p.add_argument("--out", default=out)
    p.add_argument("--no-plot", action="store_true")
    add_sweep_arguments(p)
    return p.parse_args(["--sweep", sweep_spec, "--scheme", "ct", "--no-plot"])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--bench", default="virtual-slcan")
    parser.add_argument("--sweep", default="latency=0:2ms:9")
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    workers = args.workers or os.cpu_count() or 1
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, executor in (
            ("serial", SerialExecutor()),
            ("process", LocalProcessExecutor(workers)),
        ):
            start = time.perf_counter()
            doc = sweep(sweep_args(args.bench, f"{tmp}/{name}", args.sweep), executor, False)
            wall = time.perf_counter() - start
            results[name] = {
                "wall_s": wall,
                "points": doc["points_run"],
                "per_point_s": wall / doc["points_run"],
                "status": doc["status"],
                "ct_max_error": [s["mean"] for s in doc["control"]["ct"]["max_position_error_rad"]],
            }
            if not args.json:
                print(f"{name:>8}: {doc['points_run']} points in {wall:.1f} s "
                      f"({wall / doc['points_run']:.2f} s per point)", file=sys.stderr)  # fmt: skip
    same = results["serial"]["ct_max_error"] == results["process"]["ct_max_error"]
    report = {
        "sweep": args.sweep,
        "bench": args.bench,
        "cpus": os.cpu_count(),
        "workers": workers,
        "load_average": os.getloadavg(),
        "serial_s": results["serial"]["wall_s"],
        "process_s": results["process"]["wall_s"],
        "speedup": results["serial"]["wall_s"] / results["process"]["wall_s"],
        "identical_results": same,
        "runs": results,
    }
    if args.json:
        print(json.dumps(report))
    else:
        print(
            f"sweep {args.sweep} over {args.bench}: serial {report['serial_s']:.1f} s, "
            f"process pool ({workers} workers on {report['cpus']} CPUs) "
            f"{report['process_s']:.1f} s, speed-up {report['speedup']:.2f}x; "
            f"results identical: {same}"
        )
    return 0 if same and all(r["status"] == "complete" for r in results.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
