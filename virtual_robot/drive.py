"""Emulated servo drive: CiA 402 power state machine, torque mode, encoder and watchdog.

Pure logic: no I/O, no threads, no clock of its own. A transport (CAN RPDO/SDO or the serial
dialect) calls the ``write_*`` methods with the current clock time ``now`` in seconds; the plant
loop calls :meth:`DriveModel.update` once per sampling period after the plant advanced to
``now`` and applies :attr:`DriveModel.torque_Nm` to the motor.

Objects (CiA 402 unless noted): 0x6040 controlword, 0x6041 statusword, 0x6060/0x6061 mode,
0x6071 target torque, 0x6072 max torque, 0x6076 rated torque (1000 ‰), 0x6077 torque actual,
0x6064 position actual, 0x606C velocity actual, 0x603F error code; CiA 301 0x1001 error
register and EMCY.

Boot: the drive starts in NOT_READY_TO_SWITCH_ON and performs transition 1 to
SWITCH_ON_DISABLED at the first update()/write_controlword()/write_target_torque() whose ``now``
is at or after ``boot_time_s``. Controlwords written before that are ignored (not stored).

Command watchdog (CiA 301 "RPDO timeout", 0x8250): every update() made while the state is
OPERATION_ENABLED increments a counter; write_target_torque() and entering OPERATION_ENABLED
reset it to 0. The profile gives the watchdog in time (``watchdog_s``); the drive counts it in
periods of its own timer, N = ceil(watchdog_s / period). The update() that brings the counter to
N faults the drive: a write followed by N - 1 updates is still enabled, the N-th update faults
(the shipped profiles: 0.5 s, N = 200 at 400 Hz, 500 at 1 kHz; docs/virtual-robot.md says why).
In realtime a stall of the robot process itself counts one period (its timer re-aligns), so
only the host's silence trips it.

Fault reaction: torque is zeroed at once and the state passes FAULT_REACTION_ACTIVE -> FAULT
within the same call, so FAULT_REACTION_ACTIVE is never observed from outside.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from drivers.protocol.cia402 import (
    ABORT_NOT_IN_STATE,
    ABORT_VALUE_RANGE,
    ABORT_VALUE_TOO_HIGH,
    ABORT_VALUE_TOO_LOW,
    CW_FAULT_RESET,
    CW_HALT,
    ERR_NONE,
    ERR_OVERSPEED,
    ERR_RPDO_TIMEOUT,
    ERREG_COMMUNICATION,
    ERREG_DEVICE_PROFILE,
    ERREG_GENERIC,
    MODE_CST,
    MODE_TQ,
    SW_PATTERNS,
    State,
    state_from_statusword,
)
from drivers.units import INT16_MAX, INT16_MIN, INT32_MAX, INT32_MIN, wrap_int32
from profiles.drive import DriveProfile

# The drive's vocabulary lives in drivers.protocol.cia402 (shared with the host); re-exported here.
__all__ = [
    "ABORT_NOT_IN_STATE",
    "ABORT_VALUE_RANGE",
    "ABORT_VALUE_TOO_HIGH",
    "ABORT_VALUE_TOO_LOW",
    "CW_FAULT_RESET",
    "CW_HALT",
    "ERREG_COMMUNICATION",
    "ERREG_DEVICE_PROFILE",
    "ERREG_GENERIC",
    "ERR_NONE",
    "ERR_OVERSPEED",
    "ERR_RPDO_TIMEOUT",
    "INT16_MAX",
    "INT16_MIN",
    "INT32_MAX",
    "INT32_MIN",
    "MODE_CST",
    "MODE_TQ",
    "DriveError",
    "DriveModel",
    "Emcy",
    "State",
    "state_from_statusword",
]

_SW_BITS = {state: value for _, value, state in SW_PATTERNS}
# The states the per-period paths (update, torque, statusword) compare with, looked up once:
# an Enum member lookup costs about as much as the rest of such a comparison.
_ENABLED = State.OPERATION_ENABLED
_QUICK_STOP = State.QUICK_STOP_ACTIVE
_NOT_READY = State.NOT_READY_TO_SWITCH_ON


class _Cmd(enum.Enum):
    SHUTDOWN = enum.auto()  # 0xxx x110
    SWITCH_ON = enum.auto()  # 0xxx 0111 (also "disable operation"); x111 from READY
    ENABLE_OPERATION = enum.auto()  # 0xxx 1111
    DISABLE_VOLTAGE = enum.auto()  # 0xxx xx0x
    QUICK_STOP = enum.auto()  # 0xxx x01x


def _decode(cw: int) -> _Cmd:
    if not cw & 0x02:
        return _Cmd.DISABLE_VOLTAGE
    if not cw & 0x04:
        return _Cmd.QUICK_STOP
    if not cw & 0x01:
        return _Cmd.SHUTDOWN
    return _Cmd.ENABLE_OPERATION if cw & 0x08 else _Cmd.SWITCH_ON


_S, _C = State, _Cmd
# CiA 402 transitions by number; pairs not listed are ignored (no state change).
_TRANSITIONS: dict[tuple[State, _Cmd], State] = {
    (_S.SWITCH_ON_DISABLED, _C.SHUTDOWN): _S.READY_TO_SWITCH_ON,  # 2
    (_S.READY_TO_SWITCH_ON, _C.SWITCH_ON): _S.SWITCHED_ON,  # 3
    (_S.READY_TO_SWITCH_ON, _C.ENABLE_OPERATION): _S.OPERATION_ENABLED,  # 3 + 4
    (_S.READY_TO_SWITCH_ON, _C.DISABLE_VOLTAGE): _S.SWITCH_ON_DISABLED,  # 7
    (_S.READY_TO_SWITCH_ON, _C.QUICK_STOP): _S.SWITCH_ON_DISABLED,  # 7
    (_S.SWITCHED_ON, _C.ENABLE_OPERATION): _S.OPERATION_ENABLED,  # 4
    (_S.SWITCHED_ON, _C.SHUTDOWN): _S.READY_TO_SWITCH_ON,  # 6
    (_S.SWITCHED_ON, _C.DISABLE_VOLTAGE): _S.SWITCH_ON_DISABLED,  # 10
    (_S.SWITCHED_ON, _C.QUICK_STOP): _S.SWITCH_ON_DISABLED,  # 10
    (_S.OPERATION_ENABLED, _C.SWITCH_ON): _S.SWITCHED_ON,  # 5
    (_S.OPERATION_ENABLED, _C.SHUTDOWN): _S.READY_TO_SWITCH_ON,  # 8
    (_S.OPERATION_ENABLED, _C.DISABLE_VOLTAGE): _S.SWITCH_ON_DISABLED,  # 9
    (_S.OPERATION_ENABLED, _C.QUICK_STOP): _S.QUICK_STOP_ACTIVE,  # 11
    (_S.QUICK_STOP_ACTIVE, _C.ENABLE_OPERATION): _S.OPERATION_ENABLED,  # 16
    (_S.QUICK_STOP_ACTIVE, _C.DISABLE_VOLTAGE): _S.SWITCH_ON_DISABLED,  # 12
}
_VOLTAGE_ON = {_S.READY_TO_SWITCH_ON, _S.SWITCHED_ON, _S.OPERATION_ENABLED, _S.QUICK_STOP_ACTIVE}
# The statusword bits a state alone sets: its pattern, 9 remote, 4 voltage enabled, 5 quick stop
# not active (one lookup a period per drive instead of three on the Enum, whose hash is Python)
_SW_STATE_BITS = {
    state: _SW_BITS[state]
    | 0x0200
    | (0x0010 if state in _VOLTAGE_ON else 0)
    | (0x0020 if state is not _S.QUICK_STOP_ACTIVE else 0)
    for state in State
}


class DriveError(Exception):
    """A rejected write; ``abort_code`` is the CiA 301 SDO abort code a transport should send."""

    def __init__(self, abort_code: int, message: str) -> None:
        super().__init__(f"0x{abort_code:08X}: {message}")
        self.abort_code = abort_code


@dataclass(frozen=True)
class Emcy:
    """One EMCY event (CiA 301): error code (0x603F), error register (0x1001), clock time."""

    error_code: int
    error_register: int
    time_s: float


def _check_range(name: str, value: int, lo: int, hi: int, code: int | None = None) -> None:
    if value > hi:
        raise DriveError(code or ABORT_VALUE_TOO_HIGH, f"{name} {value} > {hi}")
    if value < lo:
        raise DriveError(code or ABORT_VALUE_TOO_LOW, f"{name} {value} < {lo}")


def _ratio(num: float, den: float) -> float | Fraction:
    """num / den, exactly (as a Fraction) when the float quotient would overflow."""
    try:
        q = num / den
    except OverflowError:
        q = math.inf
    return q if math.isfinite(q) else Fraction(num) / Fraction(den)


class DriveModel:
    """One emulated servo drive in torque mode (CiA 402 CST / TQ)."""

    def __init__(
        self, profile: DriveProfile, boot_time_s: float = 0.0, period_s: float = 0.0025
    ) -> None:
        self.profile = profile
        self._rad_per_count = profile.rad_per_count  # read every period
        self._rated_torque_Nm = profile.rated_torque_Nm
        # the profile's watchdog (seconds) in periods of this drive's timer
        self.watchdog_periods = profile.watchdog_periods(period_s)
        self._counts = 0  # unbounded encoder count
        self._velocity = 0  # counts/s, INT32-clamped
        self._t_prev: float | None = None
        self._emcy: list[Emcy] = []
        self._sw_state: State | None = None  # the state whose _SW_STATE_BITS are memoized
        self._sw_state_bits = 0
        self._power_on(boot_time_s)

    def _power_on(self, boot_time_s: float) -> None:
        self._boot_time_s = boot_time_s
        self._state = State.NOT_READY_TO_SWITCH_ON
        self._controlword = 0
        self._mode = MODE_CST
        self._target = 0
        self._max_torque = self.profile.max_torque_permille
        self._watchdog = 0
        self._error_code = ERR_NONE
        self._error_register = 0

    # ----------------------------------------------------------------- writes from a transport

    def write_controlword(self, controlword: int, now: float) -> None:
        """0x6040 (UINT16). Invalid commands for the present state are ignored."""
        _check_range("controlword", controlword, 0, 0xFFFF, ABORT_VALUE_RANGE)
        self._boot(now)
        if self._state is State.NOT_READY_TO_SWITCH_ON:
            return  # still booting: ignored
        rising_reset = bool(controlword & ~self._controlword & CW_FAULT_RESET)
        self._controlword = controlword
        if self._state is State.FAULT:
            if rising_reset:  # transition 15
                self._state = State.SWITCH_ON_DISABLED
                self._error_code, self._error_register = ERR_NONE, 0
                self._emcy.append(Emcy(ERR_NONE, 0, now))  # CiA 301 "error reset"
            return
        # Outside FAULT the fault-reset bit has no meaning; bits 0-3 select the command.
        new = _TRANSITIONS.get((self._state, _decode(controlword)))
        if new is not None:
            if new is State.OPERATION_ENABLED and self._state is not new:
                self._watchdog = 0
            self._state = new

    def write_target_torque(self, permille: int, now: float) -> None:
        """0x6071 (INT16, ‰ of 0x6076). Feeds the command watchdog."""
        if not INT16_MIN <= permille <= INT16_MAX:  # written every period: the check inline
            _check_range("target torque", permille, INT16_MIN, INT16_MAX)
        if self._state is _NOT_READY:
            self._boot(now)
        self._target = permille
        self._watchdog = 0

    def write_mode(self, mode: int) -> None:
        """0x6060: MODE_CST (10) or MODE_TQ (4); both take torque from 0x6071."""
        if mode not in (MODE_CST, MODE_TQ):
            raise DriveError(ABORT_VALUE_RANGE, f"mode of operation {mode} not supported")
        self._mode = mode

    def write_max_torque(self, permille: int) -> None:
        """0x6072 (UINT16, ‰ of 0x6076), accepted range 1..32767."""
        _check_range("max torque", permille, 1, INT16_MAX)
        self._max_torque = permille

    def reset(self, now: float) -> None:
        """NMT reset node (CiA 301): objects back to power-on values, errors cleared.

        The encoder count and velocity are kept; queued EMCY events are kept. The drive boots
        again (transition 1) at the next update/write at or after ``now``.
        """
        self._power_on(now)

    # ----------------------------------------------------------------- one sampling period

    def update(
        self, now: float, position_rad: float, velocity_rad_s: float, count_period: bool = True
    ) -> None:
        """Sample the encoder, check overspeed and (if ``count_period``) the command watchdog.

        In lockstep every SYNC is one drive period. In realtime the drive's own period timer
        counts periods, and a SYNC only samples (``count_period=False``).
        """
        if not (math.isfinite(position_rad) and math.isfinite(velocity_rad_s)):
            raise ValueError("position and velocity must be finite")
        if self._state is _NOT_READY:
            self._boot(now)
        # the quotients by plain division, by _ratio only where that overflows (once a period
        # per joint: the call costs as much as the arithmetic)
        try:
            counts = math.floor(position_rad / self._rad_per_count)
        except OverflowError:
            counts = math.floor(_ratio(position_rad, self._rad_per_count))
        t_prev = self._t_prev
        if t_prev is None or now <= t_prev:
            self._velocity = 0
        else:
            try:
                v = round((counts - self._counts) / (now - t_prev))
            except OverflowError:
                v = round(_ratio(counts - self._counts, now - t_prev))
            self._velocity = INT32_MAX if v > INT32_MAX else INT32_MIN if v < INT32_MIN else v
        self._counts, self._t_prev = counts, now

        powered = self._state is _ENABLED or self._state is _QUICK_STOP
        if powered and abs(velocity_rad_s) > self.profile.max_velocity_rad_s:
            self._fault(ERR_OVERSPEED, ERREG_GENERIC | ERREG_DEVICE_PROFILE, now)
        if count_period and self._state is _ENABLED:
            self._watchdog += 1
            if self._watchdog >= self.watchdog_periods:
                self._fault(ERR_RPDO_TIMEOUT, ERREG_GENERIC | ERREG_COMMUNICATION, now)

    def communication_fault(self, code: int, now: float) -> None:
        """Fault with a communication error ``code`` (torque off at once), e.g. the bus is
        corrupted by a second SYNC producer."""
        self._fault(code, ERREG_GENERIC | ERREG_COMMUNICATION, now)

    def _boot(self, now: float) -> None:
        if self._state is _NOT_READY and now >= self._boot_time_s:
            self._state = State.SWITCH_ON_DISABLED  # transition 1

    def _fault(self, code: int, register: int, now: float) -> None:
        if self._state is State.FAULT and code == self._error_code:
            return
        self._state = State.FAULT_REACTION_ACTIVE  # 13: torque off (torque_Nm reads 0)
        self._error_code, self._error_register = code, register
        self._emcy.append(Emcy(code, register, now))
        self._state = State.FAULT  # 14

    def pop_emcy(self) -> list[Emcy]:
        """EMCY events since the last call, oldest first."""
        events, self._emcy = self._emcy, []
        return events

    # ----------------------------------------------------------------- many periods at once

    def enabled_outputs(self, targets_permille: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:attr:`torque_Nm` and :attr:`statusword` after each of ``targets_permille`` is
        written, for a drive that stays OPERATION ENABLED and not halted meanwhile (the same
        arithmetic, element-wise: the offline simulation's rows, virtual_robot.offline).
        ValueError if the drive is not applying torque now."""
        if self._state is not _ENABLED or self._controlword & CW_HALT:
            raise ValueError(f"drive not applying torque (state {self._state.name})")
        limit = self._max_torque
        targets = np.asarray(targets_permille, dtype=np.int64)
        torque = np.clip(targets, -limit, limit) * self._rated_torque_Nm / 1000.0
        saturated = np.abs(targets) > limit
        status = _SW_STATE_BITS[_ENABLED] | np.where(saturated, 0x0800, 0x0400)
        return torque, status

    def encoder_counts(self, position_rad: np.ndarray) -> np.ndarray:
        """The unbounded count :meth:`update` takes of each finite position (int64: every
        |position| must be below 2⁵² counts)."""
        return np.floor(np.asarray(position_rad, dtype=float) / self._rad_per_count).astype(
            np.int64
        )

    # ----------------------------------------------------------------- readouts

    @property
    def state(self) -> State:
        return self._state

    @property
    def controlword(self) -> int:
        return self._controlword

    @property
    def mode(self) -> int:
        return self._mode

    @property
    def target_torque_permille(self) -> int:
        return self._target

    @property
    def max_torque_permille(self) -> int:
        return self._max_torque

    @property
    def torque_actual_permille(self) -> int:
        """0x6077: the clamped target while applying torque, else 0."""
        # applying torque: enabled, not halted (statusword tests the same; both are read every
        # period, inline rather than through a shared property)
        if self._state is not _ENABLED or self._controlword & CW_HALT:
            return 0
        target, limit = self._target, self._max_torque  # clamped to ±limit (comparisons:
        return limit if target > limit else -limit if target < -limit else target  # no calls)

    @property
    def powered(self) -> bool:
        """Power stage on: OPERATION ENABLED or QUICK STOP ACTIVE (torque may still be zero)."""
        return self._state is _ENABLED or self._state is _QUICK_STOP

    @property
    def torque_Nm(self) -> float:
        return self.torque_actual_permille * self._rated_torque_Nm / 1000.0

    @property
    def statusword(self) -> int:
        """0x6041: state pattern + bit 4 voltage enabled, 5 quick stop (1 = not active),
        9 remote, 10 target reached, 11 internal limit active.

        Bit 10 in OPERATION ENABLED, as CiA 402 defines it for the profile modes: with halt
        (controlword bit 8) clear, the torque target is applied (not saturated); with halt set,
        the axis has stopped, i.e. velocity actual 0x606C is 0 (no count in the last period).
        """
        state = self._state
        if state is not self._sw_state:  # the state's bits, looked up when it changed
            self._sw_state, self._sw_state_bits = state, _SW_STATE_BITS[state]
        sw = self._sw_state_bits
        if state is _ENABLED:
            if self._controlword & CW_HALT:  # halted: torque 0, never saturated
                if self._velocity == 0:
                    sw |= 0x0400
            elif abs(self._target) > self._max_torque:  # saturated
                sw |= 0x0800
            else:
                sw |= 0x0400
        return sw

    @property
    def position_counts(self) -> int:
        """0x6064 (INT32, two's-complement wrap-around)."""
        return wrap_int32(self._counts)

    @property
    def velocity_counts_s(self) -> int:
        """0x606C (INT32, clamped)."""
        return self._velocity

    @property
    def error_code(self) -> int:
        return self._error_code

    @property
    def error_register(self) -> int:
        return self._error_register
