"""The bus side of :class:`~drivers.can_arm.CanArm`: sending (one write per batch where the bus
can), the ``candump -L`` traffic log, the receive thread (:class:`Receiver`, which a lockstep
cycle pauses to read the bus itself) and the dispatch of received frames to canopen, the
feedback collector and the EMCY record.

:class:`BusLink` is a mixin of :class:`~drivers.can_arm.CanArm`: it works on the state that
``CanArm.__init__`` sets up (bus, listeners, log queue, feedback slots).

Imports: :mod:`drivers.can_arm.objects`, :mod:`drivers.arm`, :mod:`drivers.candump`.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections.abc import Callable

import can
import canopen

from drivers.arm import Fault, LinkError
from drivers.can_arm.objects import (
    EMCY,
    LOCKSTEP,
    TPDO1,
    TPDO2,
    TPDO_CODECS,
    Frame,
    fault_text,
    parse_frame,
)
from drivers.protocol import cia402 as co

LOG_FLUSH_EVERY = 50  # frames
RECEIVER_POLL_S = 0.01  # receive thread wake-up: bounds close() and pausing it
PAUSE_TIMEOUT_S = 1.0  # the receive thread did not stop reading: keep it (threaded cycle)

_logger = logging.getLogger(__name__)


def channel_name(bus: can.BusABC) -> str:
    """A whitespace-free channel name for the log (candump -L has one token there)."""
    for attr in ("channel_id", "channel", "_channel"):
        value = getattr(bus, attr, None)
        if isinstance(value, str | int) and str(value):
            name = re.sub(r"[^A-Za-z0-9_.:/-]", "_", str(value))
            return f"can{name}" if name.isdigit() else name
    return "can0"


class ArmNetwork(canopen.Network):
    """canopen Network whose sends go through the arm (traffic log, counters)."""

    def __init__(self, arm: BusLink, bus: can.BusABC) -> None:
        super().__init__(bus)
        self._arm = arm

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        if not self.bus:
            raise RuntimeError("Not connected to CAN bus")
        self._arm._threaded_receive()  # canopen expects its answers from the receive thread
        # a host that has heard another while opening sends nothing more (canopen's SDO retry
        # and abort included): the refusal instead
        self._arm._refuse_while_opening()
        msg = can.Message(
            arbitration_id=can_id,
            is_extended_id=can_id > 0x7FF,
            data=data,
            is_remote_frame=remote,
            is_rx=False,
        )
        with self.send_lock:
            self._arm._send(msg)
        self.check()


class Receiver:
    """The host's receive thread (python-can's Notifier's job), which a cycle can pause.

    It calls ``read(timeout)`` (read what arrives, dispatch it) until stopped. While paused it
    does not touch the bus, so the caller's own thread may read it. As with can.Notifier, an
    exception from ``read`` ends the thread and is kept in :attr:`exception` (canopen's
    ``Network.check()`` raises it on the next send).
    """

    def __init__(self, read: Callable[[float], None], name: str) -> None:
        self._read = read
        self.exception: Exception | None = None
        self._running = threading.Event()
        self._running.set()
        self._idle = threading.Event()
        self._stopped = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stopped:
            if not self._running.is_set():
                self._idle.set()
                self._running.wait()
                continue
            self._idle.clear()
            if not self._running.is_set():  # paused meanwhile: the pauser may have seen idle
                continue
            try:
                self._read(RECEIVER_POLL_S)
            except Exception as exc:
                self.exception = exc
                _logger.debug("receive thread ended: %s", exc)
                break
        self._idle.set()

    def pause(self, timeout: float = PAUSE_TIMEOUT_S) -> bool:
        """Stop reading; True once the thread is no longer inside ``read``."""
        self._running.clear()
        return self._idle.wait(timeout)

    def resume(self) -> None:
        self._running.set()

    def stop(self, timeout: float) -> None:
        self._stopped = True
        self._running.set()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout)


class BusLink:
    """Frames in and out, the traffic log, and who reads the bus (a mixin of CanArm)."""

    # ---- frames ----------------------------------------------------------------------------
    def _send(self, msg: can.Message) -> None:
        """Send one frame; log it first (direction T). Raises can.CanError / RuntimeError."""
        bus = self.bus
        if bus is None:
            raise RuntimeError("CAN bus is closed")
        with self._send_lock:
            msg.timestamp = time.time()
            msg.is_rx = False
            self._log(msg)
            bus.send(msg)
            self.stats.frames_sent += 1

    def _send_frames(self, frames: list[tuple[int, bytes]]) -> None:
        """Send standard data frames ``(id, data)`` in order, in one write where the bus can.

        Logged with the time of sending (direction T): first, as :meth:`_send` does; in direct
        receive, just after the write, while the drives work on the frames.
        Raises can.CanError / RuntimeError.
        """
        bus = self.bus
        if bus is None:
            raise RuntimeError("CAN bus is closed")
        with self._send_lock:
            stamp = time.time()
            if self._writer is not None:
                self._log_frames_of(stamp, frames, rx=False)
            try:
                if self._bus_send_frames is not None:
                    self._bus_send_frames(frames)
                else:
                    for cob_id, data in frames:
                        bus.send(
                            can.Message(
                                timestamp=stamp,
                                arbitration_id=cob_id,
                                data=data,
                                is_extended_id=False,
                                is_rx=False,
                            )
                        )
            finally:
                if self._log_queue:
                    with self._log_lock:
                        self._drain_log()
            self.stats.frames_sent += len(frames)

    def _log(self, msg: can.Message) -> None:
        if self._writer is None:
            return
        with self._log_lock:
            writer = self._writer
            if writer is None:
                return
            self._drain_log()  # frames logged earlier go first
            writer.write_message(msg)
            self._log_frames += 1
            if self._log_frames % LOG_FLUSH_EVERY == 0:
                writer.flush()

    def _log_frames_of(self, stamp: float, frames: list[tuple[int, bytes]], rx: bool) -> None:
        """Log standard data frames seen at ``stamp``; in direct receive the lines are queued
        and written by the next :meth:`_send_frames` after its write (off the critical path)."""
        with self._log_lock:
            self._log_queue.append((stamp, frames, rx))
            if not self._direct:
                self._drain_log()

    def _drain_log(self) -> None:
        """Write the queued log lines (hold ``_log_lock``); flush every LOG_FLUSH_EVERY frames."""
        writer, queue = self._writer, self._log_queue
        if writer is None:
            queue.clear()
            return
        before = count = self._log_frames
        for stamp, frames, rx in queue:
            writer.write_frames(stamp, frames, rx)
            count += len(frames)
        queue.clear()
        self._log_frames = count
        if before // LOG_FLUSH_EVERY != count // LOG_FLUSH_EVERY:
            writer.flush()

    def _read_frames(self, timeout: float) -> None:
        """Wait up to ``timeout`` for frames, then dispatch every frame that has arrived.

        The receive thread's loop, and the cycle's own in lockstep. Raises what the bus raises.
        """
        bus = self.bus
        if bus is None:
            raise RuntimeError("CAN bus is closed")
        if self._bus_recv_frames is None:
            msg = bus.recv(timeout)
            if msg is not None:
                for listener in self._listeners:
                    listener.on_message_received(msg)
                self._on_frame(msg)
            return
        batch = self._bus_recv_frames(timeout)
        if not batch:
            return
        stamp, now = time.time(), time.monotonic()
        run: list[tuple[int, bytes]] = []  # standard data frames, dispatched a run at a time
        for item in batch:
            if type(item) is tuple:
                run.append(item)
                continue
            if run:
                self._on_standard_frames(run, stamp, now)
                run = []
            for listener in self._listeners:  # an extended, remote, error or FD frame
                listener.on_message_received(item)
            self._on_frame(item)
        if run:
            self._on_standard_frames(run, stamp, now)

    def _on_standard_frames(
        self, frames: list[tuple[int, bytes]], stamp: float, now: float
    ) -> None:
        """Received standard data frames: log, canopen, counters, feedback, EMCY (in order)."""
        if self._writer is not None:
            self._log_frames_of(stamp, frames, rx=True)
        self.stats.frames_received += len(frames)
        network = self.network
        notify = network.notify if network is not None else None
        routes, host_ids, heartbeats = self._routes, self._host_ids, self._heartbeat_ids
        for cob_id, data in frames:
            if cob_id in host_ids:
                self._foreign_host(cob_id)
            elif cob_id in heartbeats:
                self._host_heartbeat(cob_id, data)
            if notify is not None:
                try:  # what canopen's MessageListener does with a Message
                    notify(cob_id, bytearray(data), stamp)
                except Exception as exc:
                    _logger.error(str(exc))
            route = routes.get(cob_id)
            if route is None:
                continue
            try:
                codec = TPDO_CODECS.get(route[0])
                if codec is not None and len(data) == codec.size:  # feedback: the cyclic case
                    self._collect(route[0], route[1], codec.unpack(data), now)
                    continue
                frame = parse_frame(routes, cob_id, data)
                if frame is not None:
                    self._handle(frame, now)
            except Exception as exc:  # never kill the receive thread
                self._dispatch_failed(cob_id, exc)

    def _on_frame(self, msg: can.Message) -> None:
        """A received Message (extended, remote, error or FD frame, or any frame of a bus
        without batches): log, count, then as :meth:`_on_standard_frames` (canopen has had it
        from its listeners)."""
        now = time.monotonic()
        self._log(msg)
        self.stats.frames_received += 1
        if not (msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame):
            if msg.arbitration_id in self._host_ids:
                self._foreign_host(msg.arbitration_id)
            elif msg.arbitration_id in self._heartbeat_ids:
                self._host_heartbeat(msg.arbitration_id, bytes(msg.data))
        try:
            frame = parse_frame(
                self._routes,
                msg.arbitration_id,
                msg.data,
                is_extended_id=msg.is_extended_id,
                is_remote_frame=msg.is_remote_frame,
                is_error_frame=msg.is_error_frame,
            )
            if frame is not None:
                self._handle(frame, now)
        except Exception as exc:  # never kill the receive thread
            self._dispatch_failed(msg.arbitration_id, exc)

    def _refuse_beside_another_host(self) -> None:
        """Raise the one-line refusal if another host's frames were seen.

        Two hosts that start together both hear a silent bus; each then hears the other's
        set-up (on a socketcand hub, which grants the host role to the first one's frames and
        forwards nothing of the second's, only the second hears anything: the first goes on).
        """
        if self._foreign_host_frames or self._claim_lost:
            seen = (
                f"{self._foreign_host_frames} of its frames seen (first: "
                f"{self._foreign_host_first})"
                if self._foreign_host_frames
                else self._claim_lost
            )
            raise LinkError(
                f"another host is on the bus ({channel_name(self.bus)}): {seen}; not attaching "
                "(stop that run first; one host per bus)"
            )

    def _another_host(self) -> bool:
        """Whether another host's frames, or a heartbeat that wins the bus, were seen."""
        return bool(self._foreign_host_frames or self._claim_lost)

    def _send_heartbeat(self) -> None:
        """Send the host's heartbeat (co.host_heartbeat): claiming, or holding the bus."""
        assert self._claim is not None
        node, nonce = self._claim
        data = co.host_heartbeat(self._holding, nonce)
        self._send(can.Message(arbitration_id=co.HEARTBEAT_BASE + node, data=data,
                               is_extended_id=False))  # fmt: skip

    def _host_heartbeat(self, cob_id: int, data: bytes) -> None:
        """Another host's heartbeat (a device's is ignored): while we hold the bus, answered
        with ours, so that a host attaching beside an idle one hears it; before, it wins the
        bus if that host holds it already, if we have not claimed yet, or if its claim is the
        lower (node-ID, nonce): the same outcome on both hosts, whichever frame came first."""
        parsed = co.parse_host_heartbeat(data)
        if parsed is None:
            return
        holding, nonce = parsed
        if self._holding:
            try:
                self._send_heartbeat()
            except (can.CanError, RuntimeError, OSError) as exc:
                self._note_error(f"host heartbeat: {exc}")
            return
        theirs = (cob_id - co.HEARTBEAT_BASE, nonce)
        with self._claim_lock:  # against _claim_the_bus setting our claim meanwhile
            ours = self._claim
            if not self._claim_lost and (holding or ours is None or theirs < ours):
                what = "holding the bus" if holding else "claiming it"
                self._claim_lost = f"its heartbeat 0x{cob_id:03X} seen ({what})"

    def _refuse_while_opening(self) -> None:
        """During open (set-up by SDO), another host's frames end it with the refusal: an
        answer may have been the other host's, and its set-up would be disturbed by ours."""
        if not self._is_open and self.bus is not None:
            self._refuse_beside_another_host()

    def _foreign_host(self, cob_id: int) -> None:
        """A host frame received: another host's (see CanArm.__init__), counted before canopen
        sees anything after it (an SDO answer to our set-up comes after it on the bus)."""
        if not self._foreign_host_frames:
            self._foreign_host_first = self._host_ids[cob_id]
        self._foreign_host_frames += 1
        if cob_id == co.SYNC_ID:
            self._foreign_syncs += 1

    def _dispatch_failed(self, cob_id: int, exc: Exception) -> None:
        """A received frame the host could not use, kept in the link's errors (both receive
        paths): a ValueError is a frame that does not parse, anything else a handler's bug."""
        if isinstance(exc, ValueError):
            self._note_error(f"0x{cob_id:03X}: {exc}")
        else:
            self._note_error(f"listener: {type(exc).__name__}: {exc}")

    def _handle(self, frame: Frame, now: float) -> None:
        kind, j, values = frame
        if kind in (TPDO1, TPDO2):
            self._collect(kind, j, values, now)
        elif kind == EMCY:
            code, _register = values
            if code == co.ERR_NONE:
                self._emcy.pop(j, None)  # error reset
            else:
                self._emcy[j] = Fault(j, code, fault_text(code))
        elif values[0] == co.NMT_STATE_BOOTUP:
            self._booted.add(self.node_ids[j])

    def _collect(self, kind: str, j: int, values: tuple[int, ...], now: float) -> None:
        """A TPDO of drive ``j``: keep it if a SYNC of ours is waiting for it."""
        with self._fb_lock:
            since = self._collect_since
            if since is None or now < since:
                return  # not waiting, or stale (from before our SYNC)
            slots = self._fb1 if kind == TPDO1 else self._fb2
            if slots[j] is not None:
                return  # a duplicate for this SYNC (another SYNC producer on the bus)
            slots[j] = values
            self._missing -= 1
            if self._missing == 0:
                self._fb_last_at = now
                self._collect_since = None
                self._fb_event.set()

    # ---- who reads the bus ---------------------------------------------------------------------
    def _threaded_receive(self) -> None:
        """The receive thread reads the bus (canopen's SDO and NMT need it).

        From another thread while a cycle reads the bus itself, it only asks: the cycle gives
        the bus back when it ends, and later cycles leave it to the thread.
        """
        if not self._direct:
            return
        if threading.get_ident() != self._direct_owner:
            self._direct_refused = True
            return
        self._direct = False
        with self._log_lock:
            self._drain_log()
        if self._receiver is not None:
            self._receiver.resume()

    def _direct_receive(self) -> None:
        """Lockstep cycles: the caller's thread reads the bus itself, with no hand-over between
        threads per cycle. Anything canopen sends (SDO for faults(), disable(), ...) gives the
        bus back to the receive thread."""
        if self._direct or self.mode != LOCKSTEP or self._receiver is None:
            return
        if self._direct_refused:  # canopen was used from another thread during a cycle
            return
        if self._receiver.pause():
            self._direct_owner = threading.get_ident()
            self._direct = True
        else:
            self._receiver.resume()  # still busy in a callback: stay threaded


__all__ = ["ArmNetwork", "BusLink", "Receiver", "channel_name"]
