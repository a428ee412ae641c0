"""The torque gain error on one joint (τ_shaft = (1 + r) τ): the data fix only the ratio of the
joints' gains, so the selection, the physical gate and the reading treat it apart
(:attr:`~hil.diagnose.kinds.base.CandidateKind.is_gain`)."""

from __future__ import annotations

from typing import Any, ClassVar

from hil.diagnose.columns import gain_column
from hil.diagnose.finding import Finding, rounded
from hil.diagnose.kinds.base import Candidate, CandidateKind, Library, TermFit, register


class TorqueGain(CandidateKind):
    name = "gain"
    order = 30
    practical_floor = 0.005  # relative
    is_gain = True
    refit_on_training = False  # the joint it is on is a choice, not a fit
    words: ClassVar[dict[str, str]] = {"torque_gain": "the torque gain is off by {pct} %"}

    def findings(self, fit: TermFit) -> list[Finding]:
        return [
            Finding("torque_gain", fit.joint + 1, {"relative": rounded(float(fit.coef[0]))}, {})
        ]

    def candidates(self, joint: int, library: Library) -> list[Candidate]:
        return [Candidate(self.name, joint, (None,), lambda r, _v: gain_column(r, joint))]

    def simulate(self, finding: Finding, effects: Any) -> None:
        if not finding.confounded_with:
            e = finding.estimate  # the reading reported (hil.diagnose.gates.simulation_gate)
            effects.gain[(finding.joint or 1) - 1] = e[e.get("reading", "relative")]


GAIN = register(TorqueGain())
