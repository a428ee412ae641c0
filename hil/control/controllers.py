"""Tracking controllers of Khosla & Kanade (1987) on a model object of the host: the 2-DOF closed
form (:class:`hil.model.closed_form.ArmModel`, the fast path and the default) or an n-joint arm
from a URDF (:class:`hil.model.urdf.UrdfArmModel`, Pinocchio).

Each controller is a small object called once per control period with the time, the measured
state (q, q̇) and the reference (q_d, q̇_d, q̈_d); it returns a :class:`ControlCommand`: the torque
to send (clipped at the drive limits), the control law's torque before clipping, which joints
were clipped, and the torque split into named parts that add up to the unclipped torque.

With e = q_d − q, ė = q̇_d − q̇, gains K_p, K_v (diagonal, Table 1) and the model's M̃, C̃q̇, g̃, f̃
evaluated with the parameter estimate θ̃ (profile values or a `hil identify` file):

    PD    τ = J (K_p e + K_v ė) + g̃(q)                                        (independent joint)
    CT    τ = M̃(q) (K_p e + K_v ė + q̈_d) + C̃(q, q̇) q̇ + g̃(q) + f̃(q̇)          eq. (2)
    FED   τ = M̃(q_d) q̈_d + C̃(q_d, q̇_d) q̇_d + g̃(q_d) + f̃(q̇_d) + J (K_p e + K_v ė)  eq. (3)
    RFED  τ = J (K_p e + K_v ė + q̈_d) + C̃(q_d, q̇_d) q̇_d + g̃(q_d) + f̃(q̇_d)     eq. (4)

J is the constant diagonal of M̃ at a typical position (Section 2). The PD loop is scaled by the
same J so that, with the same K_p, K_v, every scheme aims at the closed loop s² + k_v s + k_p of
eq. (7) (Khosla & Kanade's equivalence between the computed-torque gains and independent joint
gains). The paper's h̃ is the Coriolis/centrifugal vector; this arm also has large viscous and
Coulomb friction, so the model-based schemes compensate f̃ with the same arguments as h̃.

Each law is written once, over the model's ``mass_matrix(θ, q)``, ``coriolis_vector(θ, q, q̇)``,
``gravity_vector(θ, q)`` and ``friction_torque(θ, q̇)``; ``len(gains.kp)`` joints. For the
2-DOF closed form these are the equations of Reyes & Kelly (1997) Section 5; for a URDF arm
Pinocchio's recursive Newton–Euler in regressor form (``computeJointTorqueRegressor``: C̃q̇ and
g̃ are RNEA at q̈ = 0 without and with gravity, column i of M̃ is RNEA at q̇ = 0, q̈ = e_i
without gravity, as CRBA's M) times the base parameters θ̃, so an identified base-parameter
vector drives the controller directly. Khosla & Kanade needed a custom Newton–Euler to do this
in 1.2 ms; here CT costs about 0.1 ms of CPU per period for 3 or 7 joints
(tests/benchmarks/bench_control.py, docs/control.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

from hil.model.closed_form import ArmModel

SCHEMES = ("pd", "ct", "fed", "rfed")
SCHEME_TITLES = {
    "pd": "PD + gravity compensation",
    "ct": "computed torque, eq. (2)",
    "fed": "feedforward dynamics compensation, eq. (3)",
    "rfed": "reduced feedforward compensation, eq. (4)",
}
FRICTION_VELOCITIES = ("measured", "reference")
CLOSED_FORM = ArmModel()  # the 9-parameter 2-DOF model: the default and fast path


class DynamicsModel(Protocol):
    """What a controller needs of a model (ArmModel and UrdfArmModel have it): the terms of
    τ = M̃(q) q̈ + C̃(q, q̇) q̇ + g̃(q) + f̃(q̇) for a parameter vector θ̃."""

    @property
    def n_joints(self) -> int: ...

    def mass_matrix(self, theta: ArrayLike, q: ArrayLike) -> np.ndarray: ...

    def coriolis_vector(self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike) -> np.ndarray: ...

    def gravity_vector(self, theta: ArrayLike, q: ArrayLike) -> np.ndarray: ...

    def friction_torque(self, theta: ArrayLike, dq: ArrayLike) -> np.ndarray: ...


@dataclass(frozen=True)
class Gains:
    """Diagonal position and velocity gains [1/s², 1/s] (Khosla & Kanade 1987, Table 1)."""

    kp: tuple[float, ...]
    kv: tuple[float, ...]

    def __post_init__(self) -> None:
        if len(self.kp) != len(self.kv):
            raise ValueError(f"{len(self.kp)} position gains but {len(self.kv)} velocity gains")
        for name, values in (("kp", self.kp), ("kv", self.kv)):
            if not all(np.isfinite(v) and v >= 0 for v in values):
                raise ValueError(f"gains {name} must be finite and >= 0, got {list(values)}")

    def damping_ratio(self) -> list[float]:
        """ζ of s² + k_v s + k_p per joint (1 = critically damped, eq. (8): k_v = 2√k_p)."""
        return [kv / (2 * np.sqrt(kp)) if kp > 0 else float("inf") for kp, kv in self.pairs()]

    def pairs(self) -> list[tuple[float, float]]:
        return list(zip(self.kp, self.kv, strict=True))


@dataclass(frozen=True)
class Reference:
    """Desired position, velocity, acceleration at one instant, each shape (n_joints,)."""

    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray


@dataclass(frozen=True)
class ControlCommand:
    tau: np.ndarray  # what is sent: tau_law clipped at ±limit
    tau_law: np.ndarray  # the control law's torque, = sum of parts
    clipped: np.ndarray  # bool per joint
    parts: dict[str, np.ndarray] = field(default_factory=dict)


def typical_inertia(
    theta: ArrayLike, q_typical: ArrayLike, model: DynamicsModel = CLOSED_FORM
) -> np.ndarray:
    """diag(M̃(q_typical)): the constant diagonal inertia J of eqs. (3)-(4), shape (n,)."""
    return np.diagonal(model.mass_matrix(theta, q_typical)).copy()


class BackwardDifference:
    """Velocity as a drive without a tachometer gives it: q̇_k = (q_k − q_{k−1}) / h.

    q_k are encoder readings, so the estimate moves in steps of one count per period
    (2π / (counts_per_rev · h)) and lags the true velocity by about h/2. The first call
    (no previous sample) returns zero velocity: the arm starts at rest.
    """

    def __init__(self, period_s: float, n_joints: int = 2) -> None:
        if not period_s > 0:
            raise ValueError(f"period must be > 0, got {period_s}")
        self.period_s = float(period_s)
        self._last: np.ndarray | None = None
        self._n = n_joints

    def __call__(self, q: ArrayLike) -> np.ndarray:
        q_arr = np.array(q, dtype=float)
        dq = np.zeros(self._n) if self._last is None else (q_arr - self._last) / self.period_s
        self._last = q_arr
        return dq


class Controller:
    """Base: model and its parameters θ̃, gains, typical inertia J, drive torque limits; the
    number of joints is the model's, and gains, limits and q_typical give one value per joint."""

    scheme: str = ""
    part_names: tuple[str, ...] = ()

    def __init__(
        self,
        theta: ArrayLike,
        gains: Gains,
        torque_limit_Nm: Sequence[float],
        *,
        model: DynamicsModel = CLOSED_FORM,
        q_typical: ArrayLike | None = None,
        friction_velocity: str = "measured",
    ) -> None:
        self.model = model
        n = model.n_joints
        self.theta = np.asarray(theta, dtype=float)
        self.gains = gains
        self.kp = np.asarray(gains.kp, dtype=float)
        self.kv = np.asarray(gains.kv, dtype=float)
        self.limit = np.asarray(torque_limit_Nm, dtype=float)
        self.q_typical = np.zeros(n) if q_typical is None else np.asarray(q_typical, dtype=float)
        for what, values in (
            ("gains", self.kp),
            ("torque limits", self.limit),
            ("typical position", self.q_typical),
        ):
            if values.shape != (n,):
                raise ValueError(f"{what}: need {n} values (one per joint), got {values.size}")
        if not np.all(self.limit > 0):
            raise ValueError(f"torque limits must be > 0, got {list(self.limit)}")
        if friction_velocity not in FRICTION_VELOCITIES:
            raise ValueError(
                f"friction_velocity must be one of {', '.join(FRICTION_VELOCITIES)}, "
                f"got {friction_velocity!r}"
            )
        self.friction_velocity = friction_velocity
        self.J = typical_inertia(self.theta, self.q_typical, model)

    def law(self, t: float, q: np.ndarray, dq: np.ndarray, ref: Reference) -> dict[str, np.ndarray]:
        """The control law's parts (their sum is the torque)."""
        raise NotImplementedError

    def __call__(self, t: float, q: ArrayLike, dq: ArrayLike, ref: Reference) -> ControlCommand:
        parts = self.law(t, np.asarray(q, dtype=float), np.asarray(dq, dtype=float), ref)
        tau_law = sum(parts.values(), np.zeros_like(self.limit))
        tau = np.clip(tau_law, -self.limit, self.limit)
        clipped = np.abs(tau_law) > self.limit
        return ControlCommand(tau=tau, tau_law=tau_law, clipped=clipped, parts=parts)

    def _servo(self, q: np.ndarray, dq: np.ndarray, ref: Reference) -> np.ndarray:
        """K_p e + K_v ė: the commanded acceleration of the feedback loop (eq. (6) without q̈_d)."""
        return self.kp * (ref.q - q) + self.kv * (ref.dq - dq)


