"""Benchmark: the headline timing study, serial against a local process pool and a Dask
LocalCluster (`make bench`).

Runs `hil jitter --sweep latency=0:2ms:9 --scheme ct` (9 levels; a fixed latency is
deterministic, so one run per level: 9 points, the baseline being the 0 ms level), each point a
lockstep CT tracking run of 6 s and an identification run of 10 s over the bench, once per
executor of ``--executors`` (default serial, process, dask: a :class:`SerialExecutor`, a
:class:`LocalProcessExecutor` of ``--workers`` processes and a Dask ``LocalCluster`` of
``--workers`` worker processes, the cluster's start and close included in its time; dask is
left out with a note when the extra is missing), and prints the wall times and the speed-ups,
with the load average before and after. Every executor writes into the same ``--out`` path (one
after another), so the sweep documents must be identical up to wall times and the executor
(:func:`hil.timing.sweep.reproducible`); that is checked. ``--json`` prints one JSON document.
No target: a report.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from hil.bench.executors import make_executor
from hil.timing.sweep import add_sweep_arguments, reproducible, sweep


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
    parser.add_argument("--executors", default="serial,process,dask")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    workers = args.workers or os.cpu_count() or 1
    kinds = [k.strip() for k in args.executors.split(",") if k.strip()]
    notes = []
    if "dask" in kinds and importlib.util.find_spec("distributed") is None:
        kinds.remove("dask")
        notes.append("dask left out: pip install 'ddbench[dask]'")
    results: dict[str, dict] = {}
    docs: dict[str, str] = {}
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "run"
        for name in kinds:
            executor = make_executor(name, workers)
            start = time.perf_counter()
            doc = sweep(sweep_args(args.bench, str(run / "sweep"), args.sweep), executor, False)
            wall = time.perf_counter() - start
            run.rename(Path(tmp) / name)  # the next executor writes to the same path
            docs[name] = json.dumps(reproducible(doc))
            results[name] = {
                "wall_s": wall,
                "points": doc["points_run"],
                "per_point_s": wall / doc["points_run"],
                "status": doc["status"],
                "executor": doc["executor"],
                "load_average_after": os.getloadavg(),
            }
            if not args.json:
                print(f"{name:>8}: {doc['points_run']} points in {wall:.1f} s "
                      f"({wall / doc['points_run']:.2f} s per point), load average after "
                      f"{os.getloadavg()[0]:.2f}", file=sys.stderr)  # fmt: skip
    same = len(set(docs.values())) == 1
    base = results[kinds[0]]["wall_s"]
    report = {
        "sweep": args.sweep,
        "bench": args.bench,
        "cpus": os.cpu_count(),
        "workers": workers,
        "load_average_before": load_before,
        "load_average_after": os.getloadavg(),
        **{f"{k}_s": r["wall_s"] for k, r in results.items()},
        "speedup": {k: base / r["wall_s"] for k, r in results.items()},
        "identical_results": same,
        "notes": notes,
        "runs": results,
    }
    if args.json:
        print(json.dumps(report))
    else:
        times = ", ".join(
            f"{k} {r['wall_s']:.1f} s ({base / r['wall_s']:.2f}x)" for k, r in results.items()
        )
        print(
            f"sweep {args.sweep} over {args.bench}, {workers} workers on {report['cpus']} CPUs "
            f"(load average {load_before[0]:.2f} before, {os.getloadavg()[0]:.2f} after): "
            f"{times}; results identical: {same}" + "".join(f"; {n}" for n in notes)
        )
    return 0 if same and all(r["status"] == "complete" for r in results.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
