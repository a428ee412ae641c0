"""Friction level change on joint j: viscous Δb and Coulomb ΔF_c against the nominal model.

The columns are the nominal model's own friction columns of joint j (Reyes & Kelly (1997)
eq. (12): b q̇_j + F_c sgn q̇_j), so β = (Δb, ΔF_c) is the change of those two parameters; wear,
temperature and lubricant move them. Its size is the change of the friction torque at the
joint's RMS speed.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hil.diagnose.effects.base import Context, Effect, SimInput, register
from hil.diagnose.finding import rounded


def friction_index(ctx: Context, joint: int) -> tuple[int, int]:
    """θ's viscous and Coulomb columns of ``joint`` (both models order friction b₁..b_n,
    F_c1..F_cn)."""
    cols = ctx.model.friction_columns
    n = ctx.n_joints
    return cols[joint], cols[n + joint]


def rms_speed(ctx: Context, joint: int) -> float:
    v = ctx.stack(lambda r: r.v_mean)[:, joint]
    return float(np.sqrt(np.mean(v[np.isfinite(v)] ** 2)))


class FrictionLevel(Effect):
    name = "friction_change"
    width = 2
    partners = ("torque_offset",)
    separate = "slow constant-speed sweeps in both directions (friction against speed)"
    floor = 0.005  # of the joint's RMS torque (a 0.2 Nm offset on an arm of 41 Nm RMS)
    floor_of_torque = True

    def columns(self, ctx: Context, joint: int | None, at: Any) -> np.ndarray:
        return ctx.Psi_raw[:, :, list(friction_index(ctx, joint))]

    def estimate(self, ctx, joint, beta, se, at):
        v = rms_speed(ctx, joint)
        size = float(beta[0] * v + beta[1])
        size_se = float(np.hypot(se[0] * v, se[1]))
        b0, f0 = (float(ctx.theta0[i]) for i in friction_index(ctx, joint))
        return (
            {
                "viscous_change_Nms": rounded(float(beta[0])),
                "viscous_se_Nms": rounded(float(se[0])),
                "coulomb_change_Nm": rounded(float(beta[1])),
                "coulomb_se_Nm": rounded(float(se[1])),
                "nominal_viscous_Nms": rounded(b0),
                "nominal_coulomb_Nm": rounded(f0),
                "at_rms_speed_Nm": rounded(size),
                "rms_speed_rad_s": rounded(v),
            },
            size,
            size_se,
        )

    def words(self, e: dict[str, Any]) -> str:
        return (
            f"friction changed: Coulomb {e['nominal_coulomb_Nm']:.3g} → "
            f"{e['nominal_coulomb_Nm'] + e['coulomb_change_Nm']:.3g} Nm "
            f"(± {e['coulomb_se_Nm']:.2g}), viscous {e['nominal_viscous_Nms']:.3g} → "
            f"{e['nominal_viscous_Nms'] + e['viscous_change_Nms']:.3g} Nm s "
            f"(± {e['viscous_se_Nms']:.2g}); {e['at_rms_speed_Nm']:+.3g} Nm at the RMS speed"
        )

    def simulation(self, ctx: Context, joint: int | None, e: dict[str, Any]) -> SimInput:
        d = np.zeros(len(ctx.theta0))
        iv, ic = friction_index(ctx, joint)
        d[iv], d[ic] = e["viscous_change_Nms"], e["coulomb_change_Nm"]
        return SimInput(dtheta=d)


register(FrictionLevel())
