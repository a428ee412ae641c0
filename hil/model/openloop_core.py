"""The host simulator's one stick–slip integrator, used with and without the diagnosis's effects.

What lives here: :func:`integrate` (RK4 sub-steps of the closed-form model of Reyes & Kelly
(1997), Section 5, with Karnopp-style stick–slip and located stick events; the scheme is described
in :mod:`hil.model.openloop`), the three things it is parametrised by, and the result type:

* :class:`TorquePath`: recorded commands → torque at the shaft. This class is the identity (each
  row acts unchanged over its own period); :mod:`hil.model.openloop_effects` adds a transport
  delay, an actuator lag, gain and offset.
* :class:`Friction`: Coulomb friction by direction; the effects module adds Stribeck friction.
* ``shaft_torque``: a position-dependent torque added at the shaft (cogging), or None.

With the identity path, plain Coulomb friction and no shaft torque this is the rigid model of
:func:`hil.model.openloop.simulate_open_loop`; every effect enters through these three, so the
stick–slip and event logic exists once. Also the input checks both modules share.

Imports: numpy and :mod:`hil.model.compiled_openloop` (the compiled sub-steps of the rows on
which a 2-DOF stick mode holds, the same bits as the Python ones);
:mod:`hil.model.openloop_effects` and :mod:`hil.model.openloop` build on this module.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from hil.model.compiled_openloop import Slider, compiled

# Stick events that may occur within one sub-step; after that many (a degenerate, chattering
# case: it happens with an actuator lag) the joints stay as they are for the rest of the sub-step,
# as the virtual robot's plant does (end of virtual_robot.stick_slip.step).
MAX_EVENTS_PER_SUBSTEP = 8
# A located velocity zero is accepted when |q̇_i| is below this (rad/s).
ZERO_VELOCITY_TOL = 1e-12
# A state that leaves this range (rad, rad/s) has diverged: its rows are NaN from there on
DIVERGED = 1e3

Pair = tuple[float, float]
# q1..qn, q̇1..q̇n (2-DOF: q1, q2, q̇1, q̇2)
State = tuple[float, ...]
Step = Callable[[State, Sequence[float], float], State]  # (state, τ, dt) → state after dt
Flow = Callable[[State, float], State]  # (state, s): τ bound
Accelerations = Callable[[float, float, float, float, float, float], Pair]
ShaftTorque = Callable[[float, float], Pair]  # q1, q2 → torque added at the shaft (Nm)
# Sub-steps of a period as (length s, 0 = the command before its delayed arrival / 1 = after)
Segments = list[tuple[float, int]]


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


class TorquePath:
    """Recorded commands → the torque applied at the shaft (before any shaft torque): here the
    identity, row k's command acting unchanged over [kh, (k+1)h).

    A subclass with a delay returns other commands and cut sub-steps from :meth:`schedule`; one
    with an actuator lag sets ``lagged`` (the torque applied over a step depends on its length
    and on a state carried from step to step, :meth:`applied` and :meth:`settle`). Without
    ``lagged`` the applied torque is a function of the command alone: the integrator maps the
    scheduled commands through :meth:`applied` once and runs them as the identity path's.
    """

    identity = True  # applied torque = command: the integrator skips the calls below
    lagged = False
    row_local = True  # schedule(torques[a:b]) is rows a..b of schedule(torques): no look-back

    def schedule(self, torques: np.ndarray, h: float, n_sub: int) -> tuple[list, list, Segments]:
        """Per period k, the command before and after the arrival of its delayed row, and the
        period's sub-steps (the same for every period)."""
        rows = torques.tolist()
        return rows, rows, [(h / n_sub, 1)] * n_sub

    def applied(self, command: Sequence[float], dt: float) -> tuple[Pair, Pair]:
        """(mean torque applied over the next dt, the path's state at dt) under a held command."""
        return (command[0], command[1]), (command[0], command[1])

    def settle(self, state: Pair) -> None:
        """Move the path's state to ``state`` (as returned by :meth:`applied`) after a step."""


