"""Emulated MIT-mode drive (T-Motor/CubeMars AK series, Mini Cheetah firmware): motor mode, the
drive's own PD, encoder, velocity estimate and command watchdog.

Pure logic like :class:`~virtual_robot.drive.DriveModel`, and stepped the same way
(:class:`~virtual_robot.stepping.Stepper`): the plant loop calls :meth:`MitDrive.update` once per
drive period after the plant advanced to ``now`` and applies :attr:`MitDrive.torque_Nm`. The
drive period is the PD loop's (the profile's ``pd_rate_hz``): the torque

    τ = sat(kp (p_des − p) + kd (v_des − v) + τ_ff, ±t_max)
    (Mini Cheetah firmware, ``controller.cpp`` torque_control)

is recomputed from every sample, in the drive's own frame (``axis_direction``) and from what
the drive measures: p from its encoder count less the zero offset, v its velocity estimate.

States: REST (power stage off, torque 0; the state after power-on and after "exit motor mode")
and MOTOR (motor mode: the PD above). Every command is stored whatever the state, and applies
once the drive is in motor mode (the real firmware keeps the last command too, the reason the
DFKI driver sends a zero command before it leaves motor mode).

Command watchdog: as on CiA 402 (drive.py), N = ceil(watchdog_s / period) drive periods in
motor mode without a command exit motor mode (torque 0, :attr:`MitDrive.last_error` says why).
"""

from __future__ import annotations

import math
from collections import deque

from drivers.protocol.mit import MitCommand
from profiles.drive import DriveProfile
from virtual_robot.drive import Emcy

WATCHDOG = "watchdog: no command for the watchdog time in motor mode; motor mode left"
COMMUNICATION = "communication fault"


class MitDrive:
    """One emulated MIT-mode drive (module docstring)."""

    def __init__(self, profile: DriveProfile, period_s: float) -> None:
        if profile.mit is None:
            raise ValueError(f"{profile.source}: not an MIT-mode drive (protocol = 'mit')")
        self.profile = profile
        mit = profile.mit
        self._dir = mit.axis_direction
        self._t_max = mit.t_max
        self._rad_per_count = profile.rad_per_count
        self.watchdog_periods = profile.watchdog_periods(period_s)
        window = max(1, round(mit.velocity_window_s / period_s)) if mit.velocity_window_s else 1
        self._history: deque[tuple[float, int]] = deque(maxlen=window + 1)
        self._counts = 0  # the drive's own encoder count (its frame), unbounded
        self._offset = 0  # the count "set zero" stored
        self._velocity = 0.0  # rad/s, drive frame
        self._watchdog = 0
        self.motor_mode = False
        self.command = MitCommand(0.0, 0.0, 0.0, 0.0, 0.0)
        self.last_error = ""
        self._events: list[Emcy] = []

    # ---- from a transport -------------------------------------------------------------------
    def enter_motor_mode(self, now: float) -> None:
        """FF..FC: power stage on, the stored command applies (watchdog restarted)."""
        if not self.motor_mode:
            self._watchdog = 0
        self.motor_mode = True
        self.last_error = ""

    def exit_motor_mode(self, now: float) -> None:
        """FF..FD: power stage off, torque 0."""
        self.motor_mode = False

    def set_zero(self, now: float) -> None:
        """FF..FE: the present position becomes p = 0 (the firmware stores the offset)."""
        self._offset = self._counts
        self._history.clear()
        self._history.append((now, self._counts))

    def write_command(self, cmd: MitCommand, now: float) -> None:
        """A p/v/kp/kd/τ command (already decoded and in range); feeds the watchdog."""
        self.command = cmd
        self._watchdog = 0

    def communication_fault(self, code: int, now: float) -> None:
        """Leave motor mode at once (torque 0), e.g. the bus is corrupted."""
        self.motor_mode = False
        self.last_error = f"{COMMUNICATION} 0x{code:04X}"
        self._events.append(Emcy(code, 0, now))

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
        if count_period and self.motor_mode:
            self._watchdog += 1
            if self._watchdog >= self.watchdog_periods:
                self.motor_mode = False
                self.last_error = WATCHDOG
                self._events.append(Emcy(0x8250, 0, now))

    def pop_emcy(self) -> list[Emcy]:
        """Watchdog and communication events since the last call (MIT mode sends none on the
        bus; the server logs them)."""
        events, self._events = self._events, []
        return events

    # ---- readouts -----------------------------------------------------------------------------
    @property
    def position_rad(self) -> float:
        """p: what the drive reports, its frame, from its zero."""
        return (self._counts - self._offset) * self._rad_per_count

    @property
    def velocity_rad_s(self) -> float:
        return self._velocity

    @property
    def drive_torque_Nm(self) -> float:
        """The PD output in the drive's frame (0 out of motor mode)."""
        if not self.motor_mode:
            return 0.0
        c = self.command
        tau = c.kp * (c.p_des - self.position_rad) + c.kd * (c.v_des - self._velocity) + c.t_ff
        t_max = self._t_max
        return t_max if tau > t_max else -t_max if tau < -t_max else tau

    @property
    def torque_Nm(self) -> float:
        """The torque on the joint (the plant's frame)."""
        return self._dir * self.drive_torque_Nm

    @property
    def powered(self) -> bool:
        return self.motor_mode


__all__ = ["COMMUNICATION", "WATCHDOG", "MitDrive"]
