"""Reference trajectories for tracking: point-to-point quintic moves joined by holds.

Khosla & Kanade (1987), Section 4.2: each joint moves between rest positions, the points of
discontinuity joined by fifth-order polynomials so that position, velocity and acceleration are
continuous. Adapted to the Reyes & Kelly arm (``profiles/experiments/khosla-kanade-tracking.toml``):
from q = 0, each joint visits ``amplitude · pattern[i]`` in turn, every move taking ``move_s`` and
followed by a hold of ``hold_s``.

A move from a to b over T seconds, with τ = (t − t0)/T ∈ [0, 1]:

    q(t)  = a + (b − a) s(τ),       s(τ)  = 10τ³ − 15τ⁴ + 6τ⁵
    q̇(t)  = (b − a) s′(τ) / T,      s′(τ) = 30τ² − 60τ³ + 30τ⁴      (peak 1.875 at τ = ½)
    q̈(t)  = (b − a) s″(τ) / T²,     s″(τ) = 60τ − 180τ² + 120τ³     (peak 10/√3 ≈ 5.774)

s(0) = 0, s(1) = 1 and s′, s″ vanish at both ends: the moves join the holds with continuous
position, velocity and acceleration (the jerk steps). Pure functions of t, vectorized over t.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

QUINTIC_PEAK_VELOCITY = 1.875  # max s′(τ), at τ = 1/2
QUINTIC_PEAK_ACCELERATION = 10.0 / math.sqrt(3.0)  # max |s″(τ)|, at τ = 1/2 ∓ √3/6


def quintic(tau: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """s(τ), s′(τ), s″(τ) of the rest-to-rest quintic, τ clipped to [0, 1]."""
    x = np.clip(np.asarray(tau, dtype=float), 0.0, 1.0)
    x2 = x * x
    s = x2 * x * (10.0 - 15.0 * x + 6.0 * x2)
    ds = 30.0 * x2 * (1.0 - 2.0 * x + x2)
    dds = 60.0 * x * (1.0 - 3.0 * x + 2.0 * x2)
    return s, ds, dds


@dataclass(frozen=True)
class PointToPoint:
    """Rest-to-rest quintic moves through ``targets[j]`` for each joint j, all joints in step.

    Joint j starts at ``start[j]`` at t = 0 (after ``start_hold_s``), then for i = 0, 1, …
    moves to ``targets[j][i]`` in ``move_s`` and holds it for ``hold_s``. After the last hold
    (or beyond ``duration_s``) it stays at its last target.
    """

    start: tuple[float, ...]
    targets: tuple[tuple[float, ...], ...]  # [joint][move]
    move_s: float
    hold_s: float
    start_hold_s: float = 0.0

    def __post_init__(self) -> None:
        if not self.move_s > 0 or self.hold_s < 0 or self.start_hold_s < 0:
            raise ValueError("move_s must be > 0; hold_s and start_hold_s >= 0")
        if len(self.targets) != len(self.start):
            raise ValueError(f"{len(self.start)} start positions but {len(self.targets)} joints")
        if len({len(t) for t in self.targets}) != 1 or not self.targets[0]:
            raise ValueError("every joint needs the same number (> 0) of targets")

    @property
    def n_joints(self) -> int:
        return len(self.start)

    @property
    def n_moves(self) -> int:
        return len(self.targets[0])

    @property
    def duration_s(self) -> float:
        """Time to the end of the last hold."""
        return self.start_hold_s + self.n_moves * (self.move_s + self.hold_s)

    def at(self, t: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q_d, q̇_d, q̈_d at time(s) t: shape (n_joints,) for a scalar t, else (len(t), n_joints)."""
        t_arr = np.asarray(t, dtype=float)
        scalar = t_arr.ndim == 0
        t_arr = np.atleast_1d(t_arr)
        slot = self.move_s + self.hold_s
        local = t_arr - self.start_hold_s
        index = np.clip(np.floor(local / slot), 0, self.n_moves - 1).astype(int)
        tau = np.where(local < 0, 0.0, (local - index * slot) / self.move_s)
        s, ds, dds = quintic(tau)
        q = np.empty((t_arr.size, self.n_joints))
        dq = np.empty_like(q)
        ddq = np.empty_like(q)
        for j in range(self.n_joints):
            points = np.array((self.start[j], *self.targets[j]))
            a, b = points[index], points[index + 1]
            q[:, j] = a + (b - a) * s
            dq[:, j] = (b - a) * ds / self.move_s
            ddq[:, j] = (b - a) * dds / self.move_s**2
        if scalar:
            return q[0], dq[0], ddq[0]
        return q, dq, ddq

    def peaks(self) -> dict[str, list[float]]:
        """Largest |q̇_d| and |q̈_d| per joint (the largest step over the quintic's peaks)."""
        out: dict[str, list[float]] = {"velocity_rad_s": [], "acceleration_rad_s2": []}
        for j in range(self.n_joints):
            points = np.array((self.start[j], *self.targets[j]))
            step = float(np.max(np.abs(np.diff(points))))
            out["velocity_rad_s"].append(step * QUINTIC_PEAK_VELOCITY / self.move_s)
            out["acceleration_rad_s2"].append(step * QUINTIC_PEAK_ACCELERATION / self.move_s**2)
        return out


def khosla_kanade_moves(
    amplitude_rad: tuple[float, ...],
    pattern: tuple[float, ...],
    *,
    move_s: float,
    hold_s: float,
    start_hold_s: float = 0.0,
) -> PointToPoint:
    """Section 4.2 adapted: from 0, joint j visits amplitude[j]·pattern[i] (e.g. 1, 0, −1, 0)."""
    return PointToPoint(
        start=tuple(0.0 for _ in amplitude_rad),
        targets=tuple(tuple(a * p for p in pattern) for a in amplitude_rad),
        move_s=move_s,
        hold_s=hold_s,
        start_hold_s=start_hold_s,
    )


__all__ = [
    "PointToPoint",
    "khosla_kanade_moves",
    "quintic",
]