class PDGravity(Controller):
    """τ = J (K_p e + K_v ė) + g̃(q): independent joint PD with gravity compensation."""

    scheme = "pd"
    part_names = ("feedback", "gravity")

    def law(self, t: float, q: np.ndarray, dq: np.ndarray, ref: Reference) -> dict[str, np.ndarray]:
        return {
            "feedback": self.J * self._servo(q, dq, ref),
            "gravity": self.model.gravity_vector(self.theta, q),
        }


class ComputedTorque(Controller):
    """Khosla & Kanade (1987) eq. (2), plus f̃(q̇); the split is that of Figs. 20-22."""

    scheme = "ct"
    part_names = ("inertial", "coriolis", "gravity", "friction")

    def law(self, t: float, q: np.ndarray, dq: np.ndarray, ref: Reference) -> dict[str, np.ndarray]:
        u = self._servo(q, dq, ref) + ref.ddq  # eq. (6)
        friction_dq = dq if self.friction_velocity == "measured" else ref.dq
        m, theta = self.model, self.theta
        return {
            "inertial": m.mass_matrix(theta, q) @ u,  # D̃(θ) u, eq. (2)
            "coriolis": m.coriolis_vector(theta, q, dq),  # h̃(θ, θ̇)
            "gravity": m.gravity_vector(theta, q),  # g̃(θ)
            "friction": m.friction_torque(theta, friction_dq),
        }


