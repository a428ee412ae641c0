"""The virtual arm: rigid body (Section 5 of Reyes & Kelly 1997), stick–slip friction, effects.

Integration is fixed-step RK4 (default 0.5 ms, five steps per 2.5 ms control period) on the state
(q, q̇) augmented with the supplied work ∫τᵀq̇ dt and the friction work ∫fᵀq̇ dt, so the energy
balance of eq. (25) can be checked on the plant itself.

Friction is a Karnopp-style stick–slip model, not a smooth tanh, by the one stick–slip step of
the virtual robot (:mod:`virtual_robot.stick_slip`: the breakaway test, the located stick
events), of which this plant is the closed-form backend (its ``StickSlipArm`` methods):
  * a joint that is stuck (q̇_i = 0) stays stuck while the friction needed to hold it,
    found from the constrained dynamics (q̈_i = 0, :meth:`Plant._holding_torques`), is inside
    its static band [−F_s⁻, F_s⁺]; it breaks away in the direction of that torque when it
    leaves the band;
  * a sliding joint feels f_i = b_i q̇_i + F_i(dir) sgn, where the direction is fixed over a step
    (so each RK4 step integrates a smooth ODE); when q̇_i reaches zero inside a step the step is
    cut at the crossing (Brent's method on the RK4 flow map, to ~1e-12 of the step),
    the joint sticks, and the band is checked again for the rest of the step. The small kinetic
    energy removed by clamping q̇_i to exactly zero is booked as dissipated.
Break-away is checked at step boundaries, so it is detected up to one step (0.5 ms) late.
The dynamics are the closed form unrolled into scalar code (:meth:`Plant._deriv`, and
:func:`_sliding_rk4`, its RK4 step written out for both joints sliding), and while both slide
under a plain amplifier whole steps run in one local loop (:meth:`Plant._advance_sliding`): the
2-DOF speed.
Joint 1's Coulomb level is direction-dependent by default (7.17 Nm for q̇1 > 0, 8.049 Nm for
q̇1 < 0, Table I).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from profiles.effects import EffectsProfile
from profiles.robot import RobotProfile
from virtual_robot.effects import (
    TransportDelay,
    amplifier_lag_step,
    cogging_torque,
    gain_offset,
    payload_theta,
    plant_effect_params,
    stribeck_level,
    velocity_squared_drag,
)
from virtual_robot.stick_slip import advance_delayed, locate_stick
from virtual_robot.stick_slip import step as stick_slip_step

# 0.5 ms = 2 kHz, five RK4 steps per 2.5 ms control period. Halving it changes q on the 10 s
# Reyes & Kelly run by ~1e-11 rad (round-off level; tests/test_plant.py bounds it by 1e-9 rad,
# which linear interpolation of the stick instants would break, at ~1e-6 rad).
DEFAULT_STEP_S = 5e-4
Pair = tuple[float, float]


@dataclass(frozen=True)
class PlantParams:
    """Everything the plant integrates: θ1..θ5, friction, and the effects' parameters."""

    theta: tuple[float, float, float, float, float]
    viscous_Nms: Pair
    coulomb_positive_Nm: Pair
    coulomb_negative_Nm: Pair
    breakaway_positive_Nm: Pair  # static band; = Coulomb level without Stribeck
    breakaway_negative_Nm: Pair
    stribeck_velocity_rad_s: Pair | None = None
    stribeck_exponent: float = 2.0
    cogging_periods_per_rev: Pair = (0.0, 0.0)
    cogging_amplitude_Nm: Pair = (0.0, 0.0)
    cogging_phase_rad: Pair = (0.0, 0.0)
    amplifier_lag_s: Pair = (0.0, 0.0)
    transport_delay_s: float = 0.0
    torque_gain_error: Pair = (0.0, 0.0)
    torque_offset_Nm: Pair = (0.0, 0.0)
    encoder_offset_rad: Pair = (0.0, 0.0)
    drag_Nms2: Pair = (0.0, 0.0)  # velocity-squared drag coefficient c per joint

    @classmethod
    def from_profiles(
        cls, robot: RobotProfile, effects: EffectsProfile | None = None
    ) -> PlantParams:
        # per-joint values as 2-tuples (a wrong length is a one-line error naming the key)
        effects = (effects or EffectsProfile()).for_joints(2, robot.name)
        theta = list(robot.theta()[:5])
        if effects.payload is not None:
            assert robot.link1.length_m is not None
            theta = payload_theta(theta, effects.payload, robot.link1.length_m, robot.gravity_m_s2)
        return cls(
            theta=tuple(float(x) for x in theta),  # type: ignore[arg-type]
            viscous_Nms=robot.viscous_Nms,
            **plant_effect_params(effects, robot.coulomb_positive_Nm, robot.coulomb_negative_Nm),
        )


