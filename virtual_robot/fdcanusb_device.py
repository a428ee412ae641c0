"""A python-can bus that *is* an mjbots fdcanusb: the host talks the fdcanusb's line protocol
(mjbots fdcanusb docs, "Serial protocol"; moteus docs/reference.md "fdcanusb") to a pty.

Host → adapter: ``can send <hex id> <hex data> [flags]`` (flags ``B``/``b`` bit rate switch,
``F`` CAN-FD) is answered ``OK`` and becomes a received :class:`can.Message`; the adapter's
``conf …`` commands are answered ``OK`` (nothing to configure); anything else ``ERR unknown
command``. Adapter → host: every sent frame is a line ``rcv <hex id> <hex data> [E] B F``.

A host that appends the line checksum `` *XX`` (CRC-8, drivers.protocol.moteus.crc8: the moteus
library does on any port that is not a USB fdcanusb, so on a pty) gets its lines checked (a bad
one: ``ERR checksum mismatch``, the frame dropped) and its replies checksummed.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
from collections import deque
from typing import Any

import can

from drivers.protocol import moteus as mo
from virtual_robot.raw_pty import open_raw_pty

MAX_LINE = 512  # the adapter's line buffer (longer: the buffer is dropped)


class FdcanusbPtyBus(can.BusABC):
    """The fdcanusb on a pty (module docstring). Counters: ``frames_in``, ``frames_out``,
    ``malformed`` (lines answered ERR)."""

    def __init__(self, channel: Any = None, **kwargs: Any) -> None:
        master, slave, path = open_raw_pty(keep_slave_open=True)
        self._master: int | None = master
        self._slave: int | None = slave
        self._wake_r, self._wake_w = os.pipe()
        self._path = path
        self._buf = b""
        self._rx: deque[can.Message] = deque()
        self._checksums = False
        self._write_lock = threading.Lock()
        self.frames_in = 0
        self.frames_out = 0
        self.malformed = 0
        self.channel_info = f"fdcanusb on {path}"
        super().__init__(channel=path, **kwargs)

    @property
    def channel_path(self) -> str:
        """The pty slave the host opens as its fdcanusb (e.g. /dev/pts/7)."""
        return self._path

    # ---- host -> adapter ---------------------------------------------------------------------
    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self._rx:
            return self._rx.popleft(), False
        master = self._master
        if master is None:
            return None, False
        ready, _, _ = select.select([master, self._wake_r], [], [], timeout)
        if master not in ready:
            return None, False
        try:
            chunk = os.read(master, 4096)
        except (BlockingIOError, InterruptedError):
            return None, False
        except OSError:  # EIO: no host has the port open
            return None, False
        self._buf += chunk
        while True:
            cut = min(
                (k for k in (self._buf.find(b"\n"), self._buf.find(b"\r")) if k >= 0), default=-1
            )
            if cut < 0:
                if len(self._buf) > MAX_LINE:
                    self._buf = b""
                break
            line, self._buf = self._buf[:cut], self._buf[cut + 1 :]
            if line.strip():
                self._line(line.strip())
        return (self._rx.popleft(), False) if self._rx else (None, False)

    def _line(self, raw: bytes) -> None:
        line, ok = mo.strip_checksum(raw)
        if ok is not None:
            self._checksums = True
        if ok is False:
            self.malformed += 1
            self._write(b"ERR checksum mismatch")
            return
        fields = line.split()
        if fields[:2] == [b"can", b"send"]:
            try:
                fd = mo.parse_can_send(fields[2:])
            except mo.FrameError as exc:
                self.malformed += 1
                self._write(f"ERR {exc}".encode())
                return
            self._write(b"OK")
            self.frames_in += 1
            self._rx.append(
                can.Message(
                    arbitration_id=fd.arbitration_id,
                    data=fd.data,
                    is_extended_id=fd.arbitration_id > 0x7FF,
                    is_fd=fd.fd,
                    bitrate_switch=fd.brs,
                    check=False,
                )
            )
        elif fields[:1] == [b"conf"]:
            self._write(b"OK")
        else:
            self.malformed += 1
            self._write(b"ERR unknown command")

    # ---- adapter -> host ---------------------------------------------------------------------
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._write(mo.format_rcv(msg.arbitration_id, bytes(msg.data)))
        self.frames_out += 1

    def _write(self, line: bytes) -> None:
        if self._checksums:
            line = mo.add_checksum(line)
        data = line + b"\r\n"
        with self._write_lock:
            master = self._master
            if master is None:
                return
            while data:
                try:
                    n = os.write(master, data)
                except BlockingIOError:  # the host does not read: wait once, then drop the line
                    if not select.select([], [master], [], 0.25)[1]:
                        return
                    continue
                except OSError:
                    return
                data = data[n:]

    def shutdown(self) -> None:
        """Close the pty (a second call does nothing)."""
        super().shutdown()
        if self._master is None:
            return
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")
        with self._write_lock:
            for fd in (self._master, self._slave, self._wake_r, self._wake_w):
                if fd is not None:
                    with contextlib.suppress(OSError):
                        os.close(fd)
            self._master = self._slave = None


__all__ = ["FdcanusbPtyBus"]
