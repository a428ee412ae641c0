"""The host's parametric model of the 2-DOF arm, linear in θ = [θ1..θ9] (Reyes & Kelly 1997).

This is the *model* the host identifies and controls with; the virtual robot's plant is the
*world* and is separate code on purpose (DESIGN.md). Pure functions over numpy arrays: every
function takes samples along the first axis, ``q``, ``dq``, ``ddq`` of shape (N, 2) (or (2,)
for one sample), and returns arrays with the same leading shape.

Conventions (Section 5): q = 0 is the arm hanging down, q2 is relative to link 1, and

    M(q) = [[θ1 + 2θ2 cos q2, θ3 + θ2 cos q2], [θ3 + θ2 cos q2, θ3]]
    C(q, q̇) q̇ = θ2 sin q2 [−(2 q̇1 q̇2 + q̇2²), q̇1²]
    g(q) = [θ4 sin q1 + θ5 sin(q1 + q2), θ5 sin(q1 + q2)]
    f(q̇) = [θ6 q̇1 + θ8 sgn q̇1, θ7 q̇2 + θ9 sgn q̇2]

The regressors split the Lagrangian structure the identification schemes need:
τ = d/dt[P(q, q̇)] θ + R(q, q̇) θ, with P = ∂φ_L/∂q̇ (:func:`momentum_regressor`) and
R = −∂φ_L/∂q + φ_F (:func:`static_regressor`), eqs. (11)-(13).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

N_PARAMS = 9
THETA_NAMES = tuple(f"theta{i}" for i in range(1, N_PARAMS + 1))
THETA_UNITS = ("kg m²", "kg m²", "kg m²", "Nm", "Nm", "Nm s", "Nm s", "Nm", "Nm")
THETA_MEANINGS = (
    "m1 lc1² + m2 l1² + m2 lc2² + I1 + I2",
    "l1 m2 lc2",
    "m2 lc2² + I2",
    "g (lc1 m1 + m2 l1)",
    "g m2 lc2",
    "b1 (viscous, joint 1)",
    "b2 (viscous, joint 2)",
    "fc1 (Coulomb, joint 1)",
    "fc2 (Coulomb, joint 2)",
)


def _pair(x: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(x, dtype=float)
    return a[..., 0], a[..., 1]


def mass_matrix(theta: ArrayLike, q: ArrayLike) -> np.ndarray:
    """M(q), shape (..., 2, 2)   (Reyes & Kelly 1997, Section 5)."""
    t = np.asarray(theta, dtype=float)
    _, q2 = _pair(q)
    c2 = np.cos(q2)
    m11 = t[0] + 2 * t[1] * c2
    m12 = t[2] + t[1] * c2
    m22 = np.full_like(c2, t[2])
    return np.stack([np.stack([m11, m12], -1), np.stack([m12, m22], -1)], -2)


def coriolis_vector(theta: ArrayLike, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
    """C(q, q̇) q̇ = θ2 sin q2 [−(2 q̇1 q̇2 + q̇2²), q̇1²], shape (..., 2)."""
    t2 = float(np.asarray(theta, dtype=float)[1])
    _, q2 = _pair(q)
    dq1, dq2 = _pair(dq)
    s2 = t2 * np.sin(q2)
    return np.stack([-s2 * (2 * dq1 * dq2 + dq2**2), s2 * dq1**2], -1)


def gravity_vector(theta: ArrayLike, q: ArrayLike) -> np.ndarray:
    """g(q) = [θ4 sin q1 + θ5 sin(q1 + q2), θ5 sin(q1 + q2)], shape (..., 2)."""
    t = np.asarray(theta, dtype=float)
    q1, q2 = _pair(q)
    s12 = t[4] * np.sin(q1 + q2)
    return np.stack([t[3] * np.sin(q1) + s12, s12], -1)


def friction_torque(theta: ArrayLike, dq: ArrayLike) -> np.ndarray:
    """f(q̇) = [θ6 q̇1 + θ8 sgn q̇1, θ7 q̇2 + θ9 sgn q̇2], shape (..., 2)   (eq. (12))."""
    t = np.asarray(theta, dtype=float)
    dq1, dq2 = _pair(dq)
    return np.stack([t[5] * dq1 + t[7] * np.sign(dq1), t[6] * dq2 + t[8] * np.sign(dq2)], -1)


def inverse_dynamics(
    theta: ArrayLike, q: ArrayLike, dq: ArrayLike, ddq: ArrayLike, *, friction: bool = True
) -> np.ndarray:
    """τ = M(q) q̈ + C(q, q̇) q̇ + g(q) [+ f(q̇)], shape (..., 2)   (eq. (15))."""
    ddq = np.asarray(ddq, dtype=float)
    tau = (
        np.einsum("...ij,...j->...i", mass_matrix(theta, q), ddq)
        + coriolis_vector(theta, q, dq)
        + gravity_vector(theta, q)
    )
    return tau + friction_torque(theta, dq) if friction else tau


def forward_dynamics(
    theta: ArrayLike, q: ArrayLike, dq: ArrayLike, tau: ArrayLike, *, friction: bool = True
) -> np.ndarray:
    """q̈ = M(q)⁻¹ (τ − C(q, q̇) q̇ − g(q) [− f(q̇)]), shape (..., 2)   (eq. (1)).

    Coulomb friction enters as θ sgn(q̇), with sgn(0) = 0: at standstill this is not the
    stiction that holds a real joint; :mod:`hil.openloop` simulates stick–slip properly.
    """
    rhs = np.asarray(tau, dtype=float) - coriolis_vector(theta, q, dq) - gravity_vector(theta, q)
    if friction:
        rhs = rhs - friction_torque(theta, dq)
    return np.linalg.solve(mass_matrix(theta, q), rhs[..., None])[..., 0]


def dynamic_regressor(q: ArrayLike, dq: ArrayLike, ddq: ArrayLike) -> np.ndarray:
    """Y(q, q̇, q̈) with Y θ = M q̈ + C q̇ + g + f, shape (..., 2, 9)   (eqs. (13), (15))."""
    q1, q2 = _pair(q)
    dq1, dq2 = _pair(dq)
    a1, a2 = _pair(ddq)
    c2, s2 = np.cos(q2), np.sin(q2)
    s1, s12 = np.sin(q1), np.sin(q1 + q2)
    z = np.zeros_like(c2)
    row1 = [
        a1,
        c2 * (2 * a1 + a2) - s2 * (2 * dq1 * dq2 + dq2**2),
        a2,
        s1,
        s12,
        dq1,
        z,
        np.sign(dq1),
        z,
    ]
    row2 = [z, c2 * a1 + s2 * dq1**2, a1 + a2, z, s12, z, dq2, z, np.sign(dq2)]
    return np.stack([np.stack(row1, -1), np.stack(row2, -1)], -2)


def momentum_regressor(q: ArrayLike, dq: ArrayLike) -> np.ndarray:
    """P(q, q̇) = ∂φ_L/∂q̇ with P θ = M(q) q̇ (the generalized momentum), shape (..., 2, 9).

    Row 1: [q̇1, cos q2 (2q̇1 + q̇2), q̇2, 0...]; row 2: [0, cos q2 q̇1, q̇1 + q̇2, 0...]. These are
    the columns the paper filters with λs/(s + λ) in Section 5.1.
    """
    _, q2 = _pair(q)
    dq1, dq2 = _pair(dq)
    c2 = np.cos(q2)
    z = np.zeros_like(c2)
    row1 = [dq1, c2 * (2 * dq1 + dq2), dq2, z, z, z, z, z, z]
    row2 = [z, c2 * dq1, dq1 + dq2, z, z, z, z, z, z]
    return np.stack([np.stack(row1, -1), np.stack(row2, -1)], -2)


def static_regressor(q: ArrayLike, dq: ArrayLike) -> np.ndarray:
    """R(q, q̇) = −∂φ_L/∂q + φ_F with τ = d/dt[P θ] + R θ, shape (..., 2, 9).

    Row 1: [0, 0, 0, sin q1, sin(q1+q2), q̇1, 0, sgn q̇1, 0];
    row 2: [0, sin q2 q̇1 (q̇1 + q̇2), 0, 0, sin(q1+q2), 0, q̇2, 0, sgn q̇2]. These are the columns
    the paper filters with λ/(s + λ) in Section 5.1.
    """
    q1, q2 = _pair(q)
    dq1, dq2 = _pair(dq)
    s12 = np.sin(q1 + q2)
    z = np.zeros_like(s12)
    row1 = [z, z, z, np.sin(q1), s12, dq1, z, np.sign(dq1), z]
    row2 = [z, np.sin(q2) * dq1 * (dq1 + dq2), z, z, s12, z, dq2, z, np.sign(dq2)]
    return np.stack([np.stack(row1, -1), np.stack(row2, -1)], -2)


def energy_regressor(q: ArrayLike, dq: ArrayLike) -> np.ndarray:
    """φ_ℰ(q, q̇) with ℰ = φ_ℰᵀ θ[:5], zero at rest hanging down, shape (..., 5)   (eq. (8)).

    [½ q̇1², cos q2 q̇1 (q̇1 + q̇2), q̇2 (q̇1 + ½ q̇2), 1 − cos q1, 1 − cos(q1 + q2)]  (Section 5.2).
    """
    q1, q2 = _pair(q)
    dq1, dq2 = _pair(dq)
    return np.stack(
        [
            0.5 * dq1**2,
            np.cos(q2) * dq1 * (dq1 + dq2),
            dq2 * (dq1 + 0.5 * dq2),
            1 - np.cos(q1),
            1 - np.cos(q1 + q2),
        ],
        -1,
    )


def friction_power_regressor(dq: ArrayLike) -> np.ndarray:
    """q̇ᵀ φ_F(q̇) = [q̇1², q̇2², |q̇1|, |q̇2|] (the power dissipated, per θ6..θ9), shape (..., 4)."""
    dq1, dq2 = _pair(dq)
    return np.stack([dq1**2, dq2**2, np.abs(dq1), np.abs(dq2)], -1)


def total_energy(theta: ArrayLike, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
    """ℰ = K + U = φ_ℰ(q, q̇)ᵀ θ[:5], shape (...)   (eqs. (5)-(8))."""
    return energy_regressor(q, dq) @ np.asarray(theta, dtype=float)[:5]


def physical_consistency(theta: ArrayLike) -> dict[str, object]:
    """Check that θ describes a physically possible arm, for every configuration.

    M(q) is positive definite for all q2 iff θ3 > 0, θ1 − 2|θ2| > 0 and
    θ1 θ3 − θ3² − θ2² > 0 (the determinant θ1θ3 − θ3² − θ2² cos² q2 at its smallest);
    friction coefficients θ6..θ9 must be ≥ 0. Returns ``{"consistent": bool, "violations": [...]}``
    with one sentence per violated condition.
    """
    t = np.asarray(theta, dtype=float)
    violations = []
    if not t[2] > 0:
        violations.append(f"M(q) not positive definite: theta3 = {t[2]:.4g} <= 0")
    if not t[0] - 2 * abs(t[1]) > 0:
        violations.append(
            f"M(q) not positive definite at q2 = pi: theta1 - 2|theta2| = "
            f"{t[0] - 2 * abs(t[1]):.4g} <= 0"
        )
    det_min = t[0] * t[2] - t[2] ** 2 - t[1] ** 2
    if not det_min > 0:
        violations.append(f"M(q) not positive definite at q2 = 0: min det = {det_min:.4g} <= 0")
    for i in range(5, 9):
        if not t[i] >= 0:
            violations.append(f"negative friction coefficient: theta{i + 1} = {t[i]:.4g}")
    return {"consistent": not violations, "violations": violations}