class Plant:
    """Fixed-step simulation of the arm under a zero-order-held shaft torque command.

    ``command(τ)`` sets the amplifier input (after the transport delay, if any);
    ``advance_to(t)`` integrates up to time t. The true state is ``q``/``dq``; what an encoder
    sees is ``measured_q`` (with the encoder-offset effect).
    """

    n_joints = 2

    def __init__(
        self,
        params: PlantParams,
        q0: Pair = (0.0, 0.0),
        dq0: Pair = (0.0, 0.0),
        t0: float = 0.0,
        max_step_s: float = DEFAULT_STEP_S,
    ) -> None:
        if not max_step_s > 0:
            raise ValueError("max_step_s must be > 0")
        self.params = params
        self.max_step_s = max_step_s
        self.t = t0
        self.q1, self.q2 = float(q0[0]), float(q0[1])
        self.v1, self.v2 = float(dq0[0]), float(dq0[1])
        # A joint without Coulomb friction (zero static band) never sticks: its dynamics are smooth.
        self._sticky = (
            max(params.breakaway_positive_Nm[0], params.breakaway_negative_Nm[0]) > 0,
            max(params.breakaway_positive_Nm[1], params.breakaway_negative_Nm[1]) > 0,
        )
        self.stuck = [self._sticky[0] and self.v1 == 0.0, self._sticky[1] and self.v2 == 0.0]
        self.slip_dir = [1.0 if self.v1 >= 0 else -1.0, 1.0 if self.v2 >= 0 else -1.0]
        self.command_Nm: Pair = (0.0, 0.0)  # amplifier input after the delay
        self.powered = (True, True)  # amplifier power stages (see command())
        self.amplifier_Nm = [0.0, 0.0]  # amplifier output (lag state)
        self.work_in_J = 0.0  # ∫ τ_shaftᵀ q̇ dt
        self.dissipated_J = 0.0  # ∫ fᵀ q̇ dt + stick clamping losses
        self.steps = 0
        self.stick_events = 0
        self._delay = TransportDelay(params.transport_delay_s) if params.transport_delay_s else None
        p = params
        self._has_stribeck = p.stribeck_velocity_rad_s is not None
        self._has_drag = any(c != 0.0 for c in p.drag_Nms2)
        # friction magnitude depends on the speed (evaluated at every derivative, not per step)
        self._speed_dependent = self._has_stribeck or self._has_drag
        self._has_cogging = any(a != 0.0 for a in p.cogging_amplitude_Nm)
        self._has_lag = any(tc > 0.0 for tc in p.amplifier_lag_s)
        self._constants = (*params.theta, *params.viscous_Nms)
        self._fast_rk4 = None
        self._plain_amplifier = (
            not self._has_lag
            and not any(params.torque_gain_error)
            and not any(params.torque_offset_Nm)
        )
        self._set_mode()

    # ---- inputs ---------------------------------------------------------------------------
    def command(
        self,
        torque_Nm: Pair,
        issued_at: float | None = None,
        powered: tuple[bool, bool] | None = None,
        deliver_at: float | None = None,
    ) -> None:
        """Set the torque command (Nm per joint), issued at ``issued_at`` (default: now).

        ``powered``: whether each amplifier's power stage is on (drive enabled). An unpowered
        amplifier puts no torque on the shaft at all: no offset, no lag tail. Takes effect now.
        ``deliver_at``: the command reaches the drive at this time, not at ``issued_at`` (an
        injected link latency, or a replayed timing trace); the transport-delay effect, if any,
        runs from there. A time already past takes effect at once.
        """
        if powered is not None:
            self.set_powered(powered)
        cmd = (float(torque_Nm[0]), float(torque_Nm[1]))
        if deliver_at is not None:
            if self._delay is None:
                self._delay = TransportDelay(self.params.transport_delay_s)
            self._delay.push(deliver_at, cmd)
        elif self._delay is None:
            self.command_Nm = cmd
        else:
            self._delay.push(self.t if issued_at is None else issued_at, cmd)

    def set_powered(self, powered: tuple[bool, bool]) -> None:
        """Switch the amplifiers' power stages (takes effect now; see :meth:`command`)."""
        self.powered = (bool(powered[0]), bool(powered[1]))

    def advance_to(self, t_end: float) -> None:
        """Integrate from the current time to ``t_end`` with steps of at most ``max_step_s``
        (:func:`virtual_robot.stick_slip.step`; cut where a delayed command arrives); while
        both joints slide under a plain amplifier, by :meth:`_advance_sliding`."""
        if self._delay is not None:
            advance_delayed(self, self._delay, t_end, self.max_step_s)
            return
        while self.t < t_end - 1e-12:
            if self._fast_rk4 is not None and self._plain_amplifier:
                self._advance_sliding(t_end)
                if self.t >= t_end - 1e-12:
                    break
            stop = min(t_end, self.t + self.max_step_s)
            stick_slip_step(self, stop - self.t)

    def step(self, dt: float) -> None:
        """Advance dt (:func:`virtual_robot.stick_slip.step`: stick events located)."""
        stick_slip_step(self, dt)

    def deliver_due(self) -> None:
        """The newest delayed command that has arrived reaches the amplifier."""
        assert self._delay is not None
        due = self._delay.pop_due(self.t)
        if due is not None:
            self.command_Nm = due

    def advance(self, duration_s: float) -> None:
        self.advance_to(self.t + duration_s)

    # ---- outputs --------------------------------------------------------------------------
    @property
    def q(self) -> Pair:
        return (self.q1, self.q2)

    @property
    def dq(self) -> Pair:
        return (self.v1, self.v2)

    @property
    def measured_q(self) -> Pair:
        off = self.params.encoder_offset_rad
        return (self.q1 + off[0], self.q2 + off[1])

    def energy_J(self) -> float:
        """Total energy ℰ = ½ q̇ᵀM(q)q̇ + θ4(1 − cos q1) + θ5(1 − cos(q1+q2))   (eqs. (5)-(7))."""
        t1, t2, t3, t4, t5 = self.params.theta
        c2 = math.cos(self.q2)
        v1, v2 = self.v1, self.v2
        kinetic = 0.5 * ((t1 + 2 * t2 * c2) * v1 * v1 + 2 * (t3 + t2 * c2) * v1 * v2 + t3 * v2 * v2)
        return kinetic + t4 * (1 - math.cos(self.q1)) + t5 * (1 - math.cos(self.q1 + self.q2))

    # ---- integration ----------------------------------------------------------------------
    def _amplifier(self, dt: float) -> tuple[Pair, Pair]:
        """Mean shaft torque (before cogging) over the next dt, and the lag state at its end."""
        if self._plain_amplifier:
            return self.command_Nm, self.command_Nm
        p = self.params
        means, ends = [0.0, 0.0], [0.0, 0.0]
        for i in (0, 1):
            if not self.powered[i]:
                continue  # power stage off: no torque, and the lag state discharges
            if self._has_lag:
                means[i], ends[i] = amplifier_lag_step(
                    self.amplifier_Nm[i], self.command_Nm[i], dt, p.amplifier_lag_s[i]
                )
            else:
                means[i] = ends[i] = self.command_Nm[i]
            means[i] = gain_offset(means[i], p.torque_gain_error[i], p.torque_offset_Nm[i])
        return (means[0], means[1]), (ends[0], ends[1])

    def _friction_level(self, i: int, direction: float, speed: float) -> float:
        """Magnitude of Coulomb (or Stribeck) friction, plus velocity-squared drag, on joint i
        sliding in ``direction`` (the drag c q̇|q̇| has magnitude c q̇², zero at rest)."""
        p = self.params
        coulomb = p.coulomb_positive_Nm[i] if direction > 0 else p.coulomb_negative_Nm[i]
        level = coulomb
        if self._has_stribeck:
            breakaway = p.breakaway_positive_Nm[i] if direction > 0 else p.breakaway_negative_Nm[i]
            assert p.stribeck_velocity_rad_s is not None
            level = stribeck_level(
                coulomb, breakaway, speed, p.stribeck_velocity_rad_s[i], p.stribeck_exponent
            )
        if self._has_drag:
            level += velocity_squared_drag(p.drag_Nms2[i], speed)
        return level

    def _deriv(
        self,
        q1: float,
        q2: float,
        v1: float,
        v2: float,
        tau1: float,
        tau2: float,
    ) -> tuple[float, float, float, float]:
        """Accelerations, supplied power and friction power (a1, a2, τᵀq̇, fᵀq̇) in the stick mode
        set by :meth:`_set_mode`.

        M(q) q̈ = τ − C(q,q̇)q̇ − g(q) − f, Section 5; a stuck joint has q̈_i = 0 and f_i is the
        constraint torque that holds it (it does no work: q̇_i = 0).
        """
        t1, t2, t3, t4, t5, b1, b2 = self._constants
        s2, c2 = math.sin(q2), math.cos(q2)
        s12 = math.sin(q1 + q2)
        if self._has_cogging:
            tau1, tau2 = self._add_cogging(q1, q2, tau1, tau2)
        t2s2 = t2 * s2
        # r = τ − C(q,q̇)q̇ − g(q)
        r1 = tau1 + t2s2 * (2.0 * v1 * v2 + v2 * v2) - t4 * math.sin(q1) - t5 * s12
        r2 = tau2 - t2s2 * v1 * v1 - t5 * s12
        m11 = t1 + 2.0 * t2 * c2
        m12 = t3 + t2 * c2
        stuck1, stuck2, level1, level2 = self._mode
        if self._speed_dependent:
            level1 = self._slip_dir1 * self._friction_level(0, self._slip_dir1, abs(v1))
            level2 = self._slip_dir2 * self._friction_level(1, self._slip_dir2, abs(v2))
        power = tau1 * v1 + tau2 * v2
        if not stuck1 and not stuck2:
            f1, f2 = b1 * v1 + level1, b2 * v2 + level2
            e1, e2 = r1 - f1, r2 - f2
            det = m11 * t3 - m12 * m12
            return (
                (t3 * e1 - m12 * e2) / det,
                (m11 * e2 - m12 * e1) / det,
                power,
                f1 * v1 + f2 * v2,
            )
        if stuck1 and not stuck2:
            f2 = b2 * v2 + level2
            return 0.0, (r2 - f2) / t3, power, f2 * v2
        if stuck2 and not stuck1:
            f1 = b1 * v1 + level1
            return (r1 - f1) / m11, 0.0, power, f1 * v1
        return 0.0, 0.0, power, 0.0

    def _holding_torques(self, tau: Pair) -> tuple[float, float]:
        """Friction each stuck joint needs to stay stuck (the constraint torques), now."""
        t1, t2, t3, t4, t5 = self.params.theta
        q1, q2, v1, v2 = self.q1, self.q2, self.v1, self.v2
        tau1, tau2 = tau
        if self._has_cogging:
            tau1, tau2 = self._add_cogging(q1, q2, tau1, tau2)
        t2s2 = t2 * math.sin(q2)
        s12 = math.sin(q1 + q2)
        r1 = tau1 + t2s2 * (2.0 * v1 * v2 + v2 * v2) - t4 * math.sin(q1) - t5 * s12
        r2 = tau2 - t2s2 * v1 * v1 - t5 * s12
        m11 = t1 + 2.0 * t2 * math.cos(q2)
        m12 = t3 + t2 * math.cos(q2)
        stuck1, stuck2 = self.stuck
        b1, b2 = self.params.viscous_Nms
        if stuck1 and stuck2:
            return r1, r2
        if stuck1:
            f2 = b2 * v2 + self.slip_dir[1] * self._friction_level(1, self.slip_dir[1], abs(v2))
            return r1 - m12 * (r2 - f2) / t3, 0.0
        f1 = b1 * v1 + self.slip_dir[0] * self._friction_level(0, self.slip_dir[0], abs(v1))
        return 0.0, r2 - m12 * (r1 - f1) / m11

    def _add_cogging(self, q1: float, q2: float, tau1: float, tau2: float) -> Pair:
        p = self.params
        return (
            tau1
            + cogging_torque(
                q1, p.cogging_periods_per_rev[0], p.cogging_amplitude_Nm[0], p.cogging_phase_rad[0]
            ),
            tau2
            + cogging_torque(
                q2, p.cogging_periods_per_rev[1], p.cogging_amplitude_Nm[1], p.cogging_phase_rad[1]
            ),
        )

    def _set_mode(self) -> None:
        """Freeze the stick mode and the sliding friction levels (until the mode changes)."""
        d1, d2 = self.slip_dir
        self._slip_dir1, self._slip_dir2 = d1, d2
        self._mode = (
            self.stuck[0],
            self.stuck[1],
            d1 * self._friction_level(0, d1, 0.0),
            d2 * self._friction_level(1, d2, 0.0),
        )
        if self._mode[0] or self._mode[1] or self._has_cogging or self._speed_dependent:
            self._fast_rk4 = None
            self._mode_rk4 = _rk4_step(self._deriv)
        else:
            self._fast_rk4 = _sliding_rk4(*self._constants, self._mode[2], self._mode[3])
            self._mode_rk4 = self._fast_rk4

    def _rk4(self, dt: float, tau: Pair) -> tuple[float, float, float, float, float, float]:
        """One classical RK4 step of (q, q̇, W_in, W_f) in the current stick mode."""
        return self._mode_rk4(self.q1, self.q2, self.v1, self.v2, tau[0], tau[1], dt)

    # ---- the stick-slip step's backend (virtual_robot.stick_slip.StickSlipArm) ---------------
    @property
    def band_positive(self) -> Pair:
        return self.params.breakaway_positive_Nm

    @property
    def band_negative(self) -> Pair:
        return self.params.breakaway_negative_Nm

    def any_stuck(self) -> bool:
        return self.stuck[0] or self.stuck[1]

    def hold_torque(self, dt: float) -> None:
        """The amplifier's mean torque over the step (the breakaway test's τ)."""
        self._step_tau = self.command_Nm if self._plain_amplifier else self._amplifier(dt)[0]

    def flow(self, s: float) -> tuple[float, float, float, float, float, float]:
        """RK4 over s in the current stick mode under the amplifier's mean torque over s."""
        tau = self.command_Nm if self._plain_amplifier else self._amplifier(s)[0]
        return self._rk4(s, tau)

    def start(self) -> tuple[float, float, float, float, float, float]:
        return (self.q1, self.q2, self.v1, self.v2, 0.0, 0.0)

    def velocity(self, end: tuple[float, ...], joint: int) -> float:
        return end[2 + joint]

    def crossed(self, end: tuple[float, ...]) -> tuple[int, ...]:
        """Sliding sticky joints whose velocity changed sign over the step."""
        sticky, stuck, d = self._sticky, self.stuck, self.slip_dir
        one = sticky[0] and not stuck[0] and end[2] * d[0] < 0.0
        two = sticky[1] and not stuck[1] and end[3] * d[1] < 0.0
        if one or two:
            return (0, 1) if one and two else (0,) if one else (1,)
        return ()

    def locate(
        self, dt: float, crossed: Sequence[int], end: tuple[float, ...]
    ) -> tuple[float, int, tuple[float, ...]]:
        # the flow is a pure function of s, a lag's included (_amplifier has no side effect)
        return locate_stick(self, dt, crossed, end)

    def commit(self, end: tuple[float, ...], s: float) -> None:
        self.q1, self.q2, self.v1, self.v2, work, diss = end
        self.work_in_J += work
        self.dissipated_J += diss
        if self._has_lag and s > 0.0:  # (a stick at s = 0: no time passed, the lag stays)
            lag_end = self._amplifier(s)[1]
            self.amplifier_Nm = [lag_end[0], lag_end[1]]

    def holding_torques(self) -> Pair:
        return self._holding_torques(self._step_tau)

    def rest(self, joint: int) -> None:
        if joint == 0:
            self.v1 = 0.0
        else:
            self.v2 = 0.0

    def dissipate(self, energy_J: float) -> None:
        self.dissipated_J += energy_J

    def mode_changed(self) -> None:
        self._set_mode()

    def _advance_sliding(self, t_end: float) -> None:
        """Whole RK4 steps while both joints slide (the common case), in one local loop.

        Same arithmetic as :func:`virtual_robot.stick_slip.step` without a stick event; stops
        before a step in which a sticky joint's velocity would change sign, and leaves that step
        to it.
        """
        rk4 = self._fast_rk4
        assert rk4 is not None
        tau1, tau2 = self.command_Nm
        sticky1, sticky2 = self._sticky
        d1, d2 = self.slip_dir
        t, h = self.t, self.max_step_s
        q1, q2, v1, v2 = self.q1, self.q2, self.v1, self.v2
        work, diss, steps = self.work_in_J, self.dissipated_J, self.steps
        while t < t_end - 1e-12:
            stop = min(t_end, t + h)
            dt = stop - t
            n1, n2, w1, w2, dw, dd = rk4(q1, q2, v1, v2, tau1, tau2, dt)
            if (sticky1 and w1 * d1 < 0.0) or (sticky2 and w2 * d2 < 0.0):
                break
            q1, q2, v1, v2 = n1, n2, w1, w2
            work += dw
            diss += dd
            t += dt
            steps += 1
        self.t, self.q1, self.q2, self.v1, self.v2 = t, q1, q2, v1, v2
        self.work_in_J, self.dissipated_J, self.steps = work, diss, steps


