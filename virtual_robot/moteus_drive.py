"""Emulated mjbots moteus controller in position mode (register protocol, docs/reference.md of
github.com/mjbots/moteus: "Theory of Operation", "A.2b Registers", "servo.*" configuration).

Encoder, velocity window and watchdog are :class:`~virtual_robot.loop_drive.LoopDrive`'s (shared
with the MIT-mode drive and the ODrive axis); the drive period is the controller's position loop
(the profile's ``[moteus] control_rate_hz``). Positions are revolutions of the output, velocities
revolutions/s, torques Nm (the firmware's units after ``motor_position.rotor_to_output_ratio``).

Modes (register 0x000): STOPPED (0, power stage off, torque 0; power-on), POSITION (10),
TIMEOUT (11) and ZERO VELOCITY (12: the position loop with kp_scale 0, velocity 0 and no
feed-forward, i.e. τ = −kd_scale · kd · v; no watchdog, as it is itself one of the firmware's
timeout modes). In position mode the torque is, every drive period (reference "Theory of
Operation", position mode):

    τ = kp_scale · kp · (p_c − p) + kd_scale · kd · (v_c − v) + τ_ff,   |τ| ≤ min(τ_max, limit)

with kp, kd the profile's ``servo.pid_position`` gains, p the measured position (encoder count),
v the velocity estimate, τ_max the command's maximum_torque (none: the limit) and the limit the
profile's rated torque × max_torque_permille / 1000 (``servo.max_current_A`` × kt). The control
position p_c is the command's position; a NaN position keeps the present control position (the
measured position when position mode starts), and p_c advances by v_c every period.

The watchdog (``servo.default_timeout_s``: the profile's ``watchdog_s``; a command's
watchdog_timeout register overrides it, NaN disables it): that long in position mode without a
command → TIMEOUT, emulated as ``servo.timeout_mode = 0`` (torque 0, power stage off; the
firmware's modes 12, zero velocity, and 15, brake, damp the motor instead: reference
"servo.timeout_mode"). TIMEOUT, as on the firmware, is left only by a stop
command; position commands sent in TIMEOUT are refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from drivers.protocol import moteus as mo
from profiles.drive import DriveProfile
from virtual_robot.drive import Emcy
from virtual_robot.loop_drive import LoopDrive

WATCHDOG = "watchdog: no command for the watchdog time in position mode; mode TIMEOUT (torque 0)"
TWO_PI = 2.0 * math.pi
NO_WATCHDOG = 1 << 62  # a watchdog_timeout of NaN: the firmware never times out


@dataclass(frozen=True)
class PositionCommand:
    """The registers of one position-mode command (0x020..0x027), physical units; the
    firmware's defaults for the ones a frame does not write."""

    position_rev: float = math.nan
    velocity_rev_s: float = 0.0
    feedforward_Nm: float = 0.0
    kp_scale: float = 1.0
    kd_scale: float = 1.0
    maximum_torque_Nm: float = math.nan  # NaN: the drive's limit
    watchdog_s: float | None = None  # None: servo.default_timeout_s; NaN: no watchdog

    def refusal(self) -> str:
        """Why the emulation refuses this command ("" when it applies it)."""
        for name in ("feedforward_Nm", "kp_scale", "kd_scale"):
            if not math.isfinite(getattr(self, name)):
                return f"{name} is not finite"
        if self.kp_scale < 0 or self.kd_scale < 0:
            return "negative kp_scale or kd_scale"
        if not math.isnan(self.maximum_torque_Nm) and not self.maximum_torque_Nm >= 0:
            return "negative maximum_torque"
        return ""


