"""One finding of the diagnosis: :class:`Finding` (an effect in the vocabulary, its joint, its
estimate and evidence), how its numbers are rounded (:func:`rounded`) and where θ keeps a joint's
Coulomb level (:func:`coulomb_column`), which the friction findings are read against.

Below the candidates and their kinds (:mod:`hil.diagnose.kinds` reads coefficients as findings);
:mod:`hil.diagnose.findings` re-exports these names. Imports: :mod:`hil.model` only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from hil.model.protocol import ArmDynamics

THETA_FC = {0: 7, 1: 8}  # index of θ8, θ9: the Coulomb level of each joint (2-DOF model)


def coulomb_column(model: ArmDynamics, joint: int) -> int:
    """Index in θ of ``joint``'s Coulomb level: θ8, θ9 of the 2-DOF model; of a URDF model
    (:class:`hil.model.urdf.UrdfArmModel`), its f_c column of that joint."""
    if model is None or not hasattr(model, "n_friction"):
        return THETA_FC[joint]
    return model.n_params - model.n_friction + model.n_joints + joint


@dataclass
class Finding:
    effect: str
    joint: int | None  # 1 | 2 as in the paper; None: both joints
    estimate: dict[str, Any]
    evidence: dict[str, Any]
    confounded_with: list[str] = field(default_factory=list)
    term: str = ""  # the accepted regression term it comes from (Candidate.key; "rate": lag/delay)

    def as_dict(self) -> dict[str, Any]:
        out = {
            "effect": self.effect,
            "joint": self.joint,
            "estimate": self.estimate,
            "evidence": self.evidence,
        }
        if self.confounded_with:
            out["confounded_with"] = self.confounded_with
        return out


def rounded(x: float, digits: int = 4) -> float:
    return float(f"{x:.{digits}g}")
