"""Torque offset on joint j, or a Coulomb asymmetry: the same column on every moving row.

τ_shaft = τ + c: y_j = Ψ_j θ₀ − c, X = −F[1]. A Coulomb friction that differs with the direction
of motion (F⁺ = F_c − c forward, F⁻ = F_c + c backward) gives the same column on every row the
diagnosis uses (rows with the joint at rest carry no weight), so the two are one finding, named
both ways; holding the joint still against a known torque, or a slow sweep through zero
velocity, tells them apart.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hil.diagnose.columns import offset_column
from hil.diagnose.effects.base import Context, Effect, SimInput, register
from hil.diagnose.finding import rounded


class TorqueOffset(Effect):
    name = "torque_offset"
    in_reference = True
    partners = ("coulomb_asymmetry",)
    separate = (
        "hold the joint still against a known torque (an offset acts at rest, a Coulomb "
        "asymmetry only in motion)"
    )
    floor = 0.005  # of the joint's RMS torque (a 0.2 Nm offset on an arm of 41 Nm RMS)
    floor_of_torque = True

    def columns(self, ctx: Context, joint: int | None, at: Any) -> np.ndarray:
        return ctx.stack(lambda r: offset_column(r, joint))

    def estimate(self, ctx, joint, beta, se, at):
        c, s = float(beta[0]), float(se[0])
        return {"offset_Nm": rounded(c), "offset_se_Nm": rounded(s)}, c, s

    def words(self, e: dict[str, Any]) -> str:
        c = e["offset_Nm"]
        return (
            f"a torque offset of {c:+.3g} ± {e['offset_se_Nm']:.2g} Nm, or equally a Coulomb "
            f"asymmetry ({-c:+.3g} Nm forward, {c:+.3g} Nm backward against the nominal level)"
        )

    def simulation(self, ctx: Context, joint: int | None, e: dict[str, Any]) -> SimInput:
        return SimInput(offset={joint: e["offset_Nm"]})


register(TorqueOffset())
