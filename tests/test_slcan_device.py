"""Device side of the LAWICEL slcan protocol (virtual_robot.slcan_device)."""

from __future__ import annotations

import os
import select
import threading
import time
from collections.abc import Iterator

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from virtual_robot.slcan_device import BEL, MAX_LINE, SlcanDeviceProtocol, SlcanPtyBus

REPLY_TOKENS = (b"\r", b"\a", b"z\r", b"Z\r", b"V1013\r", b"v1013\r", b"NDDB1\r", b"F00\r")


def split_replies(replies: bytes) -> list[bytes]:
    out, token = [], bytearray()
    for byte in replies:
        token.append(byte)
        if byte in b"\r\a":
            out.append(bytes(token))
            token.clear()
    assert not token, f"unterminated reply {bytes(token)!r}"
    return out


def test_commands_as_python_can_sends_them() -> None:
    dev = SlcanDeviceProtocol()
    replies, frames = dev.feed(b"C\rS8\r\rO\r")  # python-can: close, bitrate, data bitrate "", open
    assert replies == b"\r\r\r" and frames == []
    assert dev.is_open and dev.bitrate == 1_000_000
    replies, frames = dev.feed(b"t6018401810020000000")
    assert replies == b"" and frames == []  # no CR yet: partial line kept
    replies, frames = dev.feed(b"0\rT1234567820102\rr0803\rR000001230\r")
    assert split_replies(replies) == [b"z\r", b"Z\r", b"z\r", b"Z\r"]
    std, ext, rtr, ertr = frames
    assert (std.arbitration_id, bytes(std.data), std.is_extended_id) == (
        0x601,
        bytes.fromhex("4018100200000000"),
        False,
    )
    assert (ext.arbitration_id, bytes(ext.data), ext.is_extended_id) == (
        0x12345678,
        b"\x01\x02",
        True,
    )
    assert rtr.is_remote_frame and rtr.dlc == 3 and rtr.arbitration_id == 0x080
    assert ertr.is_remote_frame and ertr.is_extended_id and ertr.arbitration_id == 0x123
    assert dev.feed(b"V\rv\rN\rF\rZ1\rX1\rM00000000\rmFFFFFFFF\r")[0] == (
        b"V1013\rv1013\rNDDB1\rF00\r\r\r\r\r"
    )
    assert dev.feed(b"S4\r")[0] == BEL  # bit rate only while closed
    assert dev.feed(b"C\rs031C\rS4\r")[0] == b"\r\r\r"
    assert dev.bitrate == 125_000


@pytest.mark.parametrize(
    "line",
    [
        b"t12",  # short
        b"t1239",  # DLC 9
        b"t1232010203",  # DLC 2 with three data bytes
        b"t1232010",  # odd number of hex digits
        b"t8000",  # id > 0x7FF
        b"tXYZ0",  # not hex
        b"t12320x01",  # int() would take "0x", hex check must not
        b"t123 2 01 02",
        b"T2000000000",  # id > 0x1FFFFFFF
        b"r1239",
        b"r123201",  # a remote frame carries no data
        b"S",
        b"S10",
        b"s12",
        b"Y2",  # CAN FD data bit rate: not supported
        b"d1238",
        b"Q",
        b"\xff\xfe",
        b"t\x001",
    ],
)
def test_malformed_lines_get_bel(line: bytes) -> None:
    dev = SlcanDeviceProtocol()
    replies, frames = dev.feed(line + b"\r")
    assert (replies, frames) == (BEL, [])
    assert dev.malformed == 1
    assert dev.feed(b"V\r")[0] == b"V1013\r"  # and the parser carries on


def test_over_long_line_gets_one_bel_and_is_dropped() -> None:
    dev = SlcanDeviceProtocol()
    replies, _ = dev.feed(b"t" * (MAX_LINE + 1))
    replies2, _ = dev.feed(b"1" * 500 + b"\rF\r")
    assert replies + replies2 == BEL + b"F00\r"