def _sliding_rk4(
    t1: float,
    t2: float,
    t3: float,
    t4: float,
    t5: float,
    b1: float,
    b2: float,
    level1: float,
    level2: float,
):
    """:func:`_rk4_step` of :meth:`Plant._deriv` specialised to both joints sliding, without
    cogging, Stribeck or drag (the common case): the four stages written out in one function
    with the constants bound as locals, the same operations in the same order (the same bits:
    tests/test_plant.py), without a call and a tuple per stage."""
    sin, cos = math.sin, math.cos

    def step(
        q1: float,
        q2: float,
        v1: float,
        v2: float,
        tau1: float,
        tau2: float,
        dt: float,
    ) -> tuple[float, float, float, float, float, float]:
        h2 = 0.5 * dt
        # stage 1 at (q, v)
        s2, c2 = sin(q2), cos(q2)
        s12 = sin(q1 + q2)
        t2s2 = t2 * s2
        f1 = b1 * v1 + level1
        f2 = b2 * v2 + level2
        e1 = tau1 + t2s2 * (2.0 * v1 * v2 + v2 * v2) - t4 * sin(q1) - t5 * s12 - f1
        e2 = tau2 - t2s2 * v1 * v1 - t5 * s12 - f2
        m11 = t1 + 2.0 * t2 * c2
        m12 = t3 + t2 * c2
        det = m11 * t3 - m12 * m12
        a1 = (t3 * e1 - m12 * e2) / det
        a2 = (m11 * e2 - m12 * e1) / det
        p1 = tau1 * v1 + tau2 * v2
        w1 = f1 * v1 + f2 * v2
        # stage 2 at (q + h/2 v, y)
        y1, y2 = v1 + h2 * a1, v2 + h2 * a2
        x1, x2 = q1 + h2 * v1, q2 + h2 * v2
        s2, c2 = sin(x2), cos(x2)
        s12 = sin(x1 + x2)
        t2s2 = t2 * s2
        f1 = b1 * y1 + level1
        f2 = b2 * y2 + level2
        e1 = tau1 + t2s2 * (2.0 * y1 * y2 + y2 * y2) - t4 * sin(x1) - t5 * s12 - f1
        e2 = tau2 - t2s2 * y1 * y1 - t5 * s12 - f2
        m11 = t1 + 2.0 * t2 * c2
        m12 = t3 + t2 * c2
        det = m11 * t3 - m12 * m12
        bb1 = (t3 * e1 - m12 * e2) / det
        bb2 = (m11 * e2 - m12 * e1) / det
        p2 = tau1 * y1 + tau2 * y2
        w2 = f1 * y1 + f2 * y2
        # stage 3 at (q + h/2 y, z)
        z1, z2 = v1 + h2 * bb1, v2 + h2 * bb2
        x1, x2 = q1 + h2 * y1, q2 + h2 * y2
        s2, c2 = sin(x2), cos(x2)
        s12 = sin(x1 + x2)
        t2s2 = t2 * s2
        f1 = b1 * z1 + level1
        f2 = b2 * z2 + level2
        e1 = tau1 + t2s2 * (2.0 * z1 * z2 + z2 * z2) - t4 * sin(x1) - t5 * s12 - f1
        e2 = tau2 - t2s2 * z1 * z1 - t5 * s12 - f2
        m11 = t1 + 2.0 * t2 * c2
        m12 = t3 + t2 * c2
        det = m11 * t3 - m12 * m12
        cc1 = (t3 * e1 - m12 * e2) / det
        cc2 = (m11 * e2 - m12 * e1) / det
        p3 = tau1 * z1 + tau2 * z2
        w3 = f1 * z1 + f2 * z2
        # stage 4 at (q + h z, u)
        u1, u2 = v1 + dt * cc1, v2 + dt * cc2
        x1, x2 = q1 + dt * z1, q2 + dt * z2
        s2, c2 = sin(x2), cos(x2)
        s12 = sin(x1 + x2)
        t2s2 = t2 * s2
        f1 = b1 * u1 + level1
        f2 = b2 * u2 + level2
        e1 = tau1 + t2s2 * (2.0 * u1 * u2 + u2 * u2) - t4 * sin(x1) - t5 * s12 - f1
        e2 = tau2 - t2s2 * u1 * u1 - t5 * s12 - f2
        m11 = t1 + 2.0 * t2 * c2
        m12 = t3 + t2 * c2
        det = m11 * t3 - m12 * m12
        dd1 = (t3 * e1 - m12 * e2) / det
        dd2 = (m11 * e2 - m12 * e1) / det
        p4 = tau1 * u1 + tau2 * u2
        w4 = f1 * u1 + f2 * u2
        k = dt / 6.0
        return (
            q1 + k * (v1 + 2 * y1 + 2 * z1 + u1),
            q2 + k * (v2 + 2 * y2 + 2 * z2 + u2),
            v1 + k * (a1 + 2 * bb1 + 2 * cc1 + dd1),
            v2 + k * (a2 + 2 * bb2 + 2 * cc2 + dd2),
            k * (p1 + 2 * p2 + 2 * p3 + p4),
            k * (w1 + 2 * w2 + 2 * w3 + w4),
        )

    return step


