"""A CAN bus with a bit time: frames cross the virtual link no faster than a real bus allows.

On a real bus every frame occupies the wire for its length in bits (stuffing included, see
:func:`drivers.protocol.can_bits.frame_bits`) divided by the bitrate, and frames go one at a
time. :class:`BusPacer` keeps the instant the simulated bus is next free; a frame offered at
time t starts at max(t, free) and ends ``bits / bitrate`` later. The CAN server
(:class:`~virtual_robot.can_server.CanDriveServer`) uses it on both directions:

* frames from the host are handed to the drives when the last frame of what was read together
  has crossed the bus (a SYNC behind two RPDOs waits for them);
* frames to the host (TPDOs, EMCY, SDO replies, heartbeats) are written to the transport when
  the last of them has crossed the bus (the host, which needs all four TPDOs, sees them when
  the fourth would have arrived; the frames of one batch share that write).

Arbitration is first come, first served (host and drives never contend for the bus within a
cycle here: the drives answer the SYNC). Waits sleep, then spin the last ``spin_s``. It also
counts what ``canbusload`` would: frames, bits, busy time.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from drivers.protocol.can_bits import frame_bits

# (id, data, extended, remote): a remote frame's data is its DLC in zero bytes
RawFrame = tuple[int, bytes, bool, bool]
SPIN_S = 80e-6


@dataclass
class BusCounters:
    frames: int = 0
    bits: int = 0
    busy_s: float = 0.0  # time the simulated bus carried frames
    delayed_s: float = 0.0  # time frames waited for the bus to be free


class BusPacer:
    """The simulated bus's timeline at ``bitrate`` bit/s (injectable clock and sleep)."""

    def __init__(
        self,
        bitrate: int,
        *,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        spin_s: float = SPIN_S,
    ) -> None:
        if bitrate <= 0:
            raise ValueError(f"bitrate must be > 0, got {bitrate}")
        self.bitrate = int(bitrate)
        self.clock = clock
        self.sleep = sleep
        self.spin_s = spin_s
        self.free_at = -float("inf")
        self.counters = BusCounters()
        self.started_at: float | None = None

    def occupy(self, frames: Iterable[RawFrame], offered_at: float | None = None) -> float:
        """Put ``frames`` on the bus in order, offered at ``offered_at`` (now); returns the
        instant the last of them has been transmitted."""
        now = self.clock() if offered_at is None else offered_at
        if self.started_at is None:
            self.started_at = now
        end = max(now, self.free_at)
        c = self.counters
        for can_id, data, extended, remote in frames:
            bits = frame_bits(
                can_id, b"" if remote else data, extended=extended, remote=remote, dlc=len(data)
            )
            start = max(now, end)
            c.delayed_s += start - now
            end = start + bits / self.bitrate
            c.frames += 1
            c.bits += bits
            c.busy_s += bits / self.bitrate
        self.free_at = end
        return end

    def pace(self, frames: Iterable[RawFrame]) -> float:
        """:meth:`occupy`, then wait until the last frame has been transmitted."""
        end = self.occupy(frames)
        self.wait_until(end)
        return end

    def wait_until(self, t: float) -> None:
        remaining = t - self.clock()
        if remaining > self.spin_s:
            self.sleep(remaining - self.spin_s)
        while self.clock() < t:
            pass

    def load(self, now: float | None = None) -> dict[str, float | int]:
        """Frames, bits and bus load (bits / elapsed / bitrate, %) since the first frame."""
        c = self.counters
        now = self.clock() if now is None else now
        elapsed = max(now - self.started_at, 1e-9) if self.started_at is not None else 0.0
        return {
            "bitrate": self.bitrate,
            "frames": c.frames,
            "bits": c.bits,
            "elapsed_s": elapsed,
            "load_pct": 100.0 * c.bits / (elapsed * self.bitrate) if elapsed else 0.0,
            "busy_s": c.busy_s,
            "delayed_s": c.delayed_s,
        }
