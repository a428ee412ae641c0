"""What the MIT-mode client-library tests need around the unmodified libraries: a served
virtual robot in a thread, and the link each library opens by name, pointed at it.

- The DFKI driver (``mini-cheetah-motor-driver-socketcan``) opens a raw SocketCAN socket
  (``socket.socket(AF_CAN, SOCK_RAW, CAN_RAW)``, ``struct can_frame`` bytes). Where the kernel has
  no CAN (the machines this is built on, docs/vcan.md), :class:`RawCanSocket` is that socket over
  a python-can bus: the same calls, the same 16-byte frames, a receive truncated to the size
  asked for as the kernel truncates a datagram. In the vcan guest the driver uses the real one
  (tests/vcan/test_vcan_mit.py).
- TMotorCANControl opens ``can.interface.Bus(channel="can0", bustype="socketcan")`` and runs
  ``sudo /sbin/ip link set can0 …``: :func:`socketcan_as_virtual` maps python-can's
  ``socketcan`` name onto its in-process ``virtual`` bus for the test, and a ``sudo`` that does
  nothing goes first on PATH.
"""

from __future__ import annotations

import os
import socket
import stat
import struct
import types
from collections.abc import Callable
from contextlib import AbstractContextManager
from pathlib import Path

import can
import numpy as np
from loop_clients import served_on

from profiles.bench import load_bench
from virtual_robot.mit_server import MitDriveServer
from virtual_robot.serve import build_core

CAN_FRAME = struct.Struct("=IB3x8s")  # struct can_frame of <linux/can.h>


class RawCanSocket:
    """A CAN_RAW socket's calls the DFKI driver makes, over a python-can bus."""

    def __init__(self, channel: str) -> None:
        self._bus = can.Bus(interface="virtual", channel=channel)
        self._timeout: float | None = None
        self.sent: list[tuple[int, bytes]] = []  # what the library put on the bus

    def setsockopt(self, *args: object) -> None:
        pass

    def bind(self, address: tuple[str]) -> None:
        pass

    def settimeout(self, timeout: float | None) -> None:
        self._timeout = timeout

    def send(self, frame: bytes) -> int:
        can_id, dlc, data = CAN_FRAME.unpack(frame)
        self.sent.append((can_id, data[:dlc]))
        self._bus.send(can.Message(arbitration_id=can_id, data=data[:dlc], is_extended_id=False))
        return len(frame)

    def recvfrom(self, size: int) -> tuple[bytes, tuple[str]]:
        msg = self._bus.recv(self._timeout)
        if msg is None:
            raise TimeoutError("timed out")
        frame = CAN_FRAME.pack(msg.arbitration_id, msg.dlc, bytes(msg.data).ljust(8, b"\0"))
        return frame[:size], ("can0",)

    def close(self) -> None:
        self._bus.shutdown()


def raw_can_module(sock: RawCanSocket) -> types.SimpleNamespace:
    """A stand-in for the ``socket`` module as the DFKI driver uses it: its ``socket()`` hands
    out ``sock``."""
    return types.SimpleNamespace(
        socket=lambda *args: sock,
        AF_CAN=getattr(socket, "AF_CAN", 29),
        SOCK_RAW=socket.SOCK_RAW,
        CAN_RAW=getattr(socket, "CAN_RAW", 1),
        SOL_CAN_RAW=getattr(socket, "SOL_CAN_RAW", 101),
        CAN_RAW_LOOPBACK=getattr(socket, "CAN_RAW_LOOPBACK", 3),
    )


def served(bench: str, channel: str, **build: object) -> AbstractContextManager[MitDriveServer]:
    """The bench's virtual robot served by :class:`MitDriveServer` on python-can's virtual bus
    ``channel``, in a thread, until the block ends (tests/loop_clients.py)."""
    core = build_core(load_bench(bench), effects=None, mode=None, **build)  # type: ignore[arg-type]
    return served_on(MitDriveServer, core, channel, idle_timeout_s=None, log=lambda line: None)


def socketcan_as_virtual(monkeypatch: object, tmp_path: Path) -> None:
    """python-can's ``socketcan`` interface name → its ``virtual`` bus, and a no-op ``sudo`` first
    on PATH (TMotorCANControl runs ``sudo /sbin/ip link set can0 …`` when it opens its bus)."""
    from can.interfaces import BACKENDS

    monkeypatch.setitem(BACKENDS, "socketcan", ("can.interfaces.virtual", "VirtualBus"))  # type: ignore[attr-defined]
    shim = tmp_path / "bin"
    shim.mkdir()
    sudo = shim / "sudo"
    sudo.write_text("#!/bin/sh\nexit 0\n")
    sudo.chmod(sudo.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("PATH", f"{shim}{os.pathsep}{os.environ['PATH']}")  # type: ignore[attr-defined]


def run_dfki_driver(
    setattr_: Callable[[object, str, object], None], channel: str, tau: np.ndarray
) -> tuple[np.ndarray, RawCanSocket, MitDriveServer]:
    """mini-cheetah-motor-driver-socketcan, as the DFKI lab's run_experiment uses it (zero,
    enable, one torque command per period with kp = kd = 0 on each motor, reading back
    position, velocity and torque; disable), against the `dfki-a0` pendulum served in lockstep
    on the `virtual-mit-inprocess` bench. ``setattr_`` patches the driver module (pytest's
    ``monkeypatch.setattr``, or a plain one that the caller undoes). Returns (rows × (p1, v1, t1,
    p2, v2, t2) as the driver returns them, the socket with what it sent, the server)."""
    from motor_driver import canmotorlib  # the unmodified DFKI driver

    sock = RawCanSocket(channel)
    setattr_(canmotorlib, "socket", raw_can_module(sock))
    setattr_(canmotorlib, "set_zero_sleep", 0.0)  # its 1.5 s wait for a real motor
    setattr_(canmotorlib.CanMotorController, "can_socket_declared", False)
    with served("virtual-mit-inprocess", channel) as server:
        shoulder = canmotorlib.CanMotorController("can0", 1, "AK80_6_V1p1")
        elbow = canmotorlib.CanMotorController("can0", 2, "AK80_6_V1p1")
        if shoulder.enable_motor() is None or elbow.enable_motor() is None:
            raise RuntimeError("the virtual AK80-6 drives did not answer the DFKI driver's enable")
        got = np.array(
            [
                (
                    *shoulder.send_rad_command(0.0, 0.0, 0.0, 0.0, t1),
                    *elbow.send_rad_command(0.0, 0.0, 0.0, 0.0, t2),
                )
                for t1, t2 in tau
            ]
        )
        shoulder.disable_motor()
        elbow.disable_motor()
    sock.close()
    return got, sock, server
