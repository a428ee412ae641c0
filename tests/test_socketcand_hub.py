"""socketcand-compatible hub (virtual_robot.socketcand_hub): elements, handshake, fan-out."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator

import can
import pytest
from can.interfaces.socketcand.socketcand import (
    convert_ascii_message_to_can_message,
    convert_can_message_to_ascii_message,
)
from hypothesis import given, settings
from hypothesis import strategies as st

from virtual_robot.socketcand_hub import SocketcandHub, frame_element, parse_send


@pytest.fixture
def hub() -> Iterator[SocketcandHub]:
    with SocketcandHub() as h:
        yield h


def raw_client(hub: SocketcandHub) -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", hub.port), timeout=2.0)
    assert sock.recv(256) == b"< hi >"
    return sock


def read_until(sock: socket.socket, tail: bytes) -> bytes:
    got = b""
    while not got.endswith(tail):
        chunk = sock.recv(4096)
        assert chunk, f"connection closed after {got!r}"
        got += chunk
    return got


@settings(max_examples=200, deadline=None)
@given(
    cob=st.integers(0, 0x7FF),
    data=st.binary(max_size=8),
    extended=st.booleans(),
    stamp=st.floats(1.0, 2e9),
)
def test_elements_round_trip_through_python_can(
    cob: int, data: bytes, extended: bool, stamp: float
) -> None:
    cob = cob << 18 | cob if extended else cob
    msg = can.Message(timestamp=stamp, arbitration_id=cob, data=data, is_extended_id=extended)
    parsed = convert_ascii_message_to_can_message(frame_element(msg).decode())
    assert (parsed.arbitration_id, bytes(parsed.data), parsed.is_extended_id) == (
        cob,
        data,
        extended,
    )
    assert abs(parsed.timestamp - stamp) < 1e-5
    sent = parse_send(convert_can_message_to_ascii_message(msg))
    assert sent is not None
    assert (sent.arbitration_id, bytes(sent.data), sent.is_extended_id) == (cob, data, extended)


def test_dlc0_frame_element_has_the_empty_data_field() -> None:
    element = frame_element(can.Message(timestamp=12.5, arbitration_id=0x80, is_extended_id=False))
    assert element == b"< frame 080 12.500000  >"


@pytest.mark.parametrize(
    "element",
    [
        "< send 123 2 1 >",  # LEN 2, one byte
        "< send 800 0 >",  # id > 0x7FF
        "< send 12 9 1 2 3 4 5 6 7 8 9 >",
        "< send xyz 0 >",
        "< send 123 1 100 >",
        "< send 123 1 -1 >",
        "< send >",
        "< frame 123 1.0 00 >",
    ],
)
def test_malformed_send_elements(element: str) -> None:
    assert parse_send(element) is None


def test_handshake_errors_and_echo(hub: SocketcandHub) -> None:
    sock = raw_client(hub)
    try:
        sock.sendall(b"< echo >")
        assert sock.recv(256) == b"< echo >"
        sock.sendall(b"< rawmode >")  # not opened yet
        assert sock.recv(256).startswith(b"< error")
        sock.sendall(b"< open vcan7 >")
        assert sock.recv(256).startswith(b"< error")
        sock.sendall(b"< open can0 >")
        assert sock.recv(256) == b"< ok >"
        sock.sendall(b"< rawmode >")
        assert sock.recv(256) == b"< ok >"
    finally:
        sock.close()


def test_raw_mode_garbage_is_dropped_and_frames_still_flow(hub: SocketcandHub) -> None:
    robot = hub.robot_bus()
    sock = raw_client(hub)
    try:
        sock.sendall(b"< open can0 >")
        assert sock.recv(256) == b"< ok >"
        sock.sendall(b"< rawmode >")
        assert sock.recv(256) == b"< ok >"
        sock.sendall(b"junk < send 123 5 1 > < bogus > <<< send 080 0  >")
        msg = robot.recv(2.0)
        assert msg is not None and msg.arbitration_id == 0x080 and msg.dlc == 0
        assert robot.recv(0.05) is None
        assert hub.malformed == 2
        sock.sendall(b"x" * 500)  # no '<' at all: discarded
        sock.sendall(b"< send 181 2 27 6 >")
        msg = robot.recv(2.0)
        assert msg is not None and bytes(msg.data) == b"\x27\x06"
    finally:
        sock.close()
        robot.shutdown()


def test_frames_right_after_rawmode_are_held_not_merged(hub: SocketcandHub) -> None:
    """python-can reads '< ok >' with one recv; frames must not share its segment, nor get lost."""
    robot = hub.robot_bus()
    stop = threading.Event()

    def chatter() -> None:
        k = 0
        while not stop.is_set():
            robot.send(
                can.Message(arbitration_id=0x700 + k % 2, data=b"\x7f", is_extended_id=False)
            )
            k += 1
            time.sleep(0.001)

    thread = threading.Thread(target=chatter)
    thread.start()
    clients = []
    try:
        for _ in range(3):
            clients.append(
                can.Bus(interface="socketcand", host="127.0.0.1", port=hub.port, channel="can0")
            )
        for bus in clients:
            msg = bus.recv(2.0)
            assert msg is not None and msg.arbitration_id in (0x700, 0x701)
        assert hub.clients == 3
    finally:
        stop.set()
        thread.join()
        for bus in clients:
            bus.shutdown()
        robot.shutdown()


def test_close_disconnects_clients_and_stops_threads() -> None:
    before = threading.active_count()
    hub = SocketcandHub()
    sock = raw_client(hub)
    hub.close()
    hub.close()
    assert sock.recv(256) == b""
    sock.close()
    assert threading.active_count() <= before
