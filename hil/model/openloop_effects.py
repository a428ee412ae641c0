"""The extra physics the mismatch diagnosis can accept (issue 7), for the host's simulator.

What lives here: :class:`OpenLoopExtras` (the diagnosis's vocabulary of effects) and how each
enters :func:`hil.model.openloop_core.integrate`, the one stick–slip integrator (read
:mod:`hil.model.openloop`'s docstring for the scheme): the torque path from the recorded command
to the shaft as an :class:`EffectsTorquePath`, Stribeck friction as a
:class:`StribeckFriction`, cogging as a shaft torque. In the order of the torque path:

    τ_cmd ─▶ transport delay d ─▶ actuator lag T ─▶ (1 + r) τ + τ_0 ─▶ + cogging(q) ─▶ shaft

* transport delay: τ_in(t) = τ_cmd(t − d); the command of row k (held over [kh, (k+1)h)) reaches
  the amplifier at kh + d, and the amplifier input is 0 before the first one arrives. Sub-steps are
  cut at the arrival instants, so d need not be a multiple of h.
* actuator lag, per joint: T dτ/dt = τ_in − τ, stepped exactly under a held input; each RK4
  (sub-)step is integrated with the mean of τ over it,
      τ(Δt) = τ_in + (τ0 − τ_in) e^{−Δt/T},  mean = τ_in + (τ0 − τ_in)(T/Δt)(1 − e^{−Δt/T}),
  and the lag state is carried on (zero at the start).
* torque gain r and offset τ_0: τ_applied = (1 + r) τ + τ_0, after the lag.
* cogging: τ_cog,i = A_i sin(N_i q_i + φ_i) at the true angle, added at the shaft (it also enters
  the holding torque of a stuck joint).
* Stribeck friction: a sliding joint feels b q̇ + d F(|q̇|) with
      F(|q̇|) = F_c + (F_s − F_c) exp(−(|q̇| / v_s)^δ),   F_s = breakaway_ratio · F_c,
  F_c the Coulomb level of the slip direction d; the static band of a stuck joint is
  [−F_s⁻, F_s⁺]. F is evaluated at every RK4 stage with the direction frozen over the sub-step.

(The angle offset only changes what is reported; :func:`hil.model.openloop.simulate_open_loop`
applies it.) These are the definitions of the virtual robot's effects (virtual_robot/effects.py
and plant.py, docs/effects.md), written again here because the host never imports the world;
tests/test_openloop.py checks that the two agree. Sub-steps are the plant's: ``steps_per_period``
per period, cut at arrivals of delayed commands, with the lag mean taken over each (cut) sub-step.

Imports: numpy and :mod:`hil.model.openloop_core`; :mod:`hil.model.openloop` builds on this.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hil.model.openloop_core import (
    Friction,
    OpenLoopResult,
    Pair,
    Segments,
    ShaftTorque,
    State,
    TorquePath,
    integrate,
    number,
    pair,
)

# Sub-step boundaries closer than this (s) to an arrival instant are not cut (as in the plant).
_TIME_TOL = 1e-12


@dataclass(frozen=True)
class OpenLoopExtras:
    """Physics beyond the 9-parameter model, in the mismatch diagnosis's vocabulary (issue 7).

    The virtual robot's effects (virtual_robot/effects.py, docs/effects.md), defined the same way;
    the defaults switch everything off. Pairs are (joint 1, joint 2). Equations and the order of
    the torque path are in this module's docstring:

    * ``torque_offset_Nm``, ``torque_gain``: τ_applied = (1 + r) τ + τ_0 (after the lag);
    * ``actuator_lag_s``: first-order lag time constants T (0 = none);
    * ``transport_delay_s``: one pure delay d of the commands of both joints;
    * ``cogging_*``: τ_cog = A sin(N q + φ), N periods per revolution, at the true angle;
    * ``angle_offset_rad``: reported angle = true angle + δ (q0 and the result's q are reported
      angles; the dynamics use the true ones);
    * ``stribeck_*``: F(|q̇|) = F_c + (F_s − F_c) exp(−(|q̇|/v_s)^δ), F_s = ratio · F_c, and a
      static band of F_s; on when ``stribeck_velocity_rad_s`` is given (ratio default 1).
    Raises ValueError (one line) on a bad value.
    """

    torque_offset_Nm: tuple[float, float] = (0.0, 0.0)
    torque_gain: tuple[float, float] = (0.0, 0.0)
    actuator_lag_s: tuple[float, float] = (0.0, 0.0)
    transport_delay_s: float = 0.0
    cogging_periods_per_rev: tuple[float, float] = (0.0, 0.0)
    cogging_amplitude_Nm: tuple[float, float] = (0.0, 0.0)
    cogging_phase_rad: tuple[float, float] = (0.0, 0.0)
    angle_offset_rad: tuple[float, float] = (0.0, 0.0)
    stribeck_breakaway_ratio: tuple[float, float] | None = None
    stribeck_velocity_rad_s: tuple[float, float] | None = None
    stribeck_exponent: float = 2.0
    # The command held before t = 0 (None: zero, the arm starts from rest). A simulation restarted
    # inside a recording (the diagnosis's held-out segments) starts settled on the previous
    # row's command: the lag state and the delay line's rows before 0 equal it.
    initial_command_Nm: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        def put(name: str, value: object) -> None:
            object.__setattr__(self, name, value)

        if self.initial_command_Nm is not None:
            put("initial_command_Nm", pair("initial_command_Nm", self.initial_command_Nm))

        for name in (
            "torque_offset_Nm",
            "torque_gain",
            "actuator_lag_s",
            "cogging_periods_per_rev",
            "cogging_amplitude_Nm",
            "cogging_phase_rad",
            "angle_offset_rad",
        ):
            put(name, pair(name, getattr(self, name)))
        if min(self.torque_gain) <= -1.0:
            raise ValueError(f"torque_gain must be > -1 (relative), got {self.torque_gain}")
        if min(self.actuator_lag_s) < 0.0:
            raise ValueError(f"actuator_lag_s must be >= 0, got {self.actuator_lag_s}")
        if min(self.cogging_periods_per_rev) < 0.0:
            raise ValueError(
                f"cogging_periods_per_rev must be >= 0, got {self.cogging_periods_per_rev}"
            )
        delay = number("transport_delay_s", self.transport_delay_s)
        if delay < 0.0:
            raise ValueError(f"transport_delay_s must be >= 0, got {delay}")
        put("transport_delay_s", delay)
        velocity, ratio = self.stribeck_velocity_rad_s, self.stribeck_breakaway_ratio
        if velocity is None:
            if ratio is not None:
                raise ValueError("stribeck_breakaway_ratio needs stribeck_velocity_rad_s")
            return
        velocity = pair("stribeck_velocity_rad_s", velocity)
        ratio = (1.0, 1.0) if ratio is None else pair("stribeck_breakaway_ratio", ratio)
        if min(velocity) <= 0.0:
            raise ValueError(f"stribeck_velocity_rad_s must be > 0, got {velocity}")
        if min(ratio) < 1.0:
            raise ValueError(f"stribeck_breakaway_ratio must be >= 1 (F_s/F_c), got {ratio}")
        exponent = number("stribeck_exponent", self.stribeck_exponent)
        if not 0.0 < exponent <= 10.0:
            raise ValueError(f"stribeck_exponent must be in (0, 10], got {exponent}")
        put("stribeck_velocity_rad_s", velocity)
        put("stribeck_breakaway_ratio", ratio)
        put("stribeck_exponent", exponent)

    @property
    def changes_dynamics(self) -> bool:
        """Anything on but the angle offset (which only changes what is reported)."""
        return (
            any(self.torque_offset_Nm)
            or any(self.torque_gain)
            or any(self.actuator_lag_s)
            or self.transport_delay_s > 0.0
            or any(self.cogging_amplitude_Nm)
            or self.stribeck_velocity_rad_s is not None
        )


def lag_step(state: float, command: float, dt: float, time_constant_s: float) -> Pair:
    """(mean over dt, value at dt) of T dτ/dt = τ_in − τ from τ(0) = ``state``, τ_in held."""
    if time_constant_s <= 0.0 or dt <= 0.0:
        return command, command
    decay = math.exp(-dt / time_constant_s)
    gap = state - command
    return command + gap * time_constant_s / dt * (1.0 - decay), command + gap * decay


def _period_segments(h: float, n_sub: int, arrival: float | None) -> Segments:
    """Sub-steps of one period as (length, which command): 0 = the one before the arrival of the
    period's delayed command at offset ``arrival`` (None: no arrival inside the period), 1 after."""
    dt_sub = h / n_sub
    if arrival is None:
        return [(dt_sub, 1)] * n_sub
    segments = []
    t = 0.0
    while t < h - _TIME_TOL:
        stop = min(h, t + dt_sub)
        if t < arrival < stop:
            stop = arrival
        segments.append((stop - t, 1 if arrival <= t + _TIME_TOL else 0))
        t = stop
    return segments


