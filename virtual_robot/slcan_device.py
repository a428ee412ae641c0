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
        replies = bytearray()
        frames: list[can.Message] = []
        self._buffer.extend(data)
        while True:
            end = self._buffer.find(CR)
            if end < 0:
                if len(self._buffer) > MAX_LINE:
                    if not self._discarding:
                        self.malformed += 1
                        replies += BEL
                    self._discarding = True
                    self._buffer.clear()
                break
            line = bytes(self._buffer[:end])
            del self._buffer[: end + 1]
            if self._discarding:
                self._discarding = False
                continue
            reply, msg = self.command(line)
            replies += reply
            if msg is not None:
                frames.append(msg)
        return bytes(replies), frames

    def command(self, line: bytes) -> tuple[bytes, can.Message | None]:
        """One CR-terminated command (without the CR): (reply, frame sent by the host or None)."""
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
            msg = self._parse_frame(text)
            if msg is None or self.listen_only:
                return self._bad()
            self.is_open = True  # lenient: a host that transmits wants the channel open
            ack = (b"z" if cmd in "tr" else b"Z") + CR if self.ack_transmit else CR
            return ack, msg
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

    def _parse_frame(self, text: str) -> can.Message | None:
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
            data = b""
        else:
            if len(body) != 2 * dlc or not set(body) <= _HEX:
                return None
            data = bytes.fromhex(body)
        return can.Message(
            timestamp=time.time(),
            arbitration_id=can_id,
            is_extended_id=extended,
            is_remote_frame=remote,
            dlc=dlc,
            data=data,
            channel=self.channel,
            is_rx=True,
        )

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
        self._rx: deque[can.Message] = deque()
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
                    return self._rx.popleft(), False
                master = self._master
                if master is None:
                    raise can.CanOperationError("slcan device is shut down")
                left = None if deadline is None else max(0.0, deadline - time.monotonic())
                ready, _, _ = select.select([master, self._wake_r], [], [], left)
                if self._master is None:
                    raise can.CanOperationError("slcan device is shut down")
                if master in ready:
                    self._read_available(master, left)
                if not self._rx and deadline is not None and time.monotonic() >= deadline:
                    return None, False

    def _read_available(self, master: int, left: float | None) -> None:
        try:
            data = os.read(master, 4096)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno != errno.EIO:
                raise can.CanOperationError(f"slcan device read failed: {exc}") from exc
            time.sleep(0.01 if left is None else min(0.01, left))  # no host: nothing to read
            return
        replies, frames = self.device.feed(data)
        if replies:
            self._write(replies)
        self.frames_in += len(frames)
        self._rx.extend(frames)

    # ---- device -> host ---------------------------------------------------------------
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Report a frame to the host (dropped while the host has the channel closed)."""
        if self._master is None:
            raise can.CanOperationError("slcan device is shut down")
        line = self.device.encode(msg) if self.device.is_open else b""
        if line and self._write(line):
            self.frames_out += 1
        else:
            self.dropped += 1

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
