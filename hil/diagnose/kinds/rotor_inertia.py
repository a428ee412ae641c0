"""The rotor inertia model term: M22 − M12's constant part beyond θ3 (gr² Ir ∓ gr Ir,
:mod:`hil.model.closed_form`), on joint 2's rows; floored against θ3 (M22's rigid part); one that
is not positive is below the floor (no physical arm has it)."""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from hil.diagnose.finding import Finding, rounded
from hil.diagnose.kinds.base import TermFit, register
from hil.diagnose.kinds.model_term import ModelTermKind


class RotorInertia(ModelTermKind):
    name = "rotor_inertia"
    joint = 1
    positive_only = True
    words: ClassVar[dict[str, str]] = {
        "rotor_inertia": (
            "a reflected rotor inertia the model lacks: M22 exceeds M12's constant part by "
            "{theta_rotor_kgm2:.3g} kg m² beyond θ3 ({share} % of M22)"
        ),
    }

    def relative_size(self, coef: np.ndarray, rigid: np.ndarray) -> float:
        return float(coef[0]) / rigid[2]

    def findings(self, fit: TermFit) -> list[Finding]:
        rot = float(fit.coef[0])
        estimate = {
            "theta_rotor_kgm2": rounded(rot),
            "share_of_M22": rounded(rot / (float(fit.theta[2]) + rot)),
        }
        return [Finding("rotor_inertia", 2, estimate, {})]


ROTOR_INERTIA = register(RotorInertia())
