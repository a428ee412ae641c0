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
  in the new mode;
* after 8 stick events in one sub-step (chattering: a joint that breaks away on a lagged torque's
  mean over the sub-step and is pushed back at once) the joints stay as they are for the rest of
  it, as the world's plant does.

A joint with zero Coulomb friction in both directions never sticks (its dynamics are smooth).

Where it lives: this module is the entry (input checks, the angle offset, :class:`OpenLoopExtras`
re-exported) and :func:`simulate_windows`; the integrator is
:func:`hil.model.openloop_core.integrate`, one scheme for the rigid model and for the diagnosis's
effects, which :mod:`hil.model.openloop_effects` brings in as a torque path (delay, lag, gain,
offset), a friction law (Stribeck) and a shaft torque (cogging). The same scheme simulates an
n-joint model object (:class:`ModelArm`, :func:`simulate_segments`: the URDF models of
:mod:`hil.model.urdf`), through :func:`hil.model.openloop_core.integrate_arm`. Imports: numpy,
scipy's LAPACK, :mod:`hil.model.closed_form`, :mod:`hil.model.openloop_core`,
:mod:`hil.model.openloop_effects` (and, inside :func:`simulate_windows`,
:mod:`hil.model.metrics` and :mod:`hil.model.regressors`).

Written on purpose without reference to the virtual robot's plant (the world): the host's model
and the world are separate code, and tests/test_openloop.py checks that they agree. Scalar
Python floats (``math``) inside the loop: the 10 s Reyes & Kelly run at h = 2.5 ms (20,000 RK4
sub-steps, ~130 stick events) takes about 0.09 s on the 2-core development VM.
"""

from __future__ import annotations

import dataclasses
import math
import operator
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import lapack

from hil.model.closed_form import N_PARAMS, ArmModel
from hil.model.openloop_core import (
    DIVERGED,
    SIMULATION_CHUNK,
    ClosedFormArm,
    Friction,
    OpenLoopResult,
    integrate,
    integrate_arm,
    integrate_chunks,
    pair,
)
from hil.model.openloop_effects import OpenLoopExtras, integrate_with_extras


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
    intervals_s: ArrayLike | None = None,
    model: ArmModel | None = None,
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
    the result's ``q`` are reported angles (true + offset). ``intervals_s`` (N − 1 durations):
    period k lasts intervals_s[k], not h (a recording's real sample times; h is then only the
    nominal period the sub-steps are laid out on). ``model``: the
    :class:`hil.model.closed_form.ArmModel` θ is written in (default the 9-parameter model);
    its terms (rotor inertia, centre-of-mass offset) enter M(q), C q̇ and g(q) as
    :mod:`hil.model.closed_form` writes them. Raises ValueError on bad input.
    """
    th, torques, h, n_sub, start, pos, neg = _inputs(
        theta, tau, period_s, q0, dq0, steps_per_period, coulomb_positive, coulomb_negative, model
    )
    intervals = _intervals(intervals_s, len(torques))
    if extras is None:
        return integrate(th, torques, h, n_sub, start, Friction(pos, neg), intervals=intervals)
    if not isinstance(extras, OpenLoopExtras):
        raise ValueError(f"extras must be an OpenLoopExtras, got {type(extras).__name__}")
    offset = extras.angle_offset_rad
    true_start = (start[0] - offset[0], start[1] - offset[1], start[2], start[3])
    if extras.changes_dynamics:
        result = integrate_with_extras(
            th, torques, h, n_sub, true_start, pos, neg, extras, intervals
        )
    else:
        result = integrate(
            th, torques, h, n_sub, true_start, Friction(pos, neg), intervals=intervals
        )
    if offset == (0.0, 0.0):
        return result
    return dataclasses.replace(result, q=result.q + np.asarray(offset))  # reported angles


