"""Effects library: the physics a robot profile leaves out, switched on from an effects profile.

Each effect is a pure function (or a tiny FIFO) with the equation it implements; the plant wires
them into the torque path and the friction law. Order of the torque path, command to shaft:

    τ_cmd (drive, per-mille quantized) ─▶ transport delay d ─▶ amplifier lag T ─▶ gain/offset
        ─▶ + cogging(q) ─▶ τ_shaft

Encoder offset acts on the measurement side: q_measured = q + δq (then the drive's encoder floors
it to counts). Payload and Coulomb overrides change the plant's parameters, not the torque path.

Both plants use these: the 2-DOF :mod:`virtual_robot.plant` with floats per joint, the n-joint
:mod:`virtual_robot.urdf_plant` with numpy arrays over its joints (the per-joint laws
:func:`stribeck_level`, :func:`velocity_squared_drag`, :func:`cogging_torque`, :func:`gain_offset`
take either; a float keeps the ``math`` functions, so the 2-DOF plant's numbers are unchanged).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np

from profiles.effects import EffectsProfile, Payload


def stribeck_level(
    coulomb_Nm: float, breakaway_Nm: float, speed: float, stribeck_velocity: float, exponent: float
) -> float:
    """Friction magnitude at speed |v| (Stribeck curve, e.g. Armstrong-Hélouvry 1994):

        F(|v|) = F_c + (F_s − F_c) exp(−(|v| / v_s)^δ)

    equal to the breakaway level F_s at rest and tending to the Coulomb level F_c with speed.
    Viscous friction b v is added separately by the plant.
    """
    exp = np.exp if isinstance(speed, np.ndarray) else math.exp
    return coulomb_Nm + (breakaway_Nm - coulomb_Nm) * exp(
        -((speed / stribeck_velocity) ** exponent)
    )


def velocity_squared_drag(coefficient_Nms2: float, speed: float) -> float:
    """Magnitude of a velocity-squared (fluid / windage) drag at speed |v|: c v².

    The drag torque τ_drag = −c q̇ |q̇| opposes the motion like Coulomb and viscous friction, so the
    plant adds this magnitude to the sliding friction level; it vanishes at rest (no static band).
    """
    return coefficient_Nms2 * speed * speed


def cogging_torque(
    q: float, periods_per_rev: float, amplitude_Nm: float, phase_rad: float
) -> float:
    """Cogging / torque ripple: τ_cog(q) = A sin(N q + φ), N periods per revolution of the rotor."""
    sin = np.sin if isinstance(q, np.ndarray) else math.sin
    return amplitude_Nm * sin(periods_per_rev * q + phase_rad)


def cogging_work(
    q_from: np.ndarray,
    q_to: np.ndarray,
    periods_per_rev: np.ndarray,
    amplitude_Nm: np.ndarray,
    phase_rad: np.ndarray,
) -> float:
    """Work of the cogging torque from q_from to q_to, summed over the joints: τ_cog,i depends on
    q_i alone, so it is conservative and its work is path-independent,
        ∫ A sin(N q + φ) dq = (A / N) (cos(N q_from + φ) − cos(N q_to + φ)),   A sin(φ) Δq if N = 0.
    """
    n, a, p = periods_per_rev, amplitude_Nm, phase_rad
    ripple = n != 0.0
    safe = np.where(ripple, n, 1.0)
    work = np.where(
        ripple,
        a / safe * (np.cos(safe * q_from + p) - np.cos(safe * q_to + p)),
        a * np.sin(p) * (q_to - q_from),
    )
    return float(work.sum())


def amplifier_lag_step(
    torque_Nm: float, command_Nm: float, dt: float, time_constant_s: float
) -> tuple[float, float]:
    """Exact step of the first-order lag T dτ/dt = τ_cmd − τ under a held command.

    Returns (mean torque over the step, torque at its end):
        τ(dt) = τ_cmd + (τ0 − τ_cmd) e^{−dt/T},
        mean  = τ_cmd + (τ0 − τ_cmd) (T/dt) (1 − e^{−dt/T}).
    The plant integrates the rigid body with the mean, which keeps the work done exact to
    second order in dt.
    """
    if time_constant_s <= 0.0 or dt <= 0.0:
        return command_Nm, command_Nm
    decay = math.exp(-dt / time_constant_s)
    gap = torque_Nm - command_Nm
    return command_Nm + gap * time_constant_s / dt * (1.0 - decay), command_Nm + gap * decay


def gain_offset(torque_Nm: float, relative_gain_error: float, offset_Nm: float) -> float:
    """Amplifier gain and offset error: τ_out = (1 + ε) τ_in + τ_0."""
    return (1.0 + relative_gain_error) * torque_Nm + offset_Nm


def friction_bands(
    coulomb_positive_Nm: Sequence[float],
    coulomb_negative_Nm: Sequence[float],
    effects: EffectsProfile,
) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
    """Sliding Coulomb levels and static (breakaway) bands per joint, by direction, of a robot
    profile's levels under ``effects`` (fitted to the robot, EffectsProfile.for_joints): the
    ``coulomb`` effect replaces a joint's levels (None keeps the robot's), and ``stribeck``
    raises the static band to F_s = ratio · F_c; without it the band is the Coulomb level.
    Returns (positive, negative, breakaway positive, breakaway negative)."""
    pos, neg = tuple(coulomb_positive_Nm), tuple(coulomb_negative_Nm)
    if effects.coulomb is not None:
        c = effects.coulomb
        pos = tuple(r if e is None else e for r, e in zip(pos, c.positive_Nm, strict=True))
        neg = tuple(r if e is None else e for r, e in zip(neg, c.negative_Nm, strict=True))
    if effects.stribeck is None:
        return pos, neg, pos, neg
    ratio = effects.stribeck.breakaway_ratio
    return (
        pos,
        neg,
        tuple(f * r for f, r in zip(pos, ratio, strict=True)),
        tuple(f * r for f, r in zip(neg, ratio, strict=True)),
    )


def plant_effect_params(
    effects: EffectsProfile,
    coulomb_positive_Nm: Sequence[float],
    coulomb_negative_Nm: Sequence[float],
) -> dict[str, Any]:
    """The plant parameters of ``effects`` (fitted to the robot, EffectsProfile.for_joints) on a
    robot with these Coulomb levels, by the names both plants' parameters use
    (virtual_robot.plant.PlantParams, virtual_robot.urdf_plant.UrdfPlantParams); the payload is
    each plant's own. Friction levels and bands by :func:`friction_bands`."""
    pos, neg, break_pos, break_neg = friction_bands(
        coulomb_positive_Nm, coulomb_negative_Nm, effects
    )
    none = (0.0,) * len(pos)
    kw: dict[str, Any] = {
        "coulomb_positive_Nm": pos,
        "coulomb_negative_Nm": neg,
        "breakaway_positive_Nm": break_pos,
        "breakaway_negative_Nm": break_neg,
        "amplifier_lag_s": effects.amplifier_lag_s or none,
        "transport_delay_s": effects.transport_delay_s,
        "torque_gain_error": effects.torque_gain_error,
        "torque_offset_Nm": effects.torque_offset_Nm,
        "encoder_offset_rad": effects.encoder_offset_rad,
        "drag_Nms2": effects.velocity_squared_drag_Nms2 or none,
    }
    if effects.stribeck is not None:
        kw.update(
            stribeck_velocity_rad_s=effects.stribeck.velocity_rad_s,
            stribeck_exponent=effects.stribeck.exponent,
        )
    if effects.cogging is not None:
        kw.update(
            cogging_periods_per_rev=effects.cogging.periods_per_rev,
            cogging_amplitude_Nm=effects.cogging.amplitude_Nm,
            cogging_phase_rad=effects.cogging.phase_rad,
        )
    return kw