def _commands(
    torques: np.ndarray, delay_s: float, h: float, initial: Pair | None = None
) -> tuple[list, list, float | None]:
    """Amplifier inputs per period: (before the arrival, after it, arrival offset or None).

    With d = m h + ρ (0 ≤ ρ < h): period k starts with row k − m − 1 (ρ > 0) or k − m (ρ = 0)
    and switches to row k − m at kh + ρ; rows before 0 are zero torque (``initial``: that
    command instead).
    """
    rows = torques.tolist()
    n = len(rows)
    m = math.floor(delay_s / h + _TIME_TOL / h)
    rho = delay_s - m * h
    arrival = rho if rho > _TIME_TOL else None
    zero = [0.0, 0.0] if initial is None else list(initial)
    after = [rows[k - m] if k - m >= 0 else zero for k in range(n)]
    if arrival is None:
        return after, after, None
    before = [rows[k - m - 1] if k - m - 1 >= 0 else zero for k in range(n)]
    return before, after, arrival


class EffectsTorquePath(TorquePath):
    """Transport delay, actuator lag, gain and offset between the recorded command and the shaft
    (this module's docstring); the lag state starts settled on ``extras.initial_command_Nm``
    (zero when None)."""

    identity = False
    row_local = False  # a delayed command arrives in a later period

    def __init__(self, extras: OpenLoopExtras) -> None:
        self.delay_s = extras.transport_delay_s
        self.lag_s = extras.actuator_lag_s
        self.lagged = self.lag_s[0] > 0.0 or self.lag_s[1] > 0.0
        self.gain, self.offset = extras.torque_gain, extras.torque_offset_Nm
        self.initial = extras.initial_command_Nm
        # amplifier output before gain/offset (the lag state)
        self.lag: Pair = (0.0, 0.0) if self.initial is None else self.initial

    def schedule(self, torques: np.ndarray, h: float, n_sub: int) -> tuple[list, list, Segments]:
        before, after, arrival = _commands(torques, self.delay_s, h, self.initial)
        return before, after, _period_segments(h, n_sub, arrival)

    def applied(self, command: Sequence[float], dt: float) -> tuple[Pair, Pair]:
        if self.lagged:
            m1, e1 = lag_step(self.lag[0], command[0], dt, self.lag_s[0])
            m2, e2 = lag_step(self.lag[1], command[1], dt, self.lag_s[1])
        else:
            m1 = e1 = command[0]
            m2 = e2 = command[1]
        gain, offset = self.gain, self.offset
        return ((1.0 + gain[0]) * m1 + offset[0], (1.0 + gain[1]) * m2 + offset[1]), (e1, e2)

    def settle(self, state: Pair) -> None:
        self.lag = state


