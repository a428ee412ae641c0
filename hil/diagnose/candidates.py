"""The candidate vocabulary of the mismatch diagnosis: the terms the nominal model may lack.

Every kind of :data:`VOCABULARY` on every joint is a :class:`Candidate`: the values of its
nonlinear parameter (its variants: cogging periods, Stribeck velocities) and how its columns are
built from a recording's rows (:mod:`hil.diagnose.columns`); the model terms the nominal model
lacks (rotor inertia, centre-of-mass offset, :data:`hil.model.closed_form.TERMS`) are
candidates too. What a kind of candidate is (its width, floors, role, findings) is its
:class:`~hil.diagnose.kinds.base.CandidateKind` (:mod:`hil.diagnose.kinds`,
:attr:`Candidate.spec`). Here also: how many coefficients a candidate adds (:func:`term_width`),
whose rows it reaches (:func:`joints_of`), whether its estimate clears its kind's practical floor
(:func:`large_enough`), and :class:`Accepted`, a candidate the selection took.

Imports: :mod:`hil.diagnose.columns`, :mod:`hil.diagnose.kinds`, :mod:`hil.diagnose.stats` (the
evidence types) and :mod:`hil.model`; never the problem, the selection or the stages after it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hil.diagnose.columns import model_term_columns
from hil.diagnose.kinds import KINDS, kind_of
from hil.diagnose.kinds.base import Candidate, Library
from hil.diagnose.kinds.cogging import COGGING_PERIODS, cogging_periods
from hil.diagnose.kinds.stribeck import STRIBECK_MIN_ROWS, STRIBECK_VELOCITIES, stribeck_velocities
from hil.diagnose.stats import CrossValidation, Evidence
from hil.model.closed_form import TERMS, ArmModel
from hil.model.protocol import ArmDynamics

VOCABULARY = (
    "coulomb_asymmetry",
    "torque_offset",
    "stribeck",
    "cogging",
    "actuator_lag",
    "transport_delay",
    "angle_offset",
    "torque_gain",
    *TERMS,  # rotor_inertia, com_offset: model terms the nominal model lacks (closed_form)
)


LAG_GRID_S = np.geomspace(5e-5, 0.03, 28)  # lag and delay search, then refined locally


@dataclass
class Accepted:
    cand: Candidate
    variant: Any
    evidence: Evidence
    confounded_with: list[str] = field(default_factory=list)
    rival_variants: dict[str, Any] = field(default_factory=dict)


def model_term_candidates(model: ArmDynamics) -> list[Candidate]:
    """The model terms ``model`` lacks, as candidates: their columns are the regressor columns
    the model with the term appends (:func:`hil.diagnose.columns.model_term_columns`)."""
    return [
        Candidate(
            term, kind_of(term).joint, (None,), lambda r, _v, t=term: model_term_columns(r, t)
        )
        for term in model.missing_terms  # none for a URDF model (its refused_terms say why)
    ]


def candidates(
    theta: np.ndarray,
    angle_range_rad: Sequence[float] = (np.pi, np.pi),
    speeds: Sequence[np.ndarray] | None = None,
    model: ArmDynamics | None = None,
) -> list[Candidate]:
    """The candidate library, both joints. ``speeds``: per joint, |q̇| of the usable rows
    (limits the Stribeck velocities tried; without it all are). ``model``: the nominal model
    (default the 9-parameter one); the model terms it lacks are candidates too, after the
    others."""
    model = ArmModel(()) if model is None else model
    library = Library(np.asarray(theta, float), angle_range_rad, speeds, model)
    kinds = sorted((k for k in KINDS.values() if not k.model_term), key=lambda k: k.order)
    out = [c for j in range(model.n_joints) for k in kinds for c in k.candidates(j, library)]
    return out + model_term_candidates(model)


def term_width(cand: Candidate) -> int:
    """Number of coefficients a candidate adds."""
    return cand.spec.width


def term_key(a: Accepted) -> tuple[str, int]:
    return (a.cand.key, a.cand.variants.index(a.variant))


def joints_of(cand: Candidate) -> list[int]:
    """The rows a candidate's columns act on: an angle offset moves gravity on both joints, a
    centre-of-mass offset the inertia and gravity of both (on an n-joint arm: ``acts_on``)."""
    if cand.acts_on is not None:
        return list(cand.acts_on)
    return cand.spec.joints(cand.joint)


def large_enough(cand: Candidate, cv: CrossValidation) -> bool:
    """The full-data estimate is above its kind's practical floor and has the physical sign
    (the candidate's coefficients are the last of ``cv.beta``, θ its first ones)."""
    return cand.spec.large_enough(cv.beta[-term_width(cand) :], cv.beta)


__all__ = [
    "COGGING_PERIODS",
    "LAG_GRID_S",
    "STRIBECK_MIN_ROWS",
    "STRIBECK_VELOCITIES",
    "VOCABULARY",
    "Accepted",
    "Candidate",
    "candidates",
    "cogging_periods",
    "joints_of",
    "large_enough",
    "model_term_candidates",
    "stribeck_velocities",
    "term_key",
    "term_width",
]
