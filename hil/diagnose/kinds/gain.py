"""The torque gain error on one joint (τ_shaft = (1 + r) τ): the data fix only the ratio of the
joints' gains, so the selection, the physical gate and the reading treat it apart
(:attr:`~hil.diagnose.kinds.base.CandidateKind.is_gain`)."""

from __future__ import annotations

from typing import ClassVar

from hil.diagnose.finding import Finding, rounded
from hil.diagnose.kinds.base import CandidateKind, TermFit, register


class TorqueGain(CandidateKind):
    name = "gain"
    practical_floor = 0.005  # relative
    is_gain = True
    refit_on_training = False  # the joint it is on is a choice, not a fit
    words: ClassVar[dict[str, str]] = {"torque_gain": "the torque gain is off by {pct} %"}

    def findings(self, fit: TermFit) -> list[Finding]:
        return [
            Finding("torque_gain", fit.joint + 1, {"relative": rounded(float(fit.coef[0]))}, {})
        ]


GAIN = register(TorqueGain())
