"""Diagnosis against the model the user has: what changed since the nominal model θ₀.

The nominal model is the robot profile's (2-DOF closed form: its θ; a URDF arm: the URDF's base
parameters with the profile's friction), a ``--params`` file's θ, or one identified from
reference recordings of the same arm (:func:`nominal_from_reference`, the bounded least squares
``hil identify`` uses, on the diagnosis's own rows). The recording judged leaves the residual
r = y − Ψ θ₀ on its rows (:mod:`hil.diagnose.columns`); the registered drift patterns
(:mod:`hil.diagnose.effects`) are selected greedily against it with blocked cross-validation
(:mod:`hil.diagnose.stats`, the gates of :mod:`hil.diagnose.selection`), θ₀ held. A pattern is a
finding only when

1. it lowers the held-out error of the joints it acts on, block after block, on top of the
   other accepted patterns (leave-one-term-out: its own held-out proof);
2. its size exceeds twice its own blocked-jackknife standard error and the pattern's floor
   (never a finding below what the data can resolve);
3. the held-out simulated position of no joint gets worse with it (open-loop segments of the
   held-out part, :func:`hil.diagnose.heldout.simulated_segments`, the patterns fitted on the
   training part only).

A pattern whose declared partner fits as well in its place and adds nothing on top of it is
reported confounded with it, both sizes given, with the experiment that separates them.

Whether θ₀ describes the recording at all is decided by held-out prediction: the held-out
torque error of θ₀ with the drift patterns against that of θ refitted from the recording alone
(:data:`NOMINAL_TOLERANCE`); the report says which model it judged against and why.

The stage is a package: :mod:`~hil.diagnose.drift.terms` (the nominal model, a pattern's term,
the result), :mod:`~hil.diagnose.drift.fit` (the regression against θ₀),
:mod:`~hil.diagnose.drift.select` (gates and selection), :mod:`~hil.diagnose.drift.simulate`
(the held-out simulation gate) and :mod:`~hil.diagnose.drift.judge` (the whole judgement).
"""

from hil.diagnose.drift.fit import change_se, same_motion
from hil.diagnose.drift.judge import judge, nominal_from_reference
from hil.diagnose.drift.terms import (
    NOMINAL_TOLERANCE,
    RESOLVED_SE,
    SAME_MOTION,
    DriftResult,
    Nominal,
    Term,
)

__all__ = [
    "NOMINAL_TOLERANCE",
    "RESOLVED_SE",
    "SAME_MOTION",
    "DriftResult",
    "Nominal",
    "Term",
    "change_se",
    "judge",
    "nominal_from_reference",
    "same_motion",
]
