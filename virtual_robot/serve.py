"""`virtual-robot serve`: the virtual robot behind a bench's transport, until told to stop.

Builds the :class:`~virtual_robot.robot.VirtualRobot` of the bench (robot, effects, time mode,
period), opens the transport the bench names and announces it once it is ready, then serves:

* ``can``/``slcan``: :class:`SlcanPtyBus`, LAWICEL slcan on a pty; channel = the pty slave
  (e.g. /dev/pts/7), for ``can.Bus(interface="slcan", channel=..., bitrate=1000000)``.
* ``can``/``socketcand``: :class:`SocketcandHub` on 127.0.0.1; channel = "127.0.0.1:PORT",
  interface_channel = "can0", also host and port.
* ``can``/``socketcan``: python-can socketcan; channel = the bench's channel or "vcan0"
  (``moteus``: with CAN-FD frames, on an interface of MTU 72, drivers.links.open_socketcan).
* ``moteus``/``fdcanusb``: :class:`FdcanusbPtyBus`, the fdcanusb line protocol on a pty.
* ``can``/``virtual``: python-can virtual (same process only); channel = bench's or "ddbench".
* ``serial``: :func:`virtual_robot.serial_server.serve_serial` (announces for itself).

The announcement (one dict, the CLI prints it as one JSON line) for CAN links:
``{"event": "ready", "protocol": "can", "transport", "channel", "bench", "mode", "period_s",
"seed", "pid", "nodes", "bitrate"}`` plus ``interface_channel``, ``host``, ``port`` for socketcand.

The CAN links are served by :class:`CanDriveServer` (CiA 301/402, see can_server.py), or by
:class:`~virtual_robot.mit_server.MitDriveServer` on a bench with ``protocol = "mit"``
(T-Motor/CubeMars MIT mode, mit_server.py; the same transports but socketcand), or by
:class:`~virtual_robot.odrive_server.OdriveServer` with ``protocol = "odrive"`` (ODrive
CANSimple, odrive_server.py; the same transports as MIT mode), or by
:class:`~virtual_robot.moteus_server.MoteusServer` with ``protocol = "moteus"`` (mjbots
register protocol over CAN-FD: fdcanusb or socketcan). In
lockstep the drives' command watchdog counts SYNCs (robot time stands still without them), so
a wall-clock host-silence watchdog of the bench's ``timeout_s`` (the time the host itself waits
for the robot in lockstep) disables the drives when the host hangs; in realtime the drives'
own watchdog covers it. However serving ends (stop, signal, host gone), the drives are
disabled at zero torque first. A bench with
``pace_bus = true`` gives the server a :class:`~virtual_robot.bus_pacing.BusPacer` at the
bench's ``bitrate``: every frame then takes its bit time on the virtual bus, both ways (the
announcement says ``"pace_bus"``; the bus load is logged on stderr when the server stops).
"""

from __future__ import annotations

import gc
import json
import os
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import can

from drivers.protocol import cia402 as co
from profiles.bench import BenchProfile, check_drive_protocol
from profiles.effects import load_effects
from profiles.robot import load_any_robot
from profiles.timing_faults import combine
from virtual_robot.bus_pacing import BusPacer
from virtual_robot.can_server import CanDriveServer
from virtual_robot.mit_server import MitDriveServer
from virtual_robot.moteus_server import MoteusServer
from virtual_robot.odrive_server import OdriveServer
from virtual_robot.robot import LOCKSTEP, REALTIME, VirtualRobot
from virtual_robot.timing_faults import EventLog, RobotTiming

SOCKETCAND_CHANNEL = "can0"


def _stderr(line: str) -> None:
    print(f"virtual-robot: {line}", file=sys.stderr, flush=True)


