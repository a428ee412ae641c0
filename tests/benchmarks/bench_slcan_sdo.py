"""Benchmark: SDO round trip over slcan, drivers.slcan.SelectSlcanBus vs python-can's slcanBus.

Starts ``virtual-robot serve --bench virtual-slcan`` (LAWICEL on a pty), then times expedited SDO
uploads of 0x6041 (statusword) from node 1 through each bus class in turn: request on 0x601,
wait for the answer on 0x581. Prints the median µs per round trip of each, and the CPU seconds
each class's process spent idle in ``recv(0.5)`` for 3 s (python-can's read polls).

    python tests/benchmarks/bench_slcan_sdo.py [--n 2000] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

import can
from can.interfaces.slcan import slcanBus

from drivers.protocol import cia402 as co
from drivers.slcan import SelectSlcanBus


def _round_trips(bus: slcanBus, n: int) -> list[float]:
    request = can.Message(
        arbitration_id=co.SDO_RX_BASE + 1,
        is_extended_id=False,
        data=co.sdo_upload_request(0x6041, 0),
    )
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        bus.send(request)
        while True:
            msg = bus.recv(1.0)
            if msg is None:
                raise RuntimeError("no SDO answer within 1 s")
            if msg.arbitration_id == co.SDO_TX_BASE + 1:
                break
        out.append(time.perf_counter() - t0)
    return out


def _idle_cpu(bus: slcanBus, seconds: float) -> float:
    t0, c0 = time.monotonic(), time.process_time()
    while time.monotonic() - t0 < seconds:
        bus.recv(0.5)
    return time.process_time() - c0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=2000, help="round trips per class")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    robot = subprocess.Popen(
        [sys.executable, "-m", "virtual_robot.cli", "serve", "--bench", "virtual-slcan"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        info = json.loads(robot.stdout.readline())
        result = {}
        for name, cls in (("override", SelectSlcanBus), ("python-can", slcanBus)):
            bus = cls(channel=info["channel"], bitrate=1_000_000, sleep_after_open=0)
            try:
                _round_trips(bus, 50)  # warm up
                times = _round_trips(bus, args.n)
                idle = _idle_cpu(bus, 3.0)
            finally:
                bus.shutdown()
            result[name] = {
                "sdo_round_trip_us_median": round(statistics.median(times) * 1e6, 1),
                "idle_cpu_s_over_3s": round(idle, 3),
            }
    finally:
        robot.terminate()
        robot.wait(10)
    if args.json:
        print(json.dumps(result))
    else:
        for name, r in result.items():
            print(
                f"{name:>10}: SDO round trip {r['sdo_round_trip_us_median']:.0f} µs (median), "
                f"idle recv CPU {r['idle_cpu_s_over_3s']:.2f} s over 3 s"
            )
    return 0


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
