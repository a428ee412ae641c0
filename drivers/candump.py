"""The CAN traffic log (``bus.log``): ``candump -L`` lines, as python-can's CanutilsLogWriter.

:class:`CandumpWriter` writes exactly the lines :class:`can.CanutilsLogWriter` writes (python-can
4.6), so :class:`can.LogReader` reads them back, e.g. ``(1795374201.740439) can0 181#3706FBFF T``:
timestamp, channel, id#data, and ``R``/``T`` for received/sent. It is cheaper per frame on the
cyclic path: :meth:`CandumpWriter.write_frames` takes standard data frames as their fields (no
python-can Message) and lines go through a large write buffer; the owner flushes when it wants
the file on disk (:meth:`CandumpWriter.flush`).
"""

from __future__ import annotations

from pathlib import Path

import can
from can.io.canutils import CAN_ERR_BUSERROR, CAN_ERR_FLAG, CANFD_BRS, CANFD_ESI

BUFFER_BYTES = 1 << 16


def _channel_text(channel: object) -> str:
    if isinstance(channel, int) or (isinstance(channel, str) and channel.isdigit()):
        return f"can{channel}"
    return str(channel)


class CandumpWriter:
    """Append-only ``candump -L`` log of frames; python-can's CanutilsLogWriter format."""

    def __init__(self, path: str | Path, channel: str = "vcan0") -> None:
        self.channel = channel
        self._channel_text = _channel_text(channel)
        self.file = open(path, "w", encoding="utf-8", buffering=BUFFER_BYTES)  # noqa: SIM115
        self.last_timestamp: float | None = None  # the first frame's (CanutilsLogWriter's rule)

    def write_frames(self, timestamp: float, frames: list[tuple[int, bytes]], rx: bool) -> None:
        """Standard (11-bit) data frames ``(id, data)`` seen at one time, on the default channel.
        No frames, no line: the timestamp floor is set by the first frame written, not a call."""
        if not frames:
            return
        first = self.last_timestamp
        if first is None:
            first = self.last_timestamp = timestamp
        head = f"({max(timestamp, first):f}) {self._channel_text} "
        tail = " R\n" if rx else " T\n"
        self.file.write(
            "".join([f"{head}{can_id:03X}#{data.hex().upper()}{tail}" for can_id, data in frames])
        )

    def write_message(self, msg: can.Message) -> None:
        """Any python-can Message (extended, remote, error, FD), on its own channel if set."""
        if self.last_timestamp is None:
            self.last_timestamp = msg.timestamp or 0.0
        if msg.timestamp is None or msg.timestamp < self.last_timestamp:
            timestamp = self.last_timestamp
        else:
            timestamp = msg.timestamp
        channel = msg.channel if msg.channel is not None else self.channel
        line = f"({timestamp:f}) {_channel_text(channel)}"
        if msg.is_error_frame:
            line += f" {CAN_ERR_FLAG | CAN_ERR_BUSERROR:08X}#"
        elif msg.is_extended_id:
            line += f" {msg.arbitration_id:08X}#"
        else:
            line += f" {msg.arbitration_id:03X}#"
        eol = "\n" if msg.is_error_frame else (" R\n" if msg.is_rx else " T\n")
        if msg.is_remote_frame:
            line += f"R{eol}"
        else:
            if msg.is_fd:
                flags = (CANFD_BRS if msg.bitrate_switch else 0) | (
                    CANFD_ESI if msg.error_state_indicator else 0
                )
                line += f"#{flags:X}"
            line += f"{msg.data.hex().upper()}{eol}"
        self.file.write(line)

    def flush(self) -> None:
        self.file.flush()

    def stop(self) -> None:
        """Flush and close (idempotent)."""
        if not self.file.closed:
            self.file.close()
