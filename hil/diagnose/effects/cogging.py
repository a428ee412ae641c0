"""Cogging on joint j: a torque periodic in the joint angle, A sin(N q_j + φ), that the nominal
model lacks (a new motor, a magnet that moved, a damaged gear tooth).

τ_shaft = τ + A sin(N q_j + φ): y_j = Ψ_j θ₀ − A sin(N q_j + φ), X = −F[sin N q_j, cos N q_j]
(:func:`hil.diagnose.columns.cogging_columns`, the refit's own columns), β = (A cos φ, A sin φ).
The number of periods per revolution N is the linearisation point: every N the refit searches
(:func:`hil.diagnose.candidates.cogging_periods`: at least two periods over the joint's angle
range) is a start, and the one that fits best is kept (:meth:`Effect.starts`; all of them
screened at once first, :meth:`Cogging.start_columns`); N does not move after that. Its size
is A relative to the joint's RMS model torque (one floor for a 0.5 Nm pendulum and an 87 Nm
arm, like a gain's).
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np

from hil.diagnose.candidates import cogging_periods
from hil.diagnose.columns import cogging_column_chunks, cogging_columns
from hil.diagnose.effects.base import Context, Effect, register
from hil.diagnose.finding import rounded

# the least share of a cogging's power (sin² + cos² = 1 a row unfiltered) the rows' moving
# average must keep at the motion's speeds (:meth:`Cogging.unresolvable`): the effect sets'
# drawn coggings keep 28–83 %; a 126-period "cogging" fitted to a payload on the DFKI
# pendulum's 4 rad/s swings kept 1.3 % and read 2.2 times the joint's RMS torque
MIN_KEPT_POWER = 0.05


class Cogging(Effect):
    name = "cogging"
    width = 2
    nonlinear = True
    partners = ("encoder_offset",)
    separate = "a slow constant-speed sweep of the joint (cogging repeats with the angle)"
    floor = 0.02  # of the joint's RMS torque
    sized_by_amplitude = True

    def variants(self, ctx: Context) -> list[int | None]:
        return list(ctx.driven())

    def start(self, ctx: Context, joint: int | None) -> Any:
        return float(self.starts(ctx, joint)[0])

    def starts(self, ctx: Context, joint: int | None) -> list[Any]:
        assert joint is not None
        span = max(float(np.ptp(r.q[:, joint])) for r in ctx.rows)
        return [float(n) for n in cogging_periods(span)]

    def columns(self, ctx: Context, joint: int | None, at: Any) -> np.ndarray:
        return ctx.stack(lambda r: cogging_columns(r, joint, float(at)))

    def start_columns(
        self, ctx: Context, joint: int, starts: list[Any], per: int
    ) -> Iterator[np.ndarray]:
        """The columns of many periods on ``joint``'s own rows, ``per`` periods at a time,
        stacked over the recordings as :meth:`columns` stacks them: (K, ≤per, 2) arrays (one
        complex exponential and a rotation per period,
        :func:`hil.diagnose.columns.cogging_column_chunks`), for :meth:`hil.diagnose.drift.
        fit.Fit.screen`."""
        periods = [float(n) for n in starts]
        chunks = [cogging_column_chunks(r, joint, periods, per) for r in ctx.rows]
        for parts in zip(*chunks, strict=True):
            yield parts[0] if len(parts) == 1 else np.concatenate(parts)

    def change_point(self, ctx: Context, joint: int | None, at: Any) -> Any:
        return at  # β holds the amplitude itself at N

    def unresolvable(self, ctx: Context, joint: int | None, at: Any) -> str | None:
        # N periods a revolution at speed v vary at N v / 2π Hz: above the moving average's
        # band the rows keep only the slow stretches of the motion (MIN_KEPT_POWER)
        assert joint is not None
        cols = self.columns(ctx, joint, at)[:, joint, :]
        w = ctx.stack(lambda r: r.weights)[:, joint]
        kept = float(np.sum(w[:, None] * cols**2) / max(float(np.sum(w)), 1e-300))
        if kept >= MIN_KEPT_POWER:
            return None
        return (
            f"the rows' filter keeps {100 * kept:.2g} % of a cogging of {float(at):g} periods "
            f"per revolution at this motion's speeds (under {100 * MIN_KEPT_POWER:g} %): its "
            "amplitude would be read from the slowest stretches, scaled up"
        )

    def estimate(self, ctx, joint, beta, se, at):
        a, b = float(beta[0]), float(beta[1])
        amp = float(np.hypot(a, b))
        # the standard error of the amplitude (delta method, the two coefficients independent)
        amp_se = float(np.hypot(a * se[0], b * se[1]) / amp) if amp > 0 else float(np.hypot(*se))
        rms = ctx.rms_torque(joint)
        return (
            {
                "amplitude_Nm": rounded(amp),
                "amplitude_se_Nm": rounded(amp_se),
                "periods_per_rev": float(at),
                "phase_rad": rounded(float(np.arctan2(b, a))),
                "relative": rounded(amp / rms),
            },
            amp / rms,
            amp_se / rms,
        )

    def opposed(self, forward, back, size, size_back) -> bool:
        # an amplitude has no sign: a change shows the other way round half a period out of
        # phase
        return bool(np.cos(forward["phase_rad"] - back["phase_rad"]) < 0)

    def words(self, e: dict[str, Any]) -> str:
        return (
            f"a torque periodic in the joint angle, {e['amplitude_Nm']:.3g} ± "
            f"{e['amplitude_se_Nm']:.2g} Nm with {e['periods_per_rev']:g} periods per revolution "
            "(cogging: a motor's magnets or a gear)"
        )


register(Cogging())
