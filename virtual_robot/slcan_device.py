"""The adapter side of the LAWICEL "slcan" serial-line CAN protocol, on a pseudo-terminal.

A real USB slcan adapter (LAWICEL CANUSB, CANable, ...) is a serial device that takes ASCII
commands terminated by CR and bridges them to a CAN bus. :class:`SlcanPtyBus` plays that device
on the master end of a pty it opens itself; the host opens the slave end (:attr:`channel_path`)
exactly as it would open the adapter, e.g.
``can.Bus(interface="slcan", channel=path, bitrate=1000000, sleep_after_open=0)``.
For the robot the device is an ordinary python-can bus: frames the host transmits come out of
:meth:`recv`; :meth:`send` puts a frame "on the bus", i.e. reports it to the host.

Commands understood (:class:`SlcanDeviceProtocol`, replies in quotes, CR = "\\r"):

=================== ===========================================================================
``Sn`` (n = 0..9)    bit rate 10k, 20k, 50k, 100k, 125k, 250k, 500k, 750k, 1M (83.3k for 9),
                     only while closed: "\\r"
``sxxyy``            BTR0/BTR1 register bit timing, only while closed: "\\r"
``O`` / ``L`` / ``C`` open / open listen-only / close: "\\r"
``V`` ``v`` ``N``    version "V1013\\r", "v1013\\r", serial number "NDDB1\\r"
``F``                status flags "F00\\r"
``Z0``/``Z1``        timestamps off/on (on: 4 hex digits of ms, 0..EA5F, after each frame)
``X..`` ``M..`` ``m..`` auto-poll, acceptance code and mask: accepted, "\\r"
``tiiil<data>``      standard frame, l = 0..8 and 2·l hex digits; "z\\r"
``Tiiiiiiiil<data>`` extended frame; "Z\\r"
``riiil`` ``Riiiiiiiil`` remote frames; "z\\r" / "Z\\r"
(empty line)         no reply (hosts send bare CRs to flush the adapter's line buffer)
anything else        BEL "\\a", the line is dropped
=================== ===========================================================================

Lenient where a real adapter would not matter: frames from the host are accepted while the
channel is closed (that opens it), and O/L/C always succeed. Frames towards the host are sent
only while the channel is open, as on a real adapter (python-can sends C, S8, O when it opens).
CAN FD (``d``/``D``/``b``/``B``, ``Y``) is not supported (BEL).

Besides python-can's ``recv``/``send``, the bus has a batch path without Message objects for
:class:`~virtual_robot.can_server.CanDriveServer`: :meth:`SlcanPtyBus.recv_frames` returns every
frame of one read as ``(id, data, extended, remote)`` tuples and holds the replies ("z\r" acks)
back; :meth:`SlcanPtyBus.send_frames` writes them and the answer frames in one write. A host
sees the same bytes in the same order as from one frame at a time, in fewer writes.

The device keeps its own descriptor of the pty slave open, so reads on the master never hit
EIO when the host closes the port, and a host can close and reopen it at will. pyserial flushes
the input queue when it opens a port, so nothing stale from an earlier session reaches a new
host. If the host stops reading, frames towards it are dropped (after a bounded wait that keeps
a line from being cut in half) instead of blocking the robot.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import select
import string
import threading
import time
from collections import deque
from typing import Any

import can

from virtual_robot.raw_pty import open_raw_pty

BEL = b"\a"
CR = b"\r"
MAX_LINE = 64  # longest valid command is 26 characters ("T" + 8 + 1 + 16)
BITRATES = {
    "S0": 10_000,
    "S1": 20_000,
    "S2": 50_000,
    "S3": 100_000,
    "S4": 125_000,
    "S5": 250_000,
    "S6": 500_000,
    "S7": 750_000,
    "S8": 1_000_000,
    "S9": 83_300,
}
_HEX = frozenset(string.hexdigits)
_STD_FRAME = re.compile(rb"t([0-9A-Fa-f]{3})([0-8])([0-9A-Fa-f]*)")
_STD_LINE = re.compile(rb"t([0-9A-Fa-f]{3})([0-8])([0-9A-Fa-f]{0,16})\r")
_STD_LINES = re.compile(rb"(?:t[0-9A-Fa-f]{3}[0-8][0-9A-Fa-f]{0,16}\r)+")

# A frame as the parser hands it on: (CAN id, data, extended id, remote). A remote frame's data
# is ``dlc`` zero bytes (only its length means anything).
RawFrame = tuple[int, bytes, bool, bool]


class SlcanDeviceProtocol:
    """Pure LAWICEL device-side protocol: bytes from the host in, replies and frames out."""

    def __init__(
        self,
        *,
        version: str = "1013",
        serial_number: str = "DDB1",
        ack_transmit: bool = True,
        channel: str | None = None,
    ) -> None:
        self.version = version
        self.serial_number = serial_number
        self.ack_transmit = ack_transmit  # "z\r"/"Z\r" after a transmit request, as LAWICEL
        self.channel = channel
        self.is_open = False
        self.listen_only = False
        self.timestamps = False
        self.bitrate: int | None = None
        self.btr: str | None = None
        self.malformed = 0
        self._buffer = bytearray()
        self._discarding = False  # inside an over-long line: drop it up to its CR

    def feed(self, data: bytes) -> tuple[bytes, list[can.Message]]:
        """Process bytes from the host: (reply bytes for the host, frames the host sent)."""
        replies, raw = self.feed_raw(data)
        return replies, [self.to_message(frame) for frame in raw]

    def feed_raw(self, data: bytes) -> tuple[bytes, list[RawFrame]]:
        """:meth:`feed` with each frame as a :data:`RawFrame` tuple instead of a Message."""
        if not self._buffer and not self._discarding and not self.listen_only:
            fast = self._standard_frames(data)
            if fast is not None:
                return fast
        replies = bytearray()
        frames: list[RawFrame] = []
        buffer = self._buffer
        buffer.extend(data)
        if CR in buffer:
            *lines, rest = bytes(buffer).split(CR)
            buffer[:] = rest
            if self._discarding:  # the tail of an over-long line
                self._discarding = False
                del lines[0]
            for line in lines:
                reply, frame = self.command_raw(line)
                replies += reply
                if frame is not None:
                    frames.append(frame)
        if len(buffer) > MAX_LINE:  # no CR in sight: drop the line up to its CR
            if not self._discarding:
                self.malformed += 1
                replies += BEL
            self._discarding = True
            buffer.clear()
        return bytes(replies), frames

    def _standard_frames(self, data: bytes) -> tuple[bytes, list[RawFrame]] | None:
        """The cyclic case in one pass: ``data`` is whole, valid standard data frame lines
        (what :meth:`command_raw` would accept one by one). None if it is anything else."""
        if _STD_LINES.fullmatch(data) is None:
            return None
        frames: list[RawFrame] = []
        for can_id, dlc, body in _STD_LINE.findall(data):
            if len(body) != 2 * int(dlc) or int(can_id, 16) > 0x7FF:
                return None
            frames.append((int(can_id, 16), bytes.fromhex(body.decode()), False, False))
        self.is_open = True  # lenient: a host that transmits wants the channel open
        return self._ack_std * len(frames), frames

    def command(self, line: bytes) -> tuple[bytes, can.Message | None]:
        """One CR-terminated command (without the CR): (reply, frame sent by the host or None)."""
        reply, frame = self.command_raw(line)
        return reply, None if frame is None else self.to_message(frame)

    def command_raw(self, line: bytes) -> tuple[bytes, RawFrame | None]:
        """:meth:`command` with the frame as a :data:`RawFrame` tuple."""
        if line[:1] == b"t" and not self.listen_only:  # the cyclic path: a standard data frame
            match = _STD_FRAME.fullmatch(line)
            if match is not None and len(match[3]) == 2 * int(match[2]):
                can_id = int(match[1], 16)
                if can_id <= 0x7FF:
                    self.is_open = True  # lenient: a host that transmits wants the channel open
                    return self._ack_std, (can_id, bytes.fromhex(match[3].decode()), False, False)
        line = line.strip(b"\n")  # tolerate CR LF line ends
        if not line:
            return b"", None
        try:
            text = line.decode("ascii")
        except UnicodeDecodeError:
            return self._bad()
        if not text.isprintable():
            return self._bad()
        cmd, arg = text[0], text[1:]
        if cmd in "tTrR":
            frame = self._parse_frame(text)
            if frame is None or self.listen_only:
                return self._bad()
            self.is_open = True  # lenient: a host that transmits wants the channel open
            ack = (b"z" if cmd in "tr" else b"Z") + CR if self.ack_transmit else CR
            return ack, frame
        if cmd == "S" and text in BITRATES and not self.is_open:
            self.bitrate, self.btr = BITRATES[text], None
            return CR, None
        if cmd == "s" and len(arg) == 4 and set(arg) <= _HEX and not self.is_open:
            self.btr, self.bitrate = arg.upper(), None
            return CR, None
        if text in ("O", "L"):
            self.is_open, self.listen_only = True, text == "L"
            return CR, None
        if text == "C":
            self.is_open = self.listen_only = False
            return CR, None
        if text in ("V", "v"):
            return f"{cmd}{self.version}\r".encode(), None
        if text == "N":
            return f"N{self.serial_number}\r".encode(), None
        if text == "F":
            return b"F00\r", None
        if text in ("Z0", "Z1"):
            self.timestamps = text == "Z1"
            return CR, None
        if cmd == "X" and arg in ("0", "1"):
            return CR, None
        if cmd in "Mm" and len(arg) == 8 and set(arg) <= _HEX:
            return CR, None
        return self._bad()

    def _bad(self) -> tuple[bytes, None]:
        self.malformed += 1
        return BEL, None

    def _parse_frame(self, text: str) -> RawFrame | None:
        extended = text[0] in "TR"
        remote = text[0] in "rR"
        id_len = 8 if extended else 3
        head = text[1 : 1 + id_len + 1]
        if len(head) != id_len + 1 or not set(head) <= _HEX or not head[-1].isdigit():
            return None
        can_id, dlc = int(head[:-1], 16), int(head[-1])
        if can_id > (0x1FFFFFFF if extended else 0x7FF) or dlc > 8:
            return None
        body = text[2 + id_len :]
        if remote:
            if body:
                return None
            return can_id, bytes(dlc), extended, True  # a remote frame: only its length counts
        if len(body) != 2 * dlc or not set(body) <= _HEX:
            return None
        return can_id, bytes.fromhex(body), extended, False

    def to_message(self, frame: RawFrame) -> can.Message:
        """The python-can Message of a parsed frame (received now, on this channel)."""
        can_id, data, extended, remote = frame
        return can.Message(
            timestamp=time.time(),
            arbitration_id=can_id,
            is_extended_id=extended,
            is_remote_frame=remote,
            dlc=len(data),
            data=b"" if remote else data,
            channel=self.channel,
            is_rx=True,
        )

    @property
    def _ack_std(self) -> bytes:
        return b"z\r" if self.ack_transmit else CR

    def encode_frame(self, can_id: int, data: bytes) -> bytes:
        """:meth:`encode` of a standard data frame given as its id and data (no Message)."""
        if self.timestamps or len(data) > 8:
            return self.encode(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))
        return b"t%03X%d%s\r" % (can_id & 0x7FF, len(data), data.hex().upper().encode())

    def encode(self, msg: can.Message) -> bytes:
        """The line that reports ``msg`` to the host; b"" for what slcan cannot carry."""
        if msg.is_error_frame or msg.is_fd or not 0 <= msg.dlc <= 8:
            return b""
        if msg.is_extended_id:
            head = f"{'R' if msg.is_remote_frame else 'T'}{msg.arbitration_id & 0x1FFFFFFF:08X}"
        else:
            head = f"{'r' if msg.is_remote_frame else 't'}{msg.arbitration_id & 0x7FF:03X}"
        line = f"{head}{msg.dlc:d}"
        if not msg.is_remote_frame:
            line += bytes(msg.data[: msg.dlc]).hex().upper()
        if self.timestamps:
            line += f"{int(time.monotonic() * 1000) % 60000:04X}"
        return line.encode("ascii") + CR


class SlcanPtyBus(can.BusABC):
    """A python-can bus that *is* an slcan adapter: the host talks slcan to :attr:`channel_path`.

    Counters: ``frames_in`` (frames from the host), ``frames_out`` (frames reported to the host),
    ``dropped`` (frames not reported: channel closed or host not reading), and the protocol's
    ``malformed``.
    """

    WRITE_WAIT_S = 0.25  # how long a blocked write may wait for the host to read

    def __init__(
        self,
        channel: Any = None,
        *,
        ack_transmit: bool = True,
        can_filters: can.typechecking.CanFilters | None = None,
        **kwargs: Any,
    ) -> None:
        master, slave, path = open_raw_pty(keep_slave_open=True)
        self._master: int | None = master
        self._slave: int | None = slave  # kept open: no EIO on the master between host sessions
        self._wake_r, self._wake_w = os.pipe()  # shutdown() wakes a recv() blocked in select
        self._path = path
        self.device = SlcanDeviceProtocol(ack_transmit=ack_transmit, channel=path)
        self._rx: deque[RawFrame] = deque()
        self._replies = bytearray()  # replies held back by recv_frames() for the next write
        self._write_lock = threading.Lock()
        self._read_lock = threading.Lock()
        self.frames_in = 0
        self.frames_out = 0
        self.dropped = 0
        self.channel_info = f"slcan device on {path}"
        super().__init__(channel=path, can_filters=can_filters, **kwargs)

    @property
    def channel_path(self) -> str:
        """The pty slave the host opens as its slcan adapter (e.g. /dev/pts/7)."""
        return self._path

    # ---- host -> device ---------------------------------------------------------------
    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._read_lock:
            while True:
                if self._rx:
                    return self.device.to_message(self._rx.popleft()), False
                master = self._master
                if master is None:
                    raise can.CanOperationError("slcan device is shut down")
                left = None if deadline is None else max(0.0, deadline - time.monotonic())
                ready, _, _ = select.select([master, self._wake_r], [], [], left)
                if self._master is None:
                    raise can.CanOperationError("slcan device is shut down")
                if master in ready:
                    self._read_available(master, left, hold_replies=False)
                if not self._rx and deadline is not None and time.monotonic() >= deadline:
                    return None, False

    def recv_frames(self, timeout: float | None) -> list[RawFrame]:
        """Every frame the host has sent so far, waiting up to ``timeout`` for the first bytes.

        One ``select`` and one ``read``; may return [] before the timeout (a partial line). The
        replies to what was read ("z\r" acks, ...) are held back and written by the next
        :meth:`send_frames` (or :meth:`send`), ahead of its frames: call it after every batch,
        with no frames if there is nothing to send.
        """
        with self._read_lock:
            if not self._rx:
                master = self._master
                if master is None:
                    raise can.CanOperationError("slcan device is shut down")
                ready, _, _ = select.select([master, self._wake_r], [], [], timeout)
                if self._master is None:
                    raise can.CanOperationError("slcan device is shut down")
                if master in ready:
                    self._read_available(master, timeout, hold_replies=True)
            frames = list(self._rx)
            self._rx.clear()
            return frames

    def _read_available(self, master: int, left: float | None, *, hold_replies: bool) -> None:
        try:
            data = os.read(master, 4096)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno != errno.EIO:
                raise can.CanOperationError(f"slcan device read failed: {exc}") from exc
            time.sleep(0.01 if left is None else min(0.01, left))  # no host: nothing to read
            return
        replies, frames = self.device.feed_raw(data)
        if replies:
            if hold_replies:
                with self._write_lock:
                    self._replies += replies
            else:
                self._write(self._held_replies() + replies)
        self.frames_in += len(frames)
        self._rx.extend(frames)

    # ---- device -> host ---------------------------------------------------------------
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Report a frame to the host (dropped while the host has the channel closed)."""
        if self._master is None:
            raise can.CanOperationError("slcan device is shut down")
        line = self.device.encode(msg) if self.device.is_open else b""
        held = self._held_replies()
        if line:
            sent = self._write(held + line)
        else:
            sent = False
            if held:
                self._write(held)
        if sent:
            self.frames_out += 1
        else:
            self.dropped += 1

    def send_frames(self, frames: list[tuple[int, bytes]]) -> None:
        """Report standard data frames (id, data) to the host in one write, after the replies
        :meth:`recv_frames` held back; the frames are dropped while the channel is closed."""
        if self._master is None:
            raise can.CanOperationError("slcan device is shut down")
        data = self._held_replies()
        sent = 0
        if frames and self.device.is_open:
            if self.device.timestamps:
                encode = self.device.encode_frame
                data += b"".join([encode(can_id, payload) for can_id, payload in frames])
            else:  # encode_frame of each, in one pass
                data += "".join(
                    [f"t{i & 0x7FF:03X}{len(d)}{d.hex().upper()}\r" for i, d in frames]
                ).encode()
            sent = len(frames)
        if data and not self._write(data):
            sent = 0
        self.frames_out += sent
        self.dropped += len(frames) - sent

    def _held_replies(self) -> bytes:
        if not self._replies:
            return b""
        with self._write_lock:
            held = bytes(self._replies)
            self._replies.clear()
            return held

    def _write(self, data: bytes) -> bool:
        """Write all of ``data`` or, if the host does not read for WRITE_WAIT_S, give up."""
        with self._write_lock:
            master = self._master
            if master is None:
                return False
            view = memoryview(data)
            give_up = time.monotonic() + self.WRITE_WAIT_S
            while view:
                try:
                    n = os.write(master, view)
                except BlockingIOError:
                    left = give_up - time.monotonic()
                    if left <= 0:
                        return False
                    select.select([], [master], [], left)
                    continue
                except OSError:
                    return False
                view = view[n:]
            return True

    def shutdown(self) -> None:
        """Close the pty (both ends held by the device). Idempotent."""
        super().shutdown()
        with self._write_lock:
            if self._master is None:
                return
            master, slave, self._master, self._slave = self._master, self._slave, None, None
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")
        # a recv() in another thread leaves select at once; close only after it let go
        locked = self._read_lock.acquire(timeout=1.0)
        try:
            for fd in (slave, master, self._wake_r, self._wake_w):
                if fd is not None:
                    with contextlib.suppress(OSError):
                        os.close(fd)
        finally:
            if locked:
                self._read_lock.release()
