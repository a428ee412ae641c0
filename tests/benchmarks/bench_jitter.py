"""Loop timing benchmark (`make bench`): `hil jitter` at 400 Hz and 1 kHz over the pty benches.

Targets (issue 6), per run of 60 s:
* with a real-time policy (SCHED_FIFO granted): p99 release error ≤ 50 µs and ≤ 1 overrun
  (period > 1.5 h) per 10,000 cycles;
* without (``--realtime-policy off``, or refused): p99 release error ≤ 500 µs;
* command-to-feedback latency over the pty transports: median ≤ 150 µs, p99 ≤ 1 ms.
The max is reported, not gated (the VM alone stalls for milliseconds now and then).

"Period error" here is the release error against the absolute deadline (what the scheduler
controls); the period-to-period error is printed beside it. The benches are the shipped ones,
with their feedback budget (0.25 s) and the drives' watchdog (0.5 s): a stall shorter than the
budget is measured (late feedback, longest wait), a longer one ends the run and is counted. The
machine's load is printed with each run: other jobs on it change everything.

    python tests/benchmarks/bench_jitter.py [--seconds 60] [--rates 400,1000]
        [--benches virtual-slcan,virtual-serial] [--policies auto,off] [--json]
        [--hogs N] [--repeat N] [--spin on,off]

``--hogs N`` runs N CPU-bound processes (``python -c 'while True: pass'``, nice 0) beside every
run, started before it and killed after it; ``--repeat N`` runs every configuration N times and
adds, per configuration, how many runs completed and the late-cycle figures over the runs (the
issue-13 measurement: ``--hogs 2 --repeat 5 --policies auto``); the repeats go round-robin over
the configurations, so that the machine's changing load falls on all of them alike.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import subprocess
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


def run_one(
    bench: str, rate: float, seconds: float, policy: str, out: Path, spin: str = "on"
) -> dict[str, Any]:
    s = measure(
        bench,
        rate,
        seconds,
        out,
        realtime_policy=policy,
        spin=spin == "on",
        plot=False,
        progress=False,
    )
    t, sched, m = s["timing"], s["scheduler"], s["machine"]
    entry: dict[str, Any] = {
        "bench": bench,
        "rate_hz": rate,
        "requested": policy,
        "spin": spin,
        "wait": sched.get("method"),
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
        "late_feedback": t.get("late_feedback"),
        "max_feedback_wait_ms": 1e3 * t.get("max_feedback_wait_s", nan),
        "rows": s["rows"],
    }
    if s.get("bus") and s["bus"].get("frames"):
        entry["bus_load_pct"] = s["bus"]["load_pct"]
    entry["targets"] = targets(entry)
    return entry


@contextlib.contextmanager
def cpu_hogs(n: int):
    """``n`` CPU-bound processes for the duration of the block (killed and reaped after it)."""
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(max(0, n))]
    try:
        yield hogs
    finally:
        for hog in hogs:
            hog.kill()
        for hog in hogs:
            hog.wait()


def repeated(entries: list[dict[str, Any]]) -> dict[str, Any]:
    """One configuration over its runs: how many completed, and the late-cycle figures."""
    import numpy as np

    def spread(key: str) -> list[float]:
        v = [float(e[key]) for e in entries if e.get(key) is not None]
        return [float(np.min(v)), float(np.median(v)), float(np.max(v))] if v else []

    first = entries[0]
    return {
        "bench": first["bench"],
        "rate_hz": first["rate_hz"],
        "policy": first["policy"],
        "spin": first["spin"],
        "runs": len(entries),
        "completed": sum(e["status"] == "complete" for e in entries),
        "ended": [e["reason"] for e in entries if e["status"] != "complete"],
        "seconds_run": [round(e["rows"] / e["rate_hz"], 1) for e in entries],
        # min, median, max over the runs
        "deadline_misses_per_10k": spread("deadline_misses_per_10k"),
        "overruns_per_10k": spread("overruns_per_10k"),
        "late_feedback": spread("late_feedback"),
        "max_feedback_wait_ms": spread("max_feedback_wait_ms"),
        "latency_p99_us": spread("latency_p99_us"),
        "latency_max_us": spread("latency_max_us"),
        "p99_release_error_us": spread("p99_release_error_us"),
        "load_average": spread("load_average_start"),
    }


def _mmm(v: list[float]) -> str:
    return " / ".join(f"{x:.0f}" for x in v) if v else "-"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--rates", default="400,1000")
    parser.add_argument("--benches", default="virtual-slcan,virtual-serial")
    parser.add_argument("--policies", default="auto,off")
    parser.add_argument(
        "--spin",
        default="on",
        help="the deadline wait: on (sleep, then spin; the default) and/or off (sleep to the "
        "deadline), e.g. on,off for an A/B",
    )
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--hogs", type=int, default=0, help="CPU-bound processes beside each run")
    parser.add_argument("--repeat", type=int, default=1, help="runs per configuration")
    args = parser.parse_args()
    configs = [
        (bench, rate, policy, spin)
        for bench in args.benches.split(",")
        for rate in (float(r) for r in args.rates.split(","))
        for policy in args.policies.split(",")
        for spin in args.spin.split(",")
    ]
    runs: dict[tuple[str, float, str, str], list[dict[str, Any]]] = {c: [] for c in configs}
    repeat = max(1, args.repeat)
    with tempfile.TemporaryDirectory() as tmp:
        # round-robin over the configurations, so that a change in the machine's load (other
        # jobs) falls on all of them alike, not on the ones that happened to run then
        for i in range(repeat):
            for config in configs:
                bench, rate, policy, spin = config
                name = f"{bench} {rate:g} Hz {policy} spin {spin}"
                print(
                    f"running {name} for {args.seconds:g} s, run {i + 1}/{repeat}"
                    f" beside {args.hogs} CPU hogs ...",
                    file=sys.stderr,
                )
                out = Path(tmp) / f"{name.replace(' ', '-')}-{i}"
                with cpu_hogs(args.hogs):
                    entry = run_one(bench, rate, args.seconds, policy, out, spin)
                entry["load_average_start"] = entry["load_average"][0]
                entry["hogs"] = args.hogs
                print(
                    f"  {entry['status']}: {entry['rows']} rows, late feedback "
                    f"{entry['late_feedback']}, longest wait "
                    f"{entry['max_feedback_wait_ms']:.1f} ms"
                    + (f"; {entry['reason']}" if entry["reason"] else ""),
                    file=sys.stderr,
                )
                runs[config].append(entry)
    results = [e for c in configs for e in runs[c]]
    summaries = [repeated(runs[c]) for c in configs]
    ok = all(e["status"] == "complete" and all(e["targets"].values()) for e in results)
    if args.json:
        print(
            json.dumps(
                {"results": results, "configurations": summaries, "all_targets_met": ok},
                indent=1,
            )
        )
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
    if args.repeat > 1 or args.hogs:
        print(f"\nper configuration, {args.hogs} CPU hogs beside each run (min / median / max):")
        for c in summaries:
            print(
                f"{c['bench']} {c['rate_hz']:g} Hz {c['policy']} (spin {c['spin']}): "
                f"{c['completed']}/{c['runs']} "
                f"complete (s run: {c['seconds_run']}); "
                f"misses/10k {_mmm(c['deadline_misses_per_10k'])}; "
                f"late feedback {_mmm(c['late_feedback'])}; longest wait "
                f"{_mmm(c['max_feedback_wait_ms'])} ms; latency p99 {_mmm(c['latency_p99_us'])} µs"
            )
            for reason in c["ended"]:
                print(f"  ended: {reason}")
    print("all targets met" if ok else "SOME TARGETS MISSED")
    return 0  # report, do not stop `make bench`: the VM's stalls decide the tail


if __name__ == "__main__":
    sys.exit(main())