class Friction:
    """Coulomb friction by direction: a joint sliding in direction d = ±1 feels b q̇ + d F^d
    (F⁺ = ``positive``, F⁻ = ``negative``, Nm), and a stuck one stays stuck while the torque that
    holds it lies in its static band [−F⁻, F⁺]. A subclass with ``speed_dependent`` set gives
    the signed term by :meth:`sliding` at the joint's speed, and may widen the band."""

    speed_dependent = False

    def __init__(self, positive: Pair, negative: Pair) -> None:
        self.positive, self.negative = positive, negative
        self.static_positive, self.static_negative = positive, negative

    def level(self, joint: int, direction: float) -> float:
        """The signed Coulomb term d F^d of ``joint`` sliding in ``direction``."""
        return self.positive[joint] if direction > 0 else -self.negative[joint]

    def sliding(self, joint: int, direction: float, speed: float) -> float:
        """The signed friction term (beyond b q̇) of ``joint`` sliding at ``speed`` (rad/s)."""
        return self.level(joint, direction)


# ---- input checks (simulate_open_loop's arguments and OpenLoopExtras' fields) -----------------


def number(name: str, value: float) -> float:
    """``value`` as a finite float, or ValueError (one line) naming ``name``."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return x


def pair(name: str, value: Sequence[float]) -> Pair:
    """``value`` as two finite floats (joint 1, joint 2), or ValueError (one line)."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be 2 numbers, got {value!r}") from None
    if arr.shape != (2,):
        raise ValueError(f"{name} must be 2 numbers, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} holds a non-finite number: {value!r}")
    return float(arr[0]), float(arr[1])


# ---- dynamics -----------------------------------------------------------------------------


def _rigid(theta: np.ndarray) -> tuple[float, ...]:
    """θ1..θ5, b1, b2 and the model terms' (θ_rotor, θ2⊥, θ4⊥, θ5⊥) of a 9-parameter θ or of
    one in the parametrisation of ``ArmModel(TERMS)`` (hil.model.closed_form; zero when absent)."""
    extra = (float(x) for x in theta[9:13]) if len(theta) > 9 else (0.0, 0.0, 0.0, 0.0)
    return (*(float(x) for x in theta[:7]), *extra)


