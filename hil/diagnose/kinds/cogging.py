"""Cogging on one joint: A sin(n q + φ), its variants the periods n per revolution; its two
coefficients are the sine and cosine parts, its size the amplitude."""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from hil.diagnose.finding import Finding, rounded
from hil.diagnose.kinds.base import CandidateKind, TermFit, register


class Cogging(CandidateKind):
    name = "cogging"
    width = 2
    practical_floor = 0.01  # Nm amplitude
    words: ClassVar[dict[str, str]] = {
        "cogging": (
            "cogging / torque ripple of {amplitude_Nm:.3g} Nm, "
            "{periods_per_rev} periods per revolution"
        ),
    }

    def size(self, coef: np.ndarray) -> float:
        return float(np.hypot(*coef))

    def findings(self, fit: TermFit) -> list[Finding]:
        a, b = float(fit.coef[0]), float(fit.coef[1])
        estimate = {
            "periods_per_rev": int(fit.variant),
            "amplitude_Nm": rounded(math.hypot(a, b)),
            "phase_rad": rounded(math.atan2(b, a)),
        }
        return [Finding("cogging", fit.joint + 1, estimate, {})]


COGGING = register(Cogging())