def test_listen_only_refuses_transmit_and_encode() -> None:
    dev = SlcanDeviceProtocol(ack_transmit=False)
    assert dev.feed(b"L\rt0800\r")[0] == b"\r\a"
    assert dev.encode(
        can.Message(arbitration_id=0x181, data=b"\x27\x06", is_extended_id=False)
    ) == (b"t18122706\r")
    assert dev.encode(can.Message(arbitration_id=0x1ABCDEF0, data=b"", is_extended_id=True)) == (
        b"T1ABCDEF00\r"
    )
    assert dev.encode(
        can.Message(arbitration_id=0x80, is_remote_frame=True, dlc=2, is_extended_id=False)
    ) == (b"r0802\r")
    assert dev.encode(can.Message(is_error_frame=True)) == b""
    dev.feed(b"Z1\r")
    line = dev.encode(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False))
    assert len(line) == len(b"t0800") + 4 + 1  # 4 hex digits of milliseconds


@settings(max_examples=300, deadline=None)
@given(chunks=st.lists(st.binary(max_size=40), max_size=10))
def test_fuzz_random_bytes_never_crash_the_parser(chunks: list[bytes]) -> None:
    dev = SlcanDeviceProtocol()
    replies = b""
    for chunk in chunks:
        out, frames = dev.feed(chunk)
        replies += out
        for msg in frames:
            assert 0 <= msg.dlc <= 8 and len(msg.data) == (0 if msg.is_remote_frame else msg.dlc)
    tokens = split_replies(replies)
    assert all(t in REPLY_TOKENS for t in tokens)
    assert tokens.count(BEL) == dev.malformed


@settings(max_examples=300, deadline=None)
@given(
    line=st.binary(min_size=1, max_size=30).filter(
        lambda b: b"\r" not in b and b.strip(b"\n") != b"" and b[:1] not in b"tTrRSsOLCVvNFZXMm\n"
    )
)
def test_fuzz_lines_that_are_no_command_get_bel(line: bytes) -> None:
    dev = SlcanDeviceProtocol()
    assert dev.feed(line + b"\r") == (BEL, [])


# ---- on a pty -----------------------------------------------------------------------------------
@pytest.fixture
def device() -> Iterator[SlcanPtyBus]:
    bus = SlcanPtyBus()
    yield bus
    bus.shutdown()


def _host_read(fd: int, n: int) -> bytes:
    out = b""
    while len(out) < n:
        ready, _, _ = select.select([fd], [], [], 2.0)
        assert ready, f"only {out!r} from the device"
        out += os.read(fd, 100)
    return out


def test_pty_host_side_by_raw_bytes(device: SlcanPtyBus) -> None:
    host = os.open(device.channel_path, os.O_RDWR | os.O_NOCTTY)
    try:
        device.send(can.Message(arbitration_id=0x701, data=b"\x00", is_extended_id=False))
        assert device.dropped == 1  # channel closed: a real adapter reports nothing either
        os.write(host, b"S8\rO\rt080")  # a partial frame line
        assert device.recv(0.05) is None
        os.write(host, b"0\r\x07garbage\r")
        msg = device.recv(1.0)
        assert msg is not None and msg.arbitration_id == 0x080 and msg.dlc == 0
        device.send(can.Message(arbitration_id=0x181, data=b"\x27\x06", is_extended_id=False))
        got = b""
        while not got.endswith(b"t18122706\r"):
            got += _host_read(host, 1)
        assert got == b"\r\rz\r\at18122706\r"
    finally:
        os.close(host)
    # the host went away: reads see no data, the device keeps working for the next host
    assert device.recv(0.02) is None
    host = os.open(device.channel_path, os.O_RDWR | os.O_NOCTTY)
    try:
        os.write(host, b"V\r")
        assert device.recv(0.05) is None
        assert _host_read(host, 6).endswith(b"V1013\r")
    finally:
        os.close(host)


def test_shutdown_wakes_a_blocked_recv_and_is_idempotent() -> None:
    bus = SlcanPtyBus()
    errors: list[BaseException] = []

    def blocked() -> None:
        try:
            bus.recv(None)
        except can.CanOperationError as exc:
            errors.append(exc)

    thread = threading.Thread(target=blocked)
    thread.start()
    bus.shutdown()
    bus.shutdown()
    thread.join(2.0)
    assert not thread.is_alive() and errors


# ---- batch path (the cyclic exchange) ---------------------------------------------------------
def _line_by_line(lines: list[bytes]) -> tuple[bytes, list[tuple[int, bytes, bool, bool]]]:
    dev = SlcanDeviceProtocol()
    replies, frames = b"", []
    for line in lines:
        reply, frame = dev.command_raw(line)
        replies += reply
        if frame is not None:
            frames.append(frame)
    return replies, frames


