"""The candidate-kind interface and its registry (:mod:`hil.diagnose.kinds`).

A :class:`CandidateKind` is one kind of term the refit may add to the nominal model (a torque
offset, a cogging, a model term, ...): how many coefficients it adds, which joints its columns
act on, how large its coefficients must be to matter, the role it plays in the rules that are
about one physical thing (a torque gain, a torque-rate term), and how its coefficients read as
findings. :data:`KINDS` maps a kind's name (:attr:`hil.diagnose.candidates.Candidate.kind`) to
its object.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, NamedTuple

import numpy as np

from hil.diagnose.columns import RecordingRows
from hil.diagnose.finding import Finding
from hil.model.protocol import ArmDynamics


class TermFit(NamedTuple):
    """One term's fit, what its findings are read from: the joint it is on (0-based), its
    variant, its coefficients ``coef``, θ of the same fit and the model θ is of (None: the
    2-DOF model)."""

    joint: int
    variant: Any
    coef: np.ndarray
    theta: np.ndarray
    model: ArmDynamics | None = None


@dataclass(frozen=True)
class Candidate:
    """One term of a kind on one joint (0-based): ``variants`` are the values of its nonlinear
    parameter (one None when it has none); ``columns(rows, variant)`` its X."""

    kind: str  # the name of its kind in KINDS (offset, gain, ..., com_offset)
    joint: int
    variants: tuple[Any, ...]
    columns: Callable[[RecordingRows, Any], np.ndarray]
    # X of many variants on the candidate's joint, ``per`` at a time ((K, ≤per, width) arrays),
    # when that is cheaper than one by one
    chunks: Callable[[RecordingRows, tuple[Any, ...], int], Iterator[np.ndarray]] | None = None
    # the joints whose rows the columns reach, when not the kind's 2-DOF rule (an angle offset
    # on an n-joint arm moves the gravity and inertia torques of every joint)
    acts_on: tuple[int, ...] | None = None

    @property
    def spec(self) -> CandidateKind:
        """Its kind: width, floors, role and findings."""
        return kind_of(self.kind)

    @property
    def key(self) -> str:
        # a model term is one term of the arm's model, not one joint's (it may act on both)
        return self.spec.key(self.joint)


@dataclass(frozen=True)
class Library:
    """What a kind's candidates on a joint are built from (:meth:`CandidateKind.candidates`):
    the nominal fit's θ, each joint's swept angle range (rad), the usable rows' |q̇| per joint
    (None: not limited) and the nominal model."""

    theta: np.ndarray
    angle_range_rad: Sequence[float]
    speeds: Sequence[np.ndarray] | None
    model: ArmDynamics


class CandidateKind:
    """One kind of candidate term. Subclasses set the class attributes, :meth:`candidates` and
    :meth:`findings`."""

    name: str = ""
    # its place among a joint's candidates (the library's order: the selection breaks ties in it)
    order: int = 100
    width: int = 1  # coefficients it adds to the design
    # a term of the arm's model (hil.model.closed_form.TERMS): one term of the arm, not of a
    # joint (its key names no joint), fitted as part of θ and simulated in θ itself
    model_term: bool = False
    # on the 2-DOF arm its columns act on both joints' rows (a candidate's ``acts_on`` says so
    # on an n-joint arm)
    both_joints: bool = False
    # the smallest size that matters for this arm (the unit of :meth:`size`), and whether only
    # a positive size is physical (a lag, not a lead)
    practical_floor: float = 0.0
    positive_only: bool = False
    # a torque gain error: only the ratio of the joints' gains is known, so the selection, the
    # physical gate and the reading have rules of their own for it
    is_gain: bool = False
    # a torque-rate term: a lag or delay to tell apart from the exact shaft torque; the rate
    # terms of all joints are read together and gated as one term, "rate"
    is_rate: bool = False
    # its finding's magnitude is refitted on the training part for the held-out comparison
    # (False: a grid search, a choice of joint, or a term simulated in θ itself)
    refit_on_training: bool = True
    # a function of one joint's velocity alone: it must beat a generic binned velocity model
    velocity_shaped: bool = False
    # its column is built at a θ (:meth:`column_at`): rebuilt about the refitted θ once accepted
    built_at_theta: bool = False
    # two findings of one column the data cannot tell apart (reported confounded)
    confounded_findings: tuple[str, ...] = ()
    # its findings in words, by effect: templates of their estimates' keys (and the report's
    # derived ones: ms, deg, pct, share, neg)
    words: ClassVar[dict[str, str]] = {}

    def key(self, joint: int) -> str:
        """The term's key: ``name:joint`` (1-based), a model term's name alone."""
        return self.name if self.model_term else f"{self.name}:{joint + 1}"

    def joints(self, joint: int) -> list[int]:
        """The 2-DOF arm's joints whose rows the columns of the term on ``joint`` act on."""
        return [0, 1] if self.both_joints else [joint]

    def size(self, coef: np.ndarray) -> float:
        """The size the practical floor is read against: one coefficient, or their sum."""
        return float(np.sum(coef))

    def large_enough(self, coef: np.ndarray, theta: np.ndarray) -> bool:
        """The estimate ``coef`` (θ of the same fit: ``theta``) clears the practical floor with
        the physical sign."""
        size = self.size(coef)
        if self.positive_only and size <= 0:
            return False
        return abs(size) >= self.practical_floor

    def column_at(self, rows: RecordingRows, joint: int, theta: np.ndarray) -> np.ndarray:
        """Its column on ``joint`` built at ``theta`` (a kind :attr:`built_at_theta`)."""
        raise NotImplementedError

    def findings(self, fit: TermFit) -> list[Finding]:
        """The findings of one term's ``fit``, in the vocabulary."""
        raise NotImplementedError

    def candidates(self, joint: int, library: Library) -> list[Candidate]:
        """Its candidates on ``joint`` (a model term's come from the model:
        :func:`hil.diagnose.candidates.model_term_candidates`)."""
        return []

    def simulate(self, finding: Finding, effects: Any) -> None:
        """Put ``finding`` (one of its :attr:`words`' effects) into the held-out simulation's
        ``effects`` (:class:`hil.diagnose.heldout.SimulatedEffects`, whose per-joint lists it
        sets); by default it is not simulated (a model term is simulated in θ itself)."""


