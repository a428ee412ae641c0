"""Open-loop simulation of the host's identified model under recorded torques.

This is how the host checks a model (Reyes & Kelly 1997, Figs. 2, 4 and 7): drive the model with
the torques of a recording, zero-order held over each period, and compare its positions with the
recorded ones. The model is :mod:`hil.model.closed_form`'s (Section 5 of the paper):

    M(q) q̈ + C(q, q̇) q̇ + g(q) + f = τ,
    M(q) = [[θ1 + 2θ2 cos q2, θ3 + θ2 cos q2], [θ3 + θ2 cos q2, θ3]],
    C(q, q̇) q̇ = θ2 sin q2 [−(2 q̇1 q̇2 + q̇2²), q̇1²],
    g(q) = [θ4 sin q1 + θ5 sin(q1 + q2), θ5 sin(q1 + q2)],

with friction f_i = b_i q̇_i + F_i(direction) sgn q̇_i (b = θ6, θ7; F = θ8, θ9, or the
direction-dependent levels ``coulomb_positive`` / ``coulomb_negative``), simulated as
Karnopp-style stick–slip rather than with sgn(0) = 0:

* a joint at rest (q̇_i = 0) stays stuck while the friction torque needed to hold it, from the
  constrained dynamics with q̈_i = 0, lies inside its Coulomb band [−F_i⁻, F_i⁺]; outside the
  band it breaks away in the direction of that torque (checked at every sub-step boundary);
* a sliding joint has its Coulomb direction frozen over a sub-step, so each RK4 sub-step
  integrates a smooth ODE; when its velocity changes sign within a sub-step the crossing is
  located on the RK4 flow map (linear interpolation refined by Illinois regula falsi), the
  velocity is clamped to zero there, the joint sticks, and the rest of the sub-step is integrated
  in the new mode.

A joint with zero Coulomb friction in both directions never sticks (its dynamics are smooth).

Written on purpose without reference to the virtual robot's plant (the world): the host's model
and the world are separate code, and tests/test_openloop.py checks that they agree. Scalar
Python floats (``math``) inside the loop: the 10 s Reyes & Kelly run at h = 2.5 ms (20,000 RK4
sub-steps, ~130 stick events) takes about 0.09 s on the 2-core development VM.
"""

from __future__ import annotations

import dataclasses
import math
import operator
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from hil.model.closed_form import N_PARAMS

# Stick events that may occur within one sub-step before the rest of it is integrated without
# further break-away checks (only a degenerate, chattering case comes near it).
MAX_EVENTS_PER_SUBSTEP = 8
# A located velocity zero is accepted when |q̇_i| is below this (rad/s).
ZERO_VELOCITY_TOL = 1e-12

State = tuple[float, float, float, float]  # q1, q2, q̇1, q̇2
Step = Callable[[float, float, float, float, float, float, float], State]


@dataclass(frozen=True)
class OpenLoopResult:
    """Simulated samples at t = k·h, k = 0..N−1, before tau[k] is applied (row 0 = q0, dq0)."""

    t: np.ndarray  # (N,) s
    q: np.ndarray  # (N, 2) rad
    dq: np.ndarray  # (N, 2) rad/s
    stuck: np.ndarray  # (N, 2) bool: the joint is stuck (static friction holds it) at t
    stick_events: np.ndarray  # (2,) int: times a sliding joint came to rest
    breakaways: np.ndarray  # (2,) int: times a stuck joint broke away
    substeps: int  # RK4 sub-steps integrated (a sub-step cut by stick events counts once)

    @property
    def stuck_fraction(self) -> np.ndarray:
        """Fraction of the samples at which each joint is stuck, shape (2,)."""
        return self.stuck.mean(axis=0)


