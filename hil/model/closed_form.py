"""The host's parametric model of the 2-DOF arm, linear in θ = [θ1..θ9] (Reyes & Kelly 1997).

This is the *model* the host identifies and controls with; the virtual robot's plant is the
*world* and is separate code on purpose (docs/design.md). Pure functions over numpy arrays: every
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

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from profiles.robot import TERMS as ROBOT_PROFILE_TERMS

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
    stiction that holds a real joint; :mod:`hil.model.openloop` simulates stick–slip properly.
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


# ---- the model object -------------------------------------------------------------------------
#
# The 9-parameter model above is a rigid arm whose links have their centres of mass on the link
# axis and whose motors add nothing to the inertia. Real arms have two more effects, written here
# from the Lagrangian of the arm with them (Reyes & Kelly 1997, eqs. (5)-(8), extended):
#
# ``rotor_inertia`` (reflected rotor inertia, armature). Motor 2 sits on link 1 and turns its
# rotor by q1 ± gr q2 (gear ratio gr); motor 1's rotor turns by gr q1. Their kinetic energy
#     K_r = ½ Ir (gr q̇1)² + ½ Ir (q̇1 ± gr q̇2)²
# adds (gr² + 1) Ir to M11, ± gr Ir to M12 and gr² Ir to M22 (the DFKI README's model, with
# the minus sign of their ``plant.py``). The constant parts of M11 and M12 are already free
# parameters (θ1 and θ3), so the one new base parameter is the part of M22 beyond M12's
# constant part:
#     θ_rotor = M22 − (θ3 + θ2 cos q2 − θ2 cos q2) = gr² Ir ∓ gr Ir      (kg m²),
# and the arm's rigid M12 = M22 of the 9-parameter model no longer holds. Kinetic energy term
# ½ θ_rotor q̇2², no potential energy (the rotor's mass is part of link 1's).
#
# ``com_offset`` (centre of mass off the link axis). With link i's centre of mass at lc_i along
# the link and ly_i across it (positive towards increasing q), link 2's centre of mass is at
#     p2 = l1 e(q1) + lc2 e(q1 + q2) + ly2 n(q1 + q2)
# with e(φ) = (sin φ, −cos φ) along a link and n(φ) = (cos φ, sin φ) across it,
# so ½ m2 |ṗ2|² carries l1 m2 q̇1 (q̇1 + q̇2)(lc2 cos q2 − ly2 sin q2), and the potential energy
# gains g m2 ly2 sin(q1 + q2) + g m1 ly1 sin q1. Three new base parameters:
#     θ2⊥ = l1 m2 ly2 (kg m²),  θ4⊥ = g m1 ly1 (Nm),  θ5⊥ = g m2 ly2 (Nm),
# i.e. M11 += −2θ2⊥ sin q2, M12 += −θ2⊥ sin q2, C q̇ += θ2⊥ cos q2 [−(2q̇1q̇2 + q̇2²), q̇1²],
# g += [θ4⊥ cos q1 + θ5⊥ cos(q1 + q2), θ5⊥ cos(q1 + q2)]. These are the remaining base
# parameters of a planar 2R arm (its θ2 cos q2 − θ2⊥ sin q2 = ρ cos(q2 + φ)); an encoder zero
# offset of δ also shows up here (θ4 sin(q1 + δ) = θ4 cos δ sin q1 + θ4 sin δ cos q1).

TERMS = ROBOT_PROFILE_TERMS  # the terms a robot profile may name, in this order
_TERM_NAMES = {
    "rotor_inertia": ("theta_rotor",),
    "com_offset": ("theta2_perp", "theta4_perp", "theta5_perp"),
}
_TERM_UNITS = {"rotor_inertia": ("kg m²",), "com_offset": ("kg m²", "Nm", "Nm")}
_TERM_MEANINGS = {
    "rotor_inertia": ("reflected rotor inertia of motor 2: M22 − M12 beyond θ3 (gr² Ir ∓ gr Ir)",),
    "com_offset": (
        "l1 m2 ly2 (link 2 centre of mass across the link)",
        "g m1 ly1 (link 1 centre of mass across the link; also an encoder zero offset)",
        "g m2 ly2",
    ),
}
FRICTION_COLUMNS = (5, 6, 7, 8)  # θ6, θ7 (viscous), θ8, θ9 (Coulomb)
ENERGY_COLUMNS_BASE = 5  # θ1..θ5 enter the energy


def _term_momentum(term: str, q1, q2, dq1, dq2) -> list:
    """Columns of P = ∂φ_L/∂q̇ a term adds, as [(row1, row2) per parameter]."""
    z = np.zeros_like(q2)
    if term == "rotor_inertia":
        return [(z, dq2)]  # ∂(½ θ q̇2²)/∂q̇
    s2 = np.sin(q2)  # ∂(−θ2⊥ sin q2 q̇1 (q̇1 + q̇2))/∂q̇
    return [(-s2 * (2 * dq1 + dq2), -s2 * dq1), (z, z), (z, z)]


def _term_static(term: str, q1, q2, dq1, dq2) -> list:
    """Columns of R = −∂φ_L/∂q a term adds (it has no friction)."""
    z = np.zeros_like(q2)
    if term == "rotor_inertia":
        return [(z, z)]
    c12 = np.cos(q1 + q2)
    # −∂K/∂q2 of −θ2⊥ sin q2 q̇1(q̇1 + q̇2); ∂U/∂q of θ4⊥ sin q1, θ5⊥ sin(q1 + q2)
    return [(z, np.cos(q2) * dq1 * (dq1 + dq2)), (np.cos(q1), z), (c12, c12)]


def _term_energy(term: str, q1, q2, dq1, dq2) -> list:
    """Columns of φ_ℰ (ℰ = K + U, zero hanging at rest) a term adds."""
    if term == "rotor_inertia":
        return [0.5 * dq2**2]
    return [-np.sin(q2) * dq1 * (dq1 + dq2), np.sin(q1), np.sin(q1 + q2)]


def _stack_rows(cols: list) -> np.ndarray:
    """[(row1, row2) per column] → (..., 2, p)."""
    return np.stack([np.stack([c[0] for c in cols], -1), np.stack([c[1] for c in cols], -1)], -2)


def _shifted(q: ArrayLike, joint: int, shifts: ArrayLike) -> list[np.ndarray]:
    """q (..., 2) with ``joint``'s coordinate shifted by each of ``shifts``."""
    out = []
    for s in np.atleast_1d(np.asarray(shifts, float)):
        q_s = np.array(q, dtype=float)
        q_s[..., joint] += s
        out.append(q_s)
    return out


