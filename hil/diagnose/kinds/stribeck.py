"""Stribeck friction on one joint: a breakaway excess ΔF exp(−(q̇/v_s)²) sgn q̇ over the
Coulomb level, its variants the Stribeck velocities v_s; a function of the velocity alone."""

from __future__ import annotations

from typing import ClassVar

from hil.diagnose.finding import Finding, coulomb_column, rounded
from hil.diagnose.kinds.base import CandidateKind, TermFit, register


class Stribeck(CandidateKind):
    name = "stribeck"
    practical_floor = 0.03  # Nm breakaway excess, > 0
    positive_only = True
    velocity_shaped = True
    words: ClassVar[dict[str, str]] = {
        "stribeck": (
            "Stribeck friction: breakaway {breakaway_excess_Nm:.3g} Nm above the Coulomb level, "
            "decaying over {velocity_rad_s:.3g} rad/s"
        ),
    }

    def findings(self, fit: TermFit) -> list[Finding]:
        dF = float(fit.coef[0])
        fc = float(fit.theta[coulomb_column(fit.model, fit.joint)])
        estimate = {
            "breakaway_excess_Nm": rounded(dF),
            "breakaway_ratio": rounded(1 + dF / fc) if fc > 0 else None,
            "velocity_rad_s": rounded(float(fit.variant)),
            "exponent": 2.0,
        }
        return [Finding("stribeck", fit.joint + 1, estimate, {})]


STRIBECK = register(Stribeck())