def simulate_open_loop_chunks(
    theta: ArrayLike,
    tau: ArrayLike,
    period_s: float,
    *,
    q0: Sequence[float] = (0.0, 0.0),
    dq0: Sequence[float] = (0.0, 0.0),
    steps_per_period: int = 5,
    chunk: int = SIMULATION_CHUNK,
    intervals_s: ArrayLike | None = None,
) -> Iterator[OpenLoopResult]:
    """:func:`simulate_open_loop` of the rigid model (no ``extras``), its rows ``chunk`` at a
    time (:func:`hil.model.openloop_core.integrate_chunks`): the same numbers, in memory for
    one chunk whatever the recording's length (issue 13). ``intervals_s``: as for
    :func:`simulate_open_loop` (period k lasts intervals_s[k]: a realtime run's real sample
    times). Checks its input before the first chunk."""
    th, torques, h, n_sub, start, pos, neg = _inputs(
        theta, tau, period_s, q0, dq0, steps_per_period, None, None
    )
    intervals = _intervals(intervals_s, len(torques))
    arm = ClosedFormArm(th, Friction(pos, neg))
    return integrate_chunks(arm, torques, h, n_sub, start, intervals=intervals, chunk=chunk)


def simulation_refusal(theta: ArrayLike) -> str | None:
    """Why the rigid model θ (9 numbers) cannot be simulated, in one line, or None if it can:
    the checks :func:`simulate_open_loop` makes of θ (finite, M(q) positive definite for every
    q2, Coulomb levels θ8, θ9 ≥ 0). A least-squares θ may fail them (a fit on short or
    quantized data); a caller validating several θ reports this one as not simulated."""
    try:
        th = _theta(theta)
        _non_negative("theta8, theta9 (Coulomb)", (float(th[7]), float(th[8])))
    except ValueError as exc:
        return str(exc)
    return None


def _intervals(intervals_s: ArrayLike | None, rows: int) -> np.ndarray | None:
    """``intervals_s`` checked: None, or N − 1 positive durations for N torque rows."""
    if intervals_s is None:
        return None
    intervals = np.asarray(intervals_s, float)
    if intervals.shape != (max(rows - 1, 0),) or not np.all(intervals > 0):
        raise ValueError(
            f"intervals_s must hold {rows - 1} positive durations (one per period between the "
            f"torque rows), got shape {intervals.shape}"
        )
    return intervals


def _inputs(
    theta, tau, period_s, q0, dq0, steps_per_period, coulomb_positive, coulomb_negative, model=None
):
    """:func:`simulate_open_loop`'s arguments checked: (θ, torques, h, sub-steps, start state,
    Coulomb levels +, −)."""
    th = _theta(theta, model)
    torques = _torques(tau)
    h = _positive("period_s", period_s)
    n_sub = _steps(steps_per_period)
    start = (*pair("q0", q0), *pair("dq0", dq0))
    fc = (float(th[7]), float(th[8]))
    pos = fc if coulomb_positive is None else pair("coulomb_positive", coulomb_positive)
    neg = fc if coulomb_negative is None else pair("coulomb_negative", coulomb_negative)
    for name, levels in (("theta8, theta9 (Coulomb)", fc), ("coulomb_positive", pos)):
        _non_negative(name, levels)
    _non_negative("coulomb_negative", neg)
    return th, torques, h, n_sub, start, pos, neg


# ---- validation ---------------------------------------------------------------------------


def _theta(theta: ArrayLike, model: ArmModel | None = None) -> np.ndarray:
    """θ checked (finite, M(q) positive definite for every q2), in the simulator's form: the
    9 numbers, or with model terms ``model.expand(θ)`` (hil.model.openloop_core._rigid)."""
    th = np.asarray(theta, dtype=float)
    if model is not None and model.terms:
        if th.shape != (model.n_params,):
            raise ValueError(f"theta must hold {model.n_params} numbers, got shape {th.shape}")
        if not np.all(np.isfinite(th)):
            raise ValueError("theta holds a non-finite number")
        bad = model.mass_matrix_violations(th)
        if bad:
            raise ValueError(f"theta gives a {bad[0]}; cannot simulate")
        return model.expand(th)
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