class MoteusDrive(LoopDrive):
    """One emulated moteus controller (module docstring)."""

    def __init__(self, profile: DriveProfile, period_s: float) -> None:
        if profile.moteus is None:
            raise ValueError(f"{profile.source}: not a moteus controller (protocol = 'moteus')")
        super().__init__(profile, period_s, velocity_window_s=profile.moteus.velocity_window_s)
        self._period_s = period_s
        self._default_watchdog = self.watchdog_periods
        self.kp = profile.moteus.kp_Nm_per_rev
        self.kd = profile.moteus.kd_Nm_s_per_rev
        self.torque_limit_Nm = profile.rated_torque_Nm * profile.max_torque_permille / 1000.0
        self.mode = mo.STOPPED
        self.fault = mo.FAULT_NONE
        self.command = PositionCommand()
        self.control_position_rev: float | None = None

    @property
    def armed(self) -> bool:
        return self.mode == mo.POSITION_MODE

    def _watchdog_expired(self, now: float) -> None:
        self._leave(mo.TIMEOUT_MODE, WATCHDOG, now)

    def _leave(self, mode: int, text: str, now: float) -> None:
        self.mode = mode
        self.control_position_rev = None
        self.last_error = text
        self._events.append(Emcy(0x8250, 0, now))

    def safe_stop(self, now: float) -> None:
        self.stop()

    def communication_fault(self, code: int, now: float) -> None:
        """The bus is corrupted: TIMEOUT at once (what the firmware reaches when commands stop)."""
        if self.mode == mo.POSITION_MODE:
            self._leave(mo.TIMEOUT_MODE, f"communication fault 0x{code:04X}", now)

    # ---- from a transport -------------------------------------------------------------------
    def stop(self) -> None:
        """Mode 0: power stage off, torque 0; clears TIMEOUT and a fault."""
        self.mode = mo.STOPPED
        self.fault = mo.FAULT_NONE
        self.control_position_rev = None
        self.last_error = ""

    def refuses_zero_velocity(self, kd_scale: float) -> str:
        """Why :meth:`zero_velocity` would refuse ``kd_scale`` ("" when it applies it)."""
        if self.mode == mo.TIMEOUT_MODE:
            return "zero-velocity command refused in TIMEOUT: send a stop command first"
        why = PositionCommand(kp_scale=0.0, kd_scale=kd_scale).refusal()
        return f"zero-velocity command refused: {why}" if why else ""

    def zero_velocity(self, kd_scale: float = 1.0) -> str:
        """Mode 12 (reference "Zero velocity"): τ = −kd_scale · kd · v every drive period, no
        watchdog; returns why it was refused ("" when applied)."""
        why = self.refuses_zero_velocity(kd_scale)
        if why:
            return why
        cmd = PositionCommand(kp_scale=0.0, kd_scale=kd_scale)
        self.mode = mo.ZERO_VELOCITY_MODE
        self.command = cmd
        self.control_position_rev = None
        self.last_error = ""
        return ""

    def refuses(self, cmd: PositionCommand) -> str:
        """Why :meth:`position` would refuse ``cmd`` ("" when it applies it)."""
        if self.mode == mo.TIMEOUT_MODE:
            return "position command refused in TIMEOUT: send a stop command first"
        why = cmd.refusal()
        return f"position command refused: {why}" if why else ""

    def position(self, cmd: PositionCommand) -> str:
        """Mode 10 with ``cmd``; returns why it was refused ("" when applied; feeds the
        watchdog)."""
        why = self.refuses(cmd)
        if why:
            return why
        if self.mode != mo.POSITION_MODE:
            self.control_position_rev = None
        self.mode = mo.POSITION_MODE
        self.command = cmd
        if math.isfinite(cmd.position_rev):
            self.control_position_rev = cmd.position_rev
        elif self.control_position_rev is None:
            self.control_position_rev = self.position_rev
        if cmd.watchdog_s is None:
            self.watchdog_periods, self._watchdog_on = self._default_watchdog, True
        elif math.isnan(cmd.watchdog_s):
            self._watchdog_on = False
        else:
            self.watchdog_periods = max(1, math.ceil(cmd.watchdog_s / self._period_s - 1e-9))
        self._watchdog = 0
        self.last_error = ""
        return ""

    # ---- one drive period ---------------------------------------------------------------------
    def update(
        self, now: float, position_rad: float, velocity_rad_s: float, count_period: bool = True
    ) -> None:
        super().update(now, position_rad, velocity_rad_s, count_period)
        v = self.command.velocity_rev_s
        moving = self.mode == mo.POSITION_MODE and self.control_position_rev is not None
        if count_period and moving and math.isfinite(v):
            self.control_position_rev += v * self._period_s  # type: ignore[operator]

    # ---- readouts -----------------------------------------------------------------------------
    @property
    def position_rev(self) -> float:
        return self._counts / self.profile.counts_per_rev

    @property
    def velocity_rev_s(self) -> float:
        return self._velocity / TWO_PI

    @property
    def drive_torque_Nm(self) -> float:
        if self.mode not in (mo.POSITION_MODE, mo.ZERO_VELOCITY_MODE):
            return 0.0
        c = self.command
        tau = c.feedforward_Nm
        if c.kp_scale and self.control_position_rev is not None:
            tau += c.kp_scale * self.kp * (self.control_position_rev - self.position_rev)
        if c.kd_scale:
            v_c = c.velocity_rev_s if math.isfinite(c.velocity_rev_s) else 0.0
            tau += c.kd_scale * self.kd * (v_c - self.velocity_rev_s)
        lim = self.torque_limit_Nm
        if math.isfinite(c.maximum_torque_Nm):
            lim = min(lim, c.maximum_torque_Nm)
        return lim if tau > lim else -lim if tau < -lim else tau


__all__ = ["WATCHDOG", "MoteusDrive", "PositionCommand"]
