"""Torque gain on joint j: the torque reaching the shaft is g times the recorded one.

Convention: a recorded torque column scaled by 1/g is a gain g (a motor constant, a current
sensor or an amplifier off by that factor). Joint j's equation of the nominal model then holds
for g τ_j: y_j = Ψ_j θ₀ − (g − 1) y_j, so X = −y_j (on joint j's rows), β = g − 1.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hil.diagnose.columns import gain_column
from hil.diagnose.effects.base import Context, Effect, SimInput, r4, register


class TorqueGain(Effect):
    name = "torque_gain"
    partners = ("payload", "rotor_inertia")
    separate = (
        "a known load or a torque sensor on the shaft (a gain scales every torque of the "
        "joint, a load only its gravity and inertia)"
    )
    floor = 0.005  # relative: below this, within what a profile's numbers are known to

    def columns(self, ctx: Context, joint: int | None, at: Any) -> np.ndarray:
        return ctx.stack(lambda r: gain_column(r, joint))

    def estimate(self, ctx, joint, beta, se, at):
        g = 1.0 + float(beta[0])
        return (
            # relative: g − 1, the refit vocabulary's torque_gain number
            {"gain": r4(g), "gain_se": r4(float(se[0])), "relative": r4(g - 1)},
            (g - 1.0),
            float(se[0]),
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
