"""A socketcand-compatible CAN hub on 127.0.0.1: several TCP clients and the robot share one bus.

socketcand (https://github.com/linux-can/socketcand) exposes a Linux CAN interface over TCP with
an ASCII protocol of ``< ... >`` elements. :class:`SocketcandHub` speaks the server side of its
raw mode, as python-can's ``socketcand`` interface expects it
(``can.Bus(interface="socketcand", host="127.0.0.1", port=P, channel="can0")``):

======================================= =============================================
server → client                          client → server
======================================= =============================================
``< hi >`` on connect                    ``< open can0 >`` → ``< ok >``
                                         ``< rawmode >`` → ``< ok >``
``< frame ID SECS.USECS DATA >``          ``< send ID LEN B0 B1 ... >`` (raw mode)
(ID %03X or %08X, DATA one hex string,   ``< echo >`` → ``< echo >`` (any time)
empty for DLC 0: note the two spaces)
======================================= =============================================

python-can's client reads each handshake reply with a single ``recv`` and compares it exactly,
so nothing else may follow ``< ok >`` in the same TCP segment: frames for a client that has just
entered raw mode are held for :attr:`SocketcandHub.HOLDOFF_S` and then sent in order, not lost.
Handshake errors (wrong channel, unknown command) are answered with ``< error TEXT >``, which
python-can reports as a failed handshake. Malformed elements in raw mode are dropped and counted
(python-can would fail on an ``< error >`` it cannot parse as an error frame).

Bus semantics: every participant (a TCP client in raw mode or an in-process bus from
:meth:`SocketcandHub.robot_bus`) receives every frame sent by every *other* participant, as
on a CAN bus where a controller does not receive its own frames. Remote and error frames are not
forwarded to TCP clients (the frame element cannot carry them).

Robustness: one slow or stopped client cannot hold up the robot or the other clients (sends are
non-blocking into a bounded per-client queue; a client whose queue overflows is dropped, with
the reason logged); at most :attr:`SocketcandHub.MAX_CLIENTS` clients; the accept thread
survives running out of descriptors (EMFILE) and keeps listening; non-ASCII and malformed
elements are dropped, counted and logged at a bounded rate; a client that has not entered raw
mode :attr:`SocketcandHub.HANDSHAKE_TIMEOUT_S` after connecting is dropped, and TCP keepalive
finds peers gone without a FIN (half-open).

One host per bus: the hub grants the host role (NMT master, SYNC producer, SDO client; the
frames of :func:`drivers.protocol.cia402.host_frame_name`) to the first participant that sends
a host frame, under its lock, so of two hosts that start together exactly one gets it; the
role is free again once that participant's host frames stop for
:attr:`SocketcandHub.HOST_LEASE_S` or it disconnects. Host frames from anyone else meanwhile
are not forwarded (the drives never see a second host's set-up) and counted in
``foreign_host_frames``; a SYNC among them also tells ``on_sync_conflict`` (serve.py faults the
drives: a robot beside a second SYNC producer is not to be trusted). A host (drivers.can_arm)
listens before it sends and refuses once it sees another host's frames, so a second
`hil run --attach` refuses in one line, whether it came late (it hears the first's SYNCs or
set-up) or together with the first (its frames go nowhere and it hears the first's set-up).
``on_sync_source_gone``: the host that had sent SYNCs disconnected (the run is over).
"""

from __future__ import annotations

import contextlib
import logging
import queue
import select
import socket
import threading
import time
from collections.abc import Callable
from typing import Any

import can

from drivers.protocol import cia402 as co

_logger = logging.getLogger(__name__)
MAX_ELEMENT = 200  # characters without a closing '>' before the buffer is discarded


def _name(participant: object) -> str:
    peer = getattr(participant, "peer", None)
    return f"client {peer}" if peer else "the in-process robot bus"


