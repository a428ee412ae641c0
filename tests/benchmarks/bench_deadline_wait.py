"""The realtime scheduler's own release error, with and without its spin (issue 13).

`hil jitter`'s release error mixes the scheduler's wake-up with the link's lateness (a cycle whose
feedback came late is released late). This measures the wait alone: a thread under the policy
``hil`` takes (SCHED_FIFO 10 and the memory lock, where permitted) waits for absolute
deadlines t_0 + k·h with :class:`hil.bench.scheduler.DeadlineScheduler`, spinning (``on``: sleep
to a margin, then read the clock) or not (``off``: sleep to the deadline, what ``auto`` does
under SCHED_FIFO), in alternating blocks so that both see the same machine, beside ``--hogs``
CPU-bound processes. It reports, per variant, the release error (release − deadline)
distribution and the CPU time spun per cycle.

    python tests/benchmarks/bench_deadline_wait.py [--seconds 20] [--rate 1000] [--hogs 2]
        [--block 2] [--policy auto] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_jitter import cpu_hogs

from hil.bench.scheduler import DeadlineScheduler, acquire_realtime, release_realtime


def measure(seconds: float, rate: float, block_s: float, policy: str) -> dict[str, Any]:
    h = 1.0 / rate
    errors: dict[str, list[float]] = {"on": [], "off": []}
    spun: dict[str, float] = {"on": 0.0, "off": 0.0}
    got = acquire_realtime(policy)
    try:
        end = time.monotonic() + seconds
        variant = "on"
        while time.monotonic() < end:
            s = DeadlineScheduler(h, spin=variant == "on")
            t0 = s.start()
            for k in range(1, max(1, round(block_s * rate)) + 1):
                errors[variant].append(s.wait_for(k) - (t0 + k * h))
            spun[variant] += s.spun_s
            variant = "off" if variant == "on" else "on"
    finally:
        release_realtime(got)
    out: dict[str, Any] = {
        "policy": got.policy,
        "memory_locked": got.memory_locked,
        "rate_hz": rate,
        "load_average": os.getloadavg()[0],
    }
    for variant, e in errors.items():
        us = np.asarray(e) * 1e6
        out[f"spin {variant}"] = {
            "cycles": int(us.size),
            "median_us": float(np.median(us)),
            "p99_us": float(np.percentile(us, 99)),
            "p999_us": float(np.percentile(us, 99.9)),
            "max_us": float(us.max()),
            "spun_us_per_cycle": spun[variant] / max(1, us.size) * 1e6,
        }
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--rate", type=float, default=1000.0)
    p.add_argument("--hogs", type=int, default=2)
    p.add_argument("--block", type=float, default=2.0, help="seconds per block of one variant")
    p.add_argument("--policy", default="auto", choices=("auto", "off"))
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    with cpu_hogs(args.hogs):
        r = measure(args.seconds, args.rate, args.block, args.policy)
    r["hogs"] = args.hogs
    if args.json:
        print(json.dumps(r, indent=1))
        return 0
    print(
        f"deadline wait at {args.rate:g} Hz, {args.seconds:g} s, {r['policy']}"
        f"{' + mlock' if r['memory_locked'] else ''}, beside {args.hogs} CPU hogs "
        f"(load {r['load_average']:.1f}); release − deadline, µs"
    )
    print(
        f"{'spin':<6}{'cycles':>8}{'median':>8}{'p99':>8}{'p99.9':>8}{'max':>9}{'spun/cycle':>12}"
    )
    for variant in ("on", "off"):
        v = r[f"spin {variant}"]
        print(
            f"{variant:<6}{v['cycles']:>8}{v['median_us']:>8.1f}{v['p99_us']:>8.1f}"
            f"{v['p999_us']:>8.1f}{v['max_us']:>9.0f}{v['spun_us_per_cycle']:>12.1f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
