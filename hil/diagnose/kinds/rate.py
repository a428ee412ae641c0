"""The torque-rate term on one joint (τ_shaft ≈ τ − T τ̇, two coefficients whose sum is T): the
first order of an actuator lag or a transport delay, told apart afterwards from the exact shaft
torques (:func:`hil.diagnose.findings.classify_rate`)."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from hil.diagnose.columns import torque_rate_column
from hil.diagnose.finding import Finding, rounded
from hil.diagnose.kinds.base import Candidate, CandidateKind, Library, TermFit, register


class TorqueRate(CandidateKind):
    name = "rate"
    order = 50
    width = 2
    practical_floor = 1e-4  # s, > 0
    positive_only = True
    is_rate = True
    refit_on_training = False  # its lag or delay is a grid search, not a fit
    words: ClassVar[dict[str, str]] = {
        "actuator_lag": "the actuator lags the command (first order, time constant {ms} ms)",
        "transport_delay": "the commands arrive late (pure delay {ms} ms)",
    }

    def findings(self, fit: TermFit) -> list[Finding]:
        # only as a rival: its first order, lag and delay undecided
        estimate = {"time_constant_s": rounded(float(np.sum(fit.coef)))}
        return [Finding("actuator_lag", fit.joint + 1, estimate, {})]

    def candidates(self, joint: int, library: Library) -> list[Candidate]:
        return [Candidate(self.name, joint, (None,), lambda r, _v: torque_rate_column(r, joint))]

    def simulate(self, finding: Finding, effects: Any) -> None:
        j, e = (finding.joint or 1) - 1, finding.estimate
        if finding.effect == "actuator_lag":
            effects.lag[j] = max(0.0, e["time_constant_s"])
        elif not finding.confounded_with:  # a delay: the 2-DOF simulator's one, the last found
            effects.last_delay = max(0.0, e["delay_s"])
            for i in range(len(effects.delay)) if finding.joint is None else (j,):
                effects.delay[i] = effects.last_delay


RATE = register(TorqueRate())
