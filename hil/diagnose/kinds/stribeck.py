"""Stribeck friction on one joint: a breakaway excess ΔF exp(−(q̇/v_s)²) sgn q̇ over the
Coulomb level, its variants the Stribeck velocities v_s; a function of the velocity alone."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from hil.diagnose.columns import stribeck_column
from hil.diagnose.finding import Finding, coulomb_column, rounded
from hil.diagnose.kinds.base import Candidate, CandidateKind, Library, TermFit, register

STRIBECK_VELOCITIES = np.geomspace(0.02, 0.6, 16)
# A Stribeck velocity v_s is tried only where this many usable rows slide slower than 2 v_s:
# fewer, and a handful of rows next to a stick or reversal would decide the fit alone.
STRIBECK_MIN_ROWS = 200


def stribeck_velocities(speeds: np.ndarray | None) -> tuple[float, ...]:
    """The Stribeck velocities the data can support (``speeds``: |q̇| of the usable rows)."""
    if speeds is None:
        return tuple(float(v) for v in STRIBECK_VELOCITIES)
    return tuple(
        float(v) for v in STRIBECK_VELOCITIES if np.sum(speeds < 2 * v) >= STRIBECK_MIN_ROWS
    )


class Stribeck(CandidateKind):
    name = "stribeck"
    order = 10
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

    def candidates(self, joint: int, library: Library) -> list[Candidate]:
        speeds = None if library.speeds is None else library.speeds[joint]
        velocities = stribeck_velocities(speeds)
        if not velocities:
            return []
        return [Candidate(self.name, joint, velocities, lambda r, v: stribeck_column(r, joint, v))]

    def simulate(self, finding: Finding, effects: Any) -> None:
        j, e = (finding.joint or 1) - 1, finding.estimate
        effects.stribeck_excess[j] = (e["breakaway_excess_Nm"], e["velocity_rad_s"])
        if e.get("breakaway_ratio"):
            effects.has_stribeck = True
            effects.stribeck_ratio[j] = max(1.0, e["breakaway_ratio"])
            effects.stribeck_velocity[j] = e["velocity_rad_s"]


STRIBECK = register(Stribeck())
