"""An n-joint arm's model from a URDF through Pinocchio, linear in its base parameters.

The same interface as :class:`hil.model.closed_form.ArmModel` (contracts: names, units, meanings,
M(q),
C(q, q̇) q̇, g(q), friction, τ, the torque regressor, the momentum/static split and the energy
regressors), for any serial arm of revolute or prismatic joints a URDF describes, plus what a
URDF does not hold (:class:`profiles.robot.UrdfRobotProfile`: viscous and Coulomb friction per
joint, rotor inertia (armature), gear ratio).

Parameters. The *standard* parameters are, per moving body j, Pinocchio's ten dynamic parameters
π_j = [m, m c_x, m c_y, m c_z, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz] (first and second moments
about joint j's frame), then per joint the armature I_a (with the ``rotor_inertia`` term), and
per joint the viscous f_v and Coulomb f_c coefficients. Many standard parameters do not act on
the joint torques alone or act only in fixed combinations; the *base* parameters are a minimal
set of combinations that do, found numerically: the torque regressor is stacked over random
samples (q, q̇, q̈), QR with column pivoting picks r independent columns W₁ and expresses the
others as W₂ = W₁ K, so Y θ_std = Y₁ (θ₁ + K θ₂) and θ_base = θ₁ + K θ₂ (Gautier (1991),
numerical route). Every method here takes and returns base parameters unless named ``standard``;
each base parameter's meaning is its combination of standard ones.

Regressors (Reyes & Kelly (1997) eqs. (11)-(13)): with the Lagrangian L = φ_K θ − φ_P θ,

    τ = d/dt[P θ] + R θ,   P = ∂φ_K/∂q̇,   R = −∂φ_K/∂q + ∂φ_P/∂q + φ_F.

P θ = M(q) q̇ is the torque regressor of q̈ = q̇ at rest without gravity; ∂φ_P/∂q is the torque
regressor at rest; ∂φ_K/∂q is exact too, from each body's spatial velocity v and its analytic
derivative ∂v/∂q (Pinocchio's kinematic derivatives): ∂(½ vᵀ I v)/∂q_i = vᵀ I ∂v/∂q_i.

Pure numpy on top of Pinocchio (``pin`` on PyPI); samples along the first axis as in
:mod:`hil.model.closed_form`. Imports :mod:`profiles.robot` only for the profile type.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike
from scipy.linalg import qr

from hil.model.urdf_dynamics import Chain, UrdfDynamics, by_chunks
from profiles.robot import UrdfRobotProfile, load_urdf_robot

TERMS = ("rotor_inertia", "friction_offset")
BODY_PARAMS = ("m", "mx", "my", "mz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
BODY_UNITS = ("kg", "kg m", "kg m", "kg m", *(("kg m²",) * 6))
# Random samples for the base-parameter QR: enough rows to make every structural dependency
# show and no accidental one (rows = samples × joints ≫ standard parameters).
BASE_SAMPLES = 400
# A column is dependent when its pivot is below this fraction of the largest pivot. Structural
# zeros come out near 1e-15 relative; genuine columns of real arms are above 1e-6.
RANK_TOL = 1e-9
# states per pass of the batched regressor rows: a pass holds ~n² × 30 floats a state (∂V_j/∂q_i
# and the bilinear rows), 16 MB at 4096 states of a 7-joint arm
REGRESSOR_STATES_PER_CHUNK = 4096
# Configurations at which a base-parameter vector's M(q) must be positive definite.
CONSISTENCY_SAMPLES = 256


@dataclass(frozen=True)
class BaseParameters:
    """θ_base = θ_std[independent] + K θ_std[dependent]; ``expand`` is the (p_base, p_std) map."""

    independent: np.ndarray  # indices into the standard parameters, in base order
    dependent: np.ndarray
    K: np.ndarray  # (len(independent), len(dependent))
    expand: np.ndarray  # (p_base, p_std): θ_base = expand @ θ_std


class UrdfArmModel:
    """M, C q̇, g, friction and regressors of an n-joint arm described by a URDF (see module doc).

    Terms (:data:`TERMS`): ``rotor_inertia`` adds one armature parameter per joint (I_a q̈ at
    joint i, the rotor inertia reflected through the gear, gr² I_rotor); ``friction_offset``
    adds a constant torque per joint (asymmetric Coulomb friction, torque-sensor offset). The
    rigid-body part comes from the URDF; ``viscous``/``coulomb``/``friction_offset``/
    ``armature`` give the nominal (reference) values of the other standard parameters.
    ``gear_ratio`` is kept for the drives; the dynamics take the armature already reflected.
    """

    closed_form = False  # hil.model.protocol.ArmDynamics: simulated through forward_dynamics

    def __init__(
        self,
        urdf: str | Path,
        *,
        gravity_m_s2: float = 9.81,
        viscous: ArrayLike | None = None,
        coulomb: ArrayLike | None = None,
        friction_offset: ArrayLike | None = None,
        armature: ArrayLike | None = None,
        gear_ratio: ArrayLike | None = None,
        terms: tuple[str, ...] = (),
        name: str = "",
        seed: int = 0,
    ) -> None:
        for term in terms:
            if term not in TERMS:
                raise ValueError(f"unknown model term {term!r}; one of {', '.join(TERMS)}")
        self.urdf = str(urdf)
        self.name = name
        self.terms = tuple(terms)
        self._model = m = _build(self.urdf)
        if m.nq != m.nv or any(j.nq != 1 for j in m.joints[1:]):
            raise ValueError(
                f"{self.urdf}: only 1-DOF revolute/prismatic joints are supported "
                f"(nq = {m.nq}, nv = {m.nv})"
            )
        m.gravity.linear = np.array([0.0, 0.0, -gravity_m_s2])
        self.n_joints = n = m.nv
        self.joint_names = tuple(m.names[1:])
        self._data = m.createData()
        self._free = pin.Model(m)  # the same arm without gravity: M q̈ and C q̇ alone
        self._free.gravity.linear = np.zeros(3)
        self._free_data = self._free.createData()
        self._chain = Chain(m)
        self.revolute = self._chain.revolute  # hil.model.protocol.ArmDynamics

        def per_joint(x: ArrayLike | None, default: float, what: str) -> np.ndarray:
            a = np.full(n, default) if x is None else np.asarray(x, dtype=float)
            if a.shape != (n,):
                raise ValueError(f"{what}: need {n} values (one per joint), got {a.shape}")
            return a

        self.viscous = per_joint(viscous, 0.0, "viscous friction")
        self.coulomb = per_joint(coulomb, 0.0, "Coulomb friction")
        self.friction_offset = per_joint(friction_offset, 0.0, "friction offset")
        self.armature = per_joint(armature, 0.0, "armature")
        self.gear_ratio = per_joint(gear_ratio, 1.0, "gear ratio")

        bodies = [f"{p}{j}" for j in range(1, n + 1) for p in BODY_PARAMS]
        arm = [f"Ia{j}" for j in range(1, n + 1)] if "rotor_inertia" in self.terms else []
        friction = [f"fv{j}" for j in range(1, n + 1)] + [f"fc{j}" for j in range(1, n + 1)]
        if "friction_offset" in self.terms:
            friction += [f"fo{j}" for j in range(1, n + 1)]
        self.n_friction = len(friction)
        self.standard_names = tuple(bodies + arm + friction)
        self.standard_units = (
            BODY_UNITS * n + ("kg m²",) * len(arm) + ("Nm s",) * n + ("Nm",) * (len(friction) - n)
        )
        self.n_body_params = 10 * n
        self.n_rigid_standard = self.n_body_params + len(arm)  # columns the QR sorts out
        inertias = [m.inertias[j].toDynamicParameters() for j in range(1, m.njoints)]
        offsets = self.friction_offset if "friction_offset" in self.terms else []
        self.standard_theta = np.concatenate(
            [*inertias, self.armature if arm else [], self.viscous, self.coulomb, offsets]
        )
        self.base = self._base_parameters(np.random.default_rng(seed))
        self._set_names()
        self._kept_dynamics: tuple[bytes, UrdfDynamics] | None = None  # the last θ's bodies

    @classmethod
    def from_profile(
        cls, profile: UrdfRobotProfile | str | Path, *, terms: tuple[str, ...] | None = None
    ) -> UrdfArmModel:
        """The model of a robot profile that names a URDF (profiles/robots/<name>.toml), with
        the profile's ``terms`` unless ``terms`` is given."""
        p = profile if isinstance(profile, UrdfRobotProfile) else load_urdf_robot(profile)
        terms = p.terms if terms is None else terms
        n_urdf = _build(p.urdf).nv
        if n_urdf != p.n_joints:
            raise ValueError(f"{p.source}: profile says {p.n_joints} joints, {p.urdf} has {n_urdf}")
        return cls(
            p.urdf,
            gravity_m_s2=p.gravity_m_s2,
            viscous=p.viscous_Nms,
            coulomb=p.coulomb_Nm,
            # asymmetric Coulomb levels: the mean times sgn q̇ plus half their difference
            friction_offset=(np.subtract(p.coulomb_positive_Nm, p.coulomb_negative_Nm) / 2),
            armature=p.armature_kgm2,
            gear_ratio=p.gear_ratio,
            terms=terms,
            name=p.name,
        )

    # --- standard regressors (all standard columns) ---------------------------------------------

    def _samples(self, *arrays: ArrayLike) -> tuple[tuple[np.ndarray, ...], tuple[int, ...]]:
        out = []
        for a in arrays:
            x = np.asarray(a, dtype=float)
            if x.shape[-1] != self.n_joints:
                raise ValueError(f"need {self.n_joints} joint values per sample, got {x.shape}")
            out.append(x.reshape(-1, self.n_joints))
        return tuple(out), np.asarray(arrays[0]).shape[:-1]

    def _rigid_torque(self, free: bool, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray):
        model, data = (self._free, self._free_data) if free else (self._model, self._data)
        out = np.empty((len(q), self.n_joints, self.n_body_params))
        for k in range(len(q)):
            out[k] = pin.computeJointTorqueRegressor(model, data, q[k], dq[k], ddq[k])
        return out

    def _extra_columns(self, velocity_like: np.ndarray, dq: np.ndarray | None) -> np.ndarray:
        """Armature (I_a × velocity_like) and friction (f_v q̇, f_c sgn q̇) columns, (N, n, ·)."""
        N, n = velocity_like.shape
        eye = np.eye(n)
        cols = []
        if "rotor_inertia" in self.terms:
            cols.append(eye[None] * velocity_like[:, None, :])
        if dq is None:
            cols.append(np.zeros((N, n, self.n_friction)))
        else:
            cols.append(eye[None] * dq[:, None, :])
            cols.append(eye[None] * np.sign(dq)[:, None, :])  # Reyes & Kelly (1997) eq. (12)
            if "friction_offset" in self.terms:
                cols.append(np.broadcast_to(eye, (N, n, n)))
        return np.concatenate(cols, axis=-1)

    def standard_regressor(self, q: ArrayLike, dq: ArrayLike, ddq: ArrayLike) -> np.ndarray:
        """Y_std with Y_std θ_std = M q̈ + C q̇ + g + f, shape (..., n, p_std)."""
        (q, dq, ddq), lead = self._samples(q, dq, ddq)
        Y = np.concatenate(
            [self._rigid_torque(False, q, dq, ddq), self._extra_columns(ddq, dq)], axis=-1
        )
        return Y.reshape(*lead, self.n_joints, -1)

    # The momentum and static rows below come from the kinematic tree for many states at once
    # (:class:`hil.model.urdf_dynamics.Chain`), not from Pinocchio one state at a time: a 60 s
    # 7-joint recording asks for 10⁵–10⁶ states (tests/test_urdf.py checks them against
    # Pinocchio's regressors). Body j's rows are bilinear in its motions, vᵀ I(π_j) w
    # (:func:`_bilinear_inertia_regressor`), with J_j's column i the axis S_i carried to body
    # j's frame, X_{j←i} S_i (zero where joint i does not move body j).
    def _standard_momentum(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        # P θ = M(q) q̇: P_i = Σ_j (X_{j←i} S_i)ᵀ I_j V_j   (Featherstone (2008) eq. (2.63));
        # all the states in one pass (momentum_regressor hands them a chunk at a time)
        X = self._chain.transforms(q)
        axes, V = self._chain.axis_motions(X), self._chain.motions(X, dq.T)
        rows = self._body_rows(axes, V[:, None])
        return np.concatenate([rows, self._extra_columns(dq, None)], axis=-1)

    def _body_rows(self, v: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Σ-ready rows vᵀ I(π_j) w of motions ``v``, ``w`` broadcasting to (n_j, n_i, 6, N),
        one of them zero where joint i does not move body j (a subtree motion,
        :meth:`Chain.subtree_motions`): (N, n_i, 10 n_j), the joints' rows over the bodies'
        parameters, computed on the moved pairs only."""
        v, w = np.broadcast_arrays(v, w)
        bodies, joints = self._chain.moved_pairs
        # (pairs, N, 10): each component a contiguous (pairs, N) block of the gathered motions
        pairs = _bilinear_inertia_regressor(
            np.moveaxis(v[bodies, joints], 1, -1), np.moveaxis(w[bodies, joints], 1, -1)
        )
        rows = np.zeros((pairs.shape[1], self.n_joints, self.n_joints, 10))
        rows[:, joints, bodies] = np.moveaxis(pairs, 0, 1)
        return rows.reshape(len(rows), self.n_joints, self.n_body_params)

    def _standard_static(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        # g_i = Σ_j (X_{j←i} S_i)ᵀ I_j a_j, a_j the base's −g in body j's frame (the RNEA at
        # rest, Featherstone (2008) §5.3), minus ∂φ_K/∂q_i = Σ_j V_jᵀ I_j ∂V_j/∂q_i (both in
        # body j's frame); all the states in one pass (static_regressor chunks them)
        X = self._chain.transforms(q)
        a = self._chain.motions(X, None, -self._model.gravity.linear)
        rigid = self._body_rows(self._chain.axis_motions(X), a[:, None])
        V = self._chain.motions(X, dq.T)
        rigid -= self._body_rows(V[:, None], self._chain.velocity_derivatives(X, V))
        return np.concatenate([rigid, self._extra_columns(np.zeros_like(q), dq)], axis=-1)

    def _standard_kinetic(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        out = np.empty((len(q), self.n_body_params))
        for k in range(len(q)):
            out[k] = pin.computeKineticEnergyRegressor(self._free, self._free_data, q[k], dq[k])
        cols = [out]
        if "rotor_inertia" in self.terms:
            cols.append(0.5 * dq**2)
        cols.append(np.zeros((len(q), self.n_friction)))
        return np.concatenate(cols, axis=-1)

    def _standard_potential(self, q: np.ndarray) -> np.ndarray:
        m, d = self._model, self._data
        out = np.empty((len(q), self.n_body_params))
        for k in range(len(q)):
            out[k] = pin.computePotentialEnergyRegressor(m, d, q[k])
        # zero at q = 0 (the hanging/home configuration), as hil.model.closed_form.energy_regressor
        out -= pin.computePotentialEnergyRegressor(m, d, np.zeros(self.n_joints))
        extra = self.n_rigid_standard - self.n_body_params + self.n_friction
        return np.concatenate([out, np.zeros((len(q), extra))], axis=-1)

    # --- base parameters -----------------------------------------------------------------------

    def _base_parameters(self, rng: np.random.Generator) -> BaseParameters:
        n, pr = self.n_joints, self.n_rigid_standard
        q = rng.uniform(-np.pi, np.pi, size=(BASE_SAMPLES, n))
        dq, ddq = rng.normal(size=(2, BASE_SAMPLES, n))
        W = self.standard_regressor(q, dq, ddq)[..., :pr].reshape(-1, pr)
        _, R, piv = qr(W, mode="economic", pivoting=True)
        diag = np.abs(np.diag(R))
        r = int(np.sum(diag > RANK_TOL * diag[0]))
        K = np.linalg.solve(R[:r, :r], R[:r, r:])
        K[np.abs(K) < 1e-10] = 0.0
        # base order: by the standard index of each independent column (bodies first, in order)
        order = np.argsort(piv[:r])
        indep, K = piv[:r][order], K[order]
        dep = piv[r:]
        p_std = len(self.standard_names)
        fr = np.arange(pr, p_std)  # friction: always base parameters of their own
        expand = np.zeros((r + len(fr), p_std))
        expand[np.arange(r), indep] = 1.0
        expand[:r, dep] = K
        expand[np.arange(r, r + len(fr)), fr] = 1.0
        return BaseParameters(np.concatenate([indep, fr]), dep, K, expand)

    def _set_names(self) -> None:
        b, std = self.base, self.standard_names
        meanings = []
        for i, col in enumerate(b.independent):
            parts = [std[col]]
            if i < len(b.K):
                for jdx, c in zip(b.dependent, b.K[i], strict=True):
                    if c != 0.0:
                        parts.append(f"{'-' if c < 0 else '+'} {abs(c):.6g} {std[jdx]}")
            meanings.append(" ".join(parts))
        self.meanings = tuple(meanings)
        self.names = tuple(f"beta{i}" for i in range(1, len(b.independent) + 1))
        self.units = tuple(self.standard_units[c] for c in b.independent)
        self.n_params = len(self.names)

    def base_theta(self, theta_standard: ArrayLike | None = None) -> np.ndarray:
        """θ_base of a standard-parameter vector (default: the URDF's and the profile's)."""
        t = self.standard_theta if theta_standard is None else np.asarray(theta_standard, float)
        return self.base.expand @ t

    @property
    def rigid_count(self) -> int:
        """Every base parameter before the friction (and term) columns."""
        return self.n_params - self.n_friction

    @property
    def display_name(self) -> str:
        terms = f", {' and '.join(self.terms)}" if self.terms else ""
        joints = f"{self.n_joints} joint{'s' if self.n_joints != 1 else ''}"
        return f"{self.n_params}-base-parameter {self.name or 'URDF'} ({joints}{terms})"

    @property
    def rigid_words(self) -> str:
        n = self.rigid_count
        return (
            f"{self.names[0]}..{self.names[n - 1]}, the {n} rigid-body base parameters of the "
            f"{self.name or 'URDF'} model"
        )

    @property
    def missing_terms(self) -> tuple[str, ...]:
        """The 2-DOF closed-form terms do not apply: a URDF's bodies carry their own centres
        of mass; the armature and offset are this model's own ``terms``."""
        return ()

    @property
    def refused_terms(self) -> dict[str, str]:
        """The 2-DOF model terms, and the torque offset when the model already has one per
        joint (its ``friction_offset`` term); the armature is said to be the model's own when
        its ``rotor_inertia`` term is on."""
        armature = (
            "the nominal model has an armature per joint (its rotor_inertia term), fitted"
            if "rotor_inertia" in self.terms
            else "a 2-DOF closed-form term (θ_rotor beside θ3); an n-joint arm's armature is the "
            "URDF model's own rotor_inertia term: identify with it in the profile's [model] terms "
            "and compare"
        )
        out = {
            "rotor_inertia": armature,
            "com_offset": "a 2-DOF closed-form term; a URDF model's bodies carry their centres of "
            "mass in every direction already (10 parameters per body)",
        }
        if "friction_offset" in self.terms:
            out["offset"] = (
                "the nominal model has a torque offset per joint (its friction_offset term: "
                "asymmetric Coulomb friction), so a Coulomb asymmetry or torque offset is a "
                "parameter of the model, fitted, not missing physics"
            )
        return out

    def term_columns(self, term: str) -> slice:
        """The base columns a model term owns: ``friction`` (f_v per joint, f_c per joint and,
        with that term, the offsets), ``friction_offset`` (f_o per joint)."""
        if term == "friction":
            return slice(self.n_params - self.n_friction, self.n_params)
        if term == "friction_offset" and term in self.terms:
            return slice(self.n_params - self.n_joints, self.n_params)
        raise KeyError(f"model has no term {term!r} (friction, {', '.join(self.terms)})")

    @property
    def friction_columns(self) -> tuple[int, ...]:
        """Viscous and Coulomb columns (≥ 0 for a physical arm)."""
        start = self.n_params - self.n_friction
        return tuple(range(start, start + 2 * self.n_joints))

    @property
    def nonnegative_columns(self) -> tuple[int, ...]:
        """Friction coefficients (the base columns of the armature mix with link inertias)."""
        return self.friction_columns

    def _to_base(self, Y_std: np.ndarray) -> np.ndarray:
        return Y_std[..., self.base.independent]

    # --- the interface of hil.model.closed_form.ArmModel (base parameters) ---------------------

    def torque_regressor(self, q: ArrayLike, dq: ArrayLike, ddq: ArrayLike) -> np.ndarray:
        """Y with Y θ = M q̈ + C q̇ + g + f, shape (..., n, p)   (Reyes & Kelly (1997) eq. (13))."""
        return self._to_base(self.standard_regressor(q, dq, ddq))

    dynamic_regressor = torque_regressor

    def momentum_regressor(self, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """P = ∂φ_K/∂q̇ with P θ = M(q) q̇, shape (..., n, p)   (eq. (11))."""
        (q, dq), lead = self._samples(q, dq)
        # a chunk of states at a time to the end: no (states, n, p_std) array of them all
        base = lambda q, dq: self._to_base(self._standard_momentum(q, dq))  # noqa: E731
        P = by_chunks(base, q, dq, REGRESSOR_STATES_PER_CHUNK)
        return P.reshape(*lead, self.n_joints, -1)

    def static_regressor(self, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """R = −∂φ_K/∂q + ∂φ_P/∂q + φ_F with τ = d/dt[P θ] + R θ, shape (..., n, p)   (eq. (13))."""
        (q, dq), lead = self._samples(q, dq)
        base = lambda q, dq: self._to_base(self._standard_static(q, dq))  # noqa: E731
        R = by_chunks(base, q, dq, REGRESSOR_STATES_PER_CHUNK)
        return R.reshape(*lead, self.n_joints, -1)

    def kinetic_energy_regressor(self, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """φ_K with K = φ_K θ, shape (..., p)   (eq. (5))."""
        (q, dq), lead = self._samples(q, dq)
        return self._to_base(self._standard_kinetic(q, dq)).reshape(*lead, -1)

    def potential_energy_regressor(self, q: ArrayLike) -> np.ndarray:
        """φ_P with U = φ_P θ, zero at q = 0, shape (..., p)   (eq. (6))."""
        (q,), lead = self._samples(q)
        return self._to_base(self._standard_potential(q)).reshape(*lead, -1)

    def energy_regressor(self, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """φ_ℰ = φ_K + φ_P with ℰ = K + U = φ_ℰ θ, shape (..., p)   (eq. (8)).

        The energy regressors take the torque regressor's base columns, and that is exact: a
        standard direction c with Y c = 0 for every (q, q̇, q̈) does no work, q̇ᵀY c =
        d/dt(φ_ℰ c) = 0 along every motion, so φ_ℰ c is constant and, as φ_ℰ vanishes at rest
        at q = 0, zero; φ_P c (its q̇-free part) and φ_K c vanish each. Hence the energy columns
        of the dependent standard parameters are the same combinations K of the independent
        ones, φ θ_std = φ₁ (θ₁ + K θ₂) = φ₁ θ_base, for φ_K, φ_P and φ_ℰ alike
        (tests/test_urdf_energy.py checks it against Pinocchio's energies)."""
        return self.kinetic_energy_regressor(q, dq) + self.potential_energy_regressor(q)

    def friction_power_regressor(self, dq: ArrayLike) -> np.ndarray:
        """q̇ᵀ φ_F: the power friction dissipates, per base parameter, shape (..., p)."""
        (dq,), lead = self._samples(dq)
        out = np.zeros((len(dq), self.n_params))
        power = [dq**2, np.abs(dq)] + (
            [dq] if "friction_offset" in self.terms else []
        )  # q̇ᵀ φ_F per column
        out[:, self.term_columns("friction")] = np.concatenate(power, axis=-1)
        return out.reshape(*lead, -1)

    def standard_of_base(self, theta: ArrayLike) -> np.ndarray:
        """A standard-parameter vector whose base vector is θ: θ on the independent standard
        columns, zero on the dependent ones. The base regressor is the standard regressor's
        independent columns, so Y_std θ_std = Y θ exactly for any θ; the bodies it gives need
        not be physical (a zero or negative mass is exact here)."""
        t = np.asarray(theta, dtype=float)
        if t.shape != (self.n_params,):
            raise ValueError(f"theta must hold {self.n_params} numbers, got shape {t.shape}")
        out = np.zeros(len(self.standard_names))
        out[self.base.independent] = t
        return out

    def dynamics(self, theta: ArrayLike) -> UrdfDynamics:
        """M(q) and C(q, q̇) q̇ + g(q) of the base vector θ, one configuration at a time
        (:class:`UrdfDynamics`): what an integrator calls at every stage."""
        return UrdfDynamics(self, theta)

    def mass_matrix(self, theta: ArrayLike, q: ArrayLike) -> np.ndarray:
        """M(q), shape (..., n, n): Σ_j J_jᵀ I_j J_j + diag(I_a) (:class:`UrdfDynamics`),
        equal to the momentum regressor's columns P(q, e_i) θ."""
        (q,), lead = self._samples(q)
        dyn = self._dynamics_of(theta)
        M = np.array([dyn.mass_matrix(qk) for qk in q]).reshape(len(q), self.n_joints, -1)
        return M.reshape(*lead, self.n_joints, self.n_joints)

    def _dynamics_of(self, theta: ArrayLike) -> UrdfDynamics:
        """:meth:`dynamics` of θ, kept for the last θ asked (a controller calls
        :meth:`mass_matrix` with one θ every period, the diagnosis its torques with one θ)."""
        t = np.asarray(theta, dtype=float)
        kept = self._kept_dynamics
        if kept is None or kept[0] != t.tobytes():
            kept = self._kept_dynamics = (t.tobytes(), self.dynamics(t))
        return kept[1]

    def gravity_vector(self, theta: ArrayLike, q: ArrayLike) -> np.ndarray:
        """g(q) = ∂U/∂q, shape (..., n)."""
        (q,), lead = self._samples(q)
        zero = np.zeros_like(q)
        return self._rigid_only(self._rigid_torque(False, q, zero, zero), theta, lead)

    def _rigid_only(self, rigid: np.ndarray, theta: ArrayLike, lead: tuple[int, ...]):
        Y = np.concatenate([rigid, np.zeros((*rigid.shape[:2], self._n_extra))], axis=-1)
        return (self._to_base(Y) @ np.asarray(theta, dtype=float)).reshape(*lead, self.n_joints)

    def coriolis_vector(self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """C(q, q̇) q̇, shape (..., n)."""
        (q, dq), lead = self._samples(q, dq)
        return self._rigid_only(self._rigid_torque(True, q, dq, np.zeros_like(q)), theta, lead)

    @property
    def _n_extra(self) -> int:
        return len(self.standard_names) - self.n_body_params

    def friction_torque(self, theta: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """f(q̇) = f_v q̇ + f_c sgn q̇ [+ f_o] per joint, shape (..., n)   (eq. (12))."""
        (dq,), lead = self._samples(dq)
        t = np.asarray(theta, dtype=float)[self.term_columns("friction")]
        n = self.n_joints
        f = t[:n] * dq + t[n : 2 * n] * np.sign(dq)
        if "friction_offset" in self.terms:
            f = f + t[2 * n :]
        return f.reshape(*lead, n)

    def torque(self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike, ddq: ArrayLike) -> np.ndarray:
        """τ = M(q) q̈ + C(q, q̇) q̇ + g(q) + f(q̇), shape (..., n)   (eq. (15))."""
        return self.torque_regressor(q, dq, ddq) @ np.asarray(theta, dtype=float)

    def forward_dynamics(
        self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike, tau: ArrayLike
    ) -> np.ndarray:
        """q̈ = M(q)⁻¹ (τ − C(q, q̇) q̇ − g(q) − f(q̇)) of base parameters θ, shape (..., n)
        (Coulomb friction as f_c sgn q̇, no stiction). From the regressor and
        :meth:`mass_matrix` (linear in θ), not ABA: a base vector need not come from standard
        parameters with positive masses."""
        (q, dq, tau), lead = self._samples(q, dq, tau)
        t = np.asarray(theta, dtype=float)
        rest = self.torque_regressor(q, dq, np.zeros_like(q)) @ t  # C q̇ + g + f
        M = self.mass_matrix(t, q)
        ddq = np.linalg.solve(M, (tau - rest)[..., None])[..., 0]
        return ddq.reshape(*lead, self.n_joints)

    # --- the torques of one θ, on the bodies that carry it (UrdfDynamics) ----------------------

    def momentum(self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """P(q, q̇) θ = M(q) q̇ (with the armature's I_a q̇), shape (..., n): the momentum
        regressor's product, Σ_j J_jᵀ I_j J_j q̇ on the bodies that carry θ
        (:meth:`UrdfDynamics.momentum`), not from its 10n columns."""
        (q, dq), lead = self._samples(q, dq)
        return self._dynamics_of(theta).momentum(q, dq).reshape(*lead, self.n_joints)

    def static_torque(self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """R(q, q̇) θ = −∂K/∂q + g(q) + f(q̇), shape (..., n) (τ = d/dt[P θ] + R θ, Reyes &
        Kelly (1997) eq. (13)), the static regressor's product without its columns: g and
        ∂K/∂q (= C(q, q̇)ᵀ q̇) on the bodies that carry θ (:class:`UrdfDynamics`)."""
        (q, dq), lead = self._samples(q, dq)
        out = self._dynamics_of(theta).static_torque(q, dq) + self.friction_torque(theta, dq)
        return out.reshape(*lead, self.n_joints)

    def momentum_at_shifts(
        self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike, joint: int, shifts: ArrayLike
    ) -> np.ndarray:
        """:meth:`momentum` at q + s e_``joint`` for each s of ``shifts`` (S,), shape
        (S, ..., n): the frames before the joint built once
        (:meth:`UrdfDynamics.momentum_at_shifts`)."""
        (q, dq), lead = self._samples(q, dq)
        s = np.atleast_1d(np.asarray(shifts, float))
        out = self._dynamics_of(theta).momentum_at_shifts(q, dq, joint, s)
        return out.reshape(len(s), *lead, self.n_joints)

    def static_torque_at_shifts(
        self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike, joint: int, shifts: ArrayLike
    ) -> np.ndarray:
        """:meth:`static_torque` at q + s e_``joint`` for each s of ``shifts`` (S,), shape
        (S, ..., n) (:meth:`UrdfDynamics.static_torque_at_shifts`)."""
        (q, dq), lead = self._samples(q, dq)
        s = np.atleast_1d(np.asarray(shifts, float))
        out = self._dynamics_of(theta).static_torque_at_shifts(q, dq, joint, s)
        out = out + self.friction_torque(theta, dq)  # a shift leaves the velocities as they are
        return out.reshape(len(s), *lead, self.n_joints)

    # --- physical consistency ------------------------------------------------------------------

    def _base_consistency(self, theta: np.ndarray) -> dict[str, object]:
        violations = []
        for i in self.friction_columns:
            if not theta[i] >= 0:
                violations.append(f"negative {self.meanings[i]} = {theta[i]:.4g}")
        lo, hi = self._model.lowerPositionLimit, self._model.upperPositionLimit
        finite = np.isfinite(lo) & np.isfinite(hi) & (hi > lo)
        lo, hi = np.where(finite, lo, -np.pi), np.where(finite, hi, np.pi)
        q = np.random.default_rng(1).uniform(lo, hi, (CONSISTENCY_SAMPLES, self.n_joints))
        low = np.linalg.eigvalsh(self.mass_matrix(theta, q))[:, 0]
        worst = int(np.argmin(low))
        if not low[worst] > 0:
            where = ", ".join(f"{x:.3g}" for x in q[worst])
            violations.append(
                f"M(q) not positive definite: smallest eigenvalue {low[worst]:.4g} at q = "
                f"[{where}] (and {int(np.sum(low <= 0)) - 1} more of {CONSISTENCY_SAMPLES})"
            )
        return {"consistent": not violations, "violations": violations}

    def physical_consistency(self, theta: ArrayLike | None = None) -> dict[str, object]:
        """Check θ; returns ``{"consistent": bool, "violations": [...]}`` (one sentence each).

        A *standard*-parameter vector (default: the URDF's) is checked body by body: m > 0 and
        the pseudo-inertia J = [[½ tr(I) 1 − I, m c], [m cᵀ, m]] positive semidefinite
        (Wensing, Kim & Slotine (2018)); armature, viscous and Coulomb coefficients ≥ 0.
        A *base*-parameter vector (length ``n_params``) cannot be judged body by body (many
        standard vectors share it); it is checked for what it decides: viscous and Coulomb
        coefficients ≥ 0 and M(q) positive definite at CONSISTENCY_SAMPLES random
        configurations within the URDF's joint limits (a sampled, not a proof, check)."""
        t = self.standard_theta if theta is None else np.asarray(theta, dtype=float)
        if t.shape == (self.n_params,):
            return self._base_consistency(t)
        if t.shape != (len(self.standard_names),):
            raise ValueError(
                f"theta must hold {self.n_params} base or {len(self.standard_names)} standard "
                f"parameters, got shape {t.shape}"
            )
        violations = []
        for j in range(self.n_joints):
            m, mc, Ixx, Ixy, Iyy, Ixz, Iyz, Izz = (
                t[10 * j],
                t[10 * j + 1 : 10 * j + 4],
                *t[10 * j + 4 : 10 * j + 10],
            )
            name = self.joint_names[j]
            if not m > 0:
                violations.append(f"body of {name}: mass {m:.4g} kg <= 0")
            inertia = np.array([[Ixx, Ixy, Ixz], [Ixy, Iyy, Iyz], [Ixz, Iyz, Izz]])
            J = np.zeros((4, 4))
            J[:3, :3] = 0.5 * np.trace(inertia) * np.eye(3) - inertia
            J[:3, 3] = J[3, :3] = mc
            J[3, 3] = m
            low = float(np.linalg.eigvalsh(J)[0])
            if low < -1e-12 * max(1.0, float(np.abs(J).max())):
                violations.append(
                    f"body of {name}: pseudo-inertia not positive semidefinite "
                    f"(smallest eigenvalue {low:.4g})"
                )
        # armature, viscous and Coulomb coefficients; the offsets may take either sign
        for i in range(self.n_body_params, self.n_rigid_standard + 2 * self.n_joints):
            if not t[i] >= 0:
                violations.append(f"negative {self.standard_names[i]} = {t[i]:.4g}")
        return {"consistent": not violations, "violations": violations}


def _build(urdf: str) -> pin.Model:
    try:
        return pin.buildModelFromUrdf(urdf)
    except (RuntimeError, ValueError) as exc:
        raise ValueError(f"{urdf}: cannot build a model from this URDF: {exc}") from None


def _bilinear_inertia_regressor(v: np.ndarray, w: np.ndarray) -> np.ndarray:
    """vᵀ I(π) w as a regressor in π (Pinocchio's order), shape (..., 10), broadcasting v, w
    (..., 6).

    Spatial vectors are (linear, angular); the inertia about the frame origin with first moment
    h = m c and rotational inertia Ī gives vᵀ I w = m v_l·w_l + h·(v_l × w_a + w_l × v_a)
    + v_aᵀ Ī w_a (Featherstone (2008) eq. (2.63)).
    """
    v, w = np.broadcast_arrays(v, w)
    vx, vy, vz, ax, ay, az = np.moveaxis(v, -1, 0)
    wx, wy, wz, bx, by, bz = np.moveaxis(w, -1, 0)
    return np.stack(
        [
            vx * wx + vy * wy + vz * wz,
            (vy * bz - vz * by) + (wy * az - wz * ay),
            (vz * bx - vx * bz) + (wz * ax - wx * az),
            (vx * by - vy * bx) + (wx * ay - wy * ax),
            ax * bx,
            ax * by + ay * bx,
            ay * by,
            ax * bz + az * bx,
            ay * bz + az * by,
            az * bz,
        ],
        axis=-1,
    )


__all__ = [
    "TERMS",
    "BaseParameters",
    "UrdfArmModel",
]