def build_core(
    bench: BenchProfile,
    *,
    effects: str | None,
    mode: str | None,
    seed: int | None = None,
    initial_q: Sequence[float] | None = None,
) -> VirtualRobot:
    """The virtual robot of a bench: robot profile, effects, time mode and period, and the
    timing faults of the bench and effects profiles (seeded by ``seed``, else the profile's);
    the arm at rest at ``initial_q`` (default: every joint at 0)."""
    mode = mode or bench.mode
    effects_profile = load_effects(effects or bench.effects)
    faults = combine(bench.timing_faults, effects_profile.timing_faults)
    timing = None
    if faults is not None:
        # in realtime the host imposes its own side's faults; in lockstep the robot imposes
        # every delay, in simulated time (virtual_robot/timing_faults.py)
        lockstep_delays = mode == LOCKSTEP and faults.host.delays
        if faults.robot.active or faults.trace is not None or lockstep_delays:
            timing = RobotTiming(
                faults, lockstep=mode == LOCKSTEP, period_s=bench.period_s, seed=seed
            )
    robot = load_any_robot(bench.robot)
    check_drive_protocol(bench, robot.drives, robot.source)
    return VirtualRobot(
        robot,
        effects_profile,
        mode=mode,
        period_s=bench.period_s,
        clock=time.monotonic if mode == REALTIME else None,
        timing=timing,
        q0=initial_q,
    )


def _safe_stop(core: VirtualRobot, log: Callable[[str], None]) -> None:
    """Zero torque, drives disabled: every way serving ends goes through here."""
    try:
        core.disable_all()
    except Exception as exc:  # a core in a bad state must not hide why serving ended
        log(f"disabling the drives failed: {type(exc).__name__}: {exc}")


def _finish(core: VirtualRobot, log: Callable[[str], None]) -> None:
    """Close the event log; say what the injected timing faults did."""
    if isinstance(core.event_log, EventLog):
        core.event_log.close()
    if core.timing is not None:
        log(f"timing faults: {json.dumps(core.timing.describe())}")


def _watch_resets(
    core: VirtualRobot, reset: threading.Event, stop: threading.Event, log: Callable[[str], None]
) -> None:
    """A daemon thread: on every ``reset``, :meth:`VirtualRobot.reset_faults` and one line."""

    def watch() -> None:
        while not stop.is_set():
            if not reset.wait(0.1):
                continue
            reset.clear()
            cleared = core.reset_faults()
            codes = ", ".join(f"0x{code:04X}" for code in cleared)
            log(f"drive faults reset ({codes})" if cleared else "reset asked: no drive in FAULT")

    threading.Thread(target=watch, name="fault-reset", daemon=True).start()


