"""python-can 4.6.1's slcan test cases, run on a real pty against drivers.slcan.SelectSlcanBus.

Upstream's test/test_slcan.py drives ``slcanBus`` through pyserial's ``loop://`` mock, which has
no ``fileno()``, so it never reaches the override's select path. Here the same cases (receive and
send of every frame kind, partial lines, ``recv(0)``, ``get_version(0)``,
``get_serial_number(0)``) run against a pty pair: the test plays the USB adapter on the master
side, the bus opens the slave like a /dev/ttyACM device. Each case runs against python-can's own
``slcanBus`` too, so the override is held to upstream's behaviour on the same port.

Two cases a real adapter hits and the mock cannot: ``recv(0)`` with a whole frame waiting, and a
write that meets a full port (EAGAIN on the non-blocking fd) must wait up to ``send()``'s timeout.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import select
import termios
import threading
import time
import tty
from collections.abc import Iterator

import can
import pytest
from can.interfaces.slcan import slcanBus

from drivers.slcan import SelectSlcanBus

TIMEOUT = 0.01  # upstream's per-call timeout
SETTLE_S = 2.0  # how long a byte may take through the pty under load (only an upper bound)


class PtyAdapter:
    """The adapter side of a pty pair: what the test writes, the bus reads, and back."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.bus: slcanBus | None = None

    def write(self, data: bytes) -> None:
        """Send ``data`` to the bus and wait until all of it is readable on the bus side, so a
        ``recv(0)`` that follows has the whole of it waiting (the pty delivers asynchronously)."""
        assert self.bus is not None
        before = self._waiting()
        os.write(self.master, data)
        deadline = time.monotonic() + SETTLE_S
        while self._waiting() < before + len(data):
            assert time.monotonic() < deadline, "pty did not deliver"
            time.sleep(0.0005)

    def _waiting(self) -> int:
        assert self.bus is not None
        raw = fcntl.ioctl(self.bus.fileno(), termios.FIONREAD, b"\0\0\0\0")
        return int.from_bytes(raw, "little")

    def read(self, n: int, timeout: float = SETTLE_S) -> bytes:
        out = b""
        deadline = time.monotonic() + timeout
        while len(out) < n:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self.master], [], [], left)[0]:
                break
            out += os.read(self.master, n - len(out))
        return out

    def drain(self) -> bytes:
        out = b""
        while select.select([self.master], [], [], 0.05)[0]:
            out += os.read(self.master, 65536)
        return out

    def close(self) -> None:
        for fd in (self.master, self.slave):
            with contextlib.suppress(OSError):
                os.close(fd)


@pytest.fixture(params=[SelectSlcanBus, slcanBus], ids=["override", "python-can"])
def link(request: pytest.FixtureRequest) -> Iterator[tuple[slcanBus, PtyAdapter]]:
    adapter = PtyAdapter()
    bus = request.param(channel=adapter.path, sleep_after_open=0, timeout=TIMEOUT)
    adapter.bus = bus
    assert adapter.drain() == b"O\r"  # the open command
    try:
        yield bus, adapter
    finally:
        reader = threading.Thread(target=adapter.drain)  # room for the close command
        reader.start()
        bus.shutdown()
        reader.join()
        adapter.close()


def _check(msg: can.Message | None, can_id: int, ext: bool, rtr: bool, dlc: int, data: bytes):
    assert msg is not None
    assert (msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame) == (can_id, ext, rtr)
    assert msg.dlc == dlc
    if not rtr:
        assert bytes(msg.data) == data


def test_recv_extended(link) -> None:
    bus, adapter = link
    adapter.write(b"T12ABCDEF2AA55\r")
    _check(bus.recv(0), 0x12ABCDEF, True, False, 2, b"\xaa\x55")
    adapter.write(b"x12ABCDEF2AA55\r")  # CANDapter's extended-frame letter
    _check(bus.recv(0), 0x12ABCDEF, True, False, 2, b"\xaa\x55")


def test_recv_standard(link) -> None:
    bus, adapter = link
    adapter.write(b"t4563112233\r")
    _check(bus.recv(0), 0x456, False, False, 3, b"\x11\x22\x33")


def test_recv_remote(link) -> None:
    bus, adapter = link
    adapter.write(b"r1238\r")
    _check(bus.recv(0), 0x123, False, True, 8, b"")
    adapter.write(b"R12ABCDEF6\r")
    _check(bus.recv(0), 0x12ABCDEF, True, True, 6, b"")


@pytest.mark.parametrize(
    ("line", "ext", "brs"),
    [(b"d123F", False, False), (b"D12ABCDEFF", True, False), (b"b123F", False, True)],
)
def test_recv_fd(link, line: bytes, ext: bool, brs: bool) -> None:
    bus, adapter = link
    adapter.write(line + bytes(range(64)).hex().upper().encode() + b"\r")
    msg = bus.recv(0)
    assert msg is not None and msg.is_fd and msg.bitrate_switch == brs
    assert msg.is_extended_id == ext and bytes(msg.data) == bytes(range(64))


