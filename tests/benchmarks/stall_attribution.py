"""Which way a realtime CAN run's late feedback was late: host → robot, or robot → host.

Reads a realtime run directory over a virtual CAN bench (``bus.log`` with the host's stamps of
each SYNC it sent and each TPDO it read, and the virtual robot's ``robot-events.csv`` with its
own time of each sample) and splits every cycle's feedback wait into

* **up**: the host wrote the SYNC → the robot sampled on it (the host's write, the link towards
  the robot: over a pty, the kernel worker that moves the bytes, then the robot's reader thread
  and its lock), and
* **down**: the robot sampled → the host had the last TPDO (the robot's packing and write, the
  link back, the host's receive thread).

The two processes' clocks differ by an unknown offset (bus.log is wall time, the robot's is its
own monotonic time since it started), so each part is given above its own minimum over the run:
the figures are the extra delay of each direction, which is what a stall is.

    python tests/benchmarks/stall_attribution.py RUN_DIR [--worst 10]
"""

from __future__ import annotations

import argparse
import csv
import re
import sys
from pathlib import Path

import numpy as np

LINE = re.compile(r"\((\d+\.\d+)\) \S+ ([0-9A-Fa-f]+)#\S* ([TR])")
TPDO_IDS = {0x181, 0x182, 0x281, 0x282}  # TPDO1 and TPDO2 of nodes 1 and 2


def split(run: Path) -> dict[str, np.ndarray]:
    syncs: list[float] = []
    feedback: list[float] = []
    with open(run / "bus.log") as f:
        for line in f:
            m = LINE.match(line)
            if m is None:
                continue
            t, can_id, direction = float(m[1]), int(m[2], 16), m[3]
            if can_id == 0x080 and direction == "T":
                syncs.append(t)
                feedback.append(np.nan)
            elif direction == "R" and can_id in TPDO_IDS and syncs:
                feedback[-1] = t  # the last TPDO read after this SYNC
    with open(run / "robot-events.csv") as f:
        samples = [float(r["t"]) for r in csv.DictReader(f) if r["event"] == "sample"]
    n = min(len(syncs), len(samples))
    if n == 0:
        raise SystemExit(f"{run}: no SYNC in bus.log or no sample in robot-events.csv")
    # both logs end with the run's last SYNC: pair them from the end
    sync = np.asarray(syncs[-n:])
    sample = np.asarray(samples[-n:])
    fb = np.asarray(feedback[-n:])
    up = sample - sync
    up -= np.nanmin(up)
    down = fb - sync - up
    down -= np.nanmin(down)
    return {"wait": fb - sync, "up": up, "down": down}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run", type=Path)
    p.add_argument("--worst", type=int, default=10)
    args = p.parse_args()
    s = split(args.run)
    wait, up, down = s["wait"], s["up"], s["down"]
    for name, v in (("wait", wait), ("up", up), ("down", down)):
        print(
            f"{name:5s} median {np.nanmedian(v) * 1e3:6.2f}  "
            f"p99 {np.nanpercentile(v, 99) * 1e3:6.2f}  max {np.nanmax(v) * 1e3:7.2f} ms"
        )
    late = wait > 0.005
    print(
        f"{int(late.sum())} cycles waited > 5 ms: up the larger part in "
        f"{int((up[late] > down[late]).sum())}, down in {int((down[late] >= up[late]).sum())}"
    )
    print(f"worst {args.worst} cycles (ms): wait = up + down (each above its minimum)")
    for i in sorted(np.argsort(-np.nan_to_num(wait, nan=np.inf))[: args.worst]):
        print(f"  cycle {i:6d}: {wait[i] * 1e3:7.1f} = {up[i] * 1e3:7.1f} + {down[i] * 1e3:7.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
