"""Encoder zero offset on joint j: the reading is the true angle plus δ.

The model holds at the true angle, q − δ e_j: y = Ψ(q − δ e_j) θ₀. Linearised at δ̂,
Ψ(q − δ e_j) θ₀ ≈ Ψ(q − δ̂ e_j) θ₀ − (δ − δ̂) ∂(Ψθ₀)/∂q_j, refined by Gauss–Newton steps. One
angle explains what would otherwise look like centres of mass off the link axes on every link
beyond the joint (on the 2-DOF arm θ4⊥/θ4 = θ5⊥/θ5 = δ and θ2⊥ = 0 for joint 1): a joint held
at a known angle (a level, the index pulse) tells the two apart.

The rows at every δ, and their derivative, come from a few builds of the model's torques per
joint (:func:`shifted_rows`), not from rows rebuilt at each Gauss–Newton point. A shifted
reading of a revolute joint turns the bodies beyond it by the fixed rotation
E(δ) = 1 − sin δ [a]× + (1 − cos δ)[a]×² (Rodrigues): their positions, and velocities, are
affine in E's entries, the kinetic energy is quadratic in them and the potential affine, so
every torque of the rows (M q̇ and g − ∂K/∂q at each state, Reyes & Kelly (1997) eq. (13)) is a
trigonometric polynomial of degree 2 in δ, in span{1, cos δ, sin δ, cos 2δ, sin 2δ}: its
values at five equally spaced angles give it at every δ (the discrete Fourier transform of five
samples, exact for frequencies up to 2). A prismatic joint's shift is a translation δ a,
positions affine in δ, K quadratic: a polynomial of degree 2, from three values. The friction
columns do not depend on δ (a constant shift leaves the velocities as they are).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hil.diagnose.columns import RecordingRows, moving_average, rigid_torque_rows
from hil.diagnose.effects.base import Context, Effect, SimInput, register
from hil.diagnose.finding import rounded

# the angles a revolute joint's rows are built at (rad), and the basis's frequencies
FOURIER_ANGLES = 2 * np.pi * np.arange(1, 5) / 5
# the shifts a prismatic joint's rows are built at (its unit, m): any two give the quadratic
SLIDE_STEPS = np.array([-1.0, 1.0])
# Gauss–Legendre nodes per interval of the shifted builds (Ψ's rows have four)
SHIFT_NODES = 2


def _coefficients(r: RecordingRows, theta: np.ndarray, joint: int, base: np.ndarray) -> np.ndarray:
    """C (K, n, 4) of one recording's rows, before F, with Ψ(q − δ e_j) θ − Ψ(q) θ = C φ(δ)
    (:func:`basis`), from the rows at the builds' steps less ``base``, the rows at δ = 0: all
    on :data:`SHIFT_NODES` Gauss–Legendre nodes an interval (a difference of two rows of one
    rule, exact for cubics: O(h⁴) from Ψ's four-node rule, for half the model's builds)."""
    revolute = r.model.revolute[joint]
    steps = FOURIER_ANGLES if revolute else SLIDE_STEPS
    d = rigid_torque_rows(r, theta, joint, -steps, nodes=SHIFT_NODES) - base  # f(δ_m) − f(0)
    out = np.zeros((*base.shape, 4))
    if revolute:  # a_k, b_k = (2/5) Σ_m f(δ_m) (cos, sin)(k δ_m); f(0) − f(0) = 0 adds nothing
        for i, (k, trig) in enumerate(((1, np.cos), (1, np.sin), (2, np.cos), (2, np.sin))):
            out[..., i] = 0.4 * sum(dm * trig(k * s) for dm, s in zip(d, steps, strict=True))
    else:  # f(δ) − f(0) = a δ + b δ²
        (s0, s1), (d0, d1) = steps, d
        out[..., 0] = (d1 * s0**2 - d0 * s1**2) / (s1 * s0 * (s0 - s1))
        out[..., 1] = (d1 * s0 - d0 * s1) / (s1 * s0 * (s1 - s0))
    return out


def basis(revolute: bool, delta: float) -> tuple[np.ndarray, np.ndarray]:
    """φ(δ) (4,) with Ψ(q − δ e_j) θ − Ψ(q) θ = C φ(δ) (:func:`shifted_rows`), and dφ/dδ."""
    if revolute:  # cos δ − 1 as −2 sin²(δ/2): no cancellation at small δ
        s1, c1, s2, c2 = np.sin(delta), np.cos(delta), np.sin(2 * delta), np.cos(2 * delta)
        value = [-2 * np.sin(delta / 2) ** 2, s1, -2 * s1**2, s2]
        return np.array(value), np.array([-s1, c1, -2 * s2, 2 * c2])
    return np.array([delta, delta**2, 0.0, 0.0]), np.array([1.0, 2 * delta, 0.0, 0.0])


def shifted_rows(ctx: Context, joint: int) -> np.ndarray:
    """C (K, n, 4), filtered and stacked as the design, with
    F[Ψ(q − δ e_j) θ₀] − F[Ψ(q) θ₀] = C φ(δ) at every δ (:func:`basis`; module doc): built
    once per joint and kept on the context, with the unshifted rows all joints share."""
    key = ("encoder", joint)
    if key not in ctx.memo:
        if ("encoder", None) not in ctx.memo:  # the rows at δ = 0, every joint's
            ctx.memo[("encoder", None)] = [
                rigid_torque_rows(r, ctx.theta0, nodes=SHIFT_NODES) for r in ctx.rows
            ]
        base = iter(ctx.memo[("encoder", None)])
        ctx.memo[key] = ctx.stack(
            lambda r: moving_average(_coefficients(r, ctx.theta0, joint, next(base)), r.window)
        )
    return ctx.memo[key]


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
    when_unseen = (
        "no torque depends on its angle (a first axis along gravity turns the whole arm and "
        "changes no torque); hold the joint at a known angle (a level, the index pulse) to "
        "check its zero"
    )
    step_tolerance = 1e-7  # rad: 0.03 % of the floor

    def acts_on(self, ctx: Context, joint: int | None) -> list[int]:
        return list(range(ctx.n_joints))  # gravity and inertia of every joint move with q_j

    def start(self, ctx: Context, joint: int | None) -> Any:
        return 0.0

    def columns(self, ctx: Context, joint: int | None, at: Any) -> np.ndarray:
        # d/dδ of F[Ψ(q − δ e_j) θ₀] at δ̂
        assert joint is not None
        _value, slope = basis(ctx.model.revolute[joint], float(at))
        return (shifted_rows(ctx, joint) @ slope)[:, :, None]

    def shift(self, ctx: Context, joint: int | None, at: Any) -> np.ndarray | None:
        if not at:
            return None
        assert joint is not None
        value, _slope = basis(ctx.model.revolute[joint], float(at))
        return shifted_rows(ctx, joint) @ value

    def update(self, ctx, joint, beta, at):
        return float(at + beta[0])

    def estimate(self, ctx, joint, beta, se, at):
        d, s = float(at + beta[0]), float(se[0])
        return (
            {"offset_rad": rounded(d), "offset_se_rad": rounded(s), "deg": rounded(np.degrees(d))},
            d,
            s,
        )

    def words(self, e: dict[str, Any]) -> str:
        return (
            f"the encoder zero is off by {e['offset_rad']:+.4g} ± {e['offset_se_rad']:.2g} rad "
            f"({e['deg']:+.3g} deg): the reading is the true angle plus that"
        )

    def simulation(self, ctx: Context, joint: int | None, e: dict[str, Any]) -> SimInput:
        return SimInput(angle={joint: e["offset_rad"]})


register(EncoderOffset())
