"""What the model terms (:data:`hil.model.closed_form.TERMS`: rotor inertia, centre-of-mass
offset) share as candidates: their coefficients are parameters of the arm's model, appended to θ,
and their floor is relative to the rigid-body parameters they join, since arms differ in size by
orders of magnitude (:data:`RELATIVE_FLOOR`)."""

from __future__ import annotations

import numpy as np

from hil.diagnose.kinds.base import CandidateKind
from hil.model.closed_form import ArmModel

RELATIVE_FLOOR = 0.01


class ModelTermKind(CandidateKind):
    model_term = True
    refit_on_training = False  # simulated in θ itself
    joint = 0  # the joint whose rows its columns reach first (its key names no joint)

    @property
    def width(self) -> int:  # type: ignore[override]
        return ArmModel((self.name,)).n_params - ArmModel(()).n_params

    def relative_size(self, coef: np.ndarray, rigid: np.ndarray) -> float:
        """The term's size against the rigid-body parameters ``rigid`` (|θ1..θ5|, never 0)."""
        raise NotImplementedError

    def large_enough(self, coef: np.ndarray, theta: np.ndarray) -> bool:
        rigid = np.abs(np.asarray(theta, float)[:5]) + 1e-12
        return self.relative_size(coef, rigid) >= RELATIVE_FLOOR
