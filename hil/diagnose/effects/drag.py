"""Velocity-squared drag on joint j: a torque c q̇_j |q̇_j| the nominal model lacks.

Air or fluid drag and a seal or fan that grows with speed add c q̇|q̇| to the torque the drive
must give: y_j = Ψ_j θ₀ + c F[q̇_j |q̇_j|], X = F[q̇_j |q̇_j|] (the interval mean over the
Gauss–Legendre nodes, filtered as Ψ and y are), β = c in N m s². Without this pattern the
drag's part along Ψ_j θ₀ (fast rows carry both the large torques and the drag) is read as a
torque gain on its joint; with it, the selection names whichever explains the held-out rows
better. A viscous change (friction_change) is its partner: both grow with speed, one
linearly, one with its square.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hil.diagnose.columns import _node_average, moving_average
from hil.diagnose.effects.base import Context, Effect, SimInput, on_joint, r4, register


class VelocitySquaredDrag(Effect):
    name = "velocity_squared_drag"
    partners = ("friction_change", "torque_gain")
    separate = (
        "constant-speed sweeps at several speeds (a drag grows with the square of the speed, "
        "viscous friction linearly, a gain with the torque)"
    )

    def columns(self, ctx: Context, joint: int | None, at: Any) -> np.ndarray:
        def col(r):
            v = r.v_nodes[..., joint]
            return moving_average(_node_average(v * np.abs(v))[:, None], r.window)

        return on_joint(ctx.stack(col), joint, ctx.n_joints)

    def estimate(self, ctx, joint, beta, se, at):
        c, s = float(beta[0]), float(se[0])
        return {"coefficient_Nms2": r4(c), "coefficient_se_Nms2": r4(s)}, c, s

    def words(self, e: dict[str, Any]) -> str:
        return (
            f"a velocity-squared drag c q̇|q̇| with c = {e['coefficient_Nms2']:.3g} ± "
            f"{e['coefficient_se_Nms2']:.2g} N m s² (air, fluid or a seal growing with speed)"
        )

    def simulation(self, ctx: Context, joint: int | None, e: dict[str, Any]) -> SimInput:
        return SimInput()  # the plant has no drag term: judged by held-out torque alone


register(VelocitySquaredDrag())
