"""The encoder (angle) offset on one joint: reading = true angle + δ. Its column is
−∂(Ψθ)/∂q_j at a θ, so it moves the gravity and inertia torques of both joints and is rebuilt
about the refitted θ once accepted."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from hil.diagnose.columns import RecordingRows, angle_offset_column
from hil.diagnose.finding import Finding, rounded
from hil.diagnose.kinds.base import Candidate, CandidateKind, Library, TermFit, register


class AngleOffset(CandidateKind):
    name = "angle"
    order = 60
    practical_floor = 3e-4  # rad
    both_joints = True
    built_at_theta = True
    words: ClassVar[dict[str, str]] = {
        "angle_offset": "the encoder zero is off by {offset_rad:+.4g} rad ({deg} deg)",
    }

    def column_at(self, rows: RecordingRows, joint: int, theta: np.ndarray) -> np.ndarray:
        return angle_offset_column(rows, joint, theta)

    def findings(self, fit: TermFit) -> list[Finding]:
        return [
            Finding("angle_offset", fit.joint + 1, {"offset_rad": rounded(float(fit.coef[0]))}, {})
        ]

    def candidates(self, joint: int, library: Library) -> list[Candidate]:
        model, theta = library.model, library.theta
        return [
            Candidate(
                self.name,
                joint,
                (None,),
                lambda r, _v: angle_offset_column(r, joint, theta),
                acts_on=None if model.closed_form else tuple(range(model.n_joints)),
            )
        ]

    def simulate(self, finding: Finding, effects: Any) -> None:
        effects.angle[(finding.joint or 1) - 1] = finding.estimate["offset_rad"]


ANGLE = register(AngleOffset())
