"""From a bench profile to an :class:`~drivers.arm.Arm`: pick the protocol, build the transport.

This is the only place that knows which transports exist. A real bench differs from a virtual
one only by its profile (channel, ``virtual = false``); the code path is the same.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from drivers.arm import Arm, SafetyLimits
from profiles.bench import BenchProfile
from profiles.drive import load_drive
from profiles.robot import load_any_robot


def limits_of(bench: BenchProfile) -> SafetyLimits:
    return SafetyLimits(
        torque_Nm=bench.torque_limit_Nm,
        velocity_rad_s=bench.velocity_limit_rad_s,
        position_rad=bench.position_limit_rad,
    )


def can_bus_kwargs(bench: BenchProfile, channel: dict[str, Any]) -> dict[str, Any]:
    """python-can `can.Bus(**kwargs)` for the bench, given the announced or configured channel."""
    where = channel.get("channel") or bench.channel
    if bench.transport == "slcan":
        # python-can waits 2 s after opening a serial adapter by default; a pty needs none
        sleep = 0.0 if bench.virtual else 2.0
        return {
            "interface": "slcan",
            "channel": where,
            "bitrate": bench.bitrate,
            "sleep_after_open": sleep,
        }
    if bench.transport == "socketcand":
        host, _, port = str(where).rpartition(":")
        return {
            "interface": "socketcand",
            "host": host or "127.0.0.1",
            "port": int(port),
            "channel": channel.get("interface_channel", "can0"),
            # without TCP_NODELAY, Nagle holds small frames for ~40 ms: 16 periods at 400 Hz
            "tcp_tune": True,
        }
    if bench.transport == "socketcan":
        return {"interface": "socketcan", "channel": where or "can0"}
    if bench.transport == "virtual":
        return {"interface": "virtual", "channel": where or "ddbench"}
    raise ValueError(f"{bench.source}: transport {bench.transport!r} is not a CAN transport")


def open_socketcan(channel: str) -> Any:
    """python-can SocketCAN bus on ``channel``; a missing interface is a one-line OSError.

    The interface is looked up first: python-can logs a second line of its own when the bind fails.
    """
    import socket

    import can

    try:
        socket.if_nametoindex(channel)
    except OSError:
        if channel.startswith("vcan"):
            make = f"ip link add dev {channel} type vcan && ip link set up {channel}"
            raise OSError(f"{channel} missing: run `{make}` (docs/vcan.md)") from None
        raise OSError(f"socketcan channel {channel} missing: no such network interface") from None
    try:
        return can.Bus(interface="socketcan", channel=channel)
    except Exception as exc:  # CanError is not an OSError; the CLIs report OSErrors
        raise OSError(f"cannot open socketcan channel {channel}: {exc}") from exc


def make_can_bus(kwargs: dict[str, Any]) -> Any:
    """``can.Bus(**kwargs)``; slcan goes through :class:`drivers.slcan.SelectSlcanBus`."""
    import can

    if kwargs.get("interface") == "socketcan" and set(kwargs) == {"interface", "channel"}:
        return open_socketcan(kwargs["channel"])
    if kwargs.get("interface") == "slcan":
        from drivers.slcan import SelectSlcanBus

        rest = {k: v for k, v in kwargs.items() if k != "interface"}
        return SelectSlcanBus(**rest)
    return can.Bus(**kwargs)


def open_arm(
    bench: BenchProfile,
    channel: dict[str, Any],
    *,
    mode: str | None = None,
    log_dir: str | Path | None = None,
) -> Arm:
    """An unopened Arm for the bench (use it as a context manager): one drive per joint of the
    bench's robot (a 2-DOF or a URDF robot profile; see profiles.bench.bench_for_robot)."""
    robot = load_any_robot(bench.robot)
    if robot.drives is None:
        raise ValueError(f"{robot.source}: [joints] drives: a bench needs one drive per joint")
    drives = [load_drive(name) for name in robot.drives]
    mode = mode or bench.mode
    log_dir = Path(log_dir) if log_dir is not None else None
    common = {
        "period_s": bench.period_s,
        "mode": mode,
        "timeout_s": bench.timeout_s,
        "limits": limits_of(bench),
        "feedback_budget_s": bench.feedback_budget_s,
    }
    if bench.protocol == "can":
        from drivers.can_arm import CanArm

        kwargs = can_bus_kwargs(bench, channel)
        return CanArm(
            lambda: make_can_bus(kwargs),
            drives,
            log_path=log_dir / "bus.log" if log_dir else None,
            **common,
        )
    from drivers.serial_arm import SerialArm

    port = channel.get("channel") or bench.channel
    serial_log = log_dir / "serial.log" if log_dir else None
    return SerialArm(port, drives, log_path=serial_log, baudrate=bench.baudrate, **common)


__all__ = [
    "limits_of",
    "open_arm",
]
