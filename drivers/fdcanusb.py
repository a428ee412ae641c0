"""The host's side of an mjbots fdcanusb (a USB CAN-FD adapter with a serial line protocol,
moteus docs/reference.md "fdcanusb"; the virtual robot's is virtual_robot.fdcanusb_device): a
python-can bus over pyserial.

``send`` writes ``can send <id> <data> BF`` (bit rate switch, CAN-FD) and does not wait for the
adapter's ``OK``; ``recv`` returns the ``rcv`` lines as CAN-FD messages and skips ``OK``. An
``ERR`` line is kept in :attr:`FdcanusbBus.errors` and skipped. Lines are sent without the
optional checksum (a USB fdcanusb needs none); a reply's checksum is checked and a line with a
wrong one dropped (counted in :attr:`FdcanusbBus.bad_checksums`).
"""

from __future__ import annotations

import time
from typing import Any

import can
import serial

from drivers.protocol import moteus as mo


class FdcanusbBus(can.BusABC):
    """python-can bus on the fdcanusb at serial port ``channel`` (module docstring)."""

    def __init__(self, channel: str, **kwargs: Any) -> None:
        self._port = serial.Serial(channel, baudrate=921600, timeout=0)
        self._buf = b""
        self.errors: list[str] = []
        self.bad_checksums = 0
        self.channel_info = f"fdcanusb on {channel}"
        super().__init__(channel=channel, **kwargs)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        data = mo.pad_fd(bytes(msg.data))
        line = f"can send {msg.arbitration_id:04x} {data.hex().upper()} BF\n".encode()
        self._port.write(line)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        end = None if timeout is None else time.monotonic() + timeout
        while True:
            cut = self._buf.find(b"\n")
            if cut >= 0:
                line, self._buf = self._buf[:cut].strip(), self._buf[cut + 1 :]
                msg = self._line(line)
                if msg is not None:
                    return msg, False
                continue
            left = None if end is None else end - time.monotonic()
            if left is not None and left <= 0:
                return None, False
            self._port.timeout = left if left is None else min(left, 0.05)
            chunk = self._port.read(max(1, self._port.in_waiting))
            self._buf += chunk

    def _line(self, raw: bytes) -> can.Message | None:
        line, ok = mo.strip_checksum(raw)
        if ok is False:
            self.bad_checksums += 1
            return None
        fields = line.split()
        if fields[:1] == [b"ERR"]:
            self.errors.append(line.decode(errors="replace"))
            return None
        if fields[:1] != [b"rcv"] or len(fields) < 3:
            return None
        try:
            arb, data = int(fields[1], 16), bytes.fromhex(fields[2].decode())
        except ValueError:
            self.errors.append(f"unreadable line {line!r}")
            return None
        return can.Message(
            arbitration_id=arb,
            data=data,
            is_extended_id=b"E" in fields[3:] or arb > 0x7FF,
            is_fd=True,
            check=False,
        )

    def shutdown(self) -> None:
        super().shutdown()
        self._port.close()


__all__ = ["FdcanusbBus"]