def _accelerations(
    theta: np.ndarray,
    stuck1: bool,
    stuck2: bool,
    d1: float,
    d2: float,
    friction: Friction,
    shaft_torque: ShaftTorque | None,
) -> Accelerations:
    """q̈ = M⁻¹(τ + τ_shaft − C q̇ − g − f) in one stick mode (Section 5), a stuck joint's q̈_i = 0.

    f_i = b_i q̇_i + the friction term of joint i sliding in direction d_i, frozen over the
    sub-step (a constant unless ``friction`` is speed dependent). With the model terms
    (hil.model.closed_form, "the model object"): M22 = θ3 + θ_rotor; the centre-of-mass offset
    adds −θ2⊥ sin q2 (2, 1) to M11, M12, θ2⊥ cos q2 to the Coriolis factor θ2 sin q2, and
    θ4⊥ cos q1 + θ5⊥ cos(q1 + q2), θ5⊥ cos(q1 + q2) to g (zero terms change nothing, bit for
    bit).
    """
    t1, t2, t3, t4, t5, b1, b2, rot, p2, p4, p5 = _rigid(theta)
    m22 = t3 + rot
    perp = p2 != 0.0 or p4 != 0.0 or p5 != 0.0
    sin, cos = math.sin, math.cos
    level1, level2 = friction.level(0, d1), friction.level(1, d2)
    sliding = friction.sliding if friction.speed_dependent else None

    if not stuck1 and not stuck2:

        def acc(q1, q2, v1, v2, tau1, tau2):
            s2, c2 = sin(q2), cos(q2)
            g1, g12 = t4 * sin(q1), t5 * sin(q1 + q2)
            k = t2 * s2
            m11 = t1 + 2.0 * t2 * c2
            m12 = t3 + t2 * c2
            if perp:
                c12 = cos(q1 + q2)
                g1, g12, k = g1 + p4 * cos(q1), g12 + p5 * c12, k + p2 * c2
                m11, m12 = m11 - 2.0 * p2 * s2, m12 - p2 * s2
            # e = τ − C(q, q̇) q̇ − g(q) − f(q̇)
            e1 = tau1 + k * (2.0 * v1 * v2 + v2 * v2) - g1 - g12 - b1 * v1
            e1 -= level1 if sliding is None else sliding(0, d1, abs(v1))
            e2 = tau2 - k * v1 * v1 - g12 - b2 * v2
            e2 -= level2 if sliding is None else sliding(1, d2, abs(v2))
            det = m11 * m22 - m12 * m12
            return (m22 * e1 - m12 * e2) / det, (m11 * e2 - m12 * e1) / det

    elif stuck1 and not stuck2:

        def acc(q1, q2, v1, v2, tau1, tau2):
            # q̇1 = q̈1 = 0: row 2 of M q̈ = e alone
            k, g12 = t2 * sin(q2), t5 * sin(q1 + q2)
            if perp:
                k, g12 = k + p2 * cos(q2), g12 + p5 * cos(q1 + q2)
            e2 = tau2 - k * v1 * v1 - g12 - b2 * v2
            e2 -= level2 if sliding is None else sliding(1, d2, abs(v2))
            return 0.0, e2 / m22

    elif stuck2 and not stuck1:

        def acc(q1, q2, v1, v2, tau1, tau2):
            # q̇2 = q̈2 = 0: row 1 of M q̈ = e alone
            s2, c2 = sin(q2), cos(q2)
            k, g1, g12, m11 = t2 * s2, t4 * sin(q1), t5 * sin(q1 + q2), t1 + 2.0 * t2 * c2
            if perp:
                k, g1 = k + p2 * c2, g1 + p4 * cos(q1)
                g12, m11 = g12 + p5 * cos(q1 + q2), m11 - 2.0 * p2 * s2
            e1 = tau1 + k * (2.0 * v1 * v2 + v2 * v2) - g1 - g12 - b1 * v1
            e1 -= level1 if sliding is None else sliding(0, d1, abs(v1))
            return e1 / m11, 0.0

    else:

        def acc(q1, q2, v1, v2, tau1, tau2):
            return 0.0, 0.0

    if shaft_torque is None:
        return acc
    rigid = acc

    def acc_with_shaft_torque(q1, q2, v1, v2, tau1, tau2):
        c1, c2 = shaft_torque(q1, q2)
        return rigid(q1, q2, v1, v2, tau1 + c1, tau2 + c2)

    return acc_with_shaft_torque


def _rk4(acc: Accelerations) -> Step:
    """Classical fourth-order Runge–Kutta on (q, q̇) with τ held, step length given per call."""

    def step(state, tau, dt):
        q1, q2, v1, v2 = state
        tau1, tau2 = tau
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
    tau: Pair,
    stuck: Sequence[bool],
    direction: Sequence[float],
    friction: Friction,
    shaft_torque: ShaftTorque | None,
) -> Pair:
    """Friction torque each stuck joint needs to stay at rest (q̈_i = 0), from M q̈ = τ − Cq̇ − g − f.

    Both stuck: f = τ − g. Joint i stuck, j sliding with friction f_j (b_j q̇_j + its term):
    f_i = r_i − m_ij (r_j − f_j) / m_jj, with r = τ + τ_shaft − C(q, q̇) q̇ − g(q) (M, C, g with
    the model terms as in :func:`_accelerations`).
    """
    t1, t2, t3, t4, t5, b1, b2, rot, p2, p4, p5 = _rigid(theta)
    q1, q2, v1, v2 = state
    tau1, tau2 = tau
    if shaft_torque is not None:
        c1, c2 = shaft_torque(q1, q2)
        tau1, tau2 = tau1 + c1, tau2 + c2
    s2, c2 = math.sin(q2), math.cos(q2)
    k = t2 * s2
    g1, g12 = t4 * math.sin(q1), t5 * math.sin(q1 + q2)
    m11, m12 = t1 + 2.0 * t2 * c2, t3 + t2 * c2
    if p2 != 0.0 or p4 != 0.0 or p5 != 0.0:
        k, g1, g12 = k + p2 * c2, g1 + p4 * math.cos(q1), g12 + p5 * math.cos(q1 + q2)
        m11, m12 = m11 - 2.0 * p2 * s2, m12 - p2 * s2
    r1 = tau1 + k * (2.0 * v1 * v2 + v2 * v2) - g1 - g12
    r2 = tau2 - k * v1 * v1 - g12
    if stuck[0] and stuck[1]:
        return r1, r2
    if stuck[0]:
        f2 = b2 * v2 + friction.sliding(1, direction[1], abs(v2))
        return r1 - m12 * (r2 - f2) / (t3 + rot), 0.0
    f1 = b1 * v1 + friction.sliding(0, direction[0], abs(v1))
    return 0.0, r2 - m12 * (r1 - f1) / m11


