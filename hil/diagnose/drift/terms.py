"""The drift stage's vocabulary: the nominal model (:class:`Nominal`), a drift pattern's term in
a fit (:class:`Term`), the stage's result (:class:`DriftResult`) and its constants.

Imports the effect registry's types and :mod:`hil.diagnose.problem`'s problem only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hil.diagnose.effects import Effect
from hil.diagnose.findings import Finding
from hil.diagnose.problem import Problem
from hil.model.protocol import ArmDynamics

# The nominal model is judged against when its held-out torque error with the drift patterns is
# at most this factor of the error of θ refitted from the recording alone on every joint: a
# model that predicts the recording that much worse than the recording's own fit does not
# describe this arm (another arm, another load case), and its drift would be a wrong story.
NOMINAL_TOLERANCE = 1.5
RESOLVED_SE = 2.0  # a finding's size must exceed this many of its standard errors
GATE_ROUNDS = 4  # selections run again after a term failed a gate
# The recording runs the reference's motion again (its regressor rows within this fraction of the
# reference's, block for block): the model's error then falls in the same blocks on both sides
# and the change is judged block-paired (:func:`change_se`)
SAME_MOTION = 0.1


@dataclass
class Nominal:
    """The model the recording is judged against: θ₀ in ``model``'s parameters, where it came
    from (``source``: profile | params | reference) and why it is the one used."""

    theta: np.ndarray
    model: ArmDynamics
    source: str
    why: str
    theta_se: np.ndarray | None = None
    # bootstrap draws of θ₀ (draws, p) when it was identified: its own uncertainty, which a
    # drift must exceed as well as the recording's (a θ₀ off by its error leaves a structured
    # residual that the patterns project onto)
    theta_draws: np.ndarray | None = None
    # the reference recordings' own departures from θ (effect name, joint, linearisation
    # point, coefficients): part of the nominal model, so that what persists is not a change
    terms: list[tuple[str, int | None, Any, np.ndarray]] = field(default_factory=list)
    reference: Problem | None = None  # the reference recordings' rows (the reverse check)
    geometry: dict[str, float] | None = None  # the 2-DOF arm's l1 and g (its payload pattern)
    # what effects built on the reference's rows at θ (:attr:`Context.memo` of the
    # identification, whose θ this is): the reference judged later reuses them (a 7-joint
    # arm's encoder rows are 5 torque builds per joint)
    memo: dict = field(default_factory=dict)


@dataclass
class Term:
    effect: Effect
    joint: int | None
    at: Any = None
    cols: np.ndarray | None = None  # raw (K, n, width)
    shift: np.ndarray | None = None  # raw (K, n): the model's change at ``at``
    searched: bool = False  # its starting points (:meth:`Effect.starts`) have been tried

    @property
    def width(self) -> int:
        """Its number of coefficients (its columns', once built)."""
        return self.effect.width if self.cols is None else self.cols.shape[-1]

    @property
    def key(self) -> str:
        return self.effect.name + ("" if self.joint is None else f":{self.joint + 1}")


@dataclass
class DriftResult:
    document: dict[str, Any]
    findings: list[Finding] = field(default_factory=list)
    used: bool = True  # the nominal model described the recording (else: refit)
    # joint (1-based) -> the joints whose rows share a θ column with its rows: a refit of θ
    # from the recording moves them together (hil.diagnose.cli.merge_drift); empty: unknown
    shares: dict[int, set[int]] = field(default_factory=dict)
    # the change judged, for plots (:func:`hil.diagnose.drift.judge.change_arrays`): "t" (K,),
    # "change" (K, n) Nm (the paired difference r_rec − r_ref, or the recording's residual
    # against θ₀), "modelled" (K, n) Nm (the named findings' part of it), "weight" (K, n)
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
