"""Loop timing benchmark (`make bench`): `hil jitter` at 400 Hz and 1 kHz over the pty benches.

Targets (issue 6), per run of 60 s:
* with a real-time policy (SCHED_FIFO granted): p99 release error ≤ 50 µs and ≤ 1 overrun
  (period > 1.5 h) per 10,000 cycles;
* without (``--realtime-policy off``, or refused): p99 release error ≤ 500 µs;
* command-to-feedback latency over the pty transports: median ≤ 150 µs, p99 ≤ 1 ms.
The max is reported, not gated (the VM alone stalls for milliseconds now and then).

"Period error" here is the release error against the absolute deadline (what the scheduler
controls); the period-to-period error is printed beside it. The copies of the benches wait 20
periods for feedback (as bench_hil.py's), so that a VM stall is measured rather than ending the
run. The machine's load is printed with each run: other jobs on it change everything.

    python tests/benchmarks/bench_jitter.py [--seconds 60] [--rates 400,1000]
        [--benches virtual-slcan,virtual-serial] [--policies auto,off] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

from hil.timing.jitter_cli import measure

nan = float("nan")


def targets(entry: dict[str, Any]) -> dict[str, bool]:
    fifo = entry["policy"] == "SCHED_FIFO"
    release_limit = 50.0 if fifo else 500.0
    met = {
        f"p99 release error <= {release_limit:g} us": entry["p99_release_error_us"]
        <= release_limit,
        "latency median <= 150 us": entry["latency_median_us"] <= 150.0,
        "latency p99 <= 1000 us": entry["latency_p99_us"] <= 1000.0,
    }
    if fifo:
        met["overruns <= 1 per 10k"] = entry["overruns_per_10k"] <= 1.0
    return met


def run_one(bench: str, rate: float, seconds: float, policy: str, out: Path) -> dict[str, Any]:
    s = measure(
        bench,
        rate,
        seconds,
        out,
        realtime_policy=policy,
        plot=False,
        progress=False,
    )
    t, sched, m = s["timing"], s["scheduler"], s["machine"]
    entry: dict[str, Any] = {
        "bench": bench,
        "rate_hz": rate,
        "requested": policy,
        "policy": sched.get("policy"),
        "memory_locked": sched.get("memory_locked"),
        "status": s["status"],
        "reason": s["reason"],
        "cycles": t["cycles"],
        "p99_release_error_us": t["release_error"].get("p99_us", float("nan")),
        "p999_release_error_us": t["release_error"].get("p999_us", float("nan")),
        "max_release_error_us": t["release_error"].get("max_us", float("nan")),
        "p99_period_error_us": t["period_error"].get("p99_us", float("nan")),
        "overruns": t["overruns"],
        "overruns_per_10k": t["overruns_per_10k"] if t["overruns_per_10k"] is not None else nan,
        "deadline_misses_per_10k": t["deadline_misses_per_10k"],
        "latency_median_us": t["latency"].get("median_us", float("nan")),
        "latency_p99_us": t["latency"].get("p99_us", float("nan")),
        "latency_max_us": t["latency"].get("max_us", float("nan")),
        "spin_us_per_cycle": sched.get("mean_spin_us"),
        "load_average": [m["load_average_start"][0], m["load_average_end"][0]],
    }
    if s.get("bus") and s["bus"].get("frames"):
        entry["bus_load_pct"] = s["bus"]["load_pct"]
    entry["targets"] = targets(entry)
    return entry


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--rates", default="400,1000")
    parser.add_argument("--benches", default="virtual-slcan,virtual-serial")
    parser.add_argument("--policies", default="auto,off")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for bench in args.benches.split(","):
            for rate in (float(r) for r in args.rates.split(",")):
                for policy in args.policies.split(","):
                    name = f"{bench} {rate:g} Hz {policy}"
                    print(f"running {name} for {args.seconds:g} s ...", file=sys.stderr)
                    out = Path(tmp) / name.replace(" ", "-")
                    results.append(run_one(bench, rate, args.seconds, policy, out))
    ok = all(e["status"] == "complete" and all(e["targets"].values()) for e in results)
    if args.json:
        print(json.dumps({"results": results, "all_targets_met": ok}))
        return 0  # report, do not stop `make bench`: the VM's stalls decide the tail
    head = (
        f"{'run':<34}{'policy':>12}{'p99 rel':>9}{'p99 per':>9}{'max rel':>9}{'ovr/10k':>9}"
        f"{'lat p50':>9}{'lat p99':>9}{'load':>11}  status"
    )
    print(head + "\n" + "-" * len(head))
    for e in results:
        missed = [k for k, v in e["targets"].items() if not v]
        print(
            f"{e['bench'] + ' ' + format(e['rate_hz'], 'g') + ' Hz':<34}"
            f"{(e['policy'] or '?').replace('SCHED_', ''):>12}"
            f"{e['p99_release_error_us']:9.0f}{e['p99_period_error_us']:9.0f}"
            f"{e['max_release_error_us']:9.0f}{e['overruns_per_10k']:9.1f}"
            f"{e['latency_median_us']:9.0f}{e['latency_p99_us']:9.0f}"
            f"{e['load_average'][0]:5.2f}-{e['load_average'][1]:<5.2f}  "
            f"{e['status']}" + (f"; missed: {', '.join(missed)}" if missed else "")
        )
    print("(µs; p99 rel: release − deadline; p99 per: |period − h|; load: load average)")
    print("all targets met" if ok else "SOME TARGETS MISSED")
    return 0  # report, do not stop `make bench`: the VM's stalls decide the tail


if __name__ == "__main__":
    sys.exit(main())
