"""The centre-of-mass offset model term: link 2's centre of mass off its axis (θ2⊥ in the
inertia, θ4⊥, θ5⊥ in gravity), acting on both joints' rows; floored by the largest of θ2⊥
against θ2 and (θ4⊥, θ5⊥) against (θ4, θ5)."""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from hil.diagnose.finding import Finding, rounded
from hil.diagnose.kinds.base import TermFit, register
from hil.diagnose.kinds.model_term import ModelTermKind


class ComOffset(ModelTermKind):
    name = "com_offset"
    joint = 0
    both_joints = True
    words: ClassVar[dict[str, str]] = {
        "com_offset": (
            "the centres of mass lie off the link axes (or an encoder zero is off): "
            "θ2⊥ = {theta2_perp_kgm2:.3g} kg m², θ4⊥ = {theta4_perp_Nm:.3g} Nm, "
            "θ5⊥ = {theta5_perp_Nm:.3g} Nm"
        ),
    }

    def relative_size(self, coef: np.ndarray, rigid: np.ndarray) -> float:
        return max(
            abs(float(coef[0])) / rigid[1],
            float(np.hypot(coef[1], coef[2]) / np.hypot(rigid[3], rigid[4])),
        )

    def findings(self, fit: TermFit) -> list[Finding]:
        estimate = {
            "theta2_perp_kgm2": rounded(float(fit.coef[0])),
            "theta4_perp_Nm": rounded(float(fit.coef[1])),
            "theta5_perp_Nm": rounded(float(fit.coef[2])),
        }
        return [Finding("com_offset", None, estimate, {})]


COM_OFFSET = register(ComOffset())