@dataclass(frozen=True)
class ArmModel:
    """The planar 2R arm's rigid-body model, linear in named parameters θ.

    ``ArmModel(())`` is exactly the 9-parameter model of the module functions (same columns,
    same numbers); each entry of ``terms`` (from :data:`TERMS`) appends its parameters after
    θ9, in that order. Every method takes samples along the leading axes like the module
    functions. The identification and diagnosis take a model object, so a different model
    (e.g. one built from a URDF) can stand in with the same methods.
    """

    terms: tuple[str, ...] = ()
    n_joints = 2  # a class constant (no annotation: not a field), as UrdfArmModel.n_joints
    closed_form = True  # hil.model.protocol.ArmDynamics: the compiled 2-DOF simulator applies
    revolute = (True, True)  # both joints turn

    def __post_init__(self) -> None:
        terms = tuple(self.terms)
        object.__setattr__(self, "terms", terms)
        for term in terms:
            if term not in TERMS:
                raise ValueError(f"unknown model term {term!r}; expected one of {', '.join(TERMS)}")
        if len(set(terms)) != len(terms):
            raise ValueError(f"model terms repeat: {', '.join(terms)}")

    # --- names -------------------------------------------------------------------------------
    @property
    def names(self) -> tuple[str, ...]:
        return THETA_NAMES + sum((_TERM_NAMES[t] for t in self.terms), ())

    @property
    def units(self) -> tuple[str, ...]:
        return THETA_UNITS + sum((_TERM_UNITS[t] for t in self.terms), ())

    @property
    def meanings(self) -> tuple[str, ...]:
        return THETA_MEANINGS + sum((_TERM_MEANINGS[t] for t in self.terms), ())

    @property
    def n_params(self) -> int:
        return len(self.names)

    def term_columns(self, term: str) -> slice:
        """The columns of θ that ``term`` owns."""
        start = N_PARAMS
        for t in self.terms:
            width = len(_TERM_NAMES[t])
            if t == term:
                return slice(start, start + width)
            start += width
        raise KeyError(f"model has no term {term!r} (terms: {', '.join(self.terms) or 'none'})")

    @property
    def rigid_count(self) -> int:
        """θ1..θ5 are the rigid-body parameters (θ6..θ9 friction, then the terms')."""
        return 5

    @property
    def display_name(self) -> str:
        if not self.terms:
            return "9-parameter"
        return f"{self.n_params}-parameter ({' and '.join(self.terms)})"

    @property
    def rigid_words(self) -> str:
        return "θ1..θ5 of the 2-DOF arm"

    @property
    def missing_terms(self) -> tuple[str, ...]:
        return tuple(t for t in TERMS if t not in self.terms)

    @property
    def refused_terms(self) -> dict[str, str]:
        """Every candidate of the diagnosis applies to the closed-form model."""
        return {}

    @property
    def friction_columns(self) -> tuple[int, ...]:
        """θ6, θ7 (viscous b1, b2), θ8, θ9 (Coulomb fc1, fc2): bounded ≥ 0."""
        return FRICTION_COLUMNS

    @property
    def nonnegative_columns(self) -> tuple[int, ...]:
        """Columns that are ≥ 0 for any physical arm: friction and the rotor inertia."""
        extra = ()
        if "rotor_inertia" in self.terms:
            extra = (self.term_columns("rotor_inertia").start,)
        return FRICTION_COLUMNS + extra

    def _theta(self, theta: ArrayLike) -> np.ndarray:
        t = np.asarray(theta, dtype=float)
        if t.shape != (self.n_params,):
            raise ValueError(f"theta must hold {self.n_params} numbers, got shape {t.shape}")
        return t

    # --- regressors --------------------------------------------------------------------------
    def _with_terms(self, base: np.ndarray, columns, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """``base`` (..., 2, 9) with each term's (row1, row2) columns from ``columns`` appended."""
        if not self.terms:
            return base
        q1, q2 = _pair(q)
        dq1, dq2 = _pair(dq)
        extra = [c for t in self.terms for c in columns(t, q1, q2, dq1, dq2)]
        return np.concatenate([base, _stack_rows(extra)], -1)

    def momentum_regressor(self, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """P(q, q̇) with P θ = M(q) q̇, shape (..., 2, p)."""
        return self._with_terms(momentum_regressor(q, dq), _term_momentum, q, dq)

    def static_regressor(self, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """R(q, q̇) = −∂φ_L/∂q + φ_F with τ = d/dt[P θ] + R θ, shape (..., 2, p)."""
        return self._with_terms(static_regressor(q, dq), _term_static, q, dq)

    def momentum(self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """P(q, q̇) θ = M(q) q̇, shape (..., 2) (as :meth:`UrdfArmModel.momentum`)."""
        return self.momentum_regressor(q, dq) @ self._theta(theta)

    def static_torque(self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """R(q, q̇) θ, shape (..., 2) (as :meth:`UrdfArmModel.static_torque`)."""
        return self.static_regressor(q, dq) @ self._theta(theta)

    def momentum_at_shifts(
        self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike, joint: int, shifts: ArrayLike
    ) -> np.ndarray:
        """:meth:`momentum` at q + s e_``joint`` for each s of ``shifts`` (S,), (S, ..., 2)."""
        return np.stack([self.momentum(theta, q_s, dq) for q_s in _shifted(q, joint, shifts)])

    def static_torque_at_shifts(
        self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike, joint: int, shifts: ArrayLike
    ) -> np.ndarray:
        """:meth:`static_torque` at q + s e_``joint`` for each s of ``shifts``, (S, ..., 2)."""
        return np.stack([self.static_torque(theta, q_s, dq) for q_s in _shifted(q, joint, shifts)])

    def dynamic_regressor(self, q: ArrayLike, dq: ArrayLike, ddq: ArrayLike) -> np.ndarray:
        """Y(q, q̇, q̈) with Y θ = M q̈ + C q̇ + g + f, shape (..., 2, p)."""
        base = dynamic_regressor(q, dq, ddq)
        if not self.terms:
            return base
        q1, q2 = _pair(q)
        dq1, dq2 = _pair(dq)
        a1, a2 = _pair(ddq)
        c2, s2 = np.cos(q2), np.sin(q2)
        z = np.zeros_like(q2)
        cols = []
        for t in self.terms:
            if t == "rotor_inertia":  # d/dt (θ q̇2) on joint 2
                cols.append((z, a2))
            else:  # the θ2 column with q2 → q2 + π/2, then the cos gravity columns
                cols.append(
                    (-s2 * (2 * a1 + a2) - c2 * (2 * dq1 * dq2 + dq2**2), -s2 * a1 + c2 * dq1**2)
                )
                c12 = np.cos(q1 + q2)
                cols += [(np.cos(q1), z), (c12, c12)]
        return np.concatenate([base, _stack_rows(cols)], -1)

    def energy_regressor(self, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """φ_ℰ with ℰ = K + U = φ_ℰ θ (zero at rest hanging down), shape (..., p); the friction
        columns are zero."""
        q1, q2 = _pair(q)
        dq1, dq2 = _pair(dq)
        base = energy_regressor(q, dq)
        z = np.zeros((*base.shape[:-1], 4))
        extra = [c for t in self.terms for c in _term_energy(t, q1, q2, dq1, dq2)]
        parts = [base, z] + ([np.stack(extra, -1)] if extra else [])
        return np.concatenate(parts, -1)

    def friction_power_regressor(self, dq: ArrayLike) -> np.ndarray:
        """q̇ᵀ φ_F(q̇) on the friction columns (zero elsewhere), shape (..., p)."""
        fp = friction_power_regressor(dq)
        out = np.zeros((*fp.shape[:-1], self.n_params))
        out[..., list(FRICTION_COLUMNS)] = fp
        return out

    # --- dynamics ----------------------------------------------------------------------------
    def mass_matrix(self, theta: ArrayLike, q: ArrayLike) -> np.ndarray:
        """M(q), shape (..., 2, 2); column j is P(q, e_j) θ."""
        t = self._theta(theta)
        if not self.terms:
            return mass_matrix(t, q)
        qa = np.asarray(q, dtype=float)
        cols = [
            self.momentum_regressor(qa, np.broadcast_to(e, qa.shape)) @ t
            for e in (np.array([1.0, 0.0]), np.array([0.0, 1.0]))
        ]
        return np.stack(cols, -1)

    def coriolis_vector(self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """C(q, q̇) q̇, shape (..., 2)."""
        t = self._theta(theta)
        if not self.terms:
            return coriolis_vector(t, q, dq)
        qa = np.asarray(q, dtype=float)
        Y = self.dynamic_regressor(qa, dq, np.zeros(np.shape(dq)))
        keep = np.zeros(self.n_params)
        keep[1] = 1.0
        if "com_offset" in self.terms:
            keep[self.term_columns("com_offset").start] = 1.0
        return Y @ (t * keep)

    def gravity_vector(self, theta: ArrayLike, q: ArrayLike) -> np.ndarray:
        """g(q), shape (..., 2)."""
        t = self._theta(theta)
        if not self.terms:
            return gravity_vector(t, q)
        qa = np.asarray(q, dtype=float)
        zero = np.zeros(qa.shape)
        keep = np.zeros(self.n_params)
        keep[[3, 4]] = 1.0
        if "com_offset" in self.terms:
            c = self.term_columns("com_offset")
            keep[c.start + 1 : c.stop] = 1.0
        return self.dynamic_regressor(qa, zero, zero) @ (t * keep)

    def friction_torque(self, theta: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """f(q̇) = [θ6 q̇1 + θ8 sgn q̇1, θ7 q̇2 + θ9 sgn q̇2], shape (..., 2)."""
        return friction_torque(self._theta(theta)[:N_PARAMS], dq)

    def torque(self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike, ddq: ArrayLike) -> np.ndarray:
        """τ = M q̈ + C q̇ + g + f = Y(q, q̇, q̈) θ, shape (..., 2)."""
        t = self._theta(theta)
        if not self.terms:
            return inverse_dynamics(t, q, dq, ddq)
        return self.dynamic_regressor(q, dq, ddq) @ t

    def forward_dynamics(
        self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike, tau: ArrayLike
    ) -> np.ndarray:
        """q̈ = M⁻¹ (τ − C q̇ − g − f), shape (..., 2) (sgn(0) = 0: no stiction)."""
        t = self._theta(theta)
        if not self.terms:
            return forward_dynamics(t, q, dq, tau)
        rhs = (
            np.asarray(tau, dtype=float) - self.dynamic_regressor(q, dq, np.zeros(np.shape(dq))) @ t
        )
        return np.linalg.solve(self.mass_matrix(t, q), rhs[..., None])[..., 0]

    def total_energy(self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """ℰ = K + U, shape (...)."""
        return self.energy_regressor(q, dq) @ self._theta(theta)

    def physical_consistency(self, theta: ArrayLike) -> dict[str, object]:
        """M(q) positive definite for every q2, friction ≥ 0, rotor inertia ≥ 0, in closed form.

        With x = θ2 cos q2 − θ2⊥ sin q2 ∈ [−ρ, ρ] (ρ = √(θ2² + θ2⊥²)) and m22 = θ3 + θ_rotor,
        M = [[θ1 + 2x, θ3 + x], [θ3 + x, m22]]; det = (θ1 + 2x) m22 − (θ3 + x)² is concave in
        x, so M ≻ 0 for all q2 iff m22 > 0 and det > 0 at x = ±ρ. For ``terms=()`` this is
        :func:`physical_consistency` (same messages)."""
        t = self._theta(theta)
        if not self.terms:
            return physical_consistency(t)
        violations = self.mass_matrix_violations(t)
        for i in self.nonnegative_columns:
            if not t[i] >= 0:
                violations.append(f"negative {self.names[i]} = {t[i]:.4g} (must be >= 0)")
        return {"consistent": not violations, "violations": violations}

    def with_terms(self, terms: tuple[str, ...]) -> ArmModel:
        """This model with ``terms`` appended (their parameters after this model's)."""
        return ArmModel(self.terms + tuple(terms))

    def expand(self, theta: ArrayLike) -> np.ndarray:
        """θ in the parametrisation of ``ArmModel(TERMS)`` (every term, in :data:`TERMS`
        order), zero for the terms this model lacks: the form the host's open-loop simulator
        (:mod:`hil.model.openloop_core`) takes."""
        t = self._theta(theta)
        full = ArmModel(TERMS)
        out = np.zeros(full.n_params)
        out[:N_PARAMS] = t[:N_PARAMS]
        for term in self.terms:
            out[full.term_columns(term)] = t[self.term_columns(term)]
        return out

    def mass_matrix_violations(self, theta: ArrayLike) -> list[str]:
        """Why M(q) is not positive definite for every q2 (empty when it is), in closed form
        (:meth:`physical_consistency`'s first part)."""
        t = self._theta(theta)
        if not self.terms:
            return [v for v in physical_consistency(t)["violations"] if v.startswith("M(q)")]
        rot = t[self.term_columns("rotor_inertia")][0] if "rotor_inertia" in self.terms else 0.0
        perp = "com_offset" in self.terms
        perp_value = t[self.term_columns("com_offset")][0] if perp else 0.0
        rho = float(np.hypot(t[1], perp_value))
        m22 = t[2] + rot
        violations = []
        if not m22 > 0:
            violations.append(
                f"M(q) not positive definite: M22 = theta3 + theta_rotor = {m22:.4g} <= 0"
            )
        for x in (rho, -rho):
            det = (t[0] + 2 * x) * m22 - (t[2] + x) ** 2
            if not det > 0:
                where = "theta2 cos q2" + (" - theta2_perp sin q2" if perp else "")
                violations.append(
                    f"M(q) not positive definite where {where} = {x:.4g}: det = {det:.4g} <= 0"
                )
        return violations

    def min_mass_eigenvalue(self, theta: ArrayLike, n_grid: int = 73) -> float:
        """The smallest eigenvalue of M(q) over q2 ∈ [−π, π] (on a grid), kg m²."""
        q = np.zeros((n_grid, 2))
        q[:, 1] = np.linspace(-np.pi, np.pi, n_grid)
        return float(np.linalg.eigvalsh(self.mass_matrix(theta, q)).min())


def robot_model(profile: object) -> ArmModel:
    """The model a robot profile says its arm has (``profile.terms``; none: the 9-parameter)."""
    return ArmModel(tuple(getattr(profile, "terms", ()) or ()))


__all__ = [
    "N_PARAMS",
    "TERMS",
    "THETA_MEANINGS",
    "THETA_NAMES",
    "THETA_UNITS",
    "ArmModel",
    "coriolis_vector",
    "dynamic_regressor",
    "energy_regressor",
    "forward_dynamics",
    "friction_power_regressor",
    "friction_torque",
    "gravity_vector",
    "inverse_dynamics",
    "mass_matrix",
    "momentum_regressor",
    "physical_consistency",
    "robot_model",
    "static_regressor",
    "total_energy",
]
