"""The torque offset on one joint: one column that is also a direction-dependent Coulomb
friction (F⁺ = θ_fc − c, F⁻ = θ_fc + c), so both readings are reported, confounded."""

from __future__ import annotations

from typing import Any, ClassVar

from hil.diagnose.columns import offset_column
from hil.diagnose.finding import Finding, coulomb_column, rounded
from hil.diagnose.kinds.base import Candidate, CandidateKind, Library, TermFit, register


class TorqueOffset(CandidateKind):
    name = "offset"
    order = 20
    practical_floor = 0.02  # Nm
    confounded_findings = ("coulomb_asymmetry", "torque_offset")
    words: ClassVar[dict[str, str]] = {
        "coulomb_asymmetry": (
            "Coulomb friction depends on the direction of motion: {positive_Nm:+.2f} Nm forward, "
            "{neg} Nm backward (the model assumed {symmetric_model_Nm:.2f} Nm both ways)"
        ),
        "torque_offset": "a constant torque offset of {offset_Nm:+.3g} Nm",
    }

    def findings(self, fit: TermFit) -> list[Finding]:
        c = float(fit.coef[0])
        fc = float(fit.theta[coulomb_column(fit.model, fit.joint)])
        return [
            Finding(
                "coulomb_asymmetry",
                fit.joint + 1,
                {
                    "positive_Nm": rounded(fc - c),
                    "negative_Nm": rounded(fc + c),
                    "difference_Nm": rounded(2 * c),
                    "symmetric_model_Nm": rounded(fc),
                },
                {},
                ["torque_offset"],
            ),
            Finding(
                "torque_offset", fit.joint + 1, {"offset_Nm": rounded(c)}, {}, ["coulomb_asymmetry"]
            ),
        ]

    def candidates(self, joint: int, library: Library) -> list[Candidate]:
        if self.name in library.model.refused_terms:  # the model says why (refused_terms)
            return []
        return [Candidate(self.name, joint, (None,), lambda r, _v: offset_column(r, joint))]

    def simulate(self, finding: Finding, effects: Any) -> None:
        if finding.effect == "torque_offset":  # its confounded reading stands for both
            effects.offset[(finding.joint or 1) - 1] = finding.estimate["offset_Nm"]


OFFSET = register(TorqueOffset())