@pytest.mark.parametrize(
    ("msg", "line"),
    [
        (can.Message(arbitration_id=0x12ABCDEF, data=b"\xaa\x55"), b"T12ABCDEF2AA55\r"),
        (
            can.Message(arbitration_id=0x456, is_extended_id=False, data=b"\x11\x22\x33"),
            b"t4563112233\r",
        ),
        (
            can.Message(arbitration_id=0x123, is_extended_id=False, is_remote_frame=True, dlc=8),
            b"r1238\r",
        ),
        (can.Message(arbitration_id=0x12ABCDEF, is_remote_frame=True, dlc=6), b"R12ABCDEF6\r"),
        (
            can.Message(arbitration_id=0x123, is_extended_id=False, is_fd=True, data=b"\1" * 12),
            b"d1239" + b"01" * 12 + b"\r",  # FD DLC 9 = 12 bytes
        ),
        (
            can.Message(arbitration_id=0x1234, is_fd=True, bitrate_switch=True, data=b"\2" * 12),
            b"B000012349" + b"02" * 12 + b"\r",
        ),
    ],
)
def test_send(link, msg: can.Message, line: bytes) -> None:
    bus, adapter = link
    bus.send(msg)
    assert adapter.read(len(line)) == line


def test_partial_recv(link) -> None:
    bus, adapter = link
    adapter.write(b"T12ABCDEF")
    assert bus.recv(TIMEOUT) is None
    adapter.write(b"2AA55\rT12")
    _check(bus.recv(TIMEOUT), 0x12ABCDEF, True, False, 2, b"\xaa\x55")
    assert bus.recv(TIMEOUT) is None
    adapter.write(b"ABCDEF2AA55\r")
    assert bus.recv(TIMEOUT) is not None


def test_recv_zero_returns_the_waiting_frame(link) -> None:
    """A whole frame waiting: ``recv(0)`` returns it (the override returned None: its read gave
    up before reading once the deadline had passed)."""
    bus, adapter = link
    for _ in range(20):
        adapter.write(b"t4563112233\r")
        _check(bus.recv(0), 0x456, False, False, 3, b"\x11\x22\x33")
    assert bus.recv(0) is None


def test_version(link) -> None:
    bus, adapter = link
    adapter.write(b"V1013\r")
    assert bus.get_version(0) == (10, 13)
    assert adapter.read(2) == b"V\r"
    assert bus.get_version(0) == (None, None)


def test_serial_number(link) -> None:
    bus, adapter = link
    adapter.write(b"NA123\r")
    assert bus.get_serial_number(0) == "A123"
    assert bus.get_serial_number(0) is None


def test_recv_frames_zero_returns_the_waiting_frames() -> None:
    adapter = PtyAdapter()
    bus = SelectSlcanBus(channel=adapter.path, sleep_after_open=0)
    adapter.bus = bus
    adapter.drain()
    try:
        adapter.write(b"t18120102\rt2811FF\r")
        assert bus.recv_frames(0) == [(0x181, b"\x01\x02"), (0x281, b"\xff")]
        assert bus.recv_frames(0) == []
    finally:
        reader = threading.Thread(target=adapter.drain)
        reader.start()
        bus.shutdown()
        reader.join()
        adapter.close()


def _fill_port(bus: slcanBus, adapter: PtyAdapter) -> int:
    """Send frames with nobody reading until the port is full; the bytes sent. The pty's data
    moves between its buffers through a kernel worker that a loaded machine delays, so a send can
    time out on a buffer the worker is about to drain: full means a fill after a pause sends
    nothing more."""
    msg = can.Message(arbitration_id=0x601, is_extended_id=False, data=bytes(8))
    line = 22  # "t6018" + 16 hex digits + CR
    sent = 0
    while True:
        before = sent
        while True:
            try:
                bus.send(msg, timeout=0.05)
            except can.CanOperationError:
                break
            sent += line
            assert sent < 1 << 22, "the port never filled"
        if sent == before and sent > 0:
            return sent
        time.sleep(0.3)  # let the kernel worker move what it still holds


def test_send_waits_for_room_up_to_its_timeout(link) -> None:
    """The port full (nobody reading the adapter): ``send(msg, timeout)`` waits for room and
    succeeds once the adapter reads, and raises only after its timeout, not at once."""
    bus, adapter = link
    sent = _fill_port(bus, adapter)
    assert sent > 1000
    msg = can.Message(arbitration_id=0x201, is_extended_id=False, data=b"\x0f\x00")
    t0 = time.monotonic()
    with pytest.raises(can.CanOperationError):
        bus.send(msg, timeout=0.2)
    assert time.monotonic() - t0 >= 0.15  # waited for its timeout
    got = bytearray()

    def read_later() -> None:
        time.sleep(0.1)
        deadline = time.monotonic() + 5.0
        while not got.endswith(b"t2012" + b"0F00\r") and time.monotonic() < deadline:
            if select.select([adapter.master], [], [], 0.1)[0]:
                got.extend(os.read(adapter.master, 65536))

    reader = threading.Thread(target=read_later)
    reader.start()
    bus.send(msg, timeout=3.0)
    reader.join()
    assert got.endswith(b"t20120F00\r")


def test_shutdown_waits_for_room_for_its_close_command() -> None:
    adapter = PtyAdapter()
    bus = SelectSlcanBus(channel=adapter.path, sleep_after_open=0)
    adapter.bus = bus
    adapter.drain()
    _fill_port(bus, adapter)
    got = bytearray()

    def read_later() -> None:
        time.sleep(0.1)
        got.extend(adapter.drain())

    reader = threading.Thread(target=read_later)
    reader.start()
    bus.serialPortOrig.write_timeout = 3.0
    bus.shutdown()  # writes "C\r" behind the queued frames
    reader.join()
    adapter.close()
    assert got.endswith(b"C\r")  # (the send that timed out in _fill_port left half a line)
