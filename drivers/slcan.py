"""python-can's slcan interface, with an efficient read and write path.

python-can 4.6's ``slcanBus._read`` polls ``in_waiting`` in a loop and reads one byte per call
until its timeout expires, without sleeping. It holds the GIL and a whole CPU core while it waits,
which starves the loop thread and, on a 2-core machine, the virtual robot process too. Its
``_write`` also calls ``flush()`` (tcdrain), which blocks until the peer has read the frame.

This subclass overrides only those two methods. It waits on ``select`` and reads what is there,
and it writes without draining. Everything else is python-can's: the LAWICEL command set, frame
parsing, open/close and bitrate set-up. The difference, measured with
``tests/benchmarks/bench_hil.py``, is in docs/protocol.md. The subclass is used for virtual and
real slcan adapters alike (the same code path); on a platform without ``select`` on serial ports
it falls back to python-can's own read.
"""

from __future__ import annotations

import os
import select
import time

import can
from can.interfaces.slcan import slcanBus

_TERMINATORS = (ord("\r"), ord("\a"))


class SelectSlcanBus(slcanBus):
    """``can.interfaces.slcan.slcanBus`` that blocks in ``select`` instead of busy-polling."""

    def _write(self, string: str) -> None:
        data = string.encode() + self.LINE_TERMINATOR
        try:
            fd = self.serialPortOrig.fileno()
        except Exception:  # no fileno on this platform: pyserial's write
            fd = None
        try:
            if fd is None:
                self.serialPortOrig.write(data)
                return
            while data:
                written = os.write(fd, data)
                data = data[written:]
        except Exception as exc:  # pyserial raises SerialException, os.write OSError
            raise can.CanOperationError(f"Could not write to serial device: {exc}") from exc

    def _read(self, timeout: float | None) -> str | None:
        try:
            fd = self.serialPortOrig.fileno()
        except Exception:
            return super()._read(timeout)
        deadline = None if timeout is None else time.monotonic() + timeout
        buffer = self._buffer
        while True:
            for i, byte in enumerate(buffer):
                if byte in _TERMINATORS:
                    line = buffer[: i + 1].decode(errors="replace")
                    del buffer[: i + 1]
                    return line
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                return None
            ready, _, _ = select.select([fd], [], [], left)
            if not ready:
                return None
            try:
                data = os.read(fd, 4096)
            except BlockingIOError:
                continue
            except OSError as exc:
                raise can.CanOperationError(f"Could not read from serial device: {exc}") from exc
            if not data:
                raise can.CanOperationError("serial device closed")
            buffer.extend(data)