KINDS: dict[str, CandidateKind] = {}


def register(kind: CandidateKind) -> CandidateKind:
    """Add ``kind`` to the registry (by its name; a name registered again replaces it)."""
    if not kind.name:
        raise ValueError("a candidate kind needs a name")
    KINDS[kind.name] = kind
    return kind


def finding_words() -> dict[str, str]:
    """The words of every registered kind's findings, by effect (:attr:`CandidateKind.words`)."""
    return {effect: words for kind in KINDS.values() for effect, words in kind.words.items()}


def kind_of(name: str) -> CandidateKind:
    """The registered kind called ``name``."""
    return KINDS[name]


def kind_of_finding(effect: str) -> CandidateKind | None:
    """The registered kind whose findings include ``effect`` (its :attr:`~CandidateKind.words`);
    None for a finding of no kind (an unexplained structure)."""
    return next((k for k in KINDS.values() if effect in k.words), None)


def is_gain_finding(effect: str) -> bool:
    """A finding of a torque-gain kind (:attr:`CandidateKind.is_gain`: only the joints' gain
    ratio is known, so its reading and its report have rules of their own)."""
    kind = kind_of_finding(effect)
    return kind is not None and kind.is_gain


def rate_findings() -> tuple[str, ...]:
    """The findings of the torque-rate kinds (:attr:`CandidateKind.is_rate`), sorted: a lag
    and a delay, read and gated together as one term, "rate"."""
    return tuple(sorted(e for k in KINDS.values() if k.is_rate for e in k.words))
