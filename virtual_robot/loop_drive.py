"""What the drives that run their own loop share (MIT mode: virtual_robot.mit_drive; ODrive
CANSimple: virtual_robot.odrive_drive): the encoder count, the velocity estimate over a window
of counts, and the command watchdog counted in drive periods.

Stepped like :class:`~virtual_robot.drive.DriveModel` (:class:`~virtual_robot.stepping.Stepper`):
the plant loop calls :meth:`LoopDrive.update` once per drive period after the plant advanced to
``now`` and applies :attr:`LoopDrive.torque_Nm`. A subclass says when the watchdog counts
(:attr:`armed`) and what expiry does (:meth:`_watchdog_expired`).
"""

from __future__ import annotations

import math
from collections import deque

from profiles.drive import DriveProfile
from virtual_robot.drive import Emcy


class LoopDrive:
    """Encoder, velocity window and watchdog of one drive (module docstring)."""

    def __init__(
        self,
        profile: DriveProfile,
        period_s: float,
        *,
        direction: int = 1,
        velocity_window_s: float = 0.0,
    ) -> None:
        self.profile = profile
        self._dir = direction
        self._rad_per_count = profile.rad_per_count
        self.watchdog_periods = profile.watchdog_periods(period_s)
        window = max(1, round(velocity_window_s / period_s)) if velocity_window_s else 1
        self._history: deque[tuple[float, int]] = deque(maxlen=window + 1)
        self._counts = 0  # the drive's own encoder count (its frame), unbounded
        self._velocity = 0.0  # rad/s, drive frame
        self._watchdog = 0
        self.last_error = ""
        self._events: list[Emcy] = []

    # ---- for subclasses -------------------------------------------------------------------------
    @property
    def armed(self) -> bool:
        """True while the watchdog counts (the drive applies commanded torque)."""
        raise NotImplementedError

    def _watchdog_expired(self, now: float) -> None:
        raise NotImplementedError

    def feed_watchdog(self) -> None:
        self._watchdog = 0

    def restart_velocity(self, now: float) -> None:
        """The velocity window starts again at the present count (e.g. a new zero)."""
        self._history.clear()
        self._history.append((now, self._counts))

    # ---- one drive period ---------------------------------------------------------------------
    def update(
        self, now: float, position_rad: float, velocity_rad_s: float, count_period: bool = True
    ) -> None:
        """Sample the encoder (joint angle → the drive's count), estimate the velocity over the
        profile's window, and count the watchdog (``count_period``)."""
        if not (math.isfinite(position_rad) and math.isfinite(velocity_rad_s)):
            raise ValueError("position and velocity must be finite")
        counts = math.floor(self._dir * position_rad / self._rad_per_count)
        self._counts = counts
        history = self._history
        if history and now > history[0][0]:
            t0, c0 = history[0]
            self._velocity = (counts - c0) * self._rad_per_count / (now - t0)
        elif not history:
            self._velocity = 0.0
        if not history or now > history[-1][0]:
            history.append((now, counts))
        if count_period and self.armed:
            self._watchdog += 1
            if self._watchdog >= self.watchdog_periods:
                self._watchdog_expired(now)

    def pop_emcy(self) -> list[Emcy]:
        """Watchdog and communication events since the last call (the server logs them)."""
        events, self._events = self._events, []
        return events

    # ---- readouts -----------------------------------------------------------------------------
    @property
    def counts(self) -> int:
        return self._counts

    @property
    def velocity_rad_s(self) -> float:
        return self._velocity

    @property
    def drive_torque_Nm(self) -> float:
        raise NotImplementedError

    @property
    def torque_Nm(self) -> float:
        """The torque on the joint (the plant's frame)."""
        return self._dir * self.drive_torque_Nm

    @property
    def powered(self) -> bool:
        return self.armed

    def safe_stop(self, now: float) -> None:
        """Power stage off, torque 0 (the host is lost)."""
        raise NotImplementedError


__all__ = ["LoopDrive"]
