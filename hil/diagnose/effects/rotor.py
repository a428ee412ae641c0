"""Rotor inertia change on joint j: a reflected inertia ΔI_a on joint j's own equation.

ΔI_a q̈_j on joint j's row; in the momentum form of the rows (Reyes & Kelly (1997) eq. (24))
X_j = F[(q̇_j(t_{k+1}) − q̇_j(t_k)) / h_k], β = ΔI_a [kg m²] (a new motor, gearbox or coupling).
Its size is the torque ΔI_a q̈_j at the joint's RMS acceleration relative to the joint's RMS
model torque (one floor for a 0.5 Nm pendulum and an 87 Nm arm, like a gain's: an effect-free
UR5e named a −1.8e-7 kg m² change on its wrist, 21 standard errors and 4e-5 of that joint's
torque). The nominal M(q) cannot take a diagonal term on one joint alone in the 2-DOF θ, so it
is not simulated there.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hil.diagnose.effects.base import Context, Effect, on_joint, register
from hil.diagnose.finding import rounded


def _velocity_step(r, joint: int) -> np.ndarray:
    k = r.k
    h = r.h if r.stamps is None else (r.stamps[k + 1] - r.stamps[k])
    return ((r.v[k + 1, joint] - r.v[k, joint]) / h)[:, None]


def rms_acceleration(ctx: Context, joint: int) -> float:
    """The RMS of joint ``joint``'s acceleration on the filtered rows (the pattern's column, as
    the model torque it is read against is filtered)."""
    a = ctx.filtered(lambda r: _velocity_step(r, joint))
    return float(np.sqrt(np.mean(a[np.isfinite(a)] ** 2)))


class RotorInertia(Effect):
    name = "rotor_inertia_change"
    partners = ("torque_gain",)
    separate = "fast small-amplitude motion of the joint alone (inertia against gravity)"
    floor = 0.005  # of the joint's RMS torque, at its RMS acceleration (a gain's floor)

    def columns(self, ctx: Context, joint: int | None, at: Any) -> np.ndarray:
        return ctx.filtered(lambda r: on_joint(_velocity_step(r, joint), joint, ctx.n_joints))

    def estimate(self, ctx, joint, beta, se, at):
        d, s = float(beta[0]), float(se[0])
        per = rms_acceleration(ctx, joint) / ctx.rms_torque(joint)  # relative torque per kg m²
        return {"inertia_change_kgm2": rounded(d), "inertia_se_kgm2": rounded(s)}, d * per, s * per

    def words(self, e: dict[str, Any]) -> str:
        return (
            f"the reflected inertia on the joint changed by {e['inertia_change_kgm2']:+.3g} "
            f"± {e['inertia_se_kgm2']:.2g} kg m² (motor, gearbox or coupling)"
        )


register(RotorInertia())
