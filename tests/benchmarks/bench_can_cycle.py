"""Benchmark: one CAN cycle, canopen's PDO machinery vs PDOs packed with python-can (`make bench`).

Both paths run over a python-can ``virtual`` bus against the lockstep virtual robot and its
CanDriveServer (threads of this process), after the same set-up by :class:`CanArm` (NMT, PDO map
by SDO, enable). One cycle = RPDO1 to each of the 2 drives (controlword + target torque), SYNC,
wait for TPDO1 + TPDO2 of both drives, decode into rad / status:

* ``raw``: :meth:`CanArm.cycle` (PDOs packed with precompiled structs, RPDOs and SYNC sent
  together, the feedback read by the calling thread itself in lockstep; clamp, units, limit
  checks included);
* ``canopen``: ``node.rpdo[1]`` variables + ``PdoMap.transmit()``, ``network.sync.transmit()``,
  TPDO callbacks (on CanArm's receive thread, the one canopen's SDO uses) counting the four
  frames, then ``node.tpdo[n][index].raw`` and the same unit conversions (the PDO maps are read
  back from the drives by SDO with ``PdoMap.read()``).

Prints the median µs/cycle of each over several repeats; ``--json`` prints one JSON document.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import threading
import time
import uuid
from collections.abc import Callable

import can

from drivers.arm import SafetyLimits
from drivers.can_arm import CanArm
from drivers.protocol import cia402 as co
from drivers.units import counts_to_rad, position_to_rad, torque_to_permille
from profiles.drive import load_drive
from profiles.robot import load_robot
from virtual_robot.can_server import CanDriveServer
from virtual_robot.robot import VirtualRobot

H = 0.0025
LIMITS = SafetyLimits((200.0, 15.0), (12.0, 25.0), ((-1e9, 1e9), (-1e9, 1e9)))
TAU = (5.0, 0.5)


def _rig() -> tuple[CanDriveServer, can.BusABC, CanArm]:
    channel = f"bench-can-{uuid.uuid4().hex}"
    robot = load_robot("cicese")
    server_bus = can.Bus(interface="virtual", channel=channel)
    server = CanDriveServer(VirtualRobot(robot, period_s=H), server_bus)
    server.start()
    arm = CanArm(
        lambda: can.Bus(interface="virtual", channel=channel),
        [load_drive(name) for name in robot.drives],
        period_s=H,
        mode="lockstep",
        timeout_s=2.0,
        limits=LIMITS,
    )
    arm.open()
    arm.enable()
    arm.start()
    return server, server_bus, arm


def _teardown(server: CanDriveServer, server_bus: can.BusABC, arm: CanArm) -> None:
    arm.safe_stop()
    arm.close()
    server.stop()
    server_bus.shutdown()


class CanopenCycle:
    """The same cycle through canopen's PDO objects (maps read back from the drives by SDO)."""

    def __init__(self, arm: CanArm) -> None:
        assert arm.network is not None
        self.arm, self.network = arm, arm.network
        self.lock = threading.Lock()
        self.done = threading.Event()
        self.pending = 0
        self.expected = 2 * len(arm.nodes)
        self.maps = []
        for node in arm.nodes:
            node.rpdo.read()  # the configuration CanArm wrote, read back by SDO
            node.tpdo.read()  # ... and subscribed on the network
            for n in (1, 2):
                node.tpdo[n].add_callback(self._on_tpdo)
                self.maps.append(node.tpdo[n])
        self.rated = [p.rated_torque_Nm for p in arm.drives]
        self.cpr = [p.counts_per_rev for p in arm.drives]

    def _on_tpdo(self, _map: object) -> None:
        with self.lock:
            self.pending -= 1
            if self.pending == 0:
                self.done.set()

    def activate(self, on: bool) -> None:
        """canopen blocks: TPDO maps subscribed, CanArm's own frame handling off, its receive
        thread reading; raw blocks: the reverse (CanArm.cycle reads the bus itself)."""
        for pdo_map in self.maps:
            callbacks = self.network.subscribers.get(pdo_map.cob_id, [])
            if on and pdo_map.on_message not in callbacks:
                self.network.subscribe(pdo_map.cob_id, pdo_map.on_message)
            elif not on and pdo_map.on_message in callbacks:
                self.network.unsubscribe(pdo_map.cob_id, pdo_map.on_message)
        if on:
            self.arm._threaded_receive()
            self.arm._on_frame = _ignore  # type: ignore[method-assign]  # canopen only
        else:
            self.arm.__dict__.pop("_on_frame", None)

    def cycle(self, tau: tuple[float, float]) -> tuple[list[float], list[int]]:
        for node, t, r in zip(self.arm.nodes, tau, self.rated, strict=True):
            rpdo = node.rpdo[1]
            rpdo[0x6040].raw = co.CW_ENABLE_OPERATION
            rpdo[0x6071].raw = torque_to_permille(t, r)
            rpdo.transmit()
        with self.lock:
            self.pending = self.expected
            self.done.clear()
        self.network.sync.transmit()
        if not self.done.wait(2.0):
            raise RuntimeError("no TPDOs")
        q, status = [], []
        for node, c in zip(self.arm.nodes, self.cpr, strict=True):
            status.append(node.tpdo[1][0x6041].raw)
            q.append(position_to_rad(node.tpdo[1][0x6064].raw, c))
            counts_to_rad(node.tpdo[2][0x606C].raw, c)
        return q, status


