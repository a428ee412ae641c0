"""Velocity-squared drag on joint j: τ = Ψθ₀ + c q̇_j|q̇_j| (fluid, fan or seal drag that grows
with the square of speed). Without this pattern its torque is taken by the pattern nearest to
it, a torque gain (whose column, the model torque, grows with speed on a fast trajectory) or a
viscous friction change; with it, the held-out selection names the one that explains the rows
better. Its size is the drag torque at the joint's RMS speed relative to the joint's RMS model
torque (one floor for a 0.5 Nm pendulum and an 87 Nm arm, like a gain's).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hil.diagnose.columns import drag_column
from hil.diagnose.effects.base import Context, Effect, register
from hil.diagnose.effects.friction import rms_speed
from hil.diagnose.finding import rounded


class VelocitySquaredDrag(Effect):
    name = "velocity_squared_drag"
    partners = ("friction_change", "torque_gain")
    separate = (
        "constant-speed sweeps at several speeds (drag grows with speed², viscous friction "
        "with speed, a gain with the torque)"
    )
    floor = 0.02  # of the joint's RMS torque, at the RMS speed

    def columns(self, ctx: Context, joint: int | None, at: Any) -> np.ndarray:
        return ctx.stack(lambda r: drag_column(r, joint))

    def estimate(self, ctx, joint, beta, se, at):
        c, s = float(beta[0]), float(se[0])
        v2 = rms_speed(ctx, joint) ** 2
        rms = ctx.rms_torque(joint)
        return (
            {
                "coefficient_Nms2": rounded(c),
                "coefficient_se_Nms2": rounded(s),
                "at_rms_speed_Nm": rounded(c * v2),
                "relative": rounded(c * v2 / rms),
            },
            c * v2 / rms,
            s * v2 / rms,
        )

    def unphysical(self, ctx, joint, e, source):
        # a drag dissipates: below zero it would feed the motion. The nominal model has no drag
        # term (not in_reference) for a change to take off, except against reference
        # recordings, whose own drag θ₀ absorbed (a drag smaller since then is physics)
        c = e["coefficient_Nms2"]
        if source == "reference" or c >= 0:
            return None
        return (
            f"a velocity-squared drag of {c:.3g} Nm s²/rad² is below zero (it would feed the "
            "motion energy) and the nominal model has no drag for it to take off"
        )

    def words(self, e: dict[str, Any]) -> str:
        return (
            f"a drag growing with the square of speed, {e['coefficient_Nms2']:.3g} ± "
            f"{e['coefficient_se_Nms2']:.2g} Nm s²/rad² ({e['at_rms_speed_Nm']:+.3g} Nm at the "
            "RMS speed)"
        )


register(VelocitySquaredDrag())
