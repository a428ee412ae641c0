"""Coulomb asymmetry on joint j: friction that rose in one direction of motion only.

τ = Ψθ₀ + a sgn(q̇_j) 1(sgn q̇_j = d) for the direction d = ±1 (a seal or a bearing that
drags one way, a cable that winds up): X = F[sgn(q̇_j) 1(sgn q̇_j = d)] = (F[sgn q̇_j] + d F[1])/2
on joint j's rows, the nominal model's own Coulomb column (Reyes & Kelly (1997) eq. (12)) and the
offset column's moving part, so β = a is the change of the Coulomb level in that direction.

Against this column a symmetric Coulomb change (:mod:`.friction`) and a torque offset
(:mod:`.offset`) each explain half of a one-sided change, and it explains half of either of
theirs: the held-out selection tells the three apart with one coefficient each. The direction is
the pattern's linearisation point: both are tried (:meth:`starts`) and the one that fits better
is kept; the size is the scorer's and the refit vocabulary's signed asymmetry, the negative
direction's level change minus the positive's.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hil.diagnose.columns import offset_column
from hil.diagnose.effects.base import Context, Effect, SimInput, on_joint, register
from hil.diagnose.effects.friction import friction_index
from hil.diagnose.finding import rounded


class CoulombAsymmetry(Effect):
    name = "coulomb_asymmetry"
    partners = ("friction_change", "torque_offset")
    separate = (
        "slow constant-speed sweeps in both directions, and the joint held still against a "
        "known torque (an offset acts at rest, friction only in motion)"
    )
    floor = 0.005  # of the joint's RMS torque (a 0.2 Nm offset on an arm of 41 Nm RMS)
    floor_of_torque = True
    nonlinear = True  # its direction is chosen by fit, not a coefficient

    def variants(self, ctx: Context) -> list[int | None]:
        # written into a recorded torque: a joint that records none has no friction to see
        return list(ctx.driven())

    def start(self, ctx: Context, joint: int | None) -> Any:
        return 1

    def starts(self, ctx: Context, joint: int | None) -> list[Any]:
        return [1, -1]

    def change_point(self, ctx: Context, joint: int | None, at: Any) -> Any:
        return at  # β holds the level change itself, in the direction chosen

    def columns(self, ctx: Context, joint: int | None, at: Any) -> np.ndarray:
        _iv, ic = friction_index(ctx, joint)
        coulomb = ctx.Psi_raw[:, joint, ic]  # F[sgn q̇_j] on joint j's rows
        moving = -ctx.stack(lambda r: offset_column(r, joint))[:, joint, 0]  # F[1]
        return on_joint(0.5 * (coulomb + at * moving)[:, None], joint, ctx.n_joints)

    def estimate(self, ctx, joint, beta, se, at):
        a, s = float(beta[0]), float(se[0])
        positive, negative = (a, 0.0) if at > 0 else (0.0, a)
        return (
            {
                "direction": "positive" if at > 0 else "negative",
                "positive_Nm": rounded(positive),
                "negative_Nm": rounded(negative),
                "level_se_Nm": rounded(s),
            },
            negative - positive,
            s,
        )

    def words(self, e: dict[str, Any]) -> str:
        a = e["positive_Nm"] if e["direction"] == "positive" else e["negative_Nm"]
        return (
            f"the Coulomb friction changed in the {e['direction']} direction of motion only, "
            f"by {a:+.3g} ± {e['level_se_Nm']:.2g} Nm"
        )

    def simulation(self, ctx: Context, joint: int | None, e: dict[str, Any]) -> SimInput:
        # a sgn(q̇) 1(sgn q̇ = d) = (a/2) sgn q̇ + (a/2) d in motion: half a Coulomb change in θ,
        # half an offset of the torque reaching the shaft (also at rest, where the rows the
        # diagnosis fits carry no weight)
        d = 1.0 if e["direction"] == "positive" else -1.0
        a = e["positive_Nm"] if d > 0 else e["negative_Nm"]
        dtheta = np.zeros(len(ctx.theta0))
        dtheta[friction_index(ctx, joint)[1]] = 0.5 * a
        return SimInput(dtheta=dtheta, offset={joint: -0.5 * a * d})


register(CoulombAsymmetry())