def _locate_zero(
    flow: Flow, start: State, joint: int, dt: float, v_end: float, direction: float
) -> tuple[float, State]:
    """Time s in [0, dt] at which ``joint``'s velocity reaches zero, and the state there.

    The RK4 flow map from ``start`` over s is the function; its root is bracketed by
    v(0) and v(dt) = ``v_end`` of opposite signs. Linear interpolation first, then Illinois
    regula falsi to |q̇_i| < ZERO_VELOCITY_TOL. A joint that already moves against its slip
    ``direction`` at the start (it broke away on a lagged torque's mean over the step, but the
    torque of the step's first instants pushes it back) sticks at once, s = 0, as in the
    plant's stick search (virtual_robot.stick_slip.locate_stick).
    """
    v = len(start) // 2 + joint  # the joint's velocity in the state
    if start[v] * direction < 0.0:
        return 0.0, start
    lo, f_lo = 0.0, start[v]
    hi, f_hi = dt, v_end
    if f_lo == 0.0:
        # The joint broke away at the start of the step: it first moves in its break-away
        # direction (the constrained dynamics guarantee it), then reverses. The zero at s = 0 is
        # not the crossing; find an instant at which it still moves, to bracket the later zero.
        s = dt
        for _ in range(60):
            s *= 0.5
            state = flow(start, s)
            if state[v] * f_hi < 0.0:
                lo, f_lo = s, state[v]
                break
        else:
            return 0.0, start  # numerically no motion at all: it sticks at once
    s, state = dt, start
    last = 0
    for _ in range(40):
        s = lo + (hi - lo) * f_lo / (f_lo - f_hi)
        state = flow(start, s)
        w = state[v]
        if abs(w) < ZERO_VELOCITY_TOL or hi - lo < 1e-15 * dt:
            break
        if (w > 0) == (f_lo > 0):  # not yet at zero
            lo, f_lo = s, w
            if last == 1:
                f_hi *= 0.5
            last = 1
        else:
            hi, f_hi = s, w
            if last == -1:
                f_lo *= 0.5
            last = -1
    return s, state


def _flow(step: Step, path: TorquePath, command: Sequence[float], tau: Sequence[float]) -> Flow:
    """The RK4 flow over s from a state: under ``tau`` held, or under the lagged path's mean
    torque over s (a lag makes the torque depend on how far the step goes)."""
    if path.lagged:

        def lagged(state, s):
            return step(state, path.applied(command, s)[0], s)

        return lagged

    def held(state, s):
        return step(state, tau, s)

    return held


# ---- the integrator -----------------------------------------------------------------------


# Rows simulated between two yields of :func:`integrate_chunks`: bounds the per-row Python
# objects (the rows' commands, the states) a long recording would otherwise hold (issue 13).
SIMULATION_CHUNK = 1 << 16


class StickSlipArm(Protocol):
    """What :func:`integrate_arm` needs of an arm model, for any number of joints n: the RK4
    step of each stick mode and the holding torques of the stuck joints, on states
    (q1..qn, q̇1..q̇n) and torques of n joints. :class:`ClosedFormArm` is the 2-DOF closed form
    of Reyes & Kelly (1997), Section 5; ``hil.model.openloop.ModelArm`` any model object with
    regressors (an n-joint URDF model)."""

    n_joints: int
    friction: Friction  # Coulomb levels and static bands by direction, per joint

    def mode_step(self, stuck: tuple[bool, ...], direction: tuple[float, ...]) -> Step:
        """RK4 under τ held in one stick mode: q̈ = M⁻¹(τ − C q̇ − g − f) with the sliding
        joints' friction directions frozen and the stuck joints' q̈_i = 0."""
        ...

    def holding_torques(
        self,
        state: State,
        tau: Sequence[float],
        stuck: Sequence[bool],
        direction: Sequence[float],
    ) -> Sequence[float]:
        """The friction torque each stuck joint needs to stay at rest (q̈_S = 0), from the
        constrained dynamics (zero for the sliding joints)."""
        ...