def _steps(value: int) -> int:
    try:
        n = operator.index(value)
    except TypeError:
        raise ValueError(f"steps_per_period must be an integer, got {value!r}") from None
    if n < 1:
        raise ValueError(f"steps_per_period must be >= 1, got {n}")
    return n


def _non_negative(name: str, levels: tuple[float, float]) -> None:
    if levels[0] < 0 or levels[1] < 0:
        raise ValueError(f"{name} must be >= 0 (a friction band), got {levels}")


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
    n = q.shape[1]
    sim = np.empty((len(starts), L + 1, n))
    sim[:, 0] = q[starts]
    ok = np.ones(len(starts), bool)

    def acc(qq, vv, uu):
        with np.errstate(all="ignore"):
            return model.forward_dynamics(th, qq, vv, uu)

    x_q, x_v = q[starts].copy(), v[starts].copy()
    for j in range(L):
        k = starts + j
        dt = (t[k + 1] - t[k])[:, None] / steps_per_interval
        x_q, x_v, bad = rk4_held(acc, x_q, x_v, tau[k], dt, steps_per_interval)
        ok &= ~bad
        x_q[bad], x_v[bad] = q[k[bad] + 1], 0.0
        sim[:, j + 1] = x_q
    idx = starts[:, None] + np.arange(L + 1)[None, :]
    rec = q[idx]
    # error per window relative to each window's own start, so the spread measures motion
    # within windows, not the recording's overall excursion
    ref = (rec - rec[:, :1])[ok].reshape(-1, n)
    est = (sim - rec[:, :1])[ok].reshape(-1, n)
    return {
        "position_nrmse": [float(x) for x in nrmse(ref, est)] if ok.any() else [np.nan] * n,
        "windows": len(starts),
        "diverged": int(np.sum(~ok)),
        "window_s": float(L * h),
    }