@dataclass(frozen=True)
class OpenLoopExtras:
    """Physics beyond the 9-parameter model, in the mismatch diagnosis's vocabulary (issue 7).

    The virtual robot's effects (virtual_robot/effects.py, docs/effects.md), defined the same way;
    the defaults switch everything off. Pairs are (joint 1, joint 2). Equations and the order of
    the torque path are in :mod:`hil.model.openloop_effects`:

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
            put("initial_command_Nm", _pair("initial_command_Nm", self.initial_command_Nm))

        for name in (
            "torque_offset_Nm",
            "torque_gain",
            "actuator_lag_s",
            "cogging_periods_per_rev",
            "cogging_amplitude_Nm",
            "cogging_phase_rad",
            "angle_offset_rad",
        ):
            put(name, _pair(name, getattr(self, name)))
        if min(self.torque_gain) <= -1.0:
            raise ValueError(f"torque_gain must be > -1 (relative), got {self.torque_gain}")
        if min(self.actuator_lag_s) < 0.0:
            raise ValueError(f"actuator_lag_s must be >= 0, got {self.actuator_lag_s}")
        if min(self.cogging_periods_per_rev) < 0.0:
            raise ValueError(
                f"cogging_periods_per_rev must be >= 0, got {self.cogging_periods_per_rev}"
            )
        delay = _number("transport_delay_s", self.transport_delay_s)
        if delay < 0.0:
            raise ValueError(f"transport_delay_s must be >= 0, got {delay}")
        put("transport_delay_s", delay)
        velocity, ratio = self.stribeck_velocity_rad_s, self.stribeck_breakaway_ratio
        if velocity is None:
            if ratio is not None:
                raise ValueError("stribeck_breakaway_ratio needs stribeck_velocity_rad_s")
            return
        velocity = _pair("stribeck_velocity_rad_s", velocity)
        ratio = (1.0, 1.0) if ratio is None else _pair("stribeck_breakaway_ratio", ratio)
        if min(velocity) <= 0.0:
            raise ValueError(f"stribeck_velocity_rad_s must be > 0, got {velocity}")
        if min(ratio) < 1.0:
            raise ValueError(f"stribeck_breakaway_ratio must be >= 1 (F_s/F_c), got {ratio}")
        exponent = _number("stribeck_exponent", self.stribeck_exponent)
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


def simulate_open_loop(
    theta: ArrayLike,
    tau: ArrayLike,
    period_s: float,
    *,
    q0: Sequence[float] = (0.0, 0.0),
    dq0: Sequence[float] = (0.0, 0.0),
    steps_per_period: int = 5,
    coulomb_positive: Sequence[float] | None = None,
    coulomb_negative: Sequence[float] | None = None,
    extras: OpenLoopExtras | None = None,
) -> OpenLoopResult:
    """Simulate the model θ under torques ``tau`` (N, 2), each held over one period of h seconds.

    Row k of the result is the state at t = k·h before ``tau[k]`` is applied, so ``result.q``
    lines up with a recording's ``q`` when ``tau`` is its ``tau`` (drivers.recording). Each
    period is integrated with ``steps_per_period`` RK4 sub-steps with stick–slip friction (see
    the module docstring). ``coulomb_positive`` / ``coulomb_negative`` (2 levels each, Nm,
    ≥ 0) replace θ8, θ9 as the Coulomb level when a joint moves (or breaks away) in the positive
    / negative direction; either may be given alone. θ must give a positive definite M(q) for
    every q2; negative viscous coefficients are simulated as given. ``extras``
    (:class:`OpenLoopExtras`) adds the diagnosis's physics (torque offset and gain, actuator lag,
    transport delay, cogging, angle offset, Stribeck friction); with an angle offset, ``q0`` and
    the result's ``q`` are reported angles (true + offset). Raises ValueError on bad input.
    """
    th = _theta(theta)
    torques = _torques(tau)
    h = _positive("period_s", period_s)
    n_sub = _steps(steps_per_period)
    start = (*_pair("q0", q0), *_pair("dq0", dq0))
    fc = (float(th[7]), float(th[8]))
    pos = fc if coulomb_positive is None else _pair("coulomb_positive", coulomb_positive)
    neg = fc if coulomb_negative is None else _pair("coulomb_negative", coulomb_negative)
    for name, levels in (("theta8, theta9 (Coulomb)", fc), ("coulomb_positive", pos)):
        _non_negative(name, levels)
    _non_negative("coulomb_negative", neg)
    if extras is None:
        return _integrate(th, torques, h, n_sub, start, pos, neg)
    if not isinstance(extras, OpenLoopExtras):
        raise ValueError(f"extras must be an OpenLoopExtras, got {type(extras).__name__}")
    offset = extras.angle_offset_rad
    true_start = (start[0] - offset[0], start[1] - offset[1], start[2], start[3])
    if extras.changes_dynamics:
        # imported here: hil.model.openloop_effects builds on this module's integrator pieces
        from hil.model.openloop_effects import integrate_with_extras

        result = integrate_with_extras(th, torques, h, n_sub, true_start, pos, neg, extras)
    else:
        result = _integrate(th, torques, h, n_sub, true_start, pos, neg)
    if offset == (0.0, 0.0):
        return result
    return dataclasses.replace(result, q=result.q + np.asarray(offset))  # reported angles


# ---- validation ---------------------------------------------------------------------------


def _theta(theta: ArrayLike) -> np.ndarray:
    th = np.asarray(theta, dtype=float)
    if th.shape != (N_PARAMS,):
        raise ValueError(f"theta must hold {N_PARAMS} numbers, got shape {th.shape}")
    if not np.all(np.isfinite(th)):
        raise ValueError("theta holds a non-finite number")
    t1, t2, t3 = th[:3]
    # M(q) > 0 for all q2 iff θ3 > 0 and det = θ1θ3 − θ3² − θ2² cos² q2 > 0 at cos² q2 = 1
    if not (t3 > 0 and t1 * t3 - t3**2 - t2**2 > 0):
        raise ValueError(
            f"theta gives a mass matrix M(q) that is not positive definite "
            f"(theta1..3 = {t1:.4g}, {t2:.4g}, {t3:.4g}); cannot simulate"
        )
    return th


def _torques(tau: ArrayLike) -> np.ndarray:
    arr = np.asarray(tau, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"tau must have shape (N, 2), got {arr.shape}")
    if arr.shape[0] == 0:
        raise ValueError("tau has no rows")
    bad = ~np.all(np.isfinite(arr), axis=1)
    if bad.any():
        raise ValueError(f"tau holds a non-finite value at row {int(np.argmax(bad))}")
    return arr


def _positive(name: str, value: float) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not (math.isfinite(x) and x > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return x


def _number(name: str, value: float) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return x


def _steps(value: int) -> int:
    try:
        n = operator.index(value)
    except TypeError:
        raise ValueError(f"steps_per_period must be an integer, got {value!r}") from None
    if n < 1:
        raise ValueError(f"steps_per_period must be >= 1, got {n}")
    return n


def _pair(name: str, value: Sequence[float]) -> tuple[float, float]:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be 2 numbers, got {value!r}") from None
    if arr.shape != (2,):
        raise ValueError(f"{name} must be 2 numbers, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} holds a non-finite number: {value!r}")
    return float(arr[0]), float(arr[1])


def _non_negative(name: str, levels: tuple[float, float]) -> None:
    if levels[0] < 0 or levels[1] < 0:
        raise ValueError(f"{name} must be >= 0 (a friction band), got {levels}")


# ---- dynamics -----------------------------------------------------------------------------


def _accelerations(
    theta: np.ndarray, stuck1: bool, stuck2: bool, level1: float, level2: float
) -> Callable[[float, float, float, float, float, float], tuple[float, float]]:
    """q̈ = M⁻¹(τ − C q̇ − g − f) in one stick mode (Section 5), with a stuck joint's q̈_i = 0.

    ``level_i`` is the signed Coulomb term of a sliding joint, frozen over the sub-step.
    """
    t1, t2, t3, t4, t5, b1, b2 = (float(x) for x in theta[:7])
    sin, cos = math.sin, math.cos

    if not stuck1 and not stuck2:

        def both_sliding(q1, q2, v1, v2, tau1, tau2):
            s2, c2 = sin(q2), cos(q2)
            g12 = t5 * sin(q1 + q2)
            k = t2 * s2
            # e = τ − C(q, q̇) q̇ − g(q) − f(q̇)
            e1 = tau1 + k * (2.0 * v1 * v2 + v2 * v2) - t4 * sin(q1) - g12 - b1 * v1 - level1
            e2 = tau2 - k * v1 * v1 - g12 - b2 * v2 - level2
            m11 = t1 + 2.0 * t2 * c2
            m12 = t3 + t2 * c2
            det = m11 * t3 - m12 * m12
            return (t3 * e1 - m12 * e2) / det, (m11 * e2 - m12 * e1) / det

        return both_sliding

    if stuck1 and not stuck2:

        def joint2_sliding(q1, q2, v1, v2, tau1, tau2):
            # q̇1 = q̈1 = 0: row 2 of M q̈ = e alone, m22 = θ3
            e2 = tau2 - t2 * sin(q2) * v1 * v1 - t5 * sin(q1 + q2) - b2 * v2 - level2
            return 0.0, e2 / t3

        return joint2_sliding

    if stuck2 and not stuck1:

        def joint1_sliding(q1, q2, v1, v2, tau1, tau2):
            # q̇2 = q̈2 = 0: row 1 of M q̈ = e alone
            e1 = (
                tau1
                + t2 * sin(q2) * (2.0 * v1 * v2 + v2 * v2)
                - t4 * sin(q1)
                - t5 * sin(q1 + q2)
                - b1 * v1
                - level1
            )
            return e1 / (t1 + 2.0 * t2 * cos(q2)), 0.0

        return joint1_sliding

    def both_stuck(q1, q2, v1, v2, tau1, tau2):
        return 0.0, 0.0

    return both_stuck


def _rk4(acc: Callable[[float, float, float, float, float, float], tuple[float, float]]) -> Step:
    """Classical fourth-order Runge–Kutta on (q, q̇) with τ held, step length given per call."""

    def step(q1, q2, v1, v2, tau1, tau2, dt):
        h2 = 0.5 * dt
        a1, a2 = acc(q1, q2, v1, v2, tau1, tau2)
        u1, u2 = v1 + h2 * a1, v2 + h2 * a2
        b1, b2 = acc(q1 + h2 * v1, q2 + h2 * v2, u1, u2, tau1, tau2)
        w1, w2 = v1 + h2 * b1, v2 + h2 * b2
        c1, c2 = acc(q1 + h2 * u1, q2 + h2 * u2, w1, w2, tau1, tau2)
        z1, z2 = v1 + dt * c1, v2 + dt * c2
        d1, d2 = acc(q1 + dt * w1, q2 + dt * w2, z1, z2, tau1, tau2)
        k = dt / 6.0
        return (
            q1 + k * (v1 + 2.0 * (u1 + w1) + z1),
            q2 + k * (v2 + 2.0 * (u2 + w2) + z2),
            v1 + k * (a1 + 2.0 * (b1 + c1) + d1),
            v2 + k * (a2 + 2.0 * (b2 + c2) + d2),
        )

    return step


def _holding_torques(
    theta: np.ndarray,
    state: State,
    tau: tuple[float, float],
    stuck: tuple[bool, bool],
    levels: tuple[float, float],
) -> tuple[float, float]:
    """Friction torque each stuck joint needs to stay at rest (q̈_i = 0), from M q̈ = τ − Cq̇ − g − f.

    Both stuck: f = τ − g. Joint i stuck, j sliding with friction f_j = b_j q̇_j + level_j:
    f_i = r_i − m_ij (r_j − f_j) / m_jj, with r = τ − C(q, q̇) q̇ − g(q).
    """
    t1, t2, t3, t4, t5, b1, b2 = (float(x) for x in theta[:7])
    q1, q2, v1, v2 = state
    k = t2 * math.sin(q2)
    g12 = t5 * math.sin(q1 + q2)
    r1 = tau[0] + k * (2.0 * v1 * v2 + v2 * v2) - t4 * math.sin(q1) - g12
    r2 = tau[1] - k * v1 * v1 - g12
    if stuck[0] and stuck[1]:
        return r1, r2
    m12 = t3 + t2 * math.cos(q2)
    if stuck[0]:
        return r1 - m12 * (r2 - b2 * v2 - levels[1]) / t3, 0.0
    m11 = t1 + 2.0 * t2 * math.cos(q2)
    return 0.0, r2 - m12 * (r1 - b1 * v1 - levels[0]) / m11


def _locate_zero(
    step: Step, start: State, tau: tuple[float, float], joint: int, dt: float, v_end: float
) -> tuple[float, State]:
    """Time s in [0, dt] at which ``joint``'s velocity reaches zero, and the state there.

    The RK4 flow map from ``start`` over s is the function; its root is bracketed by
    v(0) and v(dt) = ``v_end`` of opposite signs. Linear interpolation first, then Illinois
    regula falsi to |q̇_i| < ZERO_VELOCITY_TOL.
    """
    lo, f_lo = 0.0, start[2 + joint]
    hi, f_hi = dt, v_end
    if f_lo == 0.0:
        # The joint broke away at the start of the step: it first moves in its break-away
        # direction (the constrained dynamics guarantee it), then reverses. The zero at s = 0 is
        # not the crossing; find an instant at which it still moves, to bracket the later zero.
        s = dt
        for _ in range(60):
            s *= 0.5
            state = step(*start, tau[0], tau[1], s)
            if state[2 + joint] * f_hi < 0.0:
                lo, f_lo = s, state[2 + joint]
                break
        else:
            return 0.0, start  # numerically no motion at all: it sticks at once
    s, state = dt, start
    last = 0
    for _ in range(40):
        s = lo + (hi - lo) * f_lo / (f_lo - f_hi)
        state = step(*start, tau[0], tau[1], s)
        v = state[2 + joint]
        if abs(v) < ZERO_VELOCITY_TOL or hi - lo < 1e-15 * dt:
            break
        if (v > 0) == (f_lo > 0):  # not yet at zero
            lo, f_lo = s, v
            if last == 1:
                f_hi *= 0.5
            last = 1
        else:
            hi, f_hi = s, v
            if last == -1:
                f_lo *= 0.5
            last = -1
    return s, state


def _integrate(
    theta: np.ndarray,
    torques: np.ndarray,
    h: float,
    n_sub: int,
    start: State,
    pos: tuple[float, float],
    neg: tuple[float, float],
) -> OpenLoopResult:
    n_rows = torques.shape[0]
    dt_sub = h / n_sub
    sticky = (max(pos[0], neg[0]) > 0.0, max(pos[1], neg[1]) > 0.0)
    q1, q2, v1, v2 = start
    stuck = [sticky[0] and v1 == 0.0, sticky[1] and v2 == 0.0]
    direction = [1.0 if v1 >= 0.0 else -1.0, 1.0 if v2 >= 0.0 else -1.0]
    stick_events = [0, 0]
    breakaways = [0, 0]
    substeps = 0
    steps: dict[tuple[bool, bool, float, float], Step] = {}

    def levels() -> tuple[float, float]:
        """Signed Coulomb terms of the joints in their current sliding directions."""
        return (
            pos[0] if direction[0] > 0 else -neg[0],
            pos[1] if direction[1] > 0 else -neg[1],
        )

    def mode_step() -> Step:
        key = (stuck[0], stuck[1], *levels())
        step = steps.get(key)
        if step is None:
            step = steps[key] = _rk4(_accelerations(theta, *key))
        return step

    def release(state: State, tau: tuple[float, float]) -> bool:
        """Let stuck joints whose holding torque leaves the band break away; True if any did."""
        changed = False
        for _ in range(2):  # releasing one joint changes the other's holding torque
            held = _holding_torques(theta, state, tau, (stuck[0], stuck[1]), levels())
            worst, worst_ratio = -1, 1.0
            for i in (0, 1):
                if not stuck[i]:
                    continue
                band = pos[i] if held[i] > 0 else neg[i]
                ratio = abs(held[i]) / band if band > 0 else (math.inf if held[i] else 0.0)
                if ratio > worst_ratio:
                    worst, worst_ratio = i, ratio
            if worst < 0:
                break
            stuck[worst] = False
            direction[worst] = 1.0 if held[worst] > 0 else -1.0
            breakaways[worst] += 1
            changed = True
            if not (stuck[0] or stuck[1]):
                break
        return changed

    q_out = [(q1, q2)] * n_rows
    dq_out = [(v1, v2)] * n_rows
    stuck_out = [(stuck[0], stuck[1])] * n_rows
    step = mode_step()
    for k, (tau1, tau2) in enumerate(torques.tolist()):
        q_out[k] = (q1, q2)
        dq_out[k] = (v1, v2)
        stuck_out[k] = (stuck[0], stuck[1])
        if k == n_rows - 1:
            break  # the last torque acts after the last sample
        tau = (tau1, tau2)
        for _ in range(n_sub):
            substeps += 1
            remaining = dt_sub
            for _event in range(MAX_EVENTS_PER_SUBSTEP):
                if (stuck[0] or stuck[1]) and release((q1, q2, v1, v2), tau):
                    step = mode_step()
                n1, n2, w1, w2 = step(q1, q2, v1, v2, tau1, tau2, remaining)
                # a sliding, sticky joint whose velocity changed sign crossed zero in the step
                cross1 = sticky[0] and not stuck[0] and w1 * direction[0] < 0.0
                cross2 = sticky[1] and not stuck[1] and w2 * direction[1] < 0.0
                if not (cross1 or cross2):
                    q1, q2, v1, v2 = n1, n2, w1, w2
                    break
                if cross1 and cross2:  # the earlier one by linear interpolation
                    joint = 0 if v1 / (v1 - w1) <= v2 / (v2 - w2) else 1
                else:
                    joint = 0 if cross1 else 1
                s, state = _locate_zero(
                    step, (q1, q2, v1, v2), tau, joint, remaining, (w1, w2)[joint]
                )
                other = 1 - joint
                if cross1 and cross2 and state[2 + other] * direction[other] < 0.0:
                    joint, other = other, joint  # the other joint crossed first after all
                    s, state = _locate_zero(step, (q1, q2, v1, v2), tau, joint, s, state[2 + joint])
                q1, q2, v1, v2 = state
                if joint == 0:
                    v1 = 0.0
                else:
                    v2 = 0.0
                stuck[joint] = True
                stick_events[joint] += 1
                step = mode_step()
                remaining -= s
                if remaining <= 1e-15 * dt_sub:
                    break
            else:
                # Chattering (stick, break away, reverse, ... in one sub-step): finish the
                # sub-step in the current mode, and stop any joint that reversed meanwhile.
                q1, q2, v1, v2 = step(q1, q2, v1, v2, tau1, tau2, remaining)
                if sticky[0] and not stuck[0] and v1 * direction[0] < 0.0:
                    v1, stuck[0] = 0.0, True
                    stick_events[0] += 1
                if sticky[1] and not stuck[1] and v2 * direction[1] < 0.0:
                    v2, stuck[1] = 0.0, True
                    stick_events[1] += 1
                step = mode_step()
    return OpenLoopResult(
        t=np.arange(n_rows) * h,
        q=np.array(q_out, dtype=float),
        dq=np.array(dq_out, dtype=float),
        stuck=np.array(stuck_out, dtype=bool),
        stick_events=np.array(stick_events),
        breakaways=np.array(breakaways),
        substeps=substeps,
    )


# ---- short-window simulation of any model object (real recordings) -------------------------


def simulate_windows(
    model: object,
    theta: ArrayLike,
    t: ArrayLike,
    q: ArrayLike,
    tau: ArrayLike,
    *,
    window_s: float,
    steps_per_interval: int = 2,
) -> dict[str, object]:
    """Open-loop simulation restarted on consecutive windows of ``window_s`` seconds.

    A closed-loop recording (a PD-tracked trajectory, a swing-up) cannot be simulated open loop
    end to end: the recorded torques were computed from the recorded states, and any model error
    grows without the feedback that kept the real arm on track (a swing-up diverges by nature).
    So, like the diagnosis, each window starts from the recorded state (q, and q̇ by the
    three-point derivative on the real time stamps) and is driven by the recorded torques held
    over each real interval (RK4, ``steps_per_interval`` sub-steps; Coulomb friction as θ sgn q̇,
    no stiction). ``model``: an :class:`hil.model.closed_form.ArmModel` (any object with its
    ``forward_dynamics``). All windows are integrated at once (vectorised over windows).

    Returns ``position_nrmse`` (per joint, over every simulated sample against the recorded q,
    scaled by the recorded q's spread within windows), ``windows`` and ``window_s``; windows whose
    simulation leaves the finite numbers count as diverged (``diverged``)."""
    from hil.model.metrics import nrmse
    from hil.model.regressors import central_difference_unequal

    th = np.asarray(theta, dtype=float)
    t = np.asarray(t, dtype=float)
    q = np.asarray(q, dtype=float)
    tau = np.asarray(tau, dtype=float)
    if not window_s > 0:
        raise ValueError(f"window_s must be > 0, got {window_s}")
    h = float(np.median(np.diff(t)))
    L = max(2, round(window_s / h))
    v = central_difference_unequal(q, t)
    starts = np.arange(1, len(q) - L - 1, L)
    if len(starts) == 0:
        raise ValueError(f"recording shorter than one window of {window_s} s")
    x_q = q[starts].copy()
    x_v = v[starts].copy()
    sim = np.empty((len(starts), L + 1, 2))
    sim[:, 0] = x_q
    ok = np.ones(len(starts), bool)

    def acc(qq, vv, uu):
        with np.errstate(all="ignore"):
            return model.forward_dynamics(th, qq, vv, uu)

    # a window whose state leaves this range (rad, rad/s) has diverged; it is counted and its
    # state reset to the recording so the arrays stay finite
    limit = 1e3
    for j in range(L):
        k = starts + j
        dt = (t[k + 1] - t[k])[:, None] / steps_per_interval
        u = tau[k]
        with np.errstate(all="ignore"):
            for _ in range(steps_per_interval):
                a1 = acc(x_q, x_v, u)
                a2 = acc(x_q + 0.5 * dt * x_v, x_v + 0.5 * dt * a1, u)
                a3 = acc(x_q + 0.5 * dt * (x_v + 0.5 * dt * a1), x_v + 0.5 * dt * a2, u)
                a4 = acc(x_q + dt * (x_v + 0.5 * dt * a2), x_v + dt * a3, u)
                x_q = x_q + dt * x_v + dt**2 / 6 * (a1 + a2 + a3)
                x_v = x_v + dt / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
                bad = ~(np.abs(x_q) < limit).all(axis=1) | ~(np.abs(x_v) < limit).all(axis=1)
                ok &= ~bad
                x_q[bad], x_v[bad] = q[k[bad] + 1], 0.0
        sim[:, j + 1] = x_q
    idx = starts[:, None] + np.arange(L + 1)[None, :]
    rec = q[idx]
    # error per window relative to each window's own start, so the spread measures motion
    # within windows, not the recording's overall excursion
    ref = (rec - rec[:, :1])[ok].reshape(-1, 2)
    est = (sim - rec[:, :1])[ok].reshape(-1, 2)
    return {
        "position_nrmse": [float(x) for x in nrmse(ref, est)] if ok.any() else [np.nan] * 2,
        "windows": len(starts),
        "diverged": int(np.sum(~ok)),
        "window_s": float(L * h),
    }


__all__ = [
    "OpenLoopExtras",
    "OpenLoopResult",
    "simulate_open_loop",
    "simulate_windows",
]