def serve(
    bench: BenchProfile,
    *,
    effects: str | None,
    mode: str | None,
    seed: int | None,
    announce: Callable[[dict[str, Any]], None],
    stop: threading.Event,
    log: Callable[[str], None] | None = None,
    event_log: str | Path | None = None,
    initial_q: Sequence[float] | None = None,
    reset: threading.Event | None = None,
) -> int:
    """Serve the bench's virtual robot until ``stop`` is set; returns the exit status (0).

    ``announce`` is called once, when the transport is ready, with
    ``{"event": "ready", "protocol", "transport", "channel", ...}``. ``seed`` is recorded in the
    announcement and seeds the injected timing faults, if any. ``event_log``: realtime, a file
    for the robot's own times of its samples and of the host's commands (``hil replay``).
    ``initial_q``: the arm's position at rest when serving starts (an experiment's
    ``initial_q_rad``; default 0 on every joint). ``reset``: each time it is set (SIGUSR1 in
    the CLI), the drives' faults are reset and logged, as a host's fault reset would.
    """
    log = log or _stderr
    core = build_core(bench, effects=effects, mode=mode, seed=seed, initial_q=initial_q)
    if reset is not None:
        _watch_resets(core, reset, stop, log)
    # robot times, for `hil replay`; not over MIT mode, whose drives sample at every frame (the
    # host's stamps then give the sample and command times, drivers.realtime_times)
    if event_log is not None and core.mode == REALTIME and not core.own_loop:
        core.event_log = EventLog(event_log)
    if core.mode == REALTIME:
        # no cyclic-GC pauses between deadlines: everything built so far is frozen out of the
        # collector's view, and the serving loop allocates no reference cycles to collect
        gc.collect()
        gc.freeze()
        gc.disable()
    if bench.protocol == "serial":
        from virtual_robot.serial_server import serve_serial

        try:
            return serve_serial(core, bench, announce=announce, stop=stop)
        finally:
            _safe_stop(core, log)
            _finish(core, log)

    info: dict[str, Any] = {
        "event": "ready",
        "protocol": bench.protocol,
        "transport": bench.transport,
        "channel": "",
        "bench": bench.name,
        "mode": core.mode,
        "period_s": core.host_period_s,
        "seed": seed,
        "pid": os.getpid(),
    }
    info["nodes"] = sorted(core.by_node)
    info["bitrate"] = bench.bitrate
    info["pace_bus"] = bench.pace_bus
    closers: list[Callable[[], None]] = []
    try:
        if bench.transport == "slcan":
            from virtual_robot.slcan_device import SlcanPtyBus

            bus: can.BusABC = SlcanPtyBus()
            info["channel"] = bus.channel_path
        elif bench.transport == "fdcanusb":
            from virtual_robot.fdcanusb_device import FdcanusbPtyBus

            bus = FdcanusbPtyBus()
            info["channel"] = bus.channel_path
        elif bench.transport == "socketcand" and bench.protocol == "can":
            from virtual_robot.socketcand_hub import SocketcandHub

            def sync_conflict(reason: str) -> None:  # the run is corrupt: stop it, say why
                core.fault_all(co.ERR_COMMUNICATION)
                log(f"{reason}; drives faulted (0x{co.ERR_COMMUNICATION:04X}), run stopped")

            def host_gone(reason: str) -> None:
                core.disable_all()
                log(f"{reason}; drives disabled")

            hub = SocketcandHub(
                "127.0.0.1",
                0,
                channel=SOCKETCAND_CHANNEL,
                log=log,
                on_sync_conflict=sync_conflict,
                on_sync_source_gone=host_gone,
            )
            closers.append(hub.close)
            bus = hub.robot_bus()
            info.update(
                channel=f"{hub.host}:{hub.port}",
                interface_channel=SOCKETCAND_CHANNEL,
                host=hub.host,
                port=hub.port,
            )
        elif bench.transport == "socketcan":
            from drivers.links import open_socketcan

            channel = bench.channel or "vcan0"
            bus = open_socketcan(channel, fd=bench.protocol == "moteus")
            info["channel"] = channel
        elif bench.transport == "virtual":
            channel = bench.channel or "ddbench"
            bus = can.Bus(interface="virtual", channel=channel)
            info["channel"] = channel
        else:
            raise ValueError(f"unknown CAN transport {bench.transport!r}")
        closers.insert(0, bus.shutdown)
        idle = bench.timeout_s if core.mode == LOCKSTEP else None
        server: CanDriveServer | MitDriveServer | OdriveServer | MoteusServer
        if bench.protocol == "moteus":
            server = MoteusServer(core, bus, idle_timeout_s=idle, log=log)
        elif bench.protocol == "mit":
            server = MitDriveServer(core, bus, idle_timeout_s=idle, log=log)
        elif bench.protocol == "odrive":
            server = OdriveServer(core, bus, idle_timeout_s=idle, log=log)
        else:
            server = CanDriveServer(
                core,
                bus,
                idle_timeout_s=idle,
                log=log,
                pacer=BusPacer(bench.bitrate) if bench.pace_bus else None,
            )
        announce(info)
        server.serve_forever(stop)
        return 0
    finally:
        _safe_stop(core, log)
        for close in closers:
            close()
        _finish(core, log)
