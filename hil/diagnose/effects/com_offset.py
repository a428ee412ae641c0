"""Centres of mass off the link axes (the 2-DOF closed form's ``com_offset`` term).

X = the three columns ``ArmModel.with_terms(("com_offset",))`` appends (θ2⊥, θ4⊥, θ5⊥), through
the same filter as Ψ (:func:`model_term_columns`). It stands here as the partner an encoder
offset is told from: one encoder angle δ on joint 1 gives θ4⊥ = δ θ4, θ5⊥ = δ θ5, θ2⊥ = 0.
Tested only where the nominal model lacks the term; not simulated (θ₀ has no place for it).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hil.diagnose.columns import model_term_columns
from hil.diagnose.effects.base import Context, Effect, register
from hil.diagnose.finding import rounded


class ComOffset(Effect):
    name = "com_offset"
    primary = False
    width = 3
    partners = ("encoder_offset",)
    separate = (
        "hold the joint at a known angle (a level, the encoder's index pulse): an encoder "
        "offset moves every reading, a centre-of-mass offset only the gravity torque"
    )

    def applies(self, ctx: Context) -> bool:
        return ctx.closed_form and "com_offset" not in ctx.model.terms

    def variants(self, ctx: Context) -> list[int | None]:
        return [None]

    def columns(self, ctx: Context, joint: int | None, at: Any) -> np.ndarray:
        return ctx.stack(lambda r: model_term_columns(r, "com_offset"))

    def estimate(self, ctx, joint, beta, se, at):
        th = ctx.theta0
        ratio = max(abs(beta[1]) / max(abs(th[3]), 1e-12), abs(beta[2]) / max(abs(th[4]), 1e-12))
        size_se = max(se[1] / max(abs(th[3]), 1e-12), se[2] / max(abs(th[4]), 1e-12))
        return (
            {
                "theta2_perp_kgm2": rounded(float(beta[0])),
                "theta4_perp_Nm": rounded(float(beta[1])),
                "theta5_perp_Nm": rounded(float(beta[2])),
                "se": [rounded(float(x)) for x in se],
            },
            float(ratio),
            float(size_se),
        )

    def words(self, e: dict[str, Any]) -> str:
        return (
            "the centres of mass lie off the link axes: "
            f"θ2⊥ = {e['theta2_perp_kgm2']:.3g} kg m², θ4⊥ = {e['theta4_perp_Nm']:.3g} Nm, "
            f"θ5⊥ = {e['theta5_perp_Nm']:.3g} Nm"
        )


register(ComOffset())
