"""Emulated ODrive axis (firmware 0.6, CANSimple) in torque control: axis state, controller
mode, the torque setpoint, encoder estimates, axis errors and the watchdog.

Encoder, velocity window and watchdog are :class:`~virtual_robot.loop_drive.LoopDrive`'s (shared
with the MIT-mode drive); the drive period is the axis' control loop (the profile's
``[odrive] control_rate_hz``). What the axis does:

* states IDLE (power stage off, torque 0; the state after power-on, Reboot, Estop and a fault)
  and CLOSED_LOOP_CONTROL. A request for closed loop is refused (stays IDLE, Procedure_Result
  INVALID_STATE) while an axis error is latched, and refused with BAD_CONFIG unless the controller
  is in TORQUE_CONTROL with PASSTHROUGH input (the only modes emulated; the power-on mode is the
  firmware's POSITION_CONTROL);
* in closed loop, the torque is the last Set_Input_Torque, clamped to ±torque_lim (the profile's
  rated torque × max_torque_permille / 1000), as the firmware's ``motor.config.torque_lim``;
* the watchdog (``axis.config.watchdog_timeout``): N = ceil(watchdog_s / period) drive periods in
  closed loop without a command → IDLE with WATCHDOG_TIMER_EXPIRED (torque 0);
* Clear_Errors clears the latched error; Estop latches ESTOP_REQUESTED and goes IDLE; Reboot
  returns the axis to its power-on state (the encoder keeps counting: it is absolute).
"""

from __future__ import annotations

import math

from drivers.protocol import odrive as od
from profiles.drive import DriveProfile
from virtual_robot.drive import Emcy
from virtual_robot.loop_drive import LoopDrive

WATCHDOG = "watchdog: no command for the watchdog time in closed loop; axis IDLE"
TWO_PI = 2.0 * math.pi


class OdriveAxis(LoopDrive):
    """One emulated ODrive axis (module docstring)."""

    def __init__(self, profile: DriveProfile, period_s: float) -> None:
        if profile.odrive is None:
            raise ValueError(f"{profile.source}: not an ODrive axis (protocol = 'odrive')")
        if not 0 <= profile.node_id < 1 << od.NODE_BITS:
            raise ValueError(
                f"{profile.source}: node id {profile.node_id}: a CANSimple node id has 6 bits"
            )
        super().__init__(profile, period_s, velocity_window_s=profile.odrive.velocity_window_s)
        self.torque_limit_Nm = profile.rated_torque_Nm * profile.max_torque_permille / 1000.0
        self._power_on()

    def _power_on(self) -> None:
        self.state = od.IDLE
        self.axis_error = od.ERROR_NONE
        self.procedure_result = od.SUCCESS
        self.control_mode = od.POSITION_CONTROL
        self.input_mode = od.PASSTHROUGH
        self.input_torque_Nm = 0.0

    @property
    def armed(self) -> bool:
        return self.state == od.CLOSED_LOOP_CONTROL

    def _watchdog_expired(self, now: float) -> None:
        self._fault(od.WATCHDOG_TIMER_EXPIRED, WATCHDOG, now)

    def _fault(self, error: int, text: str, now: float) -> None:
        self.state = od.IDLE
        self.axis_error |= error
        self.last_error = text
        self._events.append(Emcy(error & 0xFFFF or 0x8250, 0, now))

    def safe_stop(self, now: float) -> None:
        self.state = od.IDLE

    # ---- from a transport -------------------------------------------------------------------
    def request_state(self, state: int, now: float) -> str:
        """Set_Axis_State; returns why a request was refused ("" when done)."""
        if state == od.IDLE:
            self.state = od.IDLE
            self.procedure_result = od.SUCCESS
            return ""
        if state != od.CLOSED_LOOP_CONTROL:
            self.procedure_result = od.INVALID_STATE
            return f"axis state {state} is not emulated (IDLE and CLOSED_LOOP_CONTROL are)"
        if self.axis_error:
            self.procedure_result = od.INVALID_STATE
            return f"closed loop refused: axis error 0x{self.axis_error:08X} latched (Clear_Errors)"
        if (self.control_mode, self.input_mode) != (od.TORQUE_CONTROL, od.PASSTHROUGH):
            self.axis_error |= od.BAD_CONFIG
            self.procedure_result = od.INVALID_STATE
            return (
                f"closed loop refused: control mode {self.control_mode}, input mode "
                f"{self.input_mode}; only TORQUE_CONTROL (1) with PASSTHROUGH (1) is emulated"
            )
        if self.state != od.CLOSED_LOOP_CONTROL:
            self._watchdog = 0
        self.state = od.CLOSED_LOOP_CONTROL
        self.procedure_result = od.SUCCESS
        self.last_error = ""
        return ""

    def set_controller_mode(self, control_mode: int, input_mode: int) -> None:
        self.control_mode, self.input_mode = control_mode, input_mode

    def set_input_torque(self, torque_Nm: float) -> None:
        """A finite setpoint (the server drops the rest); feeds the watchdog."""
        self.input_torque_Nm = torque_Nm
        self._watchdog = 0

    def clear_errors(self) -> None:
        self.axis_error = od.ERROR_NONE
        self.procedure_result = od.SUCCESS
        self.last_error = ""

    def estop(self, now: float) -> None:
        self._fault(od.ESTOP_REQUESTED, "Estop received: axis IDLE", now)

    def communication_fault(self, code: int, now: float) -> None:
        """The bus is corrupted: IDLE at once with SYSTEM_LEVEL (no CANSimple error says more)."""
        self._fault(od.SYSTEM_LEVEL, f"communication fault 0x{code:04X}", now)

    def reboot(self, now: float) -> None:
        self._power_on()
        self.last_error = ""

    # ---- readouts -----------------------------------------------------------------------------
    @property
    def pos_estimate_rev(self) -> float:
        return self._counts / self.profile.counts_per_rev

    @property
    def vel_estimate_rev_s(self) -> float:
        return self._velocity / TWO_PI

    @property
    def drive_torque_Nm(self) -> float:
        if self.state != od.CLOSED_LOOP_CONTROL or self.control_mode != od.TORQUE_CONTROL:
            return 0.0
        tau, lim = self.input_torque_Nm, self.torque_limit_Nm
        return lim if tau > lim else -lim if tau < -lim else tau


__all__ = ["WATCHDOG", "OdriveAxis"]