class StribeckFriction(Friction):
    """Coulomb levels F_c by direction that rise to F_s = ratio · F_c towards rest (this
    module's docstring); the static band is [−F_s⁻, F_s⁺]."""

    speed_dependent = True

    def __init__(
        self, positive: Pair, negative: Pair, ratio: Pair, velocity: Pair, exponent: float
    ) -> None:
        super().__init__(positive, negative)
        self.static_positive = (positive[0] * ratio[0], positive[1] * ratio[1])
        self.static_negative = (negative[0] * ratio[0], negative[1] * ratio[1])
        self.velocity, self.exponent = velocity, exponent

    def sliding(self, joint: int, direction: float, speed: float) -> float:
        fc = self.positive[joint] if direction > 0 else self.negative[joint]
        fs = self.static_positive[joint] if direction > 0 else self.static_negative[joint]
        return direction * (
            fc + (fs - fc) * math.exp(-((speed / self.velocity[joint]) ** self.exponent))
        )


def _cogging(extras: OpenLoopExtras) -> ShaftTorque | None:
    """τ_cog,i = A_i sin(N_i q_i + φ_i), or None when both amplitudes are zero."""
    n, a, phase = (
        extras.cogging_periods_per_rev,
        extras.cogging_amplitude_Nm,
        extras.cogging_phase_rad,
    )
    if a[0] == 0.0 and a[1] == 0.0:
        return None

    def cogging(q1: float, q2: float) -> Pair:
        return a[0] * math.sin(n[0] * q1 + phase[0]), a[1] * math.sin(n[1] * q2 + phase[1])

    return cogging


def integrate_with_extras(
    theta: np.ndarray,
    torques: np.ndarray,
    h: float,
    n_sub: int,
    start: State,
    pos: Pair,
    neg: Pair,
    extras: OpenLoopExtras,
    intervals: np.ndarray | None = None,
) -> OpenLoopResult:
    """:func:`hil.model.openloop_core.integrate` with ``extras`` (angle offset excluded) and the
    Coulomb levels ``pos``, ``neg`` by direction. ``start`` is the true state; the returned q are
    true angles."""
    if extras.stribeck_velocity_rad_s is None:
        friction = Friction(pos, neg)
    else:
        ratio = extras.stribeck_breakaway_ratio or (1.0, 1.0)
        friction = StribeckFriction(
            pos, neg, ratio, extras.stribeck_velocity_rad_s, extras.stribeck_exponent
        )
    path = EffectsTorquePath(extras)
    return integrate(theta, torques, h, n_sub, start, friction, path, _cogging(extras), intervals)
