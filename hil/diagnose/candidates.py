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

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hil.diagnose.columns import (
    RecordingRows,
    angle_offset_column,
    cogging_column_chunks,
    cogging_columns,
    gain_column,
    model_term_columns,
    offset_column,
    stribeck_column,
    torque_rate_column,
)
from hil.diagnose.kinds import CandidateKind, kind_of
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


COGGING_PERIODS = np.arange(3, 401)
STRIBECK_VELOCITIES = np.geomspace(0.02, 0.6, 16)
LAG_GRID_S = np.geomspace(5e-5, 0.03, 28)  # lag and delay search, then refined locally


@dataclass(frozen=True)
class Candidate:
    """One term of the vocabulary on one joint (0 or 1): ``variants`` are the values of its
    nonlinear parameter (one None when it has none); ``columns(rows, variant)`` its X."""

    kind: str  # the name of its kind in hil.diagnose.kinds.KINDS (offset, gain, ..., com_offset)
    joint: int
    variants: tuple[Any, ...]
    columns: Callable[[RecordingRows, Any], np.ndarray]
    # X of many variants on the candidate's joint, ``per`` at a time ((K, ≤per, width) arrays),
    # when that is cheaper than one by one
    chunks: Callable[[RecordingRows, tuple[Any, ...], int], Iterator[np.ndarray]] | None = None
    # the joints whose rows the columns reach, when not :func:`joints_of`' 2-DOF rule (an angle
    # offset on an n-joint arm moves the gravity and inertia torques of every joint)
    acts_on: tuple[int, ...] | None = None

    @property
    def spec(self) -> CandidateKind:
        """Its kind: width, floors, role and findings (:mod:`hil.diagnose.kinds`)."""
        return kind_of(self.kind)

    @property
    def key(self) -> str:
        # a model term is one term of the arm's model, not one joint's (it may act on both)
        return self.spec.key(self.joint)


@dataclass
class Accepted:
    cand: Candidate
    variant: Any
    evidence: Evidence
    confounded_with: list[str] = field(default_factory=list)
    rival_variants: dict[str, Any] = field(default_factory=dict)


def cogging_periods(angle_range_rad: float) -> tuple[int, ...]:
    """Periods per revolution worth testing on a joint that swept ``angle_range_rad``: at least
    two whole periods inside the range (fewer is a smooth function of q that gravity, an angle
    offset or a torque offset also make), up to COGGING_PERIODS' top."""
    lowest = max(int(COGGING_PERIODS[0]), int(np.ceil(2 * 2 * np.pi / max(angle_range_rad, 1e-9))))
    return tuple(int(n) for n in COGGING_PERIODS if n >= lowest)


# A Stribeck velocity v_s is tried only where this many usable rows slide slower than 2 v_s:
# fewer, and a handful of rows next to a stick or reversal would decide the fit alone.
STRIBECK_MIN_ROWS = 200


def stribeck_velocities(speeds: np.ndarray | None) -> tuple[float, ...]:
    """The Stribeck velocities the data can support (``speeds``: |q̇| of the usable rows)."""
    if speeds is None:
        return tuple(float(v) for v in STRIBECK_VELOCITIES)
    return tuple(
        float(v) for v in STRIBECK_VELOCITIES if np.sum(speeds < 2 * v) >= STRIBECK_MIN_ROWS
    )


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
    out: list[Candidate] = []
    model = ArmModel(()) if model is None else model
    refused = model.refused_terms
    for j in range(model.n_joints):
        stribeck = stribeck_velocities(None if speeds is None else speeds[j])
        if stribeck:
            out.append(
                Candidate("stribeck", j, stribeck, lambda r, v, j=j: stribeck_column(r, j, v))
            )
        if "offset" not in refused:
            out.append(Candidate("offset", j, (None,), lambda r, _v, j=j: offset_column(r, j)))
        out += [
            Candidate("gain", j, (None,), lambda r, _v, j=j: gain_column(r, j)),
            Candidate(
                "cogging",
                j,
                cogging_periods(angle_range_rad[j]),
                lambda r, n, j=j: cogging_columns(r, j, n),
                lambda r, ns, per, j=j: cogging_column_chunks(r, j, ns, per),
            ),
            Candidate("rate", j, (None,), lambda r, _v, j=j: torque_rate_column(r, j)),
            Candidate(
                "angle",
                j,
                (None,),
                lambda r, _v, j=j, th=theta: angle_offset_column(r, j, th),
                acts_on=None if model.closed_form else tuple(range(model.n_joints)),
            ),
        ]
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
