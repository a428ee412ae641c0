"""The three regression models of Reyes & Kelly (1997), built from sampled data, two ways.

Every builder takes encoder readings ``q`` (N, 2) sampled at t_k = k·h and torques ``tau`` (N, 2)
held over [t_k, t_k + h) (the recording convention), and returns a :class:`Regression`: outputs
``y`` (K, m) and regressors ``Psi`` (K, m, 9) with y(k) ≈ Psi(k) θ, m = 2 (vector prediction
error) or 1 (scalar). ``discretization`` selects how continuous time is brought to samples:

``paper``
    What the paper implemented (Section 5): velocity by backward difference
    v_k = (q_k − q_{k−1})/h; λ/(s+λ) as (1 − e^{−λh}) z⁻¹ / (1 − e^{−λh} z⁻¹) and λs/(s+λ) as
    λ (1 − z⁻¹) / (1 − e^{−λh} z⁻¹); integrals by the trapezoid rule. The two filters do not
    delay alike (the low-pass has a one-sample delay, the band-pass none) and the backward
    difference lags the true velocity by h/2, so the two sides of each regression are not
    aligned in time: this biases the estimates (docs/identification.md quantifies it).

``exact``
    A formulation that is consistent on both sides. Between samples the torque is constant, so
    the work it does over [t_k, t_{k+1}] is exactly τ_kᵀ (q_{k+1} − q_k) and its impulse exactly
    h τ_k. Each model is written over sample intervals — the momentum balance
    h τ_k = [P(t_{k+1}) − P(t_k)] θ + ∫ R dt θ, the energy balance
    τ_kᵀ Δq_k = [φ_ℰ(t_{k+1}) − φ_ℰ(t_k)]ᵀ θ + ∫ q̇ᵀ φ_F dt θ — with velocities at the samples by
    central difference and the integrals over each interval taken on the cubic Hermite
    interpolant of q (Gauss–Legendre for smooth terms, exact piecewise integration of sgn q̇ and
    |q̇| between its zero crossings). Filters, where a model has them, are one discrete
    first-order low-pass applied identically to both sides, so they cannot bias anything.
    Intervals in which a joint sticks (zero velocity at both ends, no motion) carry static
    friction the model has no term for; in force-based rows (filtered dynamic) they and the
    samples their filter memory spreads them to are given zero weight (``Regression.weights``).

Filter bandwidth ``lam`` is in rad/s (the paper's "λ = 50 Hz": see docs/identification.md).

Real recordings (``t`` given): the ``exact`` rows are written per interval with that interval's
own length h_k = t_{k+1} − t_k (impulse h_k τ_k, Hermite integrals over h_k, velocities at the
samples by the three-point derivative on the unequal grid), so irregular sampling and gaps cost
nothing but the rows' noise. The row filter stays one LTI low-pass over the row sequence with
the coefficient of the median interval: any fixed linear filter applied alike to both sides of
y_k = Ψ_k θ keeps the equation exact, so the filter need not follow the clock. ``paper`` with
``t`` is the paper's own method written over each interval, as the paper derives it ("torques,
positions, and velocities are held constant between sampling instants", Sec. 5.1): backward
difference over Δt_k = t_k − t_{k−1}, each first-order filter the zero-order-hold equivalent of
that interval, a_k = e^{−λΔt_k} (exact for the held input, as e^{−λh} is for equal ones), the
trapezoid rule over Δt_k (:func:`filter_over_intervals`). Equal intervals without ``t`` keep
the LTI filters, bit for bit.

Every builder takes the model object (:class:`hil.model.closed_form.ArmModel`, default the
9-parameter
model) whose columns it fills; p = ``model.n_params``. Any model with the same methods and
``n_joints`` joints (:class:`hil.model.urdf.UrdfArmModel`) gives the ``exact`` rows of all three
schemes for n joints, q and τ of shape (N, n): the momentum and energy balances above are the
paper's n-joint equations (eqs. (11)-(13), (25)-(30)); only the 9-parameter closed form is
2-DOF.

The module is longer than 800 lines because the three models' rows are built by one pipeline
(interval integrals -> raw rows -> one row filter -> whole or chunked regressions) whose steps
share private pieces (the Hermite interpolant, the stick memory, the row checks); split, each
piece would be public for one caller.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from itertools import pairwise

import numpy as np

from hil.model.closed_form import ArmModel

NINE_PARAMETERS = ArmModel(())

SCHEMES = ("filtered_dynamic", "supplied_energy", "filtered_power")
DISCRETIZATIONS = ("paper", "exact")
# A stuck interval contaminates a filtered row by less than this fraction once it is this far
# back in the filter's memory (e^{-λ t} < 1e-3).
STICK_MEMORY_DECAY = 1e-3


@dataclass(frozen=True)
class Regression:
    """y(k) ≈ Psi(k) θ for k = 0..K−1; ``t`` the time each row refers to; ``weights`` (K, m) are
    1 for rows the model can explain and 0 for rows it cannot (stick–slip, see module doc)."""

    scheme: str
    discretization: str
    t: np.ndarray  # (K,)
    y: np.ndarray  # (K, m)
    Psi: np.ndarray  # (K, m, p)
    weights: np.ndarray  # (K, m)
    lam: float
    period_s: float


# --- discrete filters --------------------------------------------------------------------------
# Every filter is linear and time-invariant, given as (b, a) coefficients in z⁻¹, so the batch
# builders (scipy.signal.lfilter over a whole recording) and the online identifier (lfilter one
# sample at a time with its state carried in ``zi``) compute the same numbers.


def filter_coefficients(name: str, lam: float, h: float) -> tuple[list[float], list[float]]:
    """(b, a) of the named filter, a = e^{−λh}:

    ``paper_lowpass``     λ/(s+λ) → (1 − a) z⁻¹ / (1 − a z⁻¹)       (Reyes & Kelly 1997, Sec. 5.1)
    ``paper_bandpass``    λs/(s+λ) → λ (1 − z⁻¹) / (1 − a z⁻¹)       (Sec. 5.1)
    ``trapezoid``         ∫₀^{kh} by the trapezoid rule, h/2 (1 + z⁻¹) / (1 − z⁻¹)   (Sec. 5.2)
    ``interval_lowpass``  (1 − a) / (1 − a z⁻¹): unit DC gain, no delay (``exact`` filters)
    ``cumulative_sum``    1 / (1 − z⁻¹): Σ over intervals (``exact`` integrals)
    ``none``              1
    """
    e = float(np.exp(-lam * h))
    table = {
        "paper_lowpass": ([0.0, 1.0 - e], [1.0, -e]),
        "paper_bandpass": ([lam, -lam], [1.0, -e]),
        "trapezoid": ([0.5 * h, 0.5 * h], [1.0, -1.0]),
        "interval_lowpass": ([1.0 - e], [1.0, -e]),
        "cumulative_sum": ([1.0], [1.0, -1.0]),
        "none": ([1.0], [1.0]),
    }
    if name not in table:
        raise ValueError(f"unknown filter {name!r}")
    return table[name]


def filter_over_intervals(
    name: str,
    lam: float,
    dt: np.ndarray,
    x: np.ndarray,
    state: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """The first-order filter ``name`` of :func:`filter_coefficients` run over rows whose
    intervals differ: row k uses the coefficients of its own interval dt[k] = t_k − t_{k−1},
    y_k = b0(Δt_k) x_k + b1(Δt_k) x_{k−1} − a1(Δt_k) y_{k−1}. For the paper's filters this is
    Reyes & Kelly (1997) Sec. 5.1 written per interval: the ZOH equivalent of λ/(s+λ) over
    [t_{k−1}, t_k] is y_k = e^{−λΔt_k} y_{k−1} + (1 − e^{−λΔt_k}) x_{k−1}, exact for x held over
    the interval, and λs/(s+λ) is y_k = e^{−λΔt_k} y_{k−1} + λ (x_k − x_{k−1}), exact for x
    stepping at the samples; the trapezoid rule (Sec. 5.2) is y_k = y_{k−1} + Δt_k (x_k +
    x_{k−1})/2. ``state`` (x_{−1}, y_{−1}) carries a stream across calls (zeros at the start,
    as lfilter's zi = 0); returns (y, state). The rows are walked one by one: the coefficients
    change with every row, so no LTI routine applies."""
    x = np.asarray(x, dtype=float)
    dt = np.asarray(dt, dtype=float)
    if len(dt) != len(x):
        raise ValueError(f"{len(x)} rows but {len(dt)} intervals")
    x_prev, y_prev = (np.zeros(x.shape[1:]), np.zeros(x.shape[1:])) if state is None else state
    y = np.empty_like(x)
    for k in range(len(x)):
        b, a = filter_coefficients(name, lam, float(dt[k]))
        b0, b1 = b[0], (b[1] if len(b) > 1 else 0.0)
        a1 = a[1] if len(a) > 1 else 0.0
        y[k] = b0 * x[k] + b1 * x_prev - a1 * y_prev
        x_prev, y_prev = x[k], y[k]
    return y, (x_prev, y_prev)


# --- velocities and interval integrals ----------------------------------------------------------


def backward_difference(q: np.ndarray, h: float | np.ndarray) -> np.ndarray:
    """v_k = (q_k − q_{k−1}) / h, v_0 = 0 (at rest), as in the paper (Section 5). ``h``: the
    common period, or every sample's own interval t_k − t_{k−1}, shape (N − 1,)."""
    v = np.zeros_like(q)
    v[1:] = np.diff(q, axis=0) / (h if np.ndim(h) == 0 else np.asarray(h, float)[:, None])
    return v


def central_difference(q: np.ndarray, h: float) -> np.ndarray:
    """v_k = (q_{k+1} − q_{k−1}) / (2h) for k = 1..N−2; the ends are NaN (not used).

    The torque steps at every sample, so q̈ jumps there and this is off by h (q̈⁺ − q̈⁻)/4,
    about 1e-3 rad/s on the paper's excitation (0.05 % of its velocities)."""
    v = np.full_like(q, np.nan)
    v[1:-1] = (q[2:] - q[:-2]) / (2 * h)
    return v


def central_difference_unequal(q: np.ndarray, t: np.ndarray) -> np.ndarray:
    """v_k of the parabola through (t_{k−1}, q_{k−1}), (t_k, q_k), (t_{k+1}, q_{k+1}), the
    three-point derivative on an unequal grid; equal intervals give (q_{k+1} − q_{k−1}) / 2h.
    The ends are NaN (not used)."""
    v = np.full_like(q, np.nan)
    h0 = (t[1:-1] - t[:-2])[:, None]
    h1 = (t[2:] - t[1:-1])[:, None]
    v[1:-1] = (h0**2 * q[2:] - h1**2 * q[:-2] + (h1**2 - h0**2) * q[1:-1]) / (h0 * h1 * (h0 + h1))
    return v


def sample_velocities(
    q: np.ndarray, h: float, t: np.ndarray | None = None, half_window: int = 1
) -> np.ndarray:
    """The ``exact`` discretization's velocities at the samples: central difference on equal
    intervals k·h (``t`` None), the three-point derivative on the real times ``t``, or the local
    quadratic over 2·half_window + 1 of them. Linear in q, exact on a quadratic."""
    if t is None:
        return central_difference(q, h)
    if half_window <= 1:
        return central_difference_unequal(q, t)
    return local_polynomial_velocity(q, t, half_window)


# Samples per piece of :func:`held_torque_momentum_bias` (fixed, so that the result does not
# depend on how a caller chunks a recording; short, so that the double integral stays small)
BIAS_PIECE = 4096


def held_torque_momentum_bias(
    tau: np.ndarray, h: float, t: np.ndarray | None = None, half_window: int = 1
) -> np.ndarray:
    """b_k (N, n) [N m s]: what the velocity estimate (:func:`sample_velocities`) adds to a
    sliding joint's momentum at sample k because the torque is held over each interval, i.e.
    M(q_k) v̂_k = P(t_k) + b_k. At every sample the held torque steps, so q̈ has a corner there
    with M (q̈⁺ − q̈⁻) = τ_k − τ_{k−1} (friction, gravity and Coriolis torques are continuous;
    for a sliding joint this holds with other joints stuck too); a corner inside a velocity
    estimate's window is not a quadratic, and the three-point derivative is off by
    h (q̈⁺ − q̈⁻)/4 (the docstring of :func:`central_difference`). Linear in q, the estimator's
    error is the same on the torque's own double integral: with S(t) = ∫τ dt, Z(t) = ∫S dt
    (exact at the samples for a held τ), b = v̂[Z] − S, whatever the estimator (h/4 (τ_k − τ_{k−1})
    on equal intervals). The momentum balance over [t_k, t_{k+1}] then reads
    h_k τ_k + b_{k+1} − b_k = [M v̂]_{k+1} − [M v̂]_k + ∫R dt. Integrated over fixed pieces of
    BIAS_PIECE samples (each with its estimator's margin), the torque's mean taken out in each
    (the estimators are exact on the quadratic it adds to Z), so Z stays small."""
    tau = np.asarray(tau, dtype=float)
    stamps = None if t is None else np.asarray(t, dtype=float)
    n, margin = len(tau), max(1, half_window)
    out = np.full(tau.shape, np.nan)
    for a in range(0, n, BIAS_PIECE):
        b = min(n, a + BIAS_PIECE)
        lo, hi = max(0, a - margin), min(n, b + margin)
        piece = _held_torque_bias_piece(
            tau[lo:hi], h, None if stamps is None else stamps[lo:hi], half_window
        )
        out[a:b] = piece[a - lo : b - lo]
    # Exactly 0 where no step lies strictly inside the estimator's window (a torque that
    # stays put has no corner, and an unchanged held-out torque keeps no spread to scale by)
    step = np.zeros(tau.shape, bool)
    step[1:] = tau[1:] != tau[:-1]
    counts = np.vstack([np.zeros((1, tau.shape[1])), np.cumsum(step, axis=0)])
    k = np.arange(n)
    inside = counts[np.minimum(k + margin, n)] - counts[np.maximum(k - margin + 1, 0)]
    out[(inside == 0) & np.isfinite(out)] = 0.0
    return out


def _held_torque_bias_piece(
    tau: np.ndarray, h: float, t: np.ndarray | None, half_window: int
) -> np.ndarray:
    """:func:`held_torque_momentum_bias` of one piece (S and Z from its first sample)."""
    if len(tau) < 2:
        return np.full(tau.shape, np.nan)
    dt = (np.full(len(tau) - 1, h) if t is None else np.diff(t))[:, None]
    held = tau[:-1] - tau[:-1].mean(axis=0)
    start = np.zeros((1, tau.shape[1]))
    impulse = np.vstack([start, np.cumsum(held * dt, axis=0)])
    position = np.vstack([start, np.cumsum(impulse[:-1] * dt + held * dt**2 / 2, axis=0)])
    return sample_velocities(position, h, t, half_window) - impulse


def local_polynomial_velocity(q: np.ndarray, t: np.ndarray, half_window: int) -> np.ndarray:
    """v_k = slope at t_k of the least-squares quadratic through the samples k−m..k+m (real
    times; m = ``half_window`` ≥ 1; m = 1 is the three-point derivative). Quantized positions
    make the three-point derivative noisy, and that noise in the regressors biases least
    squares towards zero (errors in variables, docs/real-data.md); a window of 2m + 1 samples
    cuts the velocity noise by about m^1.5. The first and last m samples are NaN."""
    q = np.asarray(q, dtype=float)
    t = np.asarray(t, dtype=float)
    n, m = len(q), int(half_window)
    v = np.full_like(q, np.nan)
    if m < 1 or n < 2 * m + 1:
        return v
    W = np.lib.stride_tricks.sliding_window_view(np.arange(n), 2 * m + 1)
    centre = np.arange(m, n - m)
    d = t[W] - t[centre][:, None]  # (K, 2m+1)
    S = np.stack([np.sum(d**p, axis=1) for p in range(5)], -1)  # Σ d^p, p = 0..4
    G = np.stack([S[:, [0, 1, 2]], S[:, [1, 2, 3]], S[:, [2, 3, 4]]], axis=1)  # of [1, d, d²]
    for j in range(q.shape[1]):
        x = q[W, j] - q[centre, j][:, None]  # relative: keeps the solve well scaled
        rhs = np.stack([np.sum(x * d**p, axis=1) for p in range(3)], -1)
        v[centre, j] = np.linalg.solve(G, rhs[..., None])[:, 1, 0]
    return v


def velocity_half_window(lam: float, t: np.ndarray) -> int:
    """Samples each side for :func:`local_polynomial_velocity`: a half-width of 1/(4λ) s (at
    least one sample). The slope of a quadratic fitted over ±T to a sinusoid of frequency ω is
    low by about (ωT)²/10 relative: 0.16 % at ω = λ/2 (the excitation bandwidth that
    :func:`data_bandwidth` doubles), while the velocity noise of the encoder quantum falls
    as m^-1.5."""
    h = float(np.median(np.diff(t)))
    return max(1, round(1.0 / (4.0 * lam * h)))


def gauss_legendre_unit(n: int) -> tuple[np.ndarray, np.ndarray]:
    """The n Gauss–Legendre nodes on [0, 1] and their weights (summing to 1): a mean over an
    interval, exact for polynomials of degree 2n − 1."""
    nodes, weights = np.polynomial.legendre.leggauss(n)
    return 0.5 * (nodes + 1.0), 0.5 * weights


# the interval rows' rule
GL_NODES, GL_WEIGHTS = gauss_legendre_unit(4)
# Nodes per smooth piece of an interval cut at a velocity reversal
# (:func:`interval_mean_across_reversals`), on [0, 1].
_PIECE_NODES, _PIECE_WEIGHTS = gauss_legendre_unit(8)


def hermite(
    q0: np.ndarray, q1: np.ndarray, d0: np.ndarray, d1: np.ndarray, s: float | np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Cubic Hermite q(s), dq/ds(s) on s ∈ [0, 1] from end values and end slopes (× h)."""
    s2, s3 = s * s, s * s * s
    h00, h10, h01, h11 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2
    g00, g10, g01, g11 = 6 * s2 - 6 * s, 3 * s2 - 4 * s + 1, -6 * s2 + 6 * s, 3 * s2 - 2 * s
    return h00 * q0 + h10 * d0 + h01 * q1 + h11 * d1, g00 * q0 + g10 * d0 + g01 * q1 + g11 * d1


def hermite_nodes(
    q: np.ndarray, v: np.ndarray, k: np.ndarray, hk: float | np.ndarray, s: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities (len(s), K, n) at the points ``s`` ∈ [0, 1] of each interval
    [k, k + 1] on the cubic Hermite path through the samples ``q`` with velocities ``v`` (the
    one :func:`interval_integrals` integrates over); ``hk``: the
    intervals' lengths, a number or (K, 1)."""
    qs, ds = hermite(q[k], q[k + 1], hk * v[k], hk * v[k + 1], np.asarray(s)[:, None, None])
    return qs, ds / hk


def _hermite_velocity(
    q0: np.ndarray, q1: np.ndarray, d0: np.ndarray, d1: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, B, C) of the cubic Hermite's velocity dq/ds = A s² + B s + C."""
    return 6 * (q0 - q1) + 3 * (d0 + d1), -6 * (q0 - q1) - 4 * d0 - 2 * d1, d0


def hermite_velocity_cuts(
    q0: np.ndarray, q1: np.ndarray, d0: np.ndarray, d1: np.ndarray
) -> list[np.ndarray]:
    """[0, s₁, s₂, 1] per element: the cubic Hermite's velocity dq/ds = A s² + B s + C cut at
    its real roots inside (0, 1), so that sgn q̇ is constant on each piece. Roots outside
    (0, 1), or absent, become zero-length pieces at s = 1."""
    A, B, C = _hermite_velocity(q0, q1, d0, d1)
    with np.errstate(divide="ignore", invalid="ignore"):
        quad = np.abs(A) > 1e-300
        disc = np.where(quad, B * B - 4 * A * C, np.nan)
        r = np.sqrt(np.where(disc > 0, disc, np.nan))
        r1 = np.where(quad, (-B - r) / (2 * A), -C / B)
        r2 = np.where(quad, (-B + r) / (2 * A), np.nan)
    r1 = np.where((r1 > 0) & (r1 < 1), r1, 1.0)
    r2 = np.where((r2 > 0) & (r2 < 1), r2, 1.0)
    return [np.zeros_like(q0), np.minimum(r1, r2), np.maximum(r1, r2), np.ones_like(q0)]


def _sign_and_abs_integrals(
    q0: np.ndarray, q1: np.ndarray, d0: np.ndarray, d1: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """∫₀¹ sgn(dq/ds) ds and ∫₀¹ |dq/ds| ds of the cubic Hermite per element, exactly.

    dq/ds is a quadratic: [0, 1] is cut at its real roots inside (0, 1)
    (:func:`hermite_velocity_cuts`) and each piece integrated (sgn: piece length × its sign;
    |q̇|: |q(end) − q(start)|)."""
    A, B, C = _hermite_velocity(q0, q1, d0, d1)
    cuts = hermite_velocity_cuts(q0, q1, d0, d1)
    sgn_int = np.zeros_like(q0)
    abs_int = np.zeros_like(q0)
    q_at = [hermite(q0, q1, d0, d1, c)[0] for c in cuts]
    for i in range(3):
        lo, hi = cuts[i], cuts[i + 1]
        mid = 0.5 * (lo + hi)
        sgn_int += (hi - lo) * np.sign(A * mid * mid + B * mid + C)
        abs_int += np.abs(q_at[i + 1] - q_at[i])
    return sgn_int, abs_int


def interval_mean_across_reversals(
    f: Callable[[np.ndarray], np.ndarray],
    q0: np.ndarray,
    q1: np.ndarray,
    v0: np.ndarray,
    v1: np.ndarray,
    h: float | np.ndarray,
) -> np.ndarray:
    """(1/h)∫ f(q̇) dt over each interval, q̇ the derivative of the cubic Hermite interpolant
    through (q0, v0), (q1, v1) over the interval's length ``h``, for an ``f`` that is smooth
    except for a jump at q̇ = 0 (a friction law, sgn q̇ · F(|q̇|)): the interval is cut where
    q̇ changes sign (:func:`hermite_velocity_cuts`, as the Coulomb column's ∫ sgn q̇ dt) and
    each piece, on which f is smooth, integrated by Gauss–Legendre (PIECE_NODES points: a
    Stribeck decay over v_s can span a piece). Elementwise over arrays of one shape; ``h``
    broadcasts against them."""
    d0, d1 = h * v0, h * v1
    cuts = hermite_velocity_cuts(q0, q1, d0, d1)
    out = np.zeros(np.shape(q0))
    nodes = _PIECE_NODES.reshape((-1,) + (1,) * np.ndim(q0))
    for lo, hi in pairwise(cuts):
        s = lo + (hi - lo) * nodes
        v = hermite(q0, q1, d0, d1, s)[1] / h
        out += (hi - lo) * np.tensordot(_PIECE_WEIGHTS, f(v), axes=(0, 0))
    return out


def has_velocity_reversal(
    q0: np.ndarray, q1: np.ndarray, v0: np.ndarray, v1: np.ndarray, h: float | np.ndarray
) -> np.ndarray:
    """Whether the cubic Hermite's q̇ changes sign inside each interval (a root in (0, 1))."""
    return hermite_velocity_cuts(q0, q1, h * v0, h * v1)[1] < 1.0


@dataclass(frozen=True)
class IntervalIntegrals:
    """Integrals over each sample interval [t_k, t_{k+1}] of the terms the models need, for
    k = first..last (K intervals), on the cubic Hermite interpolant of q."""

    k: np.ndarray  # (K,) interval index (starts at sample k)
    R: np.ndarray | None  # (K, n, p)  ∫ R(q, q̇) dt (None: not asked for, ``static=False``)
    friction_work: np.ndarray  # (K, 2n)  ∫ [q̇1², .., q̇n², |q̇1|, .., |q̇n|] dt
    stuck: np.ndarray  # (K, n)  joint did not move over the interval (stick)


# Intervals integrated at once: bounds the quadrature's temporaries. A power of two: BLAS sums
# a vector's last few elements in a scalar tail loop (rounding apart from the SIMD body by an
# ulp), so chunks a multiple of any SIMD width give the same bits as the whole recording.
INTERVAL_CHUNK = 1 << 16


def interval_integrals(
    q: np.ndarray,
    v: np.ndarray,
    h: float | np.ndarray,
    model: ArmModel = NINE_PARAMETERS,
    *,
    static: bool = True,
) -> IntervalIntegrals:
    """∫ R dt and ∫ q̇ᵀφ_F dt over every interval whose two end velocities are known.

    ``h``: the common interval (s), or every interval's own length, shape (N − 1,).
    ``static`` False: leave ∫ R dt out (``R`` None); the energy and power rows need only the
    friction work, and R is most of the cost for a model through Pinocchio.
    ``model``: any model object with the static regressor and ``friction_columns`` (the
    viscous columns of joints 1..n, then the Coulomb ones), n joints."""
    ok = np.isfinite(v).all(axis=1)
    k = np.flatnonzero(ok[:-1] & ok[1:])
    # An n-joint model's static regressor holds (nodes, K, n, n, 10) temporaries (∂v_j/∂q_i of
    # every body and joint): the chunk shrinks with n² (by powers of two, so it still divides
    # ROW_CHUNK), so a 7-joint arm's stay as small as a 2-joint arm's (the intervals'
    # integrals are each their own: same results).
    chunk = INTERVAL_CHUNK >> max(0, int(np.ceil(np.log2(q.shape[1] ** 2 / 4))))
    if len(k) > chunk:
        # Every interval's integrals are its own: in chunks, so the (nodes, K, 2, p) values at
        # the quadrature nodes never exist for a whole long recording at once (issue 13).
        parts = [
            _interval_integrals(q, v, h, model, k[i : i + chunk], static)
            for i in range(0, len(k), chunk)
        ]
        R = np.concatenate([c.R for c in parts]) if static else None
        return IntervalIntegrals(
            k,
            R,
            *(np.concatenate([getattr(c, f) for c in parts]) for f in ("friction_work", "stuck")),
        )
    return _interval_integrals(q, v, h, model, k, static)


def _interval_integrals(
    q: np.ndarray,
    v: np.ndarray,
    h: float | np.ndarray,
    model: ArmModel,
    k: np.ndarray,
    static: bool = True,
) -> IntervalIntegrals:
    """:func:`interval_integrals` over the intervals ``k`` (both end velocities known)."""
    q0, q1 = q[k], q[k + 1]
    if np.ndim(h) == 0:
        hk: float | np.ndarray = h
        column: float | np.ndarray = h
    else:
        hk = np.asarray(h, dtype=float)[k]
        column = hk[:, None]
    d0, d1 = column * v[k], column * v[k + 1]
    # All Gauss–Legendre nodes at once: shape (nodes, K, 2).
    qs, vs = hermite_nodes(q, v, k, column, GL_NODES)
    R = None
    if np.ndim(hk) == 0:
        if static:
            R = np.tensordot(GL_WEIGHTS * hk, model.static_regressor(qs, vs), axes=(0, 0))
        sq = np.tensordot(GL_WEIGHTS * hk, vs**2, axes=(0, 0))  # degree 4: exact
    else:
        if static:
            R = np.einsum("n,nkmp->kmp", GL_WEIGHTS, model.static_regressor(qs, vs))
            R *= hk[:, None, None]
        sq = np.einsum("n,nkj->kj", GL_WEIGHTS, vs**2) * hk[:, None]
    sgn_int, abs_int = _sign_and_abs_integrals(q0, q1, d0, d1)
    dq = q1 - q0
    if R is not None:
        # Viscous (θ6, θ7) and Coulomb (θ8, θ9) columns, or joint j's of an n-joint model,
        # exactly: ∫ q̇ dt = Δq, ∫ sgn q̇ dt piecewise.
        n, fr = dq.shape[1], model.friction_columns
        for j in range(n):
            R[:, j, fr[j]] = dq[:, j]
            R[:, j, fr[n + j]] = hk * sgn_int[:, j]
    friction_work = np.column_stack([sq, abs_int])
    stuck = (dq == 0) & (np.abs(v[k]) < 1e-12) & (np.abs(v[k + 1]) < 1e-12)
    return IntervalIntegrals(k, R, friction_work, stuck)


# --- the three models -------------------------------------------------------------------------


def _check(
    q: np.ndarray, tau: np.ndarray, h: float, lam: float, discretization: str, n_joints: int = 2
) -> None:
    if q.ndim != 2 or q.shape[1] != n_joints or tau.shape != q.shape:
        raise ValueError(
            f"q and tau must both have shape (N, {n_joints}); got {q.shape} and {tau.shape}"
        )
    if not (np.isfinite(q).all() and np.isfinite(tau).all()):
        raise ValueError("q and tau must be finite (a NaN or inf in the recording?)")
    if not h > 0:
        raise ValueError(f"period must be > 0 s, got {h}")
    if not lam > 0:
        raise ValueError(f"filter bandwidth lambda must be > 0 rad/s, got {lam}")
    if discretization not in DISCRETIZATIONS:
        raise ValueError(
            f"unknown discretization {discretization!r}; "
            f"expected one of {', '.join(DISCRETIZATIONS)}"
        )


@dataclass(frozen=True)
class RawRows:
    """Unfiltered rows of one regression: the output ``y`` goes through filter ``y_filter``;
    the regressor is the sum over ``parts`` of (filter name, array (K, m, p)) each filtered.
    ``index``: the sample each row belongs to; ``stuck`` (K, m): the row's own interval had
    that joint stuck (static friction the model has no term for)."""

    index: np.ndarray
    y: np.ndarray
    y_filter: str
    parts: tuple[tuple[str, np.ndarray], ...]
    stuck: np.ndarray


@dataclass(frozen=True)
class Kinematics:
    """What every scheme's rows share: sample velocities and, for ``exact``, the interval
    integrals. Computed once per window by :func:`kinematics`. ``dt``: every interval's own
    length when the window has real time stamps (None: all equal to h)."""

    v: np.ndarray
    intervals: IntervalIntegrals | None
    model: ArmModel = NINE_PARAMETERS
    dt: np.ndarray | None = None


def kinematics(
    discretization: str,
    q: np.ndarray,
    h: float,
    *,
    model: ArmModel = NINE_PARAMETERS,
    t: np.ndarray | None = None,
    half_window: int = 1,
    keep: tuple[int, int] | None = None,
    static: bool = True,
    v: np.ndarray | None = None,
) -> Kinematics:
    """Velocities (backward difference for ``paper``, central for ``exact``) and, for
    ``exact``, the integrals over every interval with both end velocities known. ``t``: the
    samples' real times, used instead of k·h (``paper``: the backward difference over each
    sample's own interval); ``half_window`` > 1: velocities
    by :func:`local_polynomial_velocity` over 2·half_window + 1 samples (real times only);
    ``keep`` = (i, j): only intervals i..j−1 of the window (chunked building); ``static``
    False: without ∫ R dt (rows of the energy and power schemes only); ``v``: the sample
    velocities, when known (``exact``): positions shifted by a constant per joint (an encoder
    offset) have the velocities of the unshifted ones, and estimating them again cost a
    7-joint arm's encoder search a third of its row builds."""
    if discretization == "paper":
        if t is None:
            return Kinematics(backward_difference(q, h), None, model)
        dt = np.diff(np.asarray(t, dtype=float))
        return Kinematics(backward_difference(q, dt), None, model, dt)
    if t is None:
        v = central_difference(q, h) if v is None else v
        return Kinematics(v, interval_integrals(q, v, h, model, static=static), model)
    t = np.asarray(t, dtype=float)
    dt = np.diff(t)
    v = sample_velocities(q, h, t, half_window) if v is None else np.array(v, dtype=float)
    if keep is not None:  # intervals outside keep lose an end velocity, hence their rows
        v[: keep[0]] = np.nan
        v[keep[1] + 1 :] = np.nan
    return Kinematics(v, interval_integrals(q, v, dt, model, static=static), model, dt)


def raw_rows(
    scheme: str,
    discretization: str,
    q: np.ndarray,
    tau: np.ndarray,
    h: float,
    kin: Kinematics | None = None,
    *,
    model: ArmModel | None = None,
    t: np.ndarray | None = None,
) -> RawRows:
    """The unfiltered rows of ``scheme`` for every sample (paper) or interval (exact) of the
    window ``q``, ``tau`` whose inputs are complete (exact needs one sample either side).
    ``kin``: :func:`kinematics` of the same window, when several schemes share it (its model
    and time stamps are then used); else ``model`` (default 9 parameters) and ``t``."""
    if scheme not in SCHEMES:
        raise ValueError(f"unknown scheme {scheme!r}; expected one of {', '.join(SCHEMES)}")
    n = len(q)
    if kin is None:
        kin = kinematics(discretization, q, h, model=model or NINE_PARAMETERS, t=t)
    model = kin.model
    p = model.n_params
    v = kin.v
    if discretization == "paper":
        index = np.arange(n)
        if scheme == "filtered_dynamic":  # eq. (24), Section 5.1
            parts = (
                ("paper_bandpass", model.momentum_regressor(q, v)),
                ("paper_lowpass", model.static_regressor(q, v)),
            )
            return RawRows(index, tau, "paper_lowpass", parts, np.zeros((n, 2), bool))
        power = np.sum(tau * v, axis=1)[:, None]
        energy = model.energy_regressor(q, v)[:, None, :]  # zero on the friction columns
        friction = model.friction_power_regressor(v)[:, None, :]  # zero elsewhere
        if scheme == "supplied_energy":  # eq. (28), Section 5.2: ℰ(0) = 0, trapezoid integrals
            parts = (("none", energy), ("trapezoid", friction))
            return RawRows(index, power, "trapezoid", parts, np.zeros((n, 1), bool))
        parts = (("paper_bandpass", energy), ("paper_lowpass", friction))  # eq. (30), Sec. 5.3
        return RawRows(index, power, "paper_lowpass", parts, np.zeros((n, 1), bool))
    ii = kin.intervals
    assert ii is not None
    k = ii.k
    hk: float | np.ndarray = h if kin.dt is None else kin.dt[k][:, None]
    if scheme == "filtered_dynamic":
        # Momentum balance over [t_k, t_{k+1}]: h τ_k = [P(t_{k+1}) − P(t_k) + ∫R dt] θ, / h.
        P0 = model.momentum_regressor(q[k], v[k])
        P1 = model.momentum_regressor(q[k + 1], v[k + 1])
        hr = hk if np.ndim(hk) == 0 else hk[:, :, None]
        parts = (("interval_lowpass", (P1 - P0 + ii.R) / hr),)
        return RawRows(k + 1, tau[k], "interval_lowpass", parts, ii.stuck)
    # Energy balance over [t_k, t_{k+1}]: τ_kᵀΔq_k = [Δφ_ℰ, ∫q̇ᵀφ_F dt] θ   (eqs. (25), (27)),
    # for any number of joints: eq. (25) sums q̇ᵀτ over the joints.
    work = np.sum(tau[k] * (q[k + 1] - q[k]), axis=1)[:, None]
    # φ_ℰ once per sample (each is the end of one interval and the start of the next)
    at = np.union1d(k, k + 1)
    energy = model.energy_regressor(q[at], v[at])
    d_energy = energy[np.searchsorted(at, k + 1)] - energy[np.searchsorted(at, k)]
    fw = np.zeros((len(k), p))
    fw[:, list(model.friction_columns)] = ii.friction_work
    if "friction_offset" in model.terms:  # a constant torque f_o does the work f_o Δq
        fw[:, model.term_columns("friction_offset")] = q[k + 1] - q[k]
    rows = (d_energy + fw)[:, None, :]
    stuck = np.zeros((len(k), 1), bool)  # static friction does no work: energy rows hold
    if scheme == "supplied_energy":  # Σ from the first interval: eq. (28)
        return RawRows(k + 1, work, "cumulative_sum", (("cumulative_sum", rows),), stuck)
    hr = hk if np.ndim(hk) == 0 else hk[:, :, None]
    return RawRows(k + 1, work / hk, "interval_lowpass", (("interval_lowpass", rows / hr),), stuck)


def stick_memory(lam: float, h: float) -> int:
    """Samples after which a stuck interval weighs < STICK_MEMORY_DECAY in a filtered row."""
    return int(np.ceil(-np.log(STICK_MEMORY_DECAY) / (lam * h)))


NEVER_STUCK = -(10**9)  # "the last stuck row" before any was seen


def stick_weights(stuck: np.ndarray, memory: int) -> np.ndarray:
    """Weight 0 for a row whose filtered equation holds a stuck interval of that joint from the
    last ``memory`` rows, 1 otherwise."""
    return StickMemory(memory).weights(stuck)


class StickMemory:
    """:func:`stick_weights` over consecutive chunks of rows, the last stuck row carried across
    chunk borders, so chunked weights equal the whole recording's."""

    def __init__(self, memory: int) -> None:
        self.memory = memory
        self.last: np.ndarray | None = None  # (1, m): last stuck row, relative to the next chunk

    def weights(self, stuck: np.ndarray) -> np.ndarray:
        K, m = stuck.shape
        idx = np.arange(K)[:, None]
        prev = np.full((1, m), NEVER_STUCK) if self.last is None else self.last
        last = np.maximum.accumulate(np.vstack([prev, np.where(stuck, idx, NEVER_STUCK)]), axis=0)
        self.last = np.maximum(last[-1:] - K, NEVER_STUCK)
        return (idx - last[1:] > self.memory).astype(float)


class RowFilters:
    """The filters of a regression's rows (:func:`filter_coefficients`), applied chunk after
    chunk with each filter's state carried, so chunked rows equal the whole recording's."""

    def __init__(self, lam: float, h: float) -> None:
        self.lam, self.h = lam, h
        self.states: dict[int, np.ndarray] = {}
        self.varying: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def apply(self, raw: RawRows, dt: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(y, Psi) of ``raw``'s rows, filtered; ``dt``: each row's own interval (the paper's
        filters on real times, :func:`filter_over_intervals`), else the LTI filters at h."""
        # here, not with the module: the diagnosis never filters so and need not load
        # scipy.signal (~1.5 s of CPU); the online identifier, which filters inside a running
        # loop, has it imported with its own module (hil.identify.online), before any run
        from scipy.signal import lfilter

        out = []
        for i, (name, x) in enumerate(((raw.y_filter, raw.y), *raw.parts)):
            if dt is not None:
                y, self.varying[i] = filter_over_intervals(
                    name, self.lam, dt, x, self.varying.get(i)
                )
                out.append(y)
                continue
            b, a = filter_coefficients(name, self.lam, self.h)
            zi = self.states.get(i)
            if zi is None:
                zi = np.zeros((max(len(a), len(b)) - 1, *x.shape[1:]))
            y, self.states[i] = lfilter(b, a, x, axis=0, zi=zi)
            out.append(y)
        return out[0], sum(out[1:])


# Rows built at once by :func:`iter_regression`: bounds every temporary of the row building
# (about 0.3 KB a row for the filtered dynamic model). A multiple of INTERVAL_CHUNK, so the
# interval integrals are computed over the same groups of intervals as over a whole recording.
ROW_CHUNK = INTERVAL_CHUNK


def build_regression(
    scheme: str,
    q: np.ndarray,
    tau: np.ndarray,
    h: float,
    lam: float = 50.0,
    discretization: str = "exact",
    *,
    model: ArmModel = NINE_PARAMETERS,
    t: np.ndarray | None = None,
    half_window: int = 1,
) -> Regression:
    """The regression y(k) ≈ Ψ(k)ᵀθ of one scheme over a whole recording: the rows of
    :func:`iter_regression`, all of them in memory (tests, plots, short recordings; long ones
    are streamed, :mod:`hil.identify.schemes`).

    ``filtered_dynamic``: eq. (24), vector error; ``supplied_energy``: eq. (28), scalar;
    ``filtered_power``: eq. (30), scalar. See the module doc for the two discretizations.
    ``model``: whose columns (default the 9-parameter model); ``t``: the samples' real times
    (``exact``: ``h`` is then the nominal period that sets the row filter's coefficient;
    ``paper``: every filter over each row's own interval, :func:`filter_over_intervals`).
    """
    chunks = list(
        iter_regression(
            scheme, q, tau, h, lam, discretization, model=model, t=t, half_window=half_window
        )
    )
    return Regression(
        scheme,
        discretization,
        *(np.concatenate([getattr(c, f) for c in chunks]) for f in ("t", "y", "Psi", "weights")),
        lam,
        h,
    )


def _rows_from(raw: RawRows, first: int) -> RawRows:
    """``raw`` without its first ``first`` rows."""
    if first == 0:
        return raw
    parts = tuple((name, x[first:]) for name, x in raw.parts)
    return RawRows(raw.index[first:], raw.y[first:], raw.y_filter, parts, raw.stuck[first:])


def iter_regression(
    scheme: str,
    q: np.ndarray,
    tau: np.ndarray,
    h: float,
    lam: float = 50.0,
    discretization: str = "exact",
    *,
    model: ArmModel = NINE_PARAMETERS,
    t: np.ndarray | None = None,
    half_window: int = 1,
    stuck: np.ndarray | None = None,
    chunk: int = ROW_CHUNK,
):
    """The rows of :func:`build_regression` in chunks of ``chunk`` rows (:class:`RowChunk`),
    each built from its window of samples plus the few either side its velocities need, with
    the filters' states (:class:`RowFilters`) and the stick memory (:class:`StickMemory`)
    carried across chunk borders: the chunks, concatenated, are the whole recording's rows,
    and memory is O(chunk · p) beyond ``q`` and ``tau`` (issue 13). ``stuck`` (N − 1, 2):
    which intervals hold a stuck joint, when not the interval integrals' exact rule (real
    recordings, :func:`quantized_stick`); it applies to the filtered dynamic rows only."""
    q, tau = np.asarray(q, float), np.asarray(tau, float)
    _check(q, tau, h, lam, discretization, model.n_joints)
    if len(q) < 8:
        raise ValueError(f"need at least 8 samples to identify, got {len(q)}")
    if not chunk >= 1:
        raise ValueError(f"chunk must be >= 1 row, got {chunk}")
    if t is not None:
        t = np.asarray(t, dtype=float)
    n = len(q)
    filters = RowFilters(lam, h)
    memory = StickMemory(stick_memory(lam, h))
    if discretization == "paper":
        # one row per sample; the backward difference looks one sample back
        spans = [
            (s, min(s + chunk, n), max(0, s - 1), min(s + chunk, n)) for s in range(0, n, chunk)
        ]
    else:
        # intervals m..n−m−2 have both end velocities (central difference: m = 1)
        m = max(1, int(half_window)) if t is not None else 1
        last = n - m - 1
        spans = [
            (s, min(s + chunk, last), max(0, s - m), min(n, min(s + chunk, last) + m + 1))
            for s in range(m, last, chunk)
        ]
    for s, e, a, b in spans:
        tw = None if t is None else t[a:b]
        keep = None if t is None or discretization == "paper" else (s - a, e - a)
        kin = kinematics(
            discretization, q[a:b], h, model=model, t=tw, half_window=half_window, keep=keep,
            static=scheme == "filtered_dynamic",
        )  # fmt: skip
        raw = raw_rows(scheme, discretization, q[a:b], tau[a:b], h, kin)
        if discretization == "paper":
            raw = _rows_from(raw, s - a)
        row_stuck = raw.stuck
        if stuck is not None and scheme == "filtered_dynamic":
            row_stuck = stuck[raw.index - 1 + a]  # row k+1 is about interval k
        index = raw.index + a
        dt = None
        if t is not None and discretization == "paper":
            # each row's own interval t_k − t_{k−1}; a segment's first row has none before it
            # (its filters' inputs before it are zero, so only the trapezoid's first half-step
            # uses it): the nominal period there
            dt = np.where(index > 0, t[index] - t[np.maximum(index - 1, 0)], h)
        y, Psi = filters.apply(raw, dt)
        weights = memory.weights(row_stuck)
        yield RowChunk(index * h if t is None else t[index], y, Psi, weights)


# --- real recordings: bandwidth, stick detection under quantization, rows in chunks ----------


def excitation_bandwidth(q: np.ndarray, t: np.ndarray, fraction: float = 0.95) -> float:
    """ω (rad/s) below which ``fraction`` of the detrended position variance lies, the largest
    over the joints: the excitation's bandwidth, read from the data. The paper puts λ at about
    twice its highest excitation frequency (26 rad/s → 50 rad/s); :func:`data_bandwidth`
    follows that rule."""
    q = np.asarray(q, dtype=float)
    t = np.asarray(t, dtype=float)
    h = float(np.median(np.diff(t)))
    # The spectrum of the samples as if equally spaced at the median interval: irregularity
    # smears, but does not move, a band that is much lower than the sample rate.
    q2d = q.reshape(len(q), -1)
    coef = np.polynomial.polynomial.polyfit(t - t[0], q2d, 1)
    x = q2d - (coef[0] + np.outer(t - t[0], coef[1]))
    power = np.abs(np.fft.rfft(x, axis=0)) ** 2
    power[0] = 0.0
    freq = np.fft.rfftfreq(len(x), h)
    cum = np.cumsum(power, axis=0)
    total = cum[-1]
    omegas = [
        2 * np.pi * freq[np.searchsorted(cum[:, j], fraction * total[j])]
        for j in range(x.shape[1])
        if total[j] > 0
    ]
    return float(max(omegas)) if omegas else float("nan")


def data_bandwidth(q: np.ndarray, t: np.ndarray) -> float:
    """The row filter's λ (rad/s) from the data: twice :func:`excitation_bandwidth` (the
    paper's rule, Section 6), at least 2π·0.5 Hz and at most a tenth of the sample rate in
    rad/s (beyond that the rows hold mostly differentiation noise)."""
    h = float(np.median(np.diff(t)))
    lam = 2.0 * excitation_bandwidth(q, t)
    if not np.isfinite(lam):
        lam = 50.0
    return float(np.clip(lam, 2 * np.pi * 0.5, 0.1 * 2 * np.pi / h))


def quantized_stick(q: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N − 1, 2): interval k has joint j stuck, telling a stuck joint from a reversal.

    With an encoder quantum Δ, a joint reversing at acceleration a stays on one count for
    about 2√(2Δ/a), so an interval with no encoder motion is only a stick when its run of
    unchanged counts lasts longer than twice that (Δ: the smallest non-zero step seen; a: the
    RMS of the joint's acceleration from second differences over the same quantum-free scale).
    """
    q = np.asarray(q, dtype=float)
    t = np.asarray(t, dtype=float)
    dq = np.diff(q, axis=0)
    dt = np.diff(t)
    still = dq == 0
    out = np.zeros_like(still)
    for j in range(q.shape[1]):
        steps = np.abs(dq[:, j])
        moved = steps[steps > 0]
        if moved.size == 0:
            out[:, j] = still[:, j]
            continue
        quantum = float(moved.min())
        # acceleration on a 10-sample scale, where quantization is small against motion
        s = 10
        if len(q) > 2 * s + 1:
            hs = float(np.median(dt)) * s
            acc = (q[2 * s :, j] - 2 * q[s:-s, j] + q[: -2 * s, j]) / hs**2
            a_rms = float(np.sqrt(np.mean(acc**2)))
        else:
            a_rms = 0.0
        dwell = 4.0 * np.sqrt(2 * quantum / a_rms) if a_rms > 0 else np.inf
        # run lengths (in seconds) of consecutive still intervals
        col = still[:, j]
        edges = np.flatnonzero(np.diff(np.r_[0, col.astype(np.int8), 0]))
        for start, stop in zip(edges[::2], edges[1::2], strict=True):
            if np.sum(dt[start:stop]) > dwell:
                out[start:stop, j] = True
    return out


@dataclass(frozen=True)
class RowChunk:
    """Filtered rows of one chunk: ``y`` (K, m), ``Psi`` (K, m, p), ``weights`` (K, m),
    ``t`` (K,) the time of each row."""

    t: np.ndarray
    y: np.ndarray
    Psi: np.ndarray
    weights: np.ndarray


def iter_rows(
    scheme: str,
    q: np.ndarray,
    tau: np.ndarray,
    t: np.ndarray,
    lam: float,
    model: ArmModel = NINE_PARAMETERS,
    *,
    chunk: int = 20000,
    half_window: int | None = None,
):
    """The ``exact`` regression of a recording with real time stamps, in chunks of ``chunk``
    intervals with the filters' state carried across, so memory stays O(chunk · p) whatever the
    recording's length. Velocities by :func:`local_polynomial_velocity` over
    ±``half_window`` samples (default :func:`velocity_half_window`). The rows equal
    :func:`build_regression`'s with ``t`` and the same ``half_window`` (up to the stick rule,
    here :func:`quantized_stick`). Yields :class:`RowChunk`."""
    q, tau, t = (np.asarray(a, dtype=float) for a in (q, tau, t))
    h = float(np.median(np.diff(t)))
    _check(q, tau, h, lam, "exact", model.n_joints)
    m = velocity_half_window(lam, t) if half_window is None else max(1, int(half_window))
    yield from iter_regression(
        scheme, q, tau, h, lam, "exact", model=model, t=t, half_window=m,
        stuck=quantized_stick(q, t), chunk=chunk,
    )  # fmt: skip


__all__ = [
    "DISCRETIZATIONS",
    "SCHEMES",
    "Regression",
    "RowChunk",
    "build_regression",
    "data_bandwidth",
    "excitation_bandwidth",
    "filter_coefficients",
    "filter_over_intervals",
    "held_torque_momentum_bias",
    "iter_regression",
    "iter_rows",
    "sample_velocities",
]