_VALID_STD = st.builds(
    lambda i, data: b"t%03X%d%s" % (i, len(data), data.hex().encode()),
    st.integers(0, 0x7FF),
    st.binary(max_size=8),
)
_ANY_LINE = _VALID_STD | st.sampled_from(
    [b"t8000", b"t1239", b"t12320102", b"tXYZ0", b"V", b"O", b"T1234567820102", b"r0803", b""]
)


@settings(max_examples=300, deadline=None)
@given(lines=st.lists(_ANY_LINE, min_size=1, max_size=6), lower=st.booleans())
def test_feed_of_whole_lines_equals_line_by_line(lines: list[bytes], lower: bool) -> None:
    """The one-pass path for a write of whole standard frames decides as command_raw does."""
    if lower:
        lines = [line.lower() if line[:1] == b"t" else line for line in lines]
    dev = SlcanDeviceProtocol()
    assert dev.feed_raw(b"".join(line + b"\r" for line in lines)) == _line_by_line(lines)
    assert dev.feed_raw(b"t0800\r") == (b"z\r", [(0x080, b"", False, False)])


def test_recv_frames_holds_replies_for_the_batched_write(device: SlcanPtyBus) -> None:
    host = os.open(device.channel_path, os.O_RDWR | os.O_NOCTTY)
    try:
        os.write(host, b"O\rt20140F00E803\rt20240F000A00\rt0800\r")
        frames: list[tuple[int, bytes, bool, bool]] = []
        while len(frames) < 3:
            frames += device.recv_frames(1.0)
        assert frames == [
            (0x201, bytes.fromhex("0F00E803"), False, False),
            (0x202, bytes.fromhex("0F000A00"), False, False),
            (0x080, b"", False, False),
        ]
        assert select.select([host], [], [], 0.05)[0] == []  # the acks wait for the answer
        device.send_frames([(0x181, b"\x37\x06\x00\x00\x00\x00"), (0x281, b"\x01\x02")])
        expected = b"\rz\rz\rz\rt1816370600000000\rt28120102\r"
        assert _host_read(host, len(expected)) == expected
        assert device.frames_in == 3 and device.frames_out == 2
    finally:
        os.close(host)


def test_host_adapter_batch_path_against_the_device(device: SlcanPtyBus) -> None:
    """drivers.slcan.SelectSlcanBus: frames out in one write, frames in as (id, data) tuples,
    other kinds as the Messages python-can's own parser makes."""
    from drivers.slcan import SelectSlcanBus

    host = SelectSlcanBus(channel=device.channel_path, bitrate=1_000_000, sleep_after_open=0)
    try:
        host.send_frames([(0x201, b"\x0f\x00\xe8\x03"), (0x080, b"")])
        got: list[tuple[int, bytes, bool, bool]] = []
        while len(got) < 2:
            got += device.recv_frames(1.0)
        assert got == [(0x201, b"\x0f\x00\xe8\x03", False, False), (0x080, b"", False, False)]
        device.send_frames([(0x181, b"\x27\x06")])
        device.send(can.Message(arbitration_id=0x1ABCDEF0, data=b"\x01", is_extended_id=True))
        device.send(can.Message(arbitration_id=0x701, is_remote_frame=True, is_extended_id=False))
        frames: list[object] = []
        while len(frames) < 3:
            frames += host.recv_frames(1.0)
        assert frames[0] == (0x181, b"\x27\x06")
        ext, rtr = frames[1], frames[2]
        assert isinstance(ext, can.Message) and ext.is_extended_id
        assert (ext.arbitration_id, bytes(ext.data)) == (0x1ABCDEF0, b"\x01")
        assert isinstance(rtr, can.Message) and rtr.is_remote_frame and rtr.arbitration_id == 0x701
        assert host.recv_frames(0.02) == []
    finally:
        host.shutdown()


def test_host_adapter_skips_garbage_lines(device: SlcanPtyBus) -> None:
    from drivers.slcan import SelectSlcanBus

    host = SelectSlcanBus(channel=device.channel_path, bitrate=1_000_000, sleep_after_open=0)
    try:
        device._write(b"t1\rTzz\r\ar9\rt1812\x07t18122706\r")  # a line python-can cannot parse
        frames: list[object] = []
        deadline = time.monotonic() + 2.0
        while not frames and time.monotonic() < deadline:
            frames += host.recv_frames(0.2)
        assert frames == [(0x181, b"\x27\x06")]
    finally:
        host.shutdown()