def frame_element(msg: can.Message) -> bytes:
    """``< frame ID SECS.USECS DATA >`` as socketcand sends it."""
    cob = (
        f"{msg.arbitration_id & 0x1FFFFFFF:08X}"
        if msg.is_extended_id
        else f"{msg.arbitration_id & 0x7FF:03X}"
    )
    stamp = msg.timestamp or time.time()
    secs = int(stamp)
    usecs = min(999_999, round((stamp - secs) * 1e6))
    data = bytes(msg.data[: msg.dlc]).hex().upper()
    return f"< frame {cob} {secs}.{usecs:06d} {data} >".encode("ascii")


def parse_send(element: str) -> can.Message | None:
    """A ``< send ID LEN B0 ... >`` element as a message, or None if malformed."""
    parts = element[1:-1].split()
    if len(parts) < 3 or parts[0] != "send":
        return None
    cob_hex, len_hex, data_hex = parts[1], parts[2], parts[3:]
    try:
        cob, length = int(cob_hex, 16), int(len_hex, 16)
        data = bytes(int(b, 16) for b in data_hex)
    except ValueError:
        return None
    extended = len(cob_hex) > 3
    if not (
        all(len(b) <= 2 and b.isalnum() for b in data_hex)
        and cob_hex.isalnum()
        and 0 <= cob <= (0x1FFFFFFF if extended else 0x7FF)
        and length == len(data) <= 8
    ):
        return None
    return can.Message(
        timestamp=time.time(), arbitration_id=cob, is_extended_id=extended, data=data
    )


def _keepalive(sock: socket.socket, idle_s: int, interval_s: int, count: int) -> None:
    """TCP keepalive: the kernel probes a silent peer and resets a half-open connection."""
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
    for name, value in (("TCP_KEEPIDLE", idle_s), ("TCP_KEEPINTVL", interval_s),
                        ("TCP_KEEPCNT", count)):  # fmt: skip
        option = getattr(socket, name, None)  # Linux names; other systems keep their defaults
        if option is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.IPPROTO_TCP, option, value)


def _quickack(sock: socket.socket) -> None:
    """ACK at once (Linux TCP_QUICKACK, cleared by the kernel after each ACK, so re-armed).

    python-can's client leaves Nagle on unless ``tcp_tune=True``: its second small frame waits
    for the ACK of the first, which a delayed ACK holds back ~40 ms. A prompt ACK removes that
    stall, whatever the client's options.
    """
    if hasattr(socket, "TCP_QUICKACK"):
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_QUICKACK, 1)


class _HubBus(can.BusABC):
    """In-process participant of a hub: a python-can bus backed by a queue."""

    def __init__(self, hub: SocketcandHub, channel: str, **kwargs: Any) -> None:
        self._hub = hub
        self._queue: queue.SimpleQueue[can.Message | None] = queue.SimpleQueue()
        self.channel_info = f"socketcand hub {channel} (in-process)"
        super().__init__(channel=channel, **kwargs)

    def deliver(self, msg: can.Message) -> None:
        self._queue.put(msg)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self._is_shutdown:
            raise can.CanOperationError("hub bus is shut down")
        self._hub._dispatch(msg, source=self)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self._is_shutdown:
            raise can.CanOperationError("hub bus is shut down")
        try:
            msg = self._queue.get(timeout=timeout)
        except queue.Empty:
            return None, False
        if msg is None:  # put by shutdown() to wake a blocked recv()
            raise can.CanOperationError("hub bus is shut down")
        return msg, False

    def shutdown(self) -> None:
        super().shutdown()
        self._hub._remove_local(self)
        self._queue.put(None)