def _ignore(_msg: can.Message) -> None:
    """CanArm's frame handler while canopen's PDO machinery has the bus."""


def _cpu_clock(thread: threading.Thread | None) -> Callable[[], float]:
    """CPU seconds of one thread (Linux pthread CPU clocks); NaN where not available."""
    try:
        assert thread is not None and thread.ident is not None
        clock_id = time.pthread_getcpuclockid(thread.ident)
    except (AssertionError, AttributeError, OSError):
        return lambda: math.nan
    return lambda: time.clock_gettime(clock_id)


def measure(cycles: int, blocks: int) -> dict[str, list[float]]:
    """Alternating blocks of raw and canopen cycles on one rig (load drift hits both alike).

    Per block and per cycle: wall µs, and CPU µs of the host's main thread, the host's
    receive thread (the listeners, when it reads) and the server thread.
    """
    server, server_bus, arm = _rig()
    assert arm._receiver is not None
    clocks = {
        "main": _cpu_clock(threading.current_thread()),
        "receiver": _cpu_clock(arm._receiver._thread),
        "server": _cpu_clock(server._thread),
    }
    out: dict[str, list[float]] = {}
    try:
        alt = CanopenCycle(arm)
        for name, step in (("raw", arm.cycle), ("canopen", alt.cycle)) * blocks:
            alt.activate(name == "canopen")
            for _ in range(20):  # warm-up after the switch
                step(TAU)
            wall = time.perf_counter()
            cpu0 = {k: c() for k, c in clocks.items()}
            for _ in range(cycles):
                step(TAU)
            out.setdefault(f"{name}_wall", []).append((time.perf_counter() - wall) / cycles * 1e6)
            for k, c in clocks.items():
                out.setdefault(f"{name}_{k}", []).append((c() - cpu0[k]) / cycles * 1e6)
        alt.activate(False)
    finally:
        _teardown(server, server_bus, arm)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=250, help="cycles per block")
    parser.add_argument("--blocks", type=int, default=8, help="blocks of each kind, alternating")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    runs = measure(args.cycles, args.blocks)
    med = {k: round(statistics.median(v), 1) for k, v in runs.items()}
    host = {n: round(med[f"{n}_main"] + med[f"{n}_receiver"], 1) for n in ("raw", "canopen")}
    result = {
        "cycles_per_block": args.cycles,
        "blocks": args.blocks,
        "us_per_cycle": med,
        "host_cpu_us_per_cycle": host,
        "choice": "raw" if host["raw"] <= host["canopen"] else "canopen",
    }
    if args.json:
        print(json.dumps(result))
        return 0
    print(
        "CAN cycle over the python-can virtual bus, lockstep robot + server in-process, 2 drives;"
    )
    print(f"median of {args.blocks} alternating blocks of {args.cycles} cycles, µs per cycle:")
    print("                                  wall   host CPU  (main + receiver)   server CPU")
    for n, label in (
        ("raw", "raw python-can (CanArm.cycle)"),
        ("canopen", "canopen PDO machinery"),
    ):
        print(
            f"  {label:30s}{med[f'{n}_wall']:6.0f}   {host[n]:8.0f}  "
            f"({med[f'{n}_main']:4.0f} + {med[f'{n}_receiver']:4.0f})         "
            f"{med[f'{n}_server']:6.0f}"
        )
    print(f"  less host CPU: {result['choice']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