def rk4_held(
    acc, x_q: np.ndarray, x_v: np.ndarray, u: np.ndarray, dt: np.ndarray | float, steps: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``steps`` RK4 sub-steps of ``dt`` of q̈ = acc(q, q̇, u) under the held torque ``u``, for
    a batch of states (rows); returns q, q̇ and which rows left the finite range (DIVERGED),
    whose state the caller resets. Coulomb friction is whatever ``acc`` makes of sgn q̇ (no
    stiction): the integrator of :func:`simulate_windows`."""
    bad = np.zeros(len(x_q), bool)
    with np.errstate(all="ignore"):
        for _ in range(steps):
            a1 = acc(x_q, x_v, u)
            a2 = acc(x_q + 0.5 * dt * x_v, x_v + 0.5 * dt * a1, u)
            a3 = acc(x_q + 0.5 * dt * (x_v + 0.5 * dt * a1), x_v + 0.5 * dt * a2, u)
            a4 = acc(x_q + dt * (x_v + 0.5 * dt * a2), x_v + dt * a3, u)
            x_q = x_q + dt * x_v + dt**2 / 6 * (a1 + a2 + a3)
            x_v = x_v + dt / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
            now = ~(np.abs(x_q) < DIVERGED).all(axis=1) | ~(np.abs(x_v) < DIVERGED).all(axis=1)
            bad |= now
            x_q, x_v = np.where(now[:, None], 0.0, x_q), np.where(now[:, None], 0.0, x_v)
    return x_q, x_v, bad


def _solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x with a x = b by LAPACK's dgesv, as :func:`numpy.linalg.solve` does it, without its
    checks and conversions (they cost more than the solve of an n ≤ 7 system, four times per RK4
    step); a singular ``a`` raises :class:`numpy.linalg.LinAlgError` as there."""
    _, _, x, info = lapack.dgesv(a, b)
    if info > 0:
        raise np.linalg.LinAlgError("Singular matrix")
    return x


class ModelArm:
    """A model object with ``dynamics(θ)`` (M(q) and C q̇ + g at one state: an n-joint
    :class:`hil.model.urdf.UrdfArmModel`) at base parameters θ as the stick–slip integrator's arm
    (:class:`hil.model.openloop_core.StickSlipArm`): the one scheme of the 2-DOF simulation
    (module docstring) over n joints, in place of Coulomb friction as f_c sgn q̇.

    The model's friction f = f_v q̇ + f_c sgn q̇ + f_o (eq. (12), f_o with the friction_offset
    term) becomes: viscous f_v q̇ and the offset f_o as torques always acting, and Coulomb
    friction of level f_c by Karnopp's stick–slip (a joint at rest is held while the torque
    needed to hold it lies in [f_o − f_c, f_o + f_c]). ``shaft_torque(q, q̇)`` (rows of n, as
    :func:`simulate_segments` takes it): a torque added at the shaft (cogging, −the Stribeck
    excess). A step that leaves the finite range (DIVERGED) or meets a singular M(q) gives a
    NaN state, and NaN stays."""

    def __init__(self, model: Any, theta: ArrayLike, shaft_torque: Any = None) -> None:
        th = np.asarray(theta, dtype=float)
        n = model.n_joints
        columns = model.term_columns("friction")  # f_v (n), f_c (n)[, f_o (n)]
        friction = th[columns]
        coulomb = friction[n : 2 * n]
        if not np.all(coulomb >= 0):
            raise ValueError(
                f"theta has a negative Coulomb level ({', '.join(f'{c:.4g}' for c in coulomb)}); "
                "cannot simulate stick-slip"
            )
        self.model, self.theta, self.n_joints = model, th, n
        self.offset = friction[2 * n : 3 * n] if len(friction) > 2 * n else np.zeros(n)
        self.viscous = friction[:n]
        self.dynamics = model.dynamics(th)  # M(q), C q̇ + g of θ
        levels = tuple(float(c) for c in coulomb)
        self.friction = Friction(levels, levels)
        self.shaft_torque = shaft_torque

    def _residual(self, q: np.ndarray, v: np.ndarray, tau: Sequence[float]) -> np.ndarray:
        """r = τ + τ_shaft − f_o − C(q, q̇) q̇ − g(q) − f_v q̇: all but the Coulomb friction."""
        r = np.asarray(tau, dtype=float) - self.offset
        if self.shaft_torque is not None:
            r = r + self.shaft_torque(q[None], v[None])[0]
        return r - self.dynamics.rigid_bias(q, v) - self.viscous * v

    def mode_step(self, stuck: tuple[bool, ...], direction: tuple[float, ...]) -> Callable:
        """RK4 in one stick mode: q̈_S = 0, M_FF q̈_F = (r − d F^d)_F (F sliding, S stuck)."""
        n = self.n_joints
        free = np.flatnonzero(~np.array(stuck, dtype=bool))
        levels = np.array([self.friction.level(i, direction[i]) for i in range(n)])
        block = np.ix_(free, free)

        def acc(q: np.ndarray, v: np.ndarray, tau: Sequence[float]) -> np.ndarray:
            a = np.zeros(n)
            if free.size:
                r = self._residual(q, v, tau) - levels
                M = self.dynamics.mass_matrix(q)
                a[free] = _solve(M[block], r[free])
            return a

        def step(state: tuple[float, ...], tau: Sequence[float], dt: float) -> tuple[float, ...]:
            x = np.asarray(state, dtype=float)
            if not np.all(np.isfinite(x)):
                return state  # diverged before: NaN stays
            q, v = x[:n], x[n:]
            h2 = 0.5 * dt
            try:
                with np.errstate(all="ignore"):
                    a1 = acc(q, v, tau)
                    u = v + h2 * a1
                    a2 = acc(q + h2 * v, u, tau)
                    w = v + h2 * a2
                    a3 = acc(q + h2 * u, w, tau)
                    z = v + dt * a3
                    a4 = acc(q + dt * w, z, tau)
                    k = dt / 6.0
                    out = np.concatenate(
                        [q + k * (v + 2.0 * (u + w) + z), v + k * (a1 + 2.0 * (a2 + a3) + a4)]
                    )
            except np.linalg.LinAlgError:
                out = np.full(2 * n, np.nan)
            if not np.all(np.abs(out) < DIVERGED):
                out = np.full(2 * n, np.nan)
            return tuple(out.tolist())

        return step

    def holding_torques(
        self,
        state: tuple[float, ...],
        tau: Sequence[float],
        stuck: Sequence[bool],
        direction: Sequence[float],
    ) -> list[float]:
        """f_S = r_S − M_SF q̈_F with M_FF q̈_F = (r − d F^d)_F: the friction that keeps the
        stuck joints at rest (q̈_S = 0); zero for the sliding joints."""
        n = self.n_joints
        x = np.asarray(state, dtype=float)
        q, v = x[:n], x[n:]
        s = np.array(stuck, dtype=bool)
        r = self._residual(q, v, tau)
        held = np.zeros(n)
        free = np.flatnonzero(~s)
        held[s] = r[s]
        if free.size:
            M = self.dynamics.mass_matrix(q)
            levels = np.array([self.friction.level(int(i), direction[i]) for i in free])
            try:
                a_free = _solve(M[np.ix_(free, free)], r[free] - levels)
            except np.linalg.LinAlgError:
                return [0.0] * n
            held[s] -= M[np.ix_(np.flatnonzero(s), free)] @ a_free
        return held.tolist()


def simulate_segments(
    model: object,
    theta: ArrayLike,
    t: np.ndarray,
    q: np.ndarray,
    tau: np.ndarray,
    segments: Sequence[tuple[int, int]],
    dq0: np.ndarray,
    *,
    shaft_torque=None,
    angle_offset: np.ndarray | None = None,
    max_step_s: float = 1.25e-3,
) -> list[np.ndarray]:
    """Open-loop simulation of any model object with regressors and M(q) (an n-joint
    :class:`hil.model.urdf.UrdfArmModel`) over the sample ranges ``segments`` ([a, b) of the
    recording ``t``, ``q``), each from the recorded q[a] and ``dq0`` (one row per segment), row
    k's torque ``tau`` held over [t_k, t_{k+1}) (the shaft torque: a lag, delay, gain or offset
    already applied). ``shaft_torque(q, q̇)``: a torque added on the shaft (cogging, Stribeck
    friction as −f); ``angle_offset``: encoder reading = true angle + δ (the model moves in true
    angles, the result is in readings). The 2-DOF simulation's stick–slip integrator
    (:func:`hil.model.openloop_core.integrate_arm` of :class:`ModelArm`), on the segment's real
    intervals, sub-steps of at most ``max_step_s`` (of the median interval); a segment that
    diverges is NaN from there on. Returns q of each segment."""
    arm = ModelArm(model, theta, shaft_torque)
    n = q.shape[1]
    delta = np.zeros(n) if angle_offset is None else np.asarray(angle_offset, float)
    dq0 = np.asarray(dq0, float)
    out: list[np.ndarray] = []
    for i, (a, b) in enumerate(segments):
        intervals = np.diff(t[a:b])
        h = float(np.median(intervals)) if len(intervals) else 1.0
        n_sub = max(1, int(np.ceil(h / max_step_s - 1e-9)))
        start = (*(q[a] - delta).tolist(), *dq0[i].tolist())
        sim = integrate_arm(arm, tau[a:b], h, n_sub, start, intervals=intervals)
        out.append(sim.q + delta)
    return out


__all__ = [
    "ModelArm",
    "OpenLoopExtras",
    "OpenLoopResult",
    "rk4_held",
    "simulate_open_loop",
    "simulate_open_loop_chunks",
    "simulate_segments",
    "simulate_windows",
    "simulation_refusal",
]