class _Client:
    """One TCP connection: handshake, then raw-mode frames both ways.

    Output never blocks the sender (the robot's thread, or another client's): elements go into
    this client's queue and out through a non-blocking ``send``; what the socket does not take
    now, this client's own thread sends when the socket is writable. A queue above
    :attr:`SocketcandHub.MAX_QUEUED_BYTES` (a client that does not read) drops the client.
    """

    def __init__(self, hub: SocketcandHub, sock: socket.socket, peer: str) -> None:
        self.hub = hub
        self.sock = sock
        self.peer = peer
        self.state = "hi"  # hi -> open -> raw
        self.ready_at = 0.0
        self.pending: list[bytes] = []
        self.out = bytearray()  # queued output the socket has not taken yet
        self.lock = threading.Lock()
        self.alive = True
        self.thread = threading.Thread(target=self.run, name=f"socketcand-{peer}", daemon=True)

    # ---- output -----------------------------------------------------------------------
    def deliver(self, msg: can.Message) -> None:
        if self.state != "raw" or msg.is_remote_frame or msg.is_error_frame or msg.is_fd:
            return
        element = frame_element(msg)
        with self.lock:
            if time.monotonic() < self.ready_at:
                self.pending.append(element)
                return
            self._send_locked([*self.pending, element])
            self.pending.clear()

    def flush_pending(self) -> None:
        with self.lock:
            if self.pending and time.monotonic() >= self.ready_at:
                self._send_locked(self.pending)
                self.pending = []
            elif self.out:
                self._send_locked([])

    def reply(self, text: str) -> None:
        with self.lock:
            self._send_locked([text.encode("ascii", errors="backslashreplace")])

    def _send_locked(self, elements: list[bytes]) -> None:
        """Queue ``elements`` and send what the socket takes now, without waiting."""
        if not self.alive:
            return
        for element in elements:
            self.out += element
        try:
            while self.out:
                sent = self.sock.send(self.out)
                del self.out[:sent]
        except (BlockingIOError, InterruptedError):
            pass
        except OSError as exc:
            self._drop_locked(f"{exc}")
            return
        if len(self.out) > self.hub.MAX_QUEUED_BYTES:
            self._drop_locked(f"not reading ({len(self.out)} bytes queued)")

    def _drop_locked(self, reason: str) -> None:
        self.alive = False
        self.out.clear()
        self.pending.clear()
        self.hub._say("drop", f"socketcand client {self.peer} dropped: {reason}")
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)

    # ---- input ------------------------------------------------------------------------
    def run(self) -> None:
        buffer = ""
        poller = select.poll()  # not select(): descriptors above 1023 are fine
        fd = self.sock.fileno()
        try:
            self.reply("< hi >")
            handshake_until = time.monotonic() + self.hub.HANDSHAKE_TIMEOUT_S
            while self.alive and not self.hub._closed.is_set():
                if self.state != "raw" and time.monotonic() > handshake_until:
                    self.hub._say(
                        "drop",
                        f"socketcand client {self.peer} dropped: no raw mode within "
                        f"{self.hub.HANDSHAKE_TIMEOUT_S:g} s of connecting",
                    )
                    break
                wait = 0.05
                if self.pending:
                    wait = max(0.0, min(wait, self.ready_at - time.monotonic()))
                events = select.POLLIN | (select.POLLOUT if self.out else 0)
                poller.register(fd, events)
                ready = poller.poll(wait * 1000.0)
                self.flush_pending()
                if not any(
                    ev & (select.POLLIN | select.POLLHUP | select.POLLERR) for _, ev in ready
                ):
                    continue
                try:
                    chunk = self.sock.recv(4096)
                except (BlockingIOError, InterruptedError):
                    continue
                if not chunk:
                    break
                _quickack(self.sock)
                # latin-1: every byte is one character; non-ASCII is then malformed, not a crash
                buffer += chunk.decode("latin-1")
                buffer = self._elements(buffer)
        except OSError:
            pass
        finally:
            self.alive = False
            self.hub._remove_client(self)
            with contextlib.suppress(OSError):
                self.sock.close()

    def _elements(self, buffer: str) -> str:
        """Handle every complete ``< ... >`` in ``buffer``; return the unfinished rest.

        An element starts at the last '<' before its '>' (text outside elements is dropped).
        """
        while True:
            end = buffer.find(">")
            if end < 0:
                start = buffer.rfind("<")
                if start < 0:
                    return ""
                if len(buffer) - start > MAX_ELEMENT:
                    self._malformed(buffer[start : start + 40], "element too long")
                    return ""
                return buffer[start:]
            start = buffer.rfind("<", 0, end)
            if start >= 0:
                self._element(buffer[start : end + 1])
            buffer = buffer[end + 1 :]

    def _malformed(self, element: str, why: str) -> None:
        self.hub.malformed += 1
        self.hub._say(
            "malformed", f"socketcand client {self.peer}: {why}: {element[:60]!a} dropped"
        )

    def _element(self, element: str) -> None:
        if not element.isascii():
            self._malformed(element, "non-ASCII element")
            if self.state != "raw":
                self.reply("< error non-ASCII element >")
            return
        words = element[1:-1].split()
        command = words[0] if words else ""
        if command == "echo":
            self.reply("< echo >")
        elif self.state == "raw":
            msg = parse_send(element)
            if msg is None:
                self._malformed(element, "malformed")
                return
            msg.channel = self.hub.channel
            self.hub._dispatch(msg, source=self)
        elif self.state == "hi" and command == "open" and len(words) == 2:
            if words[1] != self.hub.channel:
                self.reply(f"< error could not open bus {words[1][:40]} >")
            else:
                self.state = "open"
                self.reply("< ok >")
        elif self.state == "open" and words == ["rawmode"]:
            with self.lock:
                self.ready_at = time.monotonic() + self.hub.HOLDOFF_S
            self.state = "raw"
            self.reply("< ok >")
        else:
            self._malformed(element, "unknown command")
            self.reply("< error unknown command >")


