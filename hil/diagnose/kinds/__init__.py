"""The kinds of candidate term the diagnosis's refit may add, one module per kind.

Each module defines one :class:`~hil.diagnose.kinds.base.CandidateKind` and registers it
(:func:`~hil.diagnose.kinds.base.register`); a :class:`hil.diagnose.candidates.Candidate` names
its kind and finds it in :data:`KINDS`. The selection, the physical gate, the interpretation,
the held-out fit and the simulation gate ask the kind what they need (its width, the joints it
acts on, its practical floor, whether it is a gain or a torque-rate term, its findings), never
its name; the report reads a finding in its kind's words, and the held-out simulation applies
it through its kind (:meth:`~hil.diagnose.kinds.base.CandidateKind.simulate`). A kind builds its
own candidates on each joint (:meth:`~hil.diagnose.kinds.base.CandidateKind.candidates`, in
:attr:`~hil.diagnose.kinds.base.CandidateKind.order`): adding a kind is one file here plus its
import below (tests/test_diagnose_kinds.py registers a toy kind from the test).

Why not the drift path's effects (:mod:`hil.diagnose.effects`): an effect is fitted against a
fixed nominal θ₀ over one stacked context, linearised and stepped (Gauss–Newton), sized against
the joint's RMS torque and simulated through :class:`~hil.diagnose.effects.base.SimInput`; a
candidate kind adds columns to a refit of θ itself, is tried over a grid of variants, floored in
absolute units and read with the refitted θ. The registry order of the effects is also the
drift's test order; the two vocabularies share names of findings, not their arithmetic.

Imports: :mod:`hil.diagnose.columns`, :mod:`hil.diagnose.finding` and :mod:`hil.model`; never
the candidates, the selection or the stages after it.
"""

from hil.diagnose.kinds import (  # noqa: F401  (each module registers its kind)
    angle,
    cogging,
    com_offset,
    gain,
    offset,
    rate,
    rotor_inertia,
    stribeck,
)
from hil.diagnose.kinds.base import (
    KINDS,
    Candidate,
    CandidateKind,
    Library,
    TermFit,
    finding_words,
    is_gain_finding,
    kind_of,
    kind_of_finding,
    rate_findings,
    register,
)

__all__ = [
    "KINDS",
    "Candidate",
    "CandidateKind",
    "Library",
    "TermFit",
    "finding_words",
    "is_gain_finding",
    "kind_of",
    "kind_of_finding",
    "rate_findings",
    "register",
]
