"""Torque gain on joint j: the torque reaching the shaft is g times the recorded one.

Convention: a recorded torque column scaled by 1/g is a gain g (a motor constant, a current
sensor or an amplifier off by that factor). Joint j's equation of the nominal model then holds
for g τ_j: y_j = Ψ_j θ₀ / g = Ψ_j θ₀ − (1 − 1/g) Ψ_j θ₀, so X = −Ψ_j θ₀ on joint j's rows (the
nominal model's whole torque, with its own departures), β = 1 − 1/g. The column is the model's
torque, not the recorded one: a residual the model leaves (30–50 % of a real arm's joint
torque) is in y_j, and a column of y_j would read it as a gain (errors in variables: β → −NRMSE²,
a "gain" of 0.66 on an unchanged DFKI arm).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hil.diagnose.effects.base import Context, Effect, SimInput, on_joint, register
from hil.diagnose.finding import rounded


class TorqueGain(Effect):
    name = "torque_gain"
    partners = ("payload", "rotor_inertia")
    separate = (
        "a known load or a torque sensor on the shaft (a gain scales every torque of the "
        "joint, a load only its gravity and inertia)"
    )
    floor = 0.005  # relative: below this, within what a profile's numbers are known to

    def variants(self, ctx: Context) -> list[int | None]:
        # a gain scales the recorded torque: on a joint that records none (unactuated) its
        # column is the whole model torque against y = 0, β → 1, g → ∞ (a "gain of 100")
        return list(ctx.driven())

    def columns(self, ctx: Context, joint: int | None, at: Any) -> np.ndarray:
        return on_joint(-ctx.predicted()[:, joint, None], joint, ctx.n_joints)

    def paired_columns(self, ctx, joint, at, recorded):
        # the same motion on both sides: r_rec − r_ref = (1/g − 1) y_ref exactly, the recorded
        # torque with the model's error in it; the model torque's column leaves (1 − 1/g) of
        # that error behind (18 % of DFKI A.0 joint 1's 96 % misfit), which another pattern
        # then takes (an encoder angle on joint 2)
        return on_joint(-recorded[:, joint, None], joint, ctx.n_joints)

    def change(self, beta, beta_back, se):
        # gains compose by product: with the model's error e along the column (c = ⟨e, Ψθ₀⟩ /
        # |Ψθ₀|², the same on both sides of one motion) the recording gives 1 − β = (1 + c)/g
        # and the reference 1 − β_back = 1 + c, so the change g = (1 − β_back)/(1 − β): the
        # difference β − β_back is (1 − 1/g)(1 + c), a 9.5 % gain on DFKI A.0's joint 1 (its
        # model torque 0.58 of the recorded one along itself, c = −0.42) read as 5.7 %
        keep = 1.0 - beta_back
        if not np.all(keep > 0):
            return beta - beta_back, se  # no finite reference gain to divide by
        return 1.0 - (1.0 - beta) / keep, se / keep

    def estimate(self, ctx, joint, beta, se, at):
        b = float(beta[0])
        if not b < 1.0:
            # β = 1 − 1/g ≥ 1 has no finite positive gain g (the column explains the whole
            # torque or more): no size, not a clamped one (a clamp at β = 0.99 read as g − 1 = 99)
            inf = float("inf")
            return {"gain": inf, "gain_se": inf, "relative": inf}, inf, inf
        g = 1.0 / (1.0 - b)
        g_se = float(se[0]) * g * g  # dg/dβ = 1/(1 − β)²
        return (
            # relative: g − 1, the refit vocabulary's torque_gain number
            {"gain": rounded(g), "gain_se": rounded(g_se), "relative": rounded(g - 1)},
            (g - 1.0),
            g_se,
        )

    def words(self, e: dict[str, Any]) -> str:
        return (
            f"the torque reaching the shaft is {e['gain']:.4g} ± {e['gain_se']:.2g} times the "
            f"recorded one ({100 * e['relative']:+.3g} %: motor constant, current sensing or "
            "amplifier)"
        )

    def simulation(self, ctx: Context, joint: int | None, e: dict[str, Any]) -> SimInput:
        return SimInput(gain={joint: e["gain"]})


register(TorqueGain())