class ClosedFormArm:
    """The 2-DOF closed-form model θ (:mod:`hil.model.closed_form`) as a :class:`StickSlipArm`,
    with ``friction`` and an optional position-dependent ``shaft_torque`` (cogging)."""

    n_joints = 2

    def __init__(
        self, theta: np.ndarray, friction: Friction, shaft_torque: ShaftTorque | None = None
    ) -> None:
        self.theta, self.friction, self.shaft_torque = theta, friction, shaft_torque

    def mode_step(self, stuck: tuple[bool, ...], direction: tuple[float, ...]) -> Step:
        return _rk4(
            _accelerations(self.theta, *stuck, *direction, self.friction, self.shaft_torque)  # type: ignore[misc]
        )

    def holding_torques(
        self,
        state: State,
        tau: Sequence[float],
        stuck: Sequence[bool],
        direction: Sequence[float],
    ) -> Pair:
        return _holding_torques(
            self.theta, state, (tau[0], tau[1]), stuck, direction, self.friction,
            self.shaft_torque,
        )  # fmt: skip


def integrate(
    theta: np.ndarray,
    torques: np.ndarray,
    h: float,
    n_sub: int,
    start: State,
    friction: Friction,
    path: TorquePath | None = None,
    shaft_torque: ShaftTorque | None = None,
    intervals: np.ndarray | None = None,
) -> OpenLoopResult:
    """Simulate the 2-DOF closed-form θ (checked by the caller) from the true state ``start``
    under ``torques`` (N, 2) through ``path`` (None: the identity), ``n_sub`` RK4 sub-steps per
    period h (more where a delayed command arrives inside one), with stick–slip ``friction`` and
    ``shaft_torque``: :func:`integrate_arm` of :class:`ClosedFormArm`.
    """
    arm = ClosedFormArm(theta, friction, shaft_torque)
    return integrate_arm(arm, torques, h, n_sub, start, path, intervals)


def integrate_arm(
    arm: StickSlipArm,
    torques: np.ndarray,
    h: float,
    n_sub: int,
    start: State,
    path: TorquePath | None = None,
    intervals: np.ndarray | None = None,
) -> OpenLoopResult:
    """Simulate ``arm`` (any number of joints) from the true state ``start`` under ``torques``
    (N, n): the pieces of :func:`integrate_chunks`, joined."""
    parts = list(integrate_chunks(arm, torques, h, n_sub, start, path, intervals=intervals))
    last = parts[-1]
    return OpenLoopResult(
        *(np.concatenate([getattr(c, f) for c in parts]) for f in ("t", "q", "dq", "stuck")),
        stick_events=last.stick_events,
        breakaways=last.breakaways,
        substeps=last.substeps,
    )


