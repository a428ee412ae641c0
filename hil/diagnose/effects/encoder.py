"""Encoder zero offset on joint j: the reading is the true angle plus δ.

The model holds at the true angle, q − δ e_j: y = Ψ(q − δ e_j) θ₀. Linearised at δ̂,
Ψ(q − δ e_j) θ₀ ≈ Ψ(q − δ̂ e_j) θ₀ − (δ − δ̂) ∂(Ψθ₀)/∂q_j (a forward difference in δ of the
rows rebuilt at the shifted angles, as :func:`hil.diagnose.columns.angle_offset_column`),
refined by Gauss–Newton steps. One angle explains what would otherwise look like centres of
mass off the link axes on every link beyond the joint (on the 2-DOF arm θ4⊥/θ4 = θ5⊥/θ5 = δ and
θ2⊥ = 0 for joint 1): a joint held at a known angle (a level, the index pulse) tells the two
apart.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hil.diagnose.columns import model_torque_rows, moving_average
from hil.diagnose.effects.base import REFINE_STEPS, Context, Effect, SimInput, r4, register

STEP_RAD = 1e-4  # the forward difference of ∂(Ψθ₀)/∂q_j


def memo_size(n_joints: int) -> int:
    """Shifted rows kept on a context: every joint's first column (its rows at STEP_RAD, where
    each selection, its repeats after a failed gate and the confounding checks start again:
    never evicted) and the two rows of each of the REFINE_STEPS + 1 points of a Gauss–Newton
    refinement, the least recently used evicted first. 7 joints: 17 arrays (K, 7), 3.4 MB
    each per minute at 1 kHz."""
    return n_joints + 2 * (REFINE_STEPS + 1)


def model_torque_at(ctx: Context, joint: int, delta: float) -> np.ndarray:
    """F[Ψ(q − δ e_j) θ₀] (K, n): the nominal model's rows at the true angles, from the
    model's torques (:func:`hil.diagnose.columns.model_torque_rows`), kept on the context:
    the column and the shift at one point share them, and the next selection starts again
    from STEP_RAD."""
    if delta == 0.0:
        return ctx.Psi_raw @ ctx.theta0
    key = ("encoder", joint, float(delta))
    if key in ctx.memo:
        ctx.memo[key] = ctx.memo.pop(key)  # the most recently used last
        return ctx.memo[key]

    def rows(r):
        offset = np.zeros(r.q.shape[1])
        offset[joint] = -delta
        return moving_average(model_torque_rows(r, ctx.theta0, offset), r.window)

    while len(ctx.memo) >= memo_size(ctx.n_joints):  # the least recently used goes, but
        del ctx.memo[next(k for k in ctx.memo if k[2] != STEP_RAD)]  # never a first column
    out = ctx.memo[key] = ctx.stack(rows)
    return out


class EncoderOffset(Effect):
    name = "encoder_offset"
    in_reference = True
    nonlinear = True
    partners = ("com_offset", "payload")
    separate = (
        "hold the joint at a known angle (a level, the encoder's index pulse): an encoder "
        "offset moves every reading, a centre-of-mass offset only the gravity torque"
    )
    floor = 3e-4  # rad
    step_tolerance = 1e-7  # rad: 0.03 % of the floor

    def acts_on(self, ctx: Context, joint: int | None) -> list[int]:
        return list(range(ctx.n_joints))  # gravity and inertia of every joint move with q_j

    def start(self, ctx: Context, joint: int | None) -> Any:
        return 0.0

    def columns(self, ctx: Context, joint: int | None, at: Any) -> np.ndarray:
        # d/dδ of F[Ψ(q − δ e_j) θ₀] at δ̂ (forward difference: one row build, not two)
        ahead = model_torque_at(ctx, joint, at + STEP_RAD)
        return ((ahead - model_torque_at(ctx, joint, at)) / STEP_RAD)[:, :, None]

    def shift(self, ctx: Context, joint: int | None, at: Any) -> np.ndarray | None:
        if not at:
            return None
        return model_torque_at(ctx, joint, at) - ctx.Psi_raw @ ctx.theta0

    def update(self, ctx, joint, beta, at):
        return float(at + beta[0])

    def estimate(self, ctx, joint, beta, se, at):
        d, s = float(at + beta[0]), float(se[0])
        return {"offset_rad": r4(d), "offset_se_rad": r4(s), "deg": r4(np.degrees(d))}, d, s

    def words(self, e: dict[str, Any]) -> str:
        return (
            f"the encoder zero is off by {e['offset_rad']:+.4g} ± {e['offset_se_rad']:.2g} rad "
            f"({e['deg']:+.3g} deg): the reading is the true angle plus that"
        )

    def simulation(self, ctx: Context, joint: int | None, e: dict[str, Any]) -> SimInput:
        return SimInput(angle={joint: e["offset_rad"]})


register(EncoderOffset())