def payload_theta(
    theta: list[float], payload: Payload, link1_length_m: float, gravity_m_s2: float
) -> list[float]:
    """θ1..θ5 with a payload on link 2 at distance l_p from joint 2 (mass m_p, own inertia I_p).

    The payload adds to link 2 as a second body, so by the formulas of Section 5:
        Δθ1 = m_p (l1² + l_p²) + I_p,  Δθ2 = l1 m_p l_p,  Δθ3 = m_p l_p² + I_p,
        Δθ4 = g m_p l1,                Δθ5 = g m_p l_p.
    """
    mp, lp, Ip, l1, g = (
        payload.mass_kg,
        payload.distance_m,
        payload.inertia_kgm2,
        link1_length_m,
        gravity_m_s2,
    )
    delta = [mp * (l1**2 + lp**2) + Ip, l1 * mp * lp, mp * lp**2 + Ip, g * mp * l1, g * mp * lp]
    return [t + d for t, d in zip(theta[:5], delta, strict=True)] + list(theta[5:])


class TransportDelay:
    """Pure delay d between a torque command and the amplifier: τ_in(t) = τ_cmd(t − d).

    Commands are stamped with the time they were issued; :meth:`due` yields the ones whose
    delivery time t + d has come, in order.
    """

    def __init__(self, delay_s: float) -> None:
        self.delay_s = delay_s
        self._queue: deque[tuple[float, tuple[float, ...]]] = deque()

    def push(self, issued_at: float, torque_Nm: tuple[float, ...]) -> None:
        self._queue.append((issued_at + self.delay_s, torque_Nm))

    def next_delivery(self) -> float | None:
        return self._queue[0][0] if self._queue else None

    def pop_due(self, now: float) -> tuple[float, ...] | None:
        """The newest command delivered by ``now`` (older ones are superseded), or None."""
        latest = None
        while self._queue and self._queue[0][0] <= now + 1e-12:
            latest = self._queue.popleft()[1]
        return latest

    def clear(self) -> None:
        self._queue.clear()
