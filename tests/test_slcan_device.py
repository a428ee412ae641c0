"""Device side of the LAWICEL slcan protocol (virtual_robot.slcan_device)."""

from __future__ import annotations

import os
import select
import threading
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