class SocketcandHub:
    """TCP socketcand server (raw mode) joined to in-process python-can buses.

    Threads: one accepting connections, one per client. :meth:`close` stops them all.
    Counters: ``frames`` (frames dispatched), ``malformed`` (client elements dropped).
    """

    HOLDOFF_S = 0.05  # after "< ok >" to rawmode, before the first frame goes to that client
    # a client that does not read: about 2 s of a 400 Hz cycle's 7 frames, then it is dropped
    MAX_QUEUED_BYTES = 256 * 1024
    MAX_CLIENTS = 64  # more are refused (a bus of a host, a few monitors)
    # a host silent this long gives up the role (2x the feedback budget of the virtual benches:
    # a host silent longer has ended its own run; a lockstep host sends hundreds of SYNCs a
    # second, a realtime one one a period, SDO set-up one request per answer; stalls of an
    # ordinary desktop stay well below)
    HOST_LEASE_S = 0.5
    # a client that has not entered raw mode this long after connecting is dropped (a
    # half-open or idle connection must not hold one of MAX_CLIENTS forever)
    HANDSHAKE_TIMEOUT_S = 10.0
    # TCP keepalive on every client: a peer gone without a FIN (half-open) is found and
    # dropped within about KEEPALIVE_IDLE_S + KEEPALIVE_COUNT * KEEPALIVE_INTERVAL_S
    KEEPALIVE_IDLE_S, KEEPALIVE_INTERVAL_S, KEEPALIVE_COUNT = 10, 2, 3
    LOG_BURST = 5  # log lines of one kind before they are rate-limited
    LOG_EVERY_S = 10.0  # then one line per kind per this, with the count of those left out

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        channel: str = "can0",
        log: Callable[[str], None] | None = None,
        on_sync_conflict: Callable[[str], None] | None = None,
        on_sync_source_gone: Callable[[str], None] | None = None,
    ) -> None:
        self.channel = channel
        self._log = log or _logger.info
        self._server = socket.create_server((host, port))
        self._server.settimeout(0.1)
        self._host, self._port = self._server.getsockname()[:2]
        self._clients: list[_Client] = []
        self._locals: list[_HubBus] = []
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self.frames = 0
        self.malformed = 0
        self.refused = 0  # connections refused (too many clients)
        self.accept_errors = 0  # accept() failures survived (EMFILE, ...)
        self.foreign_syncs = 0  # SYNCs from a second producer, not forwarded
        self.foreign_host_frames = 0  # host frames (SYNCs too) from a second host, not forwarded
        # one host per bus (CiA 301: one NMT master, one SYNC producer): the first participant
        # to send a host frame; another host's SDO and NMT would reconfigure the drives under
        # the first's run and its SYNCs step a lockstep robot twice, so they are refused
        self._master: object | None = None
        self._master_last = 0.0  # monotonic time of the host's last host frame
        self._master_synced = False  # the host has sent SYNCs (it runs, not only sets up)
        self._conflict_source: object | None = None  # the last second SYNC producer reported
        self._intruder: object | None = None  # the last second host reported
        self._on_sync_conflict = on_sync_conflict
        self._on_sync_source_gone = on_sync_source_gone
        self._said: dict[
            str, tuple[int, float, int]
        ] = {}  # kind -> (lines, window start, left out)
        self._say_lock = threading.Lock()
        self._accept_thread = threading.Thread(
            target=self._accept, name="socketcand-accept", daemon=True
        )
        self._accept_thread.start()

    @property
    def host(self) -> str:
        return self._host

    @property
    def port(self) -> int:
        """The TCP port clients connect to."""
        return self._port

    @property
    def clients(self) -> int:
        """Number of connected TCP clients."""
        with self._lock:
            return len(self._clients)

    def robot_bus(self) -> can.BusABC:
        """A new in-process participant (for :class:`CanDriveServer`): a python-can bus."""
        bus = _HubBus(self, self.channel)
        with self._lock:
            self._locals.append(bus)
        return bus

    def close(self) -> None:
        """Stop accepting, disconnect every client and join the threads. Idempotent."""
        if self._closed.is_set():
            return
        self._closed.set()
        with contextlib.suppress(OSError):
            self._server.close()
        with self._lock:
            clients = list(self._clients)
        for client in clients:
            with contextlib.suppress(OSError):
                client.sock.shutdown(socket.SHUT_RDWR)
        me = threading.current_thread()
        for thread in (self._accept_thread, *(c.thread for c in clients)):
            if thread is not me and thread.ident is not None:
                thread.join(timeout=2.0)

    def __enter__(self) -> SocketcandHub:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- internals ----------------------------------------------------------------------
    def _say(self, kind: str, text: str) -> None:
        """Log ``text``, at most :attr:`LOG_BURST` lines of one ``kind`` per :attr:`LOG_EVERY_S`
        (a flood of garbage or refused connections must not flood the log)."""
        now = time.monotonic()
        with self._say_lock:
            lines, since, left_out = self._said.get(kind, (0, now, 0))
            if now - since >= self.LOG_EVERY_S:
                if left_out:
                    self._log(f"socketcand hub: {left_out} more '{kind}' lines left out")
                lines, since, left_out = 0, now, 0
            if lines >= self.LOG_BURST:
                self._said[kind] = (lines, since, left_out + 1)
                return
            self._said[kind] = (lines + 1, since, left_out)
        self._log(text)

    def _accept(self) -> None:
        while not self._closed.is_set():
            try:
                sock, addr = self._server.accept()
            except TimeoutError:
                continue
            except OSError as exc:
                if self._closed.is_set():
                    return
                # EMFILE/ENFILE (out of descriptors), ENOBUFS, ECONNABORTED...: the clients
                # already connected go on; try again shortly
                self.accept_errors += 1
                self._say("accept", f"socketcand hub: accept failed ({exc}); still listening")
                self._closed.wait(0.1)
                continue
            peer = f"{addr[0]}:{addr[1]}"
            try:
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                _keepalive(sock, self.KEEPALIVE_IDLE_S, self.KEEPALIVE_INTERVAL_S,
                           self.KEEPALIVE_COUNT)  # fmt: skip
                _quickack(sock)
                sock.setblocking(False)  # sends never wait (_Client._send_locked)
                with self._lock:
                    full = len(self._clients) >= self.MAX_CLIENTS
                if full:
                    self.refused += 1
                    self._say("refused", f"socketcand hub: {peer} refused: too many clients")
                    with contextlib.suppress(OSError):
                        sock.send(b"< error too many clients >")
                    sock.close()
                    continue
                client = _Client(self, sock, peer)
                with self._lock:
                    if self._closed.is_set():
                        sock.close()
                        return
                    self._clients.append(client)
                client.thread.start()
            except (OSError, RuntimeError) as exc:  # RuntimeError: no thread to be had
                self.accept_errors += 1
                self._say("accept", f"socketcand hub: client {peer} not served ({exc})")
                with contextlib.suppress(OSError):
                    sock.close()
                self._remove_client_sock(sock)

    def _remove_client_sock(self, sock: socket.socket) -> None:
        with self._lock:
            self._clients = [c for c in self._clients if c.sock is not sock]

    @staticmethod
    def _host_frame(msg: can.Message) -> str | None:
        """What a frame only a host sends is (``co.host_frame_name``), else None."""
        if msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame:
            return None
        return co.host_frame_name(msg.arbitration_id)

    def _dispatch(self, msg: can.Message, source: object) -> None:
        """A frame sent by ``source`` reaches every other participant (a host frame only if
        ``source`` holds the host role)."""
        conflict = intruder = None
        what = self._host_frame(msg)
        with self._lock:  # the role is granted here, atomically: one of two hosts gets it
            if what is not None:
                now = time.monotonic()
                if self._master is None or (now - self._master_last > self.HOST_LEASE_S):
                    # the first host, or one after the last fell silent (a raw client's stray
                    # SYNC does not lock the bus for the host that attaches later)
                    self._master, self._master_synced = source, False
                if source is self._master:
                    self._master_last = now
                    self._master_synced |= what == "SYNC"
                else:
                    self.foreign_host_frames += 1
                    if what == "SYNC":
                        self.foreign_syncs += 1
                        if source is not self._conflict_source:  # said once per intruder
                            self._conflict_source = source
                            conflict = (
                                f"a second SYNC producer ({_name(source)}) on the bus besides "
                                f"{_name(self._master)}: its SYNCs are not forwarded"
                            )
                    elif source is not self._intruder:  # said once per intruder
                        self._intruder = source
                        intruder = (
                            f"a second host ({_name(source)}, {what}) on the bus besides "
                            f"{_name(self._master)}: its host frames are not forwarded"
                        )
                    msg = None  # type: ignore[assignment]
            if msg is not None:
                clients = [c for c in self._clients if c is not source]
                locals_ = [b for b in self._locals if b is not source]
                self.frames += 1
        if intruder is not None:
            self._log(f"socketcand hub: {intruder}")
        if conflict is not None:
            self._log(f"socketcand hub: {conflict}")
            if self._on_sync_conflict is not None:
                self._on_sync_conflict(conflict)
        if msg is None:
            return
        for client in clients:
            client.deliver(msg)
        for bus in locals_:
            bus.deliver(
                can.Message(
                    timestamp=msg.timestamp or time.time(),
                    arbitration_id=msg.arbitration_id,
                    is_extended_id=msg.is_extended_id,
                    is_remote_frame=msg.is_remote_frame,
                    is_error_frame=msg.is_error_frame,
                    dlc=msg.dlc,
                    data=bytes(msg.data or b""),
                    channel=self.channel,
                    is_rx=True,
                )
            )

    def _remove_client(self, client: _Client) -> None:
        with self._lock:
            if client in self._clients:
                self._clients.remove(client)
            was_sync_source = client is self._master and self._master_synced
            if client is self._master:
                self._master = None
        if was_sync_source and not self._closed.is_set():
            reason = f"the SYNC producer {client.peer} (the host) disconnected"
            self._log(f"socketcand hub: {reason}")
            if self._on_sync_source_gone is not None:
                self._on_sync_source_gone(reason)

    def _remove_local(self, bus: _HubBus) -> None:
        with self._lock:
            if bus in self._locals:
                self._locals.remove(bus)