def _rk4_step(deriv):
    """Classical RK4 on (q1, q2, q̇1, q̇2, W_in, W_f) with ``deriv`` -> (q̈1, q̈2, P_in, P_f)."""

    def step(
        q1: float,
        q2: float,
        v1: float,
        v2: float,
        tau1: float,
        tau2: float,
        dt: float,
    ) -> tuple[float, float, float, float, float, float]:
        h2 = 0.5 * dt
        a1, a2, p1, w1 = deriv(q1, q2, v1, v2, tau1, tau2)
        y1, y2 = v1 + h2 * a1, v2 + h2 * a2
        b1, b2, p2, w2 = deriv(q1 + h2 * v1, q2 + h2 * v2, y1, y2, tau1, tau2)
        z1, z2 = v1 + h2 * b1, v2 + h2 * b2
        c1, c2, p3, w3 = deriv(q1 + h2 * y1, q2 + h2 * y2, z1, z2, tau1, tau2)
        u1, u2 = v1 + dt * c1, v2 + dt * c2
        e1, e2, p4, w4 = deriv(q1 + dt * z1, q2 + dt * z2, u1, u2, tau1, tau2)
        k = dt / 6.0
        return (
            q1 + k * (v1 + 2 * y1 + 2 * z1 + u1),
            q2 + k * (v2 + 2 * y2 + 2 * z2 + u2),
            v1 + k * (a1 + 2 * b1 + 2 * c1 + e1),
            v2 + k * (a2 + 2 * b2 + 2 * c2 + e2),
            k * (p1 + 2 * p2 + 2 * p3 + p4),
            k * (w1 + 2 * w2 + 2 * w3 + w4),
        )

    return step