class Feedforward(Controller):
    """Khosla & Kanade (1987) eq. (3): inverse dynamics along the reference, plus J-scaled PD."""

    scheme = "fed"
    part_names = ("inertial", "coriolis", "gravity", "friction", "feedback")

    def law(self, t: float, q: np.ndarray, dq: np.ndarray, ref: Reference) -> dict[str, np.ndarray]:
        m, theta = self.model, self.theta
        return {
            "inertial": m.mass_matrix(theta, ref.q) @ ref.ddq,  # D̃(θ_d) θ̈_d
            "coriolis": m.coriolis_vector(theta, ref.q, ref.dq),  # h̃(θ_d, θ̇_d)
            "gravity": m.gravity_vector(theta, ref.q),  # g̃(θ_d)
            "friction": m.friction_torque(theta, ref.dq),
            "feedback": self.J * self._servo(q, dq, ref),  # J [K_p e + K_v ė]
        }


class ReducedFeedforward(Controller):
    """Khosla & Kanade (1987) eq. (4): eq. (3) with the constant diagonal J in place of D̃(θ_d)."""

    scheme = "rfed"
    part_names = ("inertial", "coriolis", "gravity", "friction", "feedback")

    def law(self, t: float, q: np.ndarray, dq: np.ndarray, ref: Reference) -> dict[str, np.ndarray]:
        m, theta = self.model, self.theta
        return {
            "inertial": self.J * ref.ddq,  # J θ̈_d: no off-diagonal (coupling) inertia
            "coriolis": m.coriolis_vector(theta, ref.q, ref.dq),
            "gravity": m.gravity_vector(theta, ref.q),
            "friction": m.friction_torque(theta, ref.dq),
            "feedback": self.J * self._servo(q, dq, ref),
        }


CONTROLLERS: dict[str, type[Controller]] = {
    c.scheme: c for c in (PDGravity, ComputedTorque, Feedforward, ReducedFeedforward)
}


def make_controller(
    scheme: str,
    theta: ArrayLike,
    gains: Gains,
    torque_limit_Nm: Sequence[float],
    *,
    model: DynamicsModel = CLOSED_FORM,
    q_typical: ArrayLike | None = None,
    friction_velocity: str = "measured",
) -> Controller:
    """The controller of ``scheme`` (pd, ct, fed, rfed) on ``model`` (default: the 2-DOF closed
    form) with parameters ``theta`` (that model's: θ1..θ9, or a URDF arm's base parameters)."""
    if scheme not in CONTROLLERS:
        raise ValueError(f"unknown scheme {scheme!r}; expected one of {', '.join(SCHEMES)}")
    return CONTROLLERS[scheme](
        theta,
        gains,
        torque_limit_Nm,
        model=model,
        q_typical=q_typical,
        friction_velocity=friction_velocity,
    )


__all__ = [
    "SCHEMES",
    "SCHEME_TITLES",
    "ComputedTorque",
    "ControlCommand",
    "Controller",
    "DynamicsModel",
    "Feedforward",
    "Gains",
    "PDGravity",
    "ReducedFeedforward",
    "Reference",
    "make_controller",
]