def integrate_chunks(
    arm: StickSlipArm,
    torques: np.ndarray,
    h: float,
    n_sub: int,
    start: State,
    path: TorquePath | None = None,
    *,
    intervals: np.ndarray | None = None,
    chunk: int = SIMULATION_CHUNK,
):
    """:func:`integrate_arm`, yielding its rows ``chunk`` at a time as :class:`OpenLoopResult`
    pieces (``t``, ``q``, ``dq``, ``stuck`` of those rows; the counters so far), so a long
    recording's simulation needs memory for one chunk, not for every row (issue 13).

    The scheme (:mod:`hil.model.openloop`'s docstring), for n joints: at each sub-step boundary
    stuck joints whose holding torque leaves the static band break away (the worst first, then
    the others' holding torques again); a sliding joint's direction is frozen over a sub-step; a
    velocity sign change inside it is located on the RK4 flow map (the earliest by linear
    interpolation when several joints cross), the joint sticks there and the rest of the sub-step
    is integrated in the new mode.

    ``intervals`` (N − 1 durations, s): period k lasts intervals[k] instead of h (a recording's
    real sample times); its sub-steps are stretched by intervals[k]/h, so a delay's arrival
    keeps its place as a fraction of the period (exact for the identity path and the lag).
    """
    path = TorquePath() if path is None else path
    # a path without a lag applies a torque that depends on the command alone (a gain, an
    # offset, a delayed row): mapped once per row below, then integrated as the identity path's
    # commands (the sub-steps without events take the fast branch; the same numbers)
    mapped = not path.identity and not path.lagged
    stretch = None if intervals is None else np.asarray(intervals, float) / h
    # the rows' times: k·h, or the real sample times the intervals add up to
    times = None if intervals is None else np.concatenate([[0.0], np.cumsum(stretch * h)])
    identity = path.identity or mapped
    n_rows = torques.shape[0]
    n = arm.n_joints
    joints = range(n)
    friction = arm.friction
    pos, neg = friction.static_positive, friction.static_negative
    sticky = tuple(max(pos[i], neg[i]) > 0.0 for i in joints)
    watched = tuple(i for i in joints if sticky[i])  # joints that can stick
    state = tuple(float(x) for x in start)
    stuck = [sticky[i] and state[n + i] == 0.0 for i in joints]
    direction = [1.0 if state[n + i] >= 0.0 else -1.0 for i in joints]
    stick_events = [0] * n
    breakaways = [0] * n
    substeps = 0
    steps: dict[tuple[tuple[bool, ...], tuple[float, ...]], Step] = {}

    def mode_step() -> Step:
        key = (tuple(stuck), tuple(direction))
        step = steps.get(key)
        if step is None:
            step = steps[key] = arm.mode_step(*key)
        return step

    def release(state: State, tau: Sequence[float]) -> bool:
        """Let stuck joints whose holding torque leaves the static band break away; True if any
        did."""
        changed = False
        for _ in joints:  # releasing one joint changes the others' holding torques
            held = arm.holding_torques(state, tau, stuck, direction)
            worst, worst_ratio = -1, 1.0
            for i in joints:
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
            if not any(stuck):
                break
        return changed

    def applied(commands: list) -> list:
        return [path.applied(c, h)[0] for c in commands] if mapped else commands

    # a row-local path's commands are each period's own row: scheduled chunk by chunk
    whole = None if path.row_local else path.schedule(torques, h, n_sub)
    step = mode_step()
    # the rows on which the stick mode holds, compiled when it can be (the same bits; issue 13)
    fast = None
    plain = (
        type(arm) is ClosedFormArm
        and arm.shaft_torque is None
        and type(path) is TorquePath
        and type(friction) is Friction
    )
    if plain and compiled():
        fast = Slider(_rigid(arm.theta), torques, stretch, n_sub, h / n_sub, sticky, (*pos, *neg))
    lost = (math.nan,) * n
    diverged = False
    for first in range(0, n_rows, chunk):
        rows = min(chunk, n_rows - first)
        if whole is None:
            before, after, segments = path.schedule(torques[first : first + rows], h, n_sub)
        else:
            before, after = whole[0][first : first + rows], whole[1][first : first + rows]
            segments = whole[2]
        before, after = applied(before), applied(after)
        stuck_out = [tuple(stuck)] * rows
        if diverged:  # NaN from a divergence on: this chunk is not stepped
            q_out = dq_out = [lost] * rows
            k = rows
        else:
            q_out, dq_out, k = [state[:n]] * rows, [state[n:]] * rows, 0
        while k < rows:
            if fast is not None and first + k < n_rows - 1:
                levels = (friction.level(0, direction[0]), friction.level(1, direction[1]))
                mode = (stuck[0], stuck[1])
                span = min(rows, n_rows - 1 - first) - k  # the last row is never stepped
                done, state, q_fast, dq_fast = fast.run(
                    first + k, span, state, mode, levels, (direction[0], direction[1])
                )
                # rows k..k + done − 1 taken; in the one it stopped before the mode changes (a
                # break-away or a sign change) and the loop below takes it again with its events
                q_out[k : k + done] = q_fast.tolist()
                dq_out[k : k + done] = dq_fast.tolist()
                stuck_out[k : k + done] = [mode] * done
                substeps += done * n_sub
                k += done
                if k == rows:
                    break
            if not all(abs(x) < DIVERGED for x in state):  # NaN too
                diverged = True
                q_out[k:] = dq_out[k:] = [lost] * (rows - k)
                break
            q_out[k] = state[:n]
            dq_out[k] = state[n:]
            stuck_out[k] = tuple(stuck)
            if first + k == n_rows - 1:
                break  # the last torque acts after the last sample
            commands = (before[k], after[k])
            try:
                for dt_seg, which in segments:
                    command = commands[which]
                    tau = command  # the identity path's torque (others: over what remains)
                    substeps += 1
                    remaining = dt_seg if stretch is None else dt_seg * float(stretch[first + k])
                    if identity and not any(stuck):
                        # the common sub-step, every joint sliding under the held command: one RK4
                        # step and the sign test below without the event loop's set-up (most of a
                        # long recording's validation; issue 13). A sign change falls through to the
                        # loop, which takes the same step again and locates the event.
                        new = step(state, tau, remaining)
                        for i in watched:
                            if new[n + i] * direction[i] < 0.0:
                                break
                        else:
                            state = new
                            continue
                    for _event in range(MAX_EVENTS_PER_SUBSTEP):
                        if not identity:
                            tau, path_end = path.applied(command, remaining)
                        if any(stuck) and release(state, tau):
                            step = mode_step()
                        new = step(state, tau, remaining)
                        # the sliding, sticky joints whose velocity changed sign crossed zero
                        crossed = [
                            i for i in watched if not stuck[i] and new[n + i] * direction[i] < 0.0
                        ]
                        if not crossed:
                            state = new
                            if not identity:
                                path.settle(path_end)
                            break
                        joint = crossed[0]
                        if len(crossed) > 1:  # the earliest by linear interpolation (first of ties)
                            joint = min(
                                crossed, key=lambda i: state[n + i] / (state[n + i] - new[n + i])
                            )
                        flow = _flow(step, path, command, tau)
                        here = state
                        s, state = _locate_zero(
                            flow, here, joint, remaining, new[n + joint], direction[joint]
                        )
                        earlier = [
                            i for i in crossed if i != joint and state[n + i] * direction[i] < 0.0
                        ]
                        if earlier:  # another joint crossed first after all
                            joint = earlier[0]
                            s, state = _locate_zero(
                                flow, here, joint, s, state[n + joint], direction[joint]
                            )
                        # (a zero-length lag step would jump to the command)
                        if s > 0.0 and not identity:
                            path.settle(path.applied(command, s)[1])
                        state = (*state[: n + joint], 0.0, *state[n + joint + 1 :])
                        stuck[joint] = True
                        stick_events[joint] += 1
                        step = mode_step()
                        remaining -= s
                        if remaining <= 1e-15 * dt_seg:
                            break
            except (ValueError, OverflowError, ZeroDivisionError):
                state = lost + lost  # sin(inf) or a singular M(q): diverged
            k += 1
        q_rows, dq_rows = np.array(q_out, dtype=float), np.array(dq_out, dtype=float)
        with np.errstate(invalid="ignore"):
            inside = (np.abs(q_rows) < DIVERGED).all(axis=1) & (np.abs(dq_rows) < DIVERGED).all(1)
        if not inside.all():  # rows the compiled sub-steps took past the range, and after
            q_rows[np.argmin(inside) :] = dq_rows[np.argmin(inside) :] = np.nan
            diverged = True
        yield OpenLoopResult(
            t=np.arange(first, first + rows) * h if times is None else times[first : first + rows],
            q=q_rows,
            dq=dq_rows,
            stuck=np.array(stuck_out, dtype=bool),
            stick_events=np.array(stick_events),
            breakaways=np.array(breakaways),
            substeps=substeps,
        )
