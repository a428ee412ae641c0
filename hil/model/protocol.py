"""The one interface every arm model declares: what analyses may ask of a model.

:class:`hil.model.closed_form.ArmModel` (Reyes & Kelly's 2-DOF arm in closed form) and
:class:`hil.model.urdf.UrdfArmModel` (any URDF arm through Pinocchio) both satisfy
:class:`ArmDynamics`; identification, diagnosis and control take an ``ArmDynamics`` and ask it
(``model.closed_form``, ``model.rigid_count``, ``model.refused_terms`` ...) instead of testing
its class. A new arm model is a class with these members (tests/test_model_protocol.py checks
both shipped ones with ``isinstance(model, ArmDynamics)``).

Imports: numpy typing only.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["ArmDynamics"]


@runtime_checkable
class ArmDynamics(Protocol):
    """An arm's rigid-body model, linear in named parameters θ (samples along leading axes)."""

    #: True for the 2-DOF closed form: it has its own compiled open-loop simulator and the
    #: 2-DOF model terms (rotor inertia, COM offsets) as optional columns.
    closed_form: bool
    n_joints: int
    terms: tuple[str, ...]
    #: per joint, True where it turns (its coordinate an angle), False where it slides: how the
    #: torques depend on a shift of that joint's reading (:mod:`hil.diagnose.effects.encoder`)
    revolute: tuple[bool, ...]

    @property
    def names(self) -> tuple[str, ...]: ...

    @property
    def units(self) -> tuple[str, ...]: ...

    @property
    def meanings(self) -> tuple[str, ...]:
        """What each parameter is (a URDF arm's base parameter: its standard combination)."""
        ...

    @property
    def n_params(self) -> int: ...

    @property
    def friction_columns(self) -> tuple[int, ...]: ...

    @property
    def rigid_count(self) -> int:
        """How many of θ's first parameters are rigid-body ones (the rest: friction, terms)."""
        ...

    @property
    def display_name(self) -> str:
        """How reports name the model ("9-parameter", "22-base-parameter kuka-lwr4 (7 joints)")."""
        ...

    @property
    def rigid_words(self) -> str:
        """How reports name the rigid-body parameters ("θ1..θ5 of the 2-DOF arm")."""
        ...

    @property
    def missing_terms(self) -> tuple[str, ...]:
        """Optional model terms this model could take but does not have."""
        ...

    @property
    def refused_terms(self) -> dict[str, str]:
        """Physics a diagnosis must not offer as missing for this model, with the reason."""
        ...

    @property
    def nonnegative_columns(self) -> tuple[int, ...]: ...

    def term_columns(self, term: str) -> slice: ...

    def momentum_regressor(self, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """P(q, q̇) with P θ = M(q) q̇ (Reyes & Kelly (1997) eq. (11))."""
        ...

    def static_regressor(self, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """R(q, q̇) with τ = d/dt[P θ] + R θ (Reyes & Kelly (1997) eq. (12))."""
        ...

    def momentum(self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """P(q, q̇) θ = M(q) q̇ without P's columns (the diagnosis's torque rows)."""
        ...

    def static_torque(self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike) -> np.ndarray:
        """R(q, q̇) θ without R's columns."""
        ...

    def momentum_at_shifts(
        self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike, joint: int, shifts: ArrayLike
    ) -> np.ndarray:
        """:meth:`momentum` at q + s e_joint for each s of ``shifts``, (S, ..., n): an encoder
        offset's torques (:mod:`hil.diagnose.effects.encoder`)."""
        ...

    def static_torque_at_shifts(
        self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike, joint: int, shifts: ArrayLike
    ) -> np.ndarray:
        """:meth:`static_torque` at q + s e_joint for each s of ``shifts``, (S, ..., n)."""
        ...

    def energy_regressor(self, q: ArrayLike, dq: ArrayLike) -> np.ndarray: ...

    def friction_power_regressor(self, dq: ArrayLike) -> np.ndarray: ...

    def mass_matrix(self, theta: ArrayLike, q: ArrayLike) -> np.ndarray: ...

    def coriolis_vector(self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike) -> np.ndarray: ...

    def gravity_vector(self, theta: ArrayLike, q: ArrayLike) -> np.ndarray: ...

    def friction_torque(self, theta: ArrayLike, dq: ArrayLike) -> np.ndarray: ...

    def torque(
        self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike, ddq: ArrayLike
    ) -> np.ndarray: ...

    def forward_dynamics(
        self, theta: ArrayLike, q: ArrayLike, dq: ArrayLike, tau: ArrayLike
    ) -> np.ndarray: ...

    def physical_consistency(self, theta: ArrayLike) -> dict[str, object]: ...
