"""Where the realtime stalls over the pty transports come from (issue 13): a bare round trip.

Two processes ping-pong one cycle's worth of slcan text (two RPDO lines, 30 bytes) every
millisecond, each blocked in ``select`` (no polling, one write per direction), over

* a pty (raw), as the virtual robot's slcan and serial transports do, and
* a Unix socketpair, which wakes the reader directly,

with both processes at SCHED_FIFO (where permitted) or at normal priority, beside ``--hogs``
CPU-bound processes at ``--hog-nice``. On Linux a pty's write does not wake the reader: it
queues the tty flip buffer's work (``flush_to_ldisc``) on an unbound kernel workqueue, and a
kworker at normal priority moves the bytes. SCHED_FIFO on both ends does not cover that worker,
so beside CPU-bound jobs every direction of every cycle waits for its turn on a CPU; the
socketpair shows what the same two processes get without it.

    python tests/benchmarks/bench_pty_rtt.py [--seconds 20] [--hogs 2] [--hog-nice 0] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import select
import socket
import subprocess
import sys
import time
import tty
from typing import Any

import numpy as np

MESSAGE = b"t2014000000000\rt2024000000000\r"  # two RPDOs, as one slcan write


def _echo(fd: int) -> None:
    while True:
        select.select([fd], [], [])
        data = os.read(fd, 4096)
        if data == b"q":
            os._exit(0)
        os.write(fd, data)


def round_trips(kind: str, seconds: float, fifo: bool) -> dict[str, Any]:
    """Ping-pong for ``seconds``; the round-trip distribution (µs) and the long ones."""
    if kind == "pty":
        a, b = os.openpty()
        tty.setraw(b)
    else:
        x, y = socket.socketpair()
        a, b = x.detach(), y.detach()
    policy = "SCHED_OTHER"
    pid = os.fork()
    if fifo:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
            policy = "SCHED_FIFO"
        except OSError as exc:
            policy = f"SCHED_OTHER (SCHED_FIFO refused: {exc.strerror})"
    if pid == 0:
        _echo(b)
    rtt = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        t0 = time.monotonic()
        os.write(a, MESSAGE)
        got = 0
        while got < len(MESSAGE):
            select.select([a], [], [])
            got += len(os.read(a, 4096))
        rtt.append(time.monotonic() - t0)
        time.sleep(0.001)
    os.write(a, b"q")
    os.waitpid(pid, 0)
    if fifo:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    r = np.asarray(rtt) * 1e6
    return {
        "link": kind,
        "policy": policy,
        "round_trips": int(r.size),
        "median_us": float(np.median(r)),
        "p99_us": float(np.percentile(r, 99)),
        "p999_us": float(np.percentile(r, 99.9)),
        "max_us": float(r.max()),
        "over_5ms": int((r > 5e3).sum()),
        "over_20ms": int((r > 20e3).sum()),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=20.0, help="per case")
    p.add_argument("--hogs", type=int, default=2, help="CPU-bound processes beside the cases")
    p.add_argument("--hog-nice", type=int, default=0, help="their nice value")
    p.add_argument("--policies", default="fifo,other")
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    hogs = [
        subprocess.Popen(
            ["nice", "-n", str(args.hog_nice), sys.executable, "-c", "while True: pass"]
        )
        for _ in range(args.hogs)
    ]
    results = []
    try:
        for policy in args.policies.split(","):
            for kind in ("pty", "socketpair"):
                results.append(round_trips(kind, args.seconds, policy == "fifo"))
                results[-1]["load_average"] = os.getloadavg()[0]
    finally:
        for hog in hogs:
            hog.kill()
        for hog in hogs:
            hog.wait()
    if args.json:
        print(json.dumps({"hogs": args.hogs, "hog_nice": args.hog_nice, "results": results}))
        return 0
    print(f"round trip of one slcan write, every 1 ms, beside {args.hogs} CPU hogs at nice "
          f"{args.hog_nice} (µs)")  # fmt: skip
    print(f"{'link':<12}{'policy':<12}{'n':>7}{'median':>8}{'p99':>8}{'p99.9':>8}{'max':>8}"
          f"{'>5 ms':>7}{'>20 ms':>7}{'load':>6}")  # fmt: skip
    for r in results:
        print(
            f"{r['link']:<12}{r['policy'][:11]:<12}{r['round_trips']:>7}{r['median_us']:>8.0f}"
            f"{r['p99_us']:>8.0f}{r['p999_us']:>8.0f}{r['max_us']:>8.0f}{r['over_5ms']:>7}"
            f"{r['over_20ms']:>7}{r['load_average']:>6.1f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
