"""Cogging on one joint: A sin(n q + φ), its variants the periods n per revolution; its two
coefficients are the sine and cosine parts, its size the amplitude."""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

from hil.diagnose.columns import cogging_column_chunks, cogging_columns
from hil.diagnose.finding import Finding, rounded
from hil.diagnose.kinds.base import Candidate, CandidateKind, Library, TermFit, register

COGGING_PERIODS = np.arange(3, 401)


def cogging_periods(angle_range_rad: float) -> tuple[int, ...]:
    """Periods per revolution worth testing on a joint that swept ``angle_range_rad``: at least
    two whole periods inside the range (fewer is a smooth function of q that gravity, an angle
    offset or a torque offset also make), up to COGGING_PERIODS' top."""
    lowest = max(int(COGGING_PERIODS[0]), int(np.ceil(2 * 2 * np.pi / max(angle_range_rad, 1e-9))))
    return tuple(int(n) for n in COGGING_PERIODS if n >= lowest)


class Cogging(CandidateKind):
    name = "cogging"
    order = 40
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

    def candidates(self, joint: int, library: Library) -> list[Candidate]:
        return [
            Candidate(
                self.name,
                joint,
                cogging_periods(library.angle_range_rad[joint]),
                lambda r, n: cogging_columns(r, joint, n),
                lambda r, ns, per: cogging_column_chunks(r, joint, ns, per),
            )
        ]

    def simulate(self, finding: Finding, effects: Any) -> None:
        e = finding.estimate
        effects.cogging[(finding.joint or 1) - 1] = (
            e["periods_per_rev"],
            e["amplitude_Nm"],
            e["phase_rad"],
        )


COGGING = register(Cogging())
