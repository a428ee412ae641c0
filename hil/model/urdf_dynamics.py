"""The bodies that carry one base vector θ of an n-joint URDF arm (:class:`UrdfDynamics`, built
by :meth:`hil.model.urdf.UrdfArmModel.dynamics`) and their torques, and the arm's kinematic tree
for many states at once (:class:`Chain`): Featherstone's (2008) recursions in numpy.

Imports numpy and Pinocchio only (:mod:`hil.model.urdf` imports this module).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike


class UrdfDynamics:
    """The bodies that carry one base vector θ of a :class:`UrdfArmModel`, and their torques:
    M(q) and C(q, q̇) q̇ + g(q) at one configuration through Pinocchio's kinematics (the
    open-loop simulation's accelerations); M(q) q̇ and g(q) − C(q, q̇)ᵀ q̇ at many states at
    once through :class:`Chain` (the diagnosis's torque rows). The model's only way from θ to
    bodies.

    θ is carried to the standard vector :meth:`UrdfArmModel.standard_of_base` (exact for any θ).
    The mass matrix is the kinetic energy's Hessian, M(q) = Σ_j J_jᵀ I_j J_j + diag(I_a), with
    J_j body j's Jacobian in its joint frame (one ``computeJointJacobians`` pass) and I_j its
    6×6 spatial inertia, linear in the ten dynamic parameters π_j (Featherstone (2008)
    eq. (2.63), Pinocchio's order: linear then angular),

        I_j = [[m 1, −[h]×], [[h]×, I_O]],  h = m c,  I_O the inertia about the joint frame,

    built once per θ, so a zero or negative mass needs no centre of mass (Pinocchio's own CRBA
    and ABA divide by the mass, and clamp a composite mass at zero: not exact for a base vector).
    C q̇ + g is the joint torque regressor at q̈ = 0 times the bodies' parameters: one call.
    The batched torques are Featherstone's recursions on the same I_j (exact for any θ too)."""

    def __init__(self, model: Any, theta: ArrayLike) -> None:
        """``model``: the :class:`hil.model.urdf.UrdfArmModel` whose base vector θ is."""
        n = model.n_joints
        std = model.standard_of_base(theta)
        self.n_joints = n
        self._model, self._data = model._model, model._data
        self._free, self._free_data = model._free, model._free_data
        self._bodies = std[: model.n_body_params]
        pi = self._bodies.reshape(n, 10)
        blocks = np.zeros((n, 6, 6))
        blocks[:, :3, :3] = pi[:, :1, None] * np.eye(3)
        h = _skew(pi[:, 1:4])
        blocks[:, :3, 3:] = -h
        blocks[:, 3:, :3] = h
        Ixx, Ixy, Iyy, Ixz, Iyz, Izz = pi[:, 4:].T
        blocks[:, 3:, 3:] = np.stack(
            [np.stack([Ixx, Ixy, Ixz], -1), np.stack([Ixy, Iyy, Iyz], -1),
             np.stack([Ixz, Iyz, Izz], -1)], axis=1,
        )  # fmt: skip
        self._blocks = blocks  # body j's I_j, (n, 6, 6)
        self._spatial = np.zeros((6 * n, 6 * n))  # block diagonal: body j's I_j at block j
        for j in range(n):
            self._spatial[6 * j : 6 * j + 6, 6 * j : 6 * j + 6] = blocks[j]
        arm = model.n_rigid_standard - model.n_body_params
        self._armature_diag = (
            std[model.n_body_params : model.n_rigid_standard] if arm else np.zeros(n)
        )
        self._armature = np.diag(self._armature_diag)
        self._zero = np.zeros(n)
        self._chain = model._chain
        self._gravity = -model._model.gravity.linear  # the base's acceleration at rest
        self._jacobians = np.zeros((6 * n, n))  # the bodies' Jacobians stacked, filled per call

    def mass_matrix(self, q: ArrayLike) -> np.ndarray:
        """M(q), (n, n), at one configuration q (n,)."""
        m, d, n, J = self._free, self._free_data, self.n_joints, self._jacobians
        pin.computeJointJacobians(m, d, np.asarray(q, dtype=float))
        for j in range(n):  # body j's Jacobian, (6, n); one joint's comes back as a vector
            J[6 * j : 6 * j + 6] = pin.getJointJacobian(m, d, j + 1, pin.LOCAL).reshape(6, n)
        return J.T @ (self._spatial @ J) + self._armature

    def rigid_bias(self, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """C(q, q̇) q̇ + g(q), (n,), at one state: the rigid bodies' torque at q̈ = 0."""
        Y = pin.computeJointTorqueRegressor(
            self._model, self._data, np.asarray(q, float), np.asarray(dq, float), self._zero
        )
        return (Y @ self._bodies).reshape(self.n_joints)

    # --- many states at once: the diagnosis's torque rows ---------------------------------------

    def momentum(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """M(q) q̇ at states (N, n), shape (N, n): S_iᵀ H_i + I_a q̇_i, with H_i the momentum of
        the bodies that joint i moves (:meth:`Chain.subtree_sums`; CRBA's M q̇, Featherstone
        (2008) §6.2)."""
        return by_chunks(self._momentum, q, dq)

    def _momentum(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        X = self._chain.transforms(q)
        return self._momentum_of(X, self._chain.motions(X, dq.T), dq)

    def _momentum_of(
        self, X: list, V: np.ndarray, dq: np.ndarray, start: int = 0, own: np.ndarray | None = None
    ) -> np.ndarray:
        """M(q) q̇ from the frames ``X`` and the bodies' velocities ``V`` (``start``, ``own``:
        :meth:`Chain.subtree_sums`)."""
        H = self._chain.subtree_sums(X, self._blocks, V, start, own)
        return np.einsum("ia,iak->ki", self._chain.axes, H) + self._armature_diag * dq

    def momentum_at_shifts(
        self, q: np.ndarray, dq: np.ndarray, joint: int, shifts: np.ndarray
    ) -> np.ndarray:
        """:meth:`momentum` at q + s e_``joint`` for each s of ``shifts`` (S,), shape (S, N, n):
        the bodies before ``joint`` keep their frames and velocities (Pinocchio numbers a
        parent before its children), so only the joint's transform and what follows it are
        built again for each shift."""
        return np.moveaxis(
            by_chunks(lambda q, dq: self._momentum_at_shifts(q, dq, joint, shifts), q, dq), 1, 0
        )

    def _momentum_at_shifts(
        self, q: np.ndarray, dq: np.ndarray, joint: int, shifts: np.ndarray
    ) -> np.ndarray:
        chain = self._chain
        X = chain.transforms(q)
        V = chain.motions(X, dq.T)
        own = np.einsum("jab,jbk->jak", self._blocks, V)
        out = np.empty((len(q), len(shifts), self.n_joints))
        for i, s in enumerate(shifts):
            Xs = chain.shifted(X, q, joint, s)
            Vs = chain.motions(Xs, dq.T, start=joint, known=V)
            out[:, i] = self._momentum_of(Xs, Vs, dq, joint, own)
        return out

    def static_torque(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """g(q) − ∂K/∂q = g(q) − C(q, q̇)ᵀ q̇ at states (N, n), shape (N, n).

        Turning joint i turns the bodies it moves about its axis S_i: their velocities change
        by S_i × (V_j − V_λ(i)) and their inertias turn with them, so with H_i those bodies'
        momentum and V_i joint i's velocity, ∂K/∂q_i = −H_i · (S_i × V_i) (×: the spatial cross
        product of motions, Featherstone (2008) eq. (2.31); S_i × V_λ(i) = S_i × V_i; a
        frame-free product, taken in joint i's frame). Gravity is the bodies' force at the base
        acceleration −g: g_i = S_iᵀ G_i, G_i the subtree sum of I_j a_j (the RNEA at rest,
        Featherstone (2008) §5.3). The armature's ½ I_a q̇² does not depend on q."""
        return by_chunks(self._static_torque, q, dq)

    def _static_torque(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        chain = self._chain
        X = chain.transforms(q)
        V = chain.motions(X, dq.T)
        return self._static_of(X, V, chain.motions(X, None, self._gravity), chain.axis_cross @ V)

    def _static_of(
        self,
        X: list,
        V: np.ndarray,
        A: np.ndarray,
        cross: np.ndarray,
        start: int = 0,
        own: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> np.ndarray:
        """g − ∂K/∂q from the frames ``X``, the bodies' velocities ``V``, their accelerations
        at rest under gravity ``A`` and S_i × V_i ``cross`` (``start``, ``own``: the products
        I_j V_j and I_j A_j of the bodies before ``start``, :meth:`Chain.subtree_sums`)."""
        chain, blocks = self._chain, self._blocks
        own_V, own_A = (None, None) if own is None else own
        H = chain.subtree_sums(X, blocks, V, start, own_V)
        G = chain.subtree_sums(X, blocks, A, start, own_A)
        return np.einsum("iak,iak->ki", H, cross) + np.einsum("ia,iak->ki", chain.axes, G)

    def static_torque_at_shifts(
        self, q: np.ndarray, dq: np.ndarray, joint: int, shifts: np.ndarray
    ) -> np.ndarray:
        """:meth:`static_torque` at q + s e_``joint`` for each s of ``shifts`` (S,), shape
        (S, N, n), with what precedes the joint built once (:meth:`momentum_at_shifts`)."""
        return np.moveaxis(
            by_chunks(lambda q, dq: self._static_at_shifts(q, dq, joint, shifts), q, dq), 1, 0
        )

    def _static_at_shifts(
        self, q: np.ndarray, dq: np.ndarray, joint: int, shifts: np.ndarray
    ) -> np.ndarray:
        chain, j = self._chain, joint
        X = chain.transforms(q)
        V = chain.motions(X, dq.T)
        A = chain.motions(X, None, self._gravity)
        own = (
            np.einsum("jab,jbk->jak", self._blocks, V),
            np.einsum("jab,jbk->jak", self._blocks, A),
        )
        cross = chain.axis_cross @ V  # S_i × V_i
        out = np.empty((len(q), len(shifts), self.n_joints))
        for i, s in enumerate(shifts):
            Xs = chain.shifted(X, q, j, s)
            Vs = chain.motions(Xs, dq.T, start=j, known=V)
            As = chain.motions(Xs, None, self._gravity, start=j, known=A)
            cs = cross.copy()
            cs[j:] = chain.axis_cross[j:] @ Vs[j:]
            out[:, i] = self._static_of(Xs, Vs, As, cs, j, own)
        return out


class Chain:
    """The kinematic tree of a Pinocchio model of 1-DOF revolute and prismatic joints, for
    many states at once in numpy (each array's last axis runs over the N states): Pinocchio
    computes one state per call, and the diagnosis's torque rows ask for 10⁵ of them.

    Joint j's frame sits at (L_j, p_j) in its parent's (Pinocchio's ``liMi`` = P_j exp(S_j q_j),
    P_j the joint placement, S_j its motion axis in its own frame, both from the model): a
    rotation by q_j about a_j, L_j = R_P (1 + sin q_j [a]× + (1 − cos q_j) [a]×²) (Rodrigues),
    p_j = p_P; or a translation, L_j = R_P, p_j = p_P + q_j R_P a_j."""

    def __init__(self, model: pin.Model) -> None:
        self.parents = [int(model.parents[j]) - 1 for j in range(1, model.njoints)]  # −1: base
        d = model.createData()
        pin.computeJointJacobians(model, d, pin.neutral(model))
        self.axes = np.empty((model.njoints - 1, 6))  # S_j in joint j's frame, linear first
        self._placements: list[tuple[bool, np.ndarray, np.ndarray, np.ndarray]] = []
        for j in range(1, model.njoints):
            s = pin.getJointJacobian(model, d, j, pin.LOCAL).reshape(6, -1)[:, j - 1]
            if not (np.allclose(s[:3], 0) or np.allclose(s[3:], 0)):
                raise ValueError(
                    f"joint {model.names[j]}: only revolute and prismatic joints are supported"
                )
            self.axes[j - 1] = s
            R, p = model.jointPlacements[j].rotation.copy(), model.jointPlacements[j].translation
            K = _skew(s[None, 3:])[0]
            revolute = bool(np.any(s[3:]))
            # revolute: [R_P, R_P [a]×, R_P [a]×²] as (9, 3), times [1, sin q, 1 − cos q] per
            # state; prismatic: R_P a (and zero)
            one, two = (R @ K, R @ K @ K) if revolute else (R @ s[:3], np.zeros(3))
            rodrigues = np.stack([R, one, two], axis=-1).reshape(9, 3) if revolute else one
            self._placements.append((revolute, R, p.copy(), rodrigues))
        # per joint: turns (True) or slides (False)
        self.revolute = tuple(bool(placed[0]) for placed in self._placements)
        # S_i × (crm(S_i), Featherstone (2008) eq. (2.31)): S_i × m = crm(S_i) m, (n, 6, 6)
        self.axis_cross = _motion_cross_matrix(self.axes)
        n = len(self.parents)
        moved = np.eye(n, dtype=bool)  # moved[j, i]: joint i moves body j
        for j, parent in enumerate(self.parents):
            if parent >= 0:
                moved[j] |= moved[parent]
        self.moved = moved
        # the (body j, joint i) pairs of it, as index arrays: a motion X_{j←i} u_i is zero
        # outside them
        self.moved_pairs = np.nonzero(moved)

    def transforms(self, q: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """(L_j (3, 3, N), p_j (3, N) or (3, 1)) of each joint at configurations q (N, n)."""
        return [self.transform(j, q[:, j]) for j in range(len(self._placements))]

    def transform(self, j: int, qj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(L_j (3, 3, N), p_j (3, N) or (3, 1)) of joint j at its coordinates ``qj`` (N,)."""
        revolute, R, p, rodrigues = self._placements[j]
        if revolute:
            L = rodrigues @ np.stack([np.ones_like(qj), np.sin(qj), 1 - np.cos(qj)])
            return L.reshape(3, 3, len(qj)), p[:, None]
        return np.broadcast_to(R[..., None], (3, 3, len(qj))), p[:, None] + rodrigues[:, None] * qj

    def shifted(self, X: list, q: np.ndarray, j: int, shift: float) -> list:
        """``X`` (:meth:`transforms` of q) with joint j's transform at q_j + ``shift``."""
        out = list(X)
        out[j] = self.transform(j, q[:, j] + shift)
        return out

    def motions(
        self,
        X: list,
        dq: np.ndarray | None,
        base: np.ndarray | None = None,
        start: int = 0,
        known: np.ndarray | None = None,
    ) -> np.ndarray:
        """Each body's spatial motion in its own frame, (n, 6, N): the parent's, moved to the
        joint's frame, plus S_j q̇_j (``dq`` (n, N)); the base's is 0, or the linear ``base``
        (a gravity acceleration, world frame) (Featherstone (2008) eq. (2.24)). ``start``,
        ``known``: the bodies before ``start`` taken from ``known`` (their frames unchanged),
        the rest built on them."""
        n = len(self.parents)
        N = X[0][0].shape[-1] if dq is None else dq.shape[-1]
        out = np.zeros((n, 6, N)) if known is None else known.copy()
        for j, ((L, p), parent) in enumerate(zip(X, self.parents, strict=True)):
            if j < start:
                continue
            if parent >= 0:
                v, w = out[parent, :3], out[parent, 3:]
                out[j, :3] = _rotate_back(L, v + _cross(w, p))
                out[j, 3:] = _rotate_back(L, w)
            elif base is not None:
                out[j, :3] = _rotate_back(L, np.asarray(base, float)[:, None])
                out[j, 3:] = 0.0
            else:
                out[j] = 0.0
            if dq is not None:
                out[j] += self.axes[j, :, None] * dq[j]
        return out

    def subtree_motions(self, X: list, seeds: np.ndarray) -> np.ndarray:
        """X_{j←i} u_i for every joint i and every body j it moves (j = i or beyond it),
        (n_j, n_i, 6, N), zero for a body joint i does not move: ``seeds`` (n, 6, N) or
        (n, 6, 1), u_i in joint i's frame, carried down the tree as :meth:`motions` carries a
        parent's motion (Featherstone (2008) eq. (2.24)). Pinocchio numbers a parent before
        its children."""
        n, moved = len(self.parents), self.moved
        N = max(X[0][0].shape[-1], seeds.shape[-1])
        out = np.zeros((n, n, 6, N))
        out[np.arange(n), np.arange(n)] = seeds
        for j, ((L, p), parent) in enumerate(zip(X, self.parents, strict=True)):
            for i in np.flatnonzero(moved[j, :j]):
                v, w = out[parent, i, :3], out[parent, i, 3:]
                out[j, i, :3] = _rotate_back(L, v + _cross(w, p))
                out[j, i, 3:] = _rotate_back(L, w)
        return out

    def axis_motions(self, X: list) -> np.ndarray:
        """J's columns in the bodies' frames: X_{j←i} S_i, (n_j, n_i, 6, N) (:meth:`subtree_motions`
        of the joint axes): body j's velocity is Σ_i of them times q̇_i."""
        return self.subtree_motions(X, self.axes[:, :, None])

    def velocity_derivatives(self, X: list, V: np.ndarray) -> np.ndarray:
        """∂V_j/∂q_i of the bodies' velocities ``V`` (n, 6, N) in their own frames, (n_j, n_i,
        6, N): turning joint i turns the bodies beyond it about S_i, and in their own frames
        their velocities change by X_{j←i}(V_i × S_i) (×: the spatial cross product of motions,
        Featherstone (2008) eq. (2.31); the :meth:`UrdfDynamics.static_torque` argument)."""
        return self.subtree_motions(X, -(self.axis_cross @ V))  # V_i × S_i = −S_i × V_i

    def subtree_sums(
        self,
        X: list,
        blocks: np.ndarray,
        motions: np.ndarray,
        start: int = 0,
        own: np.ndarray | None = None,
    ) -> np.ndarray:
        """Σ over the bodies that joint i moves of I_j m_j, (n, 6, N), in joint i's frame: each
        body's inertia ``blocks`` (n, 6, 6) times its motion, forces carried to the parent's
        frame (Featherstone (2008) eq. (2.25)). ``start``, ``own``: the products I_j m_j of the
        bodies before ``start`` taken from ``own`` (their motions unchanged)."""
        if own is None:
            out = np.einsum("jab,jbk->jak", blocks, motions)
        else:
            out = own.copy()
            out[start:] = np.einsum("jab,jbk->jak", blocks[start:], motions[start:])
        for j in reversed(range(len(self.parents))):
            parent = self.parents[j]
            if parent >= 0:
                L, p = X[j]
                force = _rotate(L, out[j, :3])
                out[parent, :3] += force
                out[parent, 3:] += _rotate(L, out[j, 3:]) + _cross(p, force)
        return out


# states per pass of the recursions: their arrays hold ~200 floats a state (7 joints), so 60 s
# of a 7-joint arm at 1 kHz (480,000 Gauss–Legendre nodes) at once peaked near 0.8 GB
STATES_PER_CHUNK = 32768


def by_chunks(
    fn: Callable[[np.ndarray, np.ndarray], np.ndarray],
    q: np.ndarray,
    dq: np.ndarray,
    chunk: int | None = None,
) -> np.ndarray:
    """``fn`` (states (N, n) → (N, ...)) over ``chunk`` states at a time (default
    :data:`STATES_PER_CHUNK`; each state's result depends on that state alone)."""
    chunk = STATES_PER_CHUNK if chunk is None else chunk
    if len(q) <= chunk:
        return fn(q, dq)
    return np.concatenate(
        [fn(q[i : i + chunk], dq[i : i + chunk]) for i in range(0, len(q), chunk)]
    )


def _rotate(L: np.ndarray, v: np.ndarray) -> np.ndarray:
    """L v of rotations (3, 3, N) and vectors (3, N), states along the last axis."""
    return np.einsum("abk,bk->ak", L, np.broadcast_to(v, (3, L.shape[-1])))


def _rotate_back(L: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Lᵀ v, as :func:`_rotate`."""
    return np.einsum("bak,bk->ak", L, np.broadcast_to(v, (3, L.shape[-1])))


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b of 3-vectors along the first axis (broadcasting the rest)."""
    return np.array(
        np.broadcast_arrays(
            a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]
        )
    )


def _motion_cross_matrix(m: np.ndarray) -> np.ndarray:
    """crm(m) of spatial motions m (N, 6), linear first: crm(m) u = m × u, (N, 6, 6),
    [[ω]×, [v]×; 0, [ω]×] for m = [v; ω] (Featherstone (2008) eq. (2.31))."""
    out = np.zeros((len(m), 6, 6))
    w, v = _skew(m[:, 3:]), _skew(m[:, :3])
    out[:, :3, :3] = w
    out[:, 3:, 3:] = w
    out[:, :3, 3:] = v
    return out


def _skew(v: np.ndarray) -> np.ndarray:
    """[v]× of each row of v (N, 3): [v]× w = v × w, shape (N, 3, 3)."""
    x, y, z = v.T
    zero = np.zeros_like(x)
    return np.stack(
        [np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)],
        axis=1,
    )


__all__ = ["Chain", "UrdfDynamics"]
