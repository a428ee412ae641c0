"""From a bench profile to an :class:`~drivers.arm.Arm`: pick the protocol, build the transport.

This is the only place that knows which transports exist. A real bench differs from a virtual
one only by its profile (channel, ``virtual = false``); the code path is the same.
"""

from __future__ import annotations

import socket
import time
from pathlib import Path
from typing import Any

from drivers.arm import Arm, SafetyLimits
from drivers.options import host_port
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
        host, port = host_port(str(where), f"{bench.source}: socketcand channel")
        return {
            "interface": "socketcand",
            "host": host,
            "port": port,
            "channel": channel.get("interface_channel", "can0"),
            # without TCP_NODELAY, Nagle holds small frames for ~40 ms: 16 periods at 400 Hz
            "tcp_tune": True,
        }
    if bench.transport == "socketcan":
        return {"interface": "socketcan", "channel": where or "can0"}
    if bench.transport == "virtual":
        return {"interface": "virtual", "channel": where or "ddbench"}
    raise ValueError(f"{bench.source}: transport {bench.transport!r} is not a CAN transport")


CANFD_MTU = 72  # struct canfd_frame: an interface that carries CAN-FD frames (linux/can.h)


def open_socketcan(channel: str, *, fd: bool = False) -> Any:
    """python-can SocketCAN bus on ``channel``; a missing interface is a one-line OSError.

    The interface is looked up first: python-can logs a second line of its own when the bind fails.
    ``fd``: CAN-FD frames too (moteus). The interface must then have the CAN-FD MTU (72, what a
    new vcan and a real interface set ``fd on`` have): on a classic one (MTU 16) the kernel
    refuses every FD frame at send with EINVAL, so it is a one-line OSError here, naming the
    command that makes it a CAN-FD interface.
    """
    import socket

    import can

    try:
        socket.if_nametoindex(channel)
    except OSError:
        if channel.startswith("vcan"):  # a new vcan has the CAN-FD MTU (linux vcan.c)
            make = f"ip link add dev {channel} type vcan && ip link set up {channel}"
            raise OSError(f"{channel} missing: run `{make}` (docs/vcan.md)") from None
        raise OSError(f"socketcan channel {channel} missing: no such network interface") from None
    if fd:
        mtu = interface_mtu(channel)
        if mtu is not None and mtu < CANFD_MTU:
            make = (
                f"ip link set {channel} down && ip link set {channel} mtu {CANFD_MTU} "
                f"&& ip link set up {channel}"
                if channel.startswith("vcan")
                else f"ip link set {channel} type can bitrate 1000000 dbitrate 5000000 fd on"
            )
            raise OSError(
                f"socketcan channel {channel} carries classic CAN only (MTU {mtu}), moteus needs "
                f"CAN-FD (MTU {CANFD_MTU}): run `{make}` (docs/vcan.md)"
            )
    try:
        return can.Bus(interface="socketcan", channel=channel, fd=fd)
    except Exception as exc:  # CanError is not an OSError; the CLIs report OSErrors
        raise OSError(f"cannot open socketcan channel {channel}: {exc}") from exc


def interface_mtu(channel: str) -> int | None:
    """The network interface's MTU (sysfs), None where it cannot be read."""
    try:
        return int(Path(f"/sys/class/net/{channel}/mtu").read_text())
    except (OSError, ValueError):
        return None


# a refused socketcand port is retried this long (a daemon just started), then reported
SOCKETCAND_CONNECT_S = 1.0


def check_socketcand_listens(host: str, port: int, within_s: float = SOCKETCAND_CONNECT_S) -> None:
    """Return once a server accepts a TCP connection at ``host:port``; a one-line OSError if none
    does within ``within_s`` (refusals retried 50 ms apart) or the address is bad.

    python-can's socketcand bus retries a refused connection for a fixed 10 s with no pause
    between attempts (one core busy, some 700,000 attempts, each logged) before its TimeoutError;
    a dead port is reported here instead. The probe closes its connection at once: socketcand,
    and the virtual robot's hub, serve each client on its own, so it is one client that left.
    """
    deadline = time.monotonic() + within_s
    while True:
        try:
            with socket.create_connection((host, port), timeout=within_s):
                return
        except ConnectionRefusedError:
            if time.monotonic() >= deadline:
                raise OSError(
                    f"socketcand at {host}:{port} refused the connection for {within_s:g} s: "
                    "nothing listens there"
                ) from None
            time.sleep(0.05)
        except OSError as exc:  # unreachable, no such host, no answer within within_s
            raise OSError(f"socketcand at {host}:{port}: {exc}") from None


def make_can_bus(kwargs: dict[str, Any]) -> Any:
    """``can.Bus(**kwargs)``; slcan goes through :class:`drivers.slcan.SelectSlcanBus`; a
    socketcand server is checked to listen first (:func:`check_socketcand_listens`)."""
    import can

    if kwargs.get("interface") == "socketcan" and set(kwargs) == {"interface", "channel"}:
        return open_socketcan(kwargs["channel"])
    if kwargs.get("interface") == "socketcand":
        check_socketcand_listens(kwargs["host"], kwargs["port"])
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
    if not robot.drives:  # a profile for identification only names none
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
    if bench.protocol == "odrive":
        from drivers.odrive_arm import OdriveArm

        kwargs = can_bus_kwargs(bench, channel)
        return OdriveArm(lambda: make_can_bus(kwargs), drives, **common)
    if bench.protocol == "moteus":
        from drivers.moteus_arm import MoteusArm

        port = str(channel.get("channel") or bench.channel)
        if bench.transport == "socketcan":  # a CAN-FD interface (fd on, or a vcan of MTU 72)
            return MoteusArm(lambda: open_socketcan(port, fd=True), drives, **common)
        from drivers.fdcanusb import FdcanusbBus

        return MoteusArm(lambda: FdcanusbBus(port), drives, **common)
    if bench.protocol == "mit":
        from drivers.mit_arm import MitArm

        kwargs = can_bus_kwargs(bench, channel)
        return MitArm(lambda: make_can_bus(kwargs), drives, **common)
    from drivers.serial_arm import SerialArm

    port = channel.get("channel") or bench.channel
    serial_log = log_dir / "serial.log" if log_dir else None
    return SerialArm(port, drives, log_path=serial_log, baudrate=bench.baudrate, **common)


__all__ = [
    "limits_of",
    "open_arm",
]
