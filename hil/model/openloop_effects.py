"""Open-loop simulation with the extra physics the mismatch diagnosis can accept (issue 7).

:func:`hil.model.openloop.simulate_open_loop` calls :func:`integrate_with_extras` when its
``extras`` (:class:`hil.model.openloop.OpenLoopExtras`) switch on anything that changes the
dynamics. The
stick–slip scheme is the one of :mod:`hil.model.openloop` (read its docstring first); what is added,
in the order of the torque path from the recorded command to the shaft:

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

(The angle offset only changes what is reported; :mod:`hil.model.openloop` applies it.) These are
the
definitions of the virtual robot's effects (virtual_robot/effects.py and plant.py, docs/effects.md),
written again here because the host never imports the world; tests/test_openloop.py checks that the
two agree. Sub-steps are the plant's: ``steps_per_period`` per period, cut at arrivals of delayed
commands, with the lag mean taken over each (cut) sub-step.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from hil.model.openloop import (
    MAX_EVENTS_PER_SUBSTEP,
    OpenLoopResult,
    State,
    Step,
    _locate_zero,
    _rk4,
)

if TYPE_CHECKING:
    from hil.model.openloop import OpenLoopExtras

Pair = tuple[float, float]
# Sub-step boundaries closer than this (s) to an arrival instant are not cut (as in the plant).
_TIME_TOL = 1e-12


def lag_step(state: float, command: float, dt: float, time_constant_s: float) -> Pair:
    """(mean over dt, value at dt) of T dτ/dt = τ_in − τ from τ(0) = ``state``, τ_in held."""
    if time_constant_s <= 0.0 or dt <= 0.0:
        return command, command
    decay = math.exp(-dt / time_constant_s)
    gap = state - command
    return command + gap * time_constant_s / dt * (1.0 - decay), command + gap * decay


def _period_segments(h: float, n_sub: int, arrival: float | None) -> list[tuple[float, int]]:
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


def _accelerations(
    theta: np.ndarray,
    stuck1: bool,
    stuck2: bool,
    d1: float,
    d2: float,
    friction: Callable[[int, float, float], float],
    cogging: Callable[[float, float], Pair] | None,
) -> Callable[[float, float, float, float, float, float], Pair]:
    """q̈ = M⁻¹(τ + τ_cog − C q̇ − g − f) in one stick mode; f_i = b_i q̇_i + d_i F_i(|q̇_i|)."""
    t1, t2, t3, t4, t5, b1, b2 = (float(x) for x in theta[:7])
    sin, cos = math.sin, math.cos

    def acc(q1, q2, v1, v2, tau1, tau2):
        if cogging is not None:
            c1, c2_ = cogging(q1, q2)
            tau1, tau2 = tau1 + c1, tau2 + c2_
        k = t2 * sin(q2)
        g12 = t5 * sin(q1 + q2)
        if stuck1 and stuck2:
            return 0.0, 0.0
        if stuck1:
            e2 = tau2 - k * v1 * v1 - g12 - b2 * v2 - friction(1, d2, abs(v2))
            return 0.0, e2 / t3
        e1 = tau1 + k * (2.0 * v1 * v2 + v2 * v2) - t4 * sin(q1) - g12 - b1 * v1
        e1 -= friction(0, d1, abs(v1))
        c2 = cos(q2)
        if stuck2:
            return e1 / (t1 + 2.0 * t2 * c2), 0.0
        e2 = tau2 - k * v1 * v1 - g12 - b2 * v2 - friction(1, d2, abs(v2))
        m11 = t1 + 2.0 * t2 * c2
        m12 = t3 + t2 * c2
        det = m11 * t3 - m12 * m12
        return (t3 * e1 - m12 * e2) / det, (m11 * e2 - m12 * e1) / det

    return acc


def integrate_with_extras(
    theta: np.ndarray,
    torques: np.ndarray,
    h: float,
    n_sub: int,
    start: State,
    pos: Pair,
    neg: Pair,
    extras: OpenLoopExtras,
) -> OpenLoopResult:
    """Like hil.model.openloop's integrator, with ``extras`` (angle offset excluded). ``start`` is
    the
    true state; the returned q are true angles."""
    ex = extras
    t1, t2, t3, t4, t5, b1, b2 = (float(x) for x in theta[:7])
    strib = ex.stribeck_velocity_rad_s is not None
    if strib:
        ratio = ex.stribeck_breakaway_ratio or (1.0, 1.0)
        band_pos = (pos[0] * ratio[0], pos[1] * ratio[1])
        band_neg = (neg[0] * ratio[0], neg[1] * ratio[1])
        v_s = ex.stribeck_velocity_rad_s
        expo = ex.stribeck_exponent
    else:
        band_pos, band_neg = pos, neg
    sticky = (max(band_pos[0], band_neg[0]) > 0.0, max(band_pos[1], band_neg[1]) > 0.0)

    def friction(i: int, direction: float, speed: float) -> float:
        """Signed Coulomb (or Stribeck) term d·F of joint i sliding in ``direction``."""
        fc = pos[i] if direction > 0 else neg[i]
        if not strib:
            return direction * fc
        fs = band_pos[i] if direction > 0 else band_neg[i]
        return direction * (fc + (fs - fc) * math.exp(-((speed / v_s[i]) ** expo)))

    n_cog, a_cog, p_cog = ex.cogging_periods_per_rev, ex.cogging_amplitude_Nm, ex.cogging_phase_rad
    cogging = None
    if a_cog[0] != 0.0 or a_cog[1] != 0.0:

        def cogging(q1: float, q2: float) -> Pair:
            return (
                a_cog[0] * math.sin(n_cog[0] * q1 + p_cog[0]),
                a_cog[1] * math.sin(n_cog[1] * q2 + p_cog[1]),
            )

    lag_t = ex.actuator_lag_s
    has_lag = lag_t[0] > 0.0 or lag_t[1] > 0.0
    gain, offset = ex.torque_gain, ex.torque_offset_Nm
    settled = ex.initial_command_Nm
    # amplifier output before gain/offset (the lag state): settled on the command before t = 0
    lag = [0.0, 0.0] if settled is None else [settled[0], settled[1]]

    def amplifier(cmd: list, dt: float) -> tuple[Pair, Pair]:
        """Applied torque (mean over dt, before cogging) and the lag state at dt."""
        if has_lag:
            m1, e1 = lag_step(lag[0], cmd[0], dt, lag_t[0])
            m2, e2 = lag_step(lag[1], cmd[1], dt, lag_t[1])
        else:
            m1 = e1 = cmd[0]
            m2 = e2 = cmd[1]
        return ((1.0 + gain[0]) * m1 + offset[0], (1.0 + gain[1]) * m2 + offset[1]), (e1, e2)

    before, after, arrival = _commands(torques, ex.transport_delay_s, h, settled)
    segments = _period_segments(h, n_sub, arrival)

    n_rows = torques.shape[0]
    q1, q2, v1, v2 = start
    stuck = [sticky[0] and v1 == 0.0, sticky[1] and v2 == 0.0]
    direction = [1.0 if v1 >= 0.0 else -1.0, 1.0 if v2 >= 0.0 else -1.0]
    stick_events = [0, 0]
    breakaways = [0, 0]
    substeps = 0
    steps: dict[tuple[bool, bool, float, float], Step] = {}

    def mode_step() -> Step:
        key = (stuck[0], stuck[1], direction[0], direction[1])
        step = steps.get(key)
        if step is None:
            step = steps[key] = _rk4(_accelerations(theta, *key, friction, cogging))
        return step

    def holding(state: State, tau: Pair) -> Pair:
        """Friction each stuck joint needs to stay at rest (hil.model.openloop._holding_torques)."""
        sq1, sq2, sv1, sv2 = state
        tau1, tau2 = tau
        if cogging is not None:
            c1, c2 = cogging(sq1, sq2)
            tau1, tau2 = tau1 + c1, tau2 + c2
        k = t2 * math.sin(sq2)
        g12 = t5 * math.sin(sq1 + sq2)
        r1 = tau1 + k * (2.0 * sv1 * sv2 + sv2 * sv2) - t4 * math.sin(sq1) - g12
        r2 = tau2 - k * sv1 * sv1 - g12
        if stuck[0] and stuck[1]:
            return r1, r2
        m12 = t3 + t2 * math.cos(sq2)
        if stuck[0]:
            f2 = b2 * sv2 + friction(1, direction[1], abs(sv2))
            return r1 - m12 * (r2 - f2) / t3, 0.0
        m11 = t1 + 2.0 * t2 * math.cos(sq2)
        f1 = b1 * sv1 + friction(0, direction[0], abs(sv1))
        return 0.0, r2 - m12 * (r1 - f1) / m11

    def release(state: State, tau: Pair) -> bool:
        """Let stuck joints whose holding torque leaves the static band break away."""
        changed = False
        for _ in range(2):
            held = holding(state, tau)
            worst, worst_ratio = -1, 1.0
            for i in (0, 1):
                if not stuck[i]:
                    continue
                band = band_pos[i] if held[i] > 0 else band_neg[i]
                r = abs(held[i]) / band if band > 0 else (math.inf if held[i] else 0.0)
                if r > worst_ratio:
                    worst, worst_ratio = i, r
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
    for k in range(n_rows):
        q_out[k] = (q1, q2)
        dq_out[k] = (v1, v2)
        stuck_out[k] = (stuck[0], stuck[1])
        if k == n_rows - 1:
            break
        commands = (before[k], after[k])
        for dt_seg, which in segments:
            cmd = commands[which]
            substeps += 1
            remaining = dt_seg
            # After MAX_EVENTS_PER_SUBSTEP stick events in one sub-step (chattering), the rest of
            # it is skipped with the state left as it is, as the plant does (end of Plant._step,
            # virtual_robot/plant.py; hil.model.openloop instead finishes it in the current mode).
            # It
            # happens with a lag: a joint breaks away on the mean torque over the rest of the
            # sub-step, but the lagged torque of its first instants pushes it back, 8 times.
            for _event in range(MAX_EVENTS_PER_SUBSTEP):
                tau, lag_end = amplifier(cmd, remaining)
                if (stuck[0] or stuck[1]) and release((q1, q2, v1, v2), tau):
                    step = mode_step()
                n1, n2, w1, w2 = step(q1, q2, v1, v2, tau[0], tau[1], remaining)
                cross1 = sticky[0] and not stuck[0] and w1 * direction[0] < 0.0
                cross2 = sticky[1] and not stuck[1] and w2 * direction[1] < 0.0
                if not (cross1 or cross2):
                    q1, q2, v1, v2 = n1, n2, w1, w2
                    lag[0], lag[1] = lag_end
                    break
                if cross1 and cross2:
                    joint = 0 if v1 / (v1 - w1) <= v2 / (v2 - w2) else 1
                else:
                    joint = 0 if cross1 else 1
                flow = _lagged_flow(step, amplifier, cmd)
                here = (q1, q2, v1, v2)
                s, state = _locate(flow, here, joint, remaining, (w1, w2)[joint], direction)
                other = 1 - joint
                if cross1 and cross2 and state[2 + other] * direction[other] < 0.0:
                    joint, other = other, joint
                    s, state = _locate(flow, here, joint, s, state[2 + joint], direction)
                if s > 0.0:  # (a zero-length lag step would jump to the command)
                    lag[0], lag[1] = amplifier(cmd, s)[1]
                q1, q2, v1, v2 = state
                if joint == 0:
                    v1 = 0.0
                else:
                    v2 = 0.0
                stuck[joint] = True
                stick_events[joint] += 1
                step = mode_step()
                remaining -= s
                if remaining <= 1e-15 * dt_seg:
                    break
    return OpenLoopResult(
        t=np.arange(n_rows) * h,
        q=np.array(q_out, dtype=float),
        dq=np.array(dq_out, dtype=float),
        stuck=np.array(stuck_out, dtype=bool),
        stick_events=np.array(stick_events),
        breakaways=np.array(breakaways),
        substeps=substeps,
    )


def _locate(
    flow: Step, start: State, joint: int, dt: float, v_end: float, direction: list[float]
) -> tuple[float, State]:
    """hil.model.openloop._locate_zero, except for a joint that moves against its slip direction at
    the start of the step: it broke away with the mean torque over the whole step, but the lagged
    torque of the step's first instants pushes it back; it sticks at once (s = 0), as the plant's
    regula falsi does (virtual_robot/plant.py, Plant._locate_stick)."""
    if start[2 + joint] * direction[joint] < 0.0:
        return 0.0, start
    return _locate_zero(flow, start, (0.0, 0.0), joint, dt, v_end)


def _lagged_flow(
    step: Step, amplifier: Callable[[list, float], tuple[Pair, Pair]], cmd: list
) -> Step:
    """The RK4 flow over s with the torque the amplifier applies over s (its lag mean), in the
    signature hil.model.openloop._locate_zero expects (its τ arguments are ignored)."""

    def flow(q1, q2, v1, v2, _tau1, _tau2, s):
        tau = amplifier(cmd, s)[0]
        return step(q1, q2, v1, v2, tau[0], tau[1], s)

    return flow
