"""Transport delay: the torque reaches the shaft d seconds after the recorded one, on every joint.

τ_shaft(t) = τ(t − d) (a loop delay, a bus, a filter's group delay). The nominal model holds for
the delayed torque: Ψ θ₀ = F[τ_d], so the residual is r = y − Ψ θ₀ = F[τ] − F[τ_d] (y = F[τ]),
the exact held-torque means of :func:`hil.diagnose.columns.delayed_torque_means`. It is
linearised in d at d̂ (Gauss–Newton): the model's change F[τ] − F[τ_d̂] is taken off r (both
held-torque means, so that it is zero at d̂ = 0), the column is its derivative −∂F[τ_d]/∂d (a
central difference over half a sample either side), β = δd, of the recorded torque smoothed by a
centred moving average of F's length: the recorded torque's own noise differenced into the
column would shrink the delay (errors in variables: a Panda's 5.1 ms was read as 3.1 ms, its
joint-torque sensors' noise differenced over 1 ms), and the smoothing leaves the slow torque of
the motion as it is; the model's change at d̂ stays that of the recorded torque, exactly. One
delay for the whole arm: the lag that best aligns the recorded torque with the model's, judged
against the reference as every pattern is (the change since the reference: the delay found on
the recording minus the one found on the reference's rows, at the same d̂). On a recording that
reruns the reference's motion the change is between the two recorded torques themselves
(:attr:`Effect.shifts_recorded_torque`): the paired difference r_rec − r_ref is F[τ_rec] −
F[τ_rec, d] exactly, so d̂ is stepped, and the change sized, on it (the two sides' own residuals
carry the model's error: a 1-row delay on a 10 s DFKI A.0 recording fitted 17 % of the change
there, and its change read 0.73 rows at 3.2 SE).

A delay rewrites no row of the motion, but the set that writes one into a recording drops its
last rows; the comparison with the reference is then not block-paired (:func:`hil.diagnose.
drift.same_motion`), and the sign test over blocks applies as well. Its size is in sample
intervals (the shortest recording's median), so that one floor, a quarter of a sample
(:data:`hil.diagnose.findings.RESOLVABLE_INTERVALS`, the same the refit's lag and delay have),
holds for 1 ms and 5 ms samples.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.ndimage import uniform_filter1d

from hil.diagnose.columns import RecordingRows, delayed_torque_means, moving_average
from hil.diagnose.effects.base import Context, Effect, register
from hil.diagnose.finding import rounded
from hil.diagnose.findings import RESOLVABLE_INTERVALS


def _delayed(r: RecordingRows, delay_s: float, tau: np.ndarray | None = None) -> np.ndarray:
    """F[τ_d] of one recording's rows (K, n) (``tau``: of that torque, else the recorded)."""
    t = r.stamps if r.stamps is not None else np.arange(len(r.tau)) * r.h
    tau = r.tau if tau is None else tau
    return moving_average(delayed_torque_means(tau, r.h, delay_s, t)[r.k], r.window)


def _smoothed(r: RecordingRows) -> np.ndarray:
    """The recorded torque through a centred (zero-phase) moving average of F's length."""
    return uniform_filter1d(np.asarray(r.tau, float), size=r.window, axis=0, mode="nearest")


def _interval(ctx: Context) -> float:
    return min(float(r.h) for r in ctx.rows)


class TransportDelay(Effect):
    name = "transport_delay"
    nonlinear = True
    partners = ()
    separate = "a step of the command with the shaft torque measured (a delay shifts it whole)"
    floor = RESOLVABLE_INTERVALS  # in sample intervals
    shifts_recorded_torque = True

    def variants(self, ctx: Context) -> list[int | None]:
        return [None] if ctx.driven() else []

    def acts_on(self, ctx: Context, joint: int | None) -> list[int]:
        return ctx.driven()

    def start(self, ctx: Context, joint: int | None) -> Any:
        return 0.0

    def shift(self, ctx: Context, joint: int | None, at: Any) -> np.ndarray | None:
        d = float(at)
        if d == 0.0:
            return None
        return ctx.stack(lambda r: _delayed(r, 0.0) - _delayed(r, d))

    def columns(self, ctx: Context, joint: int | None, at: Any) -> np.ndarray:
        d, eps = float(at), 0.5 * _interval(ctx)

        def column(r: RecordingRows) -> np.ndarray:
            tau = _smoothed(r)
            return (_delayed(r, d - eps, tau) - _delayed(r, d + eps, tau)) / (2 * eps)

        col = ctx.stack(column)
        return col[:, :, None]

    def update(self, ctx, joint, beta, at):
        h = _interval(ctx)
        return float(at) + float(np.clip(beta[0], -2 * h, 2 * h))  # at most two samples a step

    def estimate(self, ctx, joint, beta, se, at):
        h = _interval(ctx)
        d, s = float(at) + float(beta[0]), float(se[0])
        return (
            {"delay_s": rounded(d), "delay_se_s": rounded(s), "sample_interval_s": rounded(h)},
            d / h,
            s / h,
        )

    def words(self, e: dict[str, Any]) -> str:
        return (
            f"the torque reaches the shaft {1e3 * e['delay_s']:+.3g} ± "
            f"{1e3 * e['delay_se_s']:.2g} ms after the recorded one (a loop, bus or filter delay; "
            f"{e['delay_s'] / e['sample_interval_s']:.2g} samples)"
        )


register(TransportDelay())
