"""Emulated MIT-mode drive (T-Motor/CubeMars AK series, Mini Cheetah firmware): motor mode, the
drive's own PD, encoder, velocity estimate and command watchdog (the last three
virtual_robot.loop_drive's, shared with the ODrive axis).

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

from drivers.protocol.mit import MitCommand
from profiles.drive import DriveProfile
from virtual_robot.drive import Emcy
from virtual_robot.loop_drive import LoopDrive

WATCHDOG = "watchdog: no command for the watchdog time in motor mode; motor mode left"
COMMUNICATION = "communication fault"


class MitDrive(LoopDrive):
    """One emulated MIT-mode drive (module docstring)."""

    def __init__(self, profile: DriveProfile, period_s: float) -> None:
        if profile.mit is None:
            raise ValueError(f"{profile.source}: not an MIT-mode drive (protocol = 'mit')")
        mit = profile.mit
        super().__init__(
            profile,
            period_s,
            direction=mit.axis_direction,
            velocity_window_s=mit.velocity_window_s,
        )
        self._t_max = mit.t_max
        self._offset = 0  # the count "set zero" stored
        self.motor_mode = False
        self.command = MitCommand(0.0, 0.0, 0.0, 0.0, 0.0)

    @property
    def armed(self) -> bool:
        return self.motor_mode

    def _watchdog_expired(self, now: float) -> None:
        self.motor_mode = False
        self.last_error = WATCHDOG
        self._events.append(Emcy(0x8250, 0, now))

    def safe_stop(self, now: float) -> None:
        self.exit_motor_mode(now)

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
        self.restart_velocity(now)

    def write_command(self, cmd: MitCommand, now: float) -> None:
        """A p/v/kp/kd/τ command (already decoded and in range); feeds the watchdog."""
        self.command = cmd
        self._watchdog = 0

    def communication_fault(self, code: int, now: float) -> None:
        """Leave motor mode at once (torque 0), e.g. the bus is corrupted."""
        self.motor_mode = False
        self.last_error = f"{COMMUNICATION} 0x{code:04X}"
        self._events.append(Emcy(code, 0, now))

    # ---- readouts -----------------------------------------------------------------------------
    @property
    def position_rad(self) -> float:
        """p: what the drive reports, its frame, from its zero."""
        return (self._counts - self._offset) * self._rad_per_count

    @property
    def drive_torque_Nm(self) -> float:
        """The PD output in the drive's frame (0 out of motor mode)."""
        if not self.motor_mode:
            return 0.0
        c = self.command
        tau = c.kp * (c.p_des - self.position_rad) + c.kd * (c.v_des - self._velocity) + c.t_ff
        t_max = self._t_max
        return t_max if tau > t_max else -t_max if tau < -t_max else tau


__all__ = ["COMMUNICATION", "WATCHDOG", "MitDrive"]
