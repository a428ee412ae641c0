"""Rigid-body dynamics of the 2-DOF vertical arm, Reyes & Kelly (1997) Section 5.

Pure functions over numpy arrays. ``theta`` is the inertial part θ1..θ5 (extra entries are ignored),
``q`` and ``dq`` are joint angles and rates (q = 0: arm hanging down, q2 relative to link 1).
These are the reference equations; :mod:`virtual_robot.plant` unrolls the same expressions into
scalar code for speed, and a test checks the two agree.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike


def mass_matrix(theta: ArrayLike, q: ArrayLike) -> np.ndarray:
    """M(q) = [[θ1 + 2θ2 cos q2, θ3 + θ2 cos q2], [θ3 + θ2 cos q2, θ3]]   (Section 5)."""
    t1, t2, t3 = np.asarray(theta, dtype=float)[:3]
    c2 = np.cos(np.asarray(q, dtype=float)[1])
    return np.array([[t1 + 2 * t2 * c2, t3 + t2 * c2], [t3 + t2 * c2, t3]])


def coriolis_matrix(theta: ArrayLike, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
    """C(q, q̇) = [[−2θ2 sin q2 q̇2, −θ2 sin q2 q̇2], [θ2 sin q2 q̇1, 0]]   (Section 5)."""
    t2 = float(np.asarray(theta, dtype=float)[1])
    s2 = np.sin(np.asarray(q, dtype=float)[1])
    dq1, dq2 = np.asarray(dq, dtype=float)
    return np.array([[-2 * t2 * s2 * dq2, -t2 * s2 * dq2], [t2 * s2 * dq1, 0.0]])


def coriolis_vector(theta: ArrayLike, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
    """C(q, q̇) q̇ = θ2 sin q2 [−(2 q̇1 q̇2 + q̇2²), q̇1²]."""
    return coriolis_matrix(theta, q, dq) @ np.asarray(dq, dtype=float)


def gravity_vector(theta: ArrayLike, q: ArrayLike) -> np.ndarray:
    """g(q) = [θ4 sin q1 + θ5 sin(q1 + q2), θ5 sin(q1 + q2)]   (Section 5, g = ∂U/∂q, eq. (2))."""
    t4, t5 = np.asarray(theta, dtype=float)[3:5]
    q1, q2 = np.asarray(q, dtype=float)
    s12 = np.sin(q1 + q2)
    return np.array([t4 * np.sin(q1) + t5 * s12, t5 * s12])


def kinetic_energy(theta: ArrayLike, q: ArrayLike, dq: ArrayLike) -> float:
    """K = ½ q̇ᵀ M(q) q̇   (eq. (6))."""
    dq = np.asarray(dq, dtype=float)
    return float(0.5 * dq @ mass_matrix(theta, q) @ dq)


def potential_energy(theta: ArrayLike, q: ArrayLike) -> float:
    """U = θ4 (1 − cos q1) + θ5 (1 − cos(q1 + q2)), zero hanging down   (eq. (7), Section 5.2)."""
    t4, t5 = np.asarray(theta, dtype=float)[3:5]
    q1, q2 = np.asarray(q, dtype=float)
    return float(t4 * (1 - np.cos(q1)) + t5 * (1 - np.cos(q1 + q2)))


def total_energy(theta: ArrayLike, q: ArrayLike, dq: ArrayLike) -> float:
    """ℰ = K + U   (eq. (5))."""
    return kinetic_energy(theta, q, dq) + potential_energy(theta, q)


def forward_dynamics(theta: ArrayLike, q: ArrayLike, dq: ArrayLike, tau: ArrayLike) -> np.ndarray:
    """q̈ = M(q)⁻¹ (τ − C(q, q̇) q̇ − g(q)), τ net of friction   (eq. (1))."""
    rhs = np.asarray(tau, dtype=float) - coriolis_vector(theta, q, dq) - gravity_vector(theta, q)
    return np.linalg.solve(mass_matrix(theta, q), rhs)


def inverse_dynamics(theta: ArrayLike, q: ArrayLike, dq: ArrayLike, ddq: ArrayLike) -> np.ndarray:
    """τ = M(q) q̈ + C(q, q̇) q̇ + g(q), without friction   (eq. (1))."""
    return (
        mass_matrix(theta, q) @ np.asarray(ddq, dtype=float)
        + coriolis_vector(theta, q, dq)
        + gravity_vector(theta, q)
    )
