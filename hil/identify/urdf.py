"""Identification of an n-joint arm's base parameters from a torque recording, on the torque
regressor of :class:`hil.model.urdf.UrdfArmModel` (batch least squares, filtered, on the real
time stamps) and its held-out validation.

Method (Gautier (1997) "parallel filtering"): positions are smoothed by a zero-phase low-pass
that respects the real time stamps (see :func:`smoothed_motion`), velocities and accelerations
are the derivatives of the smoothed positions at the real stamps; then the torque regressor
Y(q, q̇, q̈) and the measured torque τ are averaged over blocks of rows by one and the same
filter, so each kept row y = Ψ θ stays exact (a fixed linear combination of rows applied to both
sides); the smoothing removes the noise differentiation would amplify and the block average
keeps the solve small. The solve is
:func:`hil.model.estimators.weighted_least_squares` (per-joint noise levels from the residuals: the
Panda's joint torques span 0.5 to 40 Nm, and plain least squares would all but ignore the
wrist).

The supplied-energy and filtered-power schemes of Reyes & Kelly (1997) for n joints
(:func:`identify_energy`): the ``exact`` rows of :mod:`hil.model.regressors` — the interval
energy balance τ_kᵀΔq_k = [Δφ_ℰ, ∫q̇ᵀφ_F dt] θ (eqs. (25), (27)), summed from the start
(supplied energy, eq. (28)) or divided by each interval's length and low-passed (filtered
power, eq. (30)) — on the model's energy regressors (:meth:`UrdfArmModel.energy_regressor`)
and the recording's real time stamps, the same code that builds the 2-DOF rows; batch least
squares (:class:`hil.model.estimators.LeastSquaresRows`).

The Panda log layout of Gaz et al. (2019) is read into the standard recording by
:func:`drivers.one_per_line.read_one_per_line_log`. Per-parameter uncertainty and "not
identifiable" (:class:`~hil.identify.schemes.Uncertainty`) follow the 2-DOF path's rule
(:mod:`hil.identify.schemes`). Imports drivers.recording, hil.identify.schemes (its
identifiability constants, uncertainty type and bootstrap block rule), hil.model.estimators,
hil.model.metrics, hil.model.regressors and hil.model.urdf; no plotting, no file reading.
The module is longer than 800 lines because the torque and energy schemes and the physically
consistent fit are read on one smoothing of the recording (its cutoff, stuck samples and
held-out split), which they share.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.signal import butter, sosfiltfilt

from drivers.recording import Recording
from hil.identify.schemes import (
    BOOTSTRAP_DRAWS,
    IDENTIFIED_MAX_RELATIVE_SE,
    Uncertainty,
    bootstrap_block_s,
)
from hil.model.estimators import (
    BlockNormalEquations,
    LeastSquaresRows,
    channel_weights,
    combine,
    solve_normal_equations,
    standard_errors,
    weighted_least_squares,
)
from hil.model.metrics import nrmse, nrmse_upper_bound
from hil.model.regressors import (
    data_bandwidth,
    excitation_bandwidth,
    iter_rows,
    local_polynomial_velocity,
    quantized_stick,
)
from hil.model.urdf import UrdfArmModel

# Smoothing of positions before differentiation, and of both sides of the regression.
DEFAULT_CUTOFF_HZ = 4.0
DEFAULT_DECIMATE = 10
# Weight of the pull towards the URDF's bodies in the consistent fit, relative to the data's.
REGULARIZATION = 1e-4
# Rows dropped at each end: the zero-phase filters' start-up transients.
EDGE_S = 0.5


def inside_edges(t: np.ndarray) -> np.ndarray:
    """Which stamps of ``t`` lie EDGE_S or more from both ends (the smoothed rows kept)."""
    return (t >= t[0] + EDGE_S) & (t <= t[-1] - EDGE_S)


# A joint's torque rows are left out within this many periods of the smoothing cutoff of a
# friction step (a stick or a reversal, friction_step_samples).
FRICTION_STEP_MARGIN_PERIODS = 1.0
# ... when the first fit's residual there is this many times its residual elsewhere
# (leave_out_friction_steps), and at least this share of the joint's rows is away from steps.
STEP_RESIDUAL_RATIO = 2.0
MIN_ROWS_AWAY_FROM_STEPS = 0.05


def torque_at_samples(rec: Recording) -> np.ndarray:
    """The torque that goes with the motion at each t_k. A held torque
    (:attr:`~drivers.recording.Recording.torque_held`) steps at t_k, so the acceleration
    there, smoothed, is that of the mean of the torques on either side, (τ_{k−1} + τ_k)/2
    (row 0 keeps τ_0); taking τ_k instead is a half-period lead that biases the viscous
    coefficients (−18 % and −22 % on joints 1 and 2 of the simulated cicese3 arm,
    docs/urdf.md). A sampled torque already belongs to its row's state."""
    if not rec.torque_held:
        return rec.tau
    out = rec.tau.copy()
    out[1:] = 0.5 * (rec.tau[1:] + rec.tau[:-1])
    return out


def torque_over_intervals(rec: Recording) -> np.ndarray:
    """Row k: the torque over [t_k, t_{k+1}] whose work the energy rows take as
    τ_kᵀ (q_{k+1} − q_k). A held torque is that (exactly); a sampled one is taken as linear
    between its samples, (τ_k + τ_{k+1})/2 (the trapezoid rule; τ_k alone would be the
    half-period lead :func:`torque_at_samples` describes). The last row has no interval."""
    if rec.torque_held:
        return rec.tau
    out = rec.tau.copy()
    out[:-1] = 0.5 * (rec.tau[:-1] + rec.tau[1:])
    return out


@dataclass(frozen=True)
class Motion:
    """Smoothed positions, velocities and accelerations on the recording's own time grid (ends
    trimmed), with the torque rows they belong to."""

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    tau: np.ndarray
    cutoff_hz: float
    # (N, n): a friction step of the joint near this sample (friction_step_samples)
    near_step: np.ndarray | None = None


def _lowpass(x: np.ndarray, cutoff_hz: float, period_s: float) -> np.ndarray:
    # Butterworth 4th order, run forward and backward (zero phase). It acts on the row sequence
    # at the median interval; rows are combined alike on both sides of every equation.
    sos = butter(4, cutoff_hz, fs=1.0 / period_s, output="sos")
    return sosfiltfilt(sos, x, axis=0)


def smoothed_motion(rec: Recording, *, cutoff_hz: float = DEFAULT_CUTOFF_HZ) -> Motion:
    """q, q̇, q̈ at the recording's real time stamps, smoothed: q is interpolated (cubic spline
    through the samples at their real times) onto a uniform grid at the median interval,
    low-passed there (zero phase), and the cubic spline of the result gives q, q̇ and q̈ back at
    the real stamps. A filter run over the raw rows as if they were equally spaced would turn
    time-stamp jitter into velocity and acceleration errors. Ends (EDGE_S) are dropped."""
    t = rec.t
    smooth = smoothed_positions(rec, cutoff_hz)
    keep = inside_edges(t)
    tk = t[keep]
    tau = torque_at_samples(rec)[keep]
    near_step = friction_step_samples(
        t, stuck_samples(rec), smooth(t, 1), FRICTION_STEP_MARGIN_PERIODS / cutoff_hz
    )[keep]
    return Motion(tk, smooth(tk), smooth(tk, 1), smooth(tk, 2), tau, cutoff_hz, near_step)


def smoothed_positions(rec: Recording, cutoff_hz: float) -> CubicSpline:
    """The smoothed positions of :func:`smoothed_motion` as a cubic spline of time (its
    derivatives are q̇ and q̈): q interpolated onto a uniform grid at the median interval,
    low-passed there at ``cutoff_hz`` (zero phase)."""
    t = rec.t
    period = float(np.median(np.diff(t)))
    if not 0 < cutoff_hz < 0.5 / period:
        raise ValueError(f"cutoff {cutoff_hz} Hz must be in (0, {0.5 / period:.4g}) Hz")
    grid = np.arange(t[0], t[-1], period)
    return CubicSpline(grid, _lowpass(CubicSpline(t, rec.q)(grid), cutoff_hz, period))


def friction_step_samples(
    t: np.ndarray, stuck: np.ndarray, dq: np.ndarray, margin_s: float
) -> np.ndarray:
    """(N, n): sample k lies within ``margin_s`` of a friction step of joint j — a sample where
    it sticks (``stuck``) or a sign change of its smoothed velocity ``dq`` (a reversal).
    Coulomb friction steps by 2 f_c there, so the true acceleration steps, and the zero-phase
    low-pass of :func:`smoothed_motion` spreads that step over about one period of its cutoff
    either side: the smoothed q̈ and sgn q̇ are wrong there by as much as the step (on the
    ur5e's wrist, 0.4 Nm of Coulomb friction on 0.0054 kg m²: 150 rad/s² per reversal; with
    the true parameters the rows near reversals left joint 4's and 5's torques 2.0 % and 2.5 %
    unexplained, without them 0.2 %: docs/urdf.md). Gautier's parallel filtering assumes a
    motion smooth within the filter's band; these rows are where it is not."""
    events = stuck.copy()
    sign = np.sign(dq)
    events[1:] |= (sign[1:] * sign[:-1]) < 0
    out = np.zeros_like(events)
    for j in range(events.shape[1]):
        te = t[events[:, j]]
        if te.size == 0:
            continue
        i = np.searchsorted(te, t)
        before = np.abs(t - te[np.clip(i - 1, 0, te.size - 1)])
        after = np.abs(te[np.clip(i, 0, te.size - 1)] - t)
        out[:, j] = np.minimum(before, after) <= margin_s
    return out


def stuck_samples(rec: Recording) -> np.ndarray:
    """(N, n): sample k touches an interval in which joint j sticks
    (:func:`hil.model.regressors.quantized_stick`, the 2-DOF path's rule, which tells a stuck
    joint from an encoder count held through a reversal). While a joint sticks, its friction is
    the static constraint torque, anywhere in the band [f_o − f_c, f_o + f_c], which the model's
    f_c sgn q̇ cannot give; and the smoothed acceleration cannot follow the step at the stick's
    start and end. Its torque equation there is left out (:func:`friction_step_samples`), as
    the 2-DOF filtered dynamic rows leave such intervals out (:mod:`hil.model.regressors`)."""
    out = np.zeros(rec.q.shape, dtype=bool)
    if len(rec.t) < 2:
        return out
    interval = quantized_stick(rec.q, rec.t)
    out[:-1] |= interval
    out[1:] |= interval
    return out


def smoothing_cutoff_hz(rec: Recording) -> float:
    """A cutoff for :func:`smoothed_motion` read from the data: eight times the excitation
    bandwidth (:func:`hil.model.regressors.excitation_bandwidth`, 95 % of the position
    variance), at least :data:`DEFAULT_CUTOFF_HZ` and at most a tenth of the sample rate.
    Only q is low-passed, not τ, so the cutoff must pass the accelerations' content, which
    reaches well above the positions' band: friction steps at each reversal and a held torque's
    steps. A 4th-order Butterworth passes |H|² = 0.93 at 0.71 of its cutoff, a 7 % error on
    the accelerations there (on the simulated cicese3 arm, 4× the bandwidth put the viscous
    coefficients 17 to 26 % off, 8× within 3 %; on the Panda of Gaz et al. 8× gives 4.28 Hz,
    4× the 4 Hz floor)."""
    period = float(np.median(np.diff(rec.t)))
    bandwidth_hz = excitation_bandwidth(rec.q, rec.t) / (2 * np.pi)
    if not np.isfinite(bandwidth_hz):
        return DEFAULT_CUTOFF_HZ
    return float(np.clip(8.0 * bandwidth_hz, DEFAULT_CUTOFF_HZ, 0.1 / period))


@dataclass(frozen=True)
class FilteredRows:
    """Rows y = Ψ θ after parallel filtering and decimation: ``t`` (K,), ``tau`` (K, n),
    ``Y`` (K, n, p); ``near_step`` (K, n): the block holds a sample near a friction step of
    that joint (:func:`friction_step_samples`); ``weights`` (K, n): 0 where the joint's
    equation is left out (:meth:`leaving_out`), else 1."""

    t: np.ndarray
    tau: np.ndarray
    Y: np.ndarray
    near_step: np.ndarray
    weights: np.ndarray

    def select(self, keep: np.ndarray) -> FilteredRows:
        """The rows where ``keep`` (K,) is true."""
        return FilteredRows(
            self.t[keep], self.tau[keep], self.Y[keep], self.near_step[keep], self.weights[keep]
        )

    def leaving_out(self, joints: np.ndarray) -> FilteredRows:
        """These rows with weight 0 on the equations of ``joints`` (n,) near friction steps."""
        weights = np.where(self.near_step & np.asarray(joints, dtype=bool), 0.0, 1.0)
        return FilteredRows(self.t, self.tau, self.Y, self.near_step, weights)


def filtered_rows(
    motion: Motion, Y: np.ndarray, *, decimate: int = DEFAULT_DECIMATE
) -> FilteredRows:
    """Average the regressor ``Y`` (N, n, p) and the torques of ``motion`` over blocks of
    ``decimate`` consecutive rows (a moving mean, then every ``decimate``-th row): the same
    linear combination of rows on both sides, so every averaged row is as exact as the rows it
    averages, and it costs one pass over the data."""
    N, n, p = Y.shape
    K = N // decimate
    both = np.concatenate([motion.tau[: K * decimate], Y[: K * decimate].reshape(-1, n * p)], 1)
    both = both.reshape(K, decimate, -1).mean(axis=1)
    t = motion.t[: K * decimate].reshape(K, decimate).mean(axis=1)
    near = np.zeros((K, n), dtype=bool)
    if motion.near_step is not None:
        near = motion.near_step[: K * decimate].reshape(K, decimate, n).any(axis=1)
    return FilteredRows(t, both[:, :n], both[:, n:].reshape(K, n, p), near, np.ones((K, n)))


def parameter_uncertainty(
    blocks: BlockNormalEquations, theta: np.ndarray, *, weighted: bool = True
) -> Uncertainty:
    """:class:`Uncertainty` of the least-squares ``theta`` from rows summed per time block
    (:class:`hil.model.estimators.BlockNormalEquations`); ``weighted``: each output channel
    weighted by 1/σ² of its residuals, as the weighted least squares was."""
    H, g, yy, n = blocks.arrays()
    w = channel_weights(H, g, yy, n, theta) if weighted else np.ones(H.shape[1])
    Hw, gw, yyw = combine(H, g, yy, w)
    theta_w = solve_normal_equations(Hw.sum(0), gw.sum(0))
    se_white, se_block = standard_errors(Hw, gw, yyw, int(n.sum()), theta_w, draws=BOOTSTRAP_DRAWS)
    identified = se_block < IDENTIFIED_MAX_RELATIVE_SE * np.abs(theta)
    return Uncertainty(se_white, se_block, identified, blocks.block_s, len(H))


@dataclass(frozen=True)
class TorqueIdentification:
    theta: np.ndarray  # base parameters of the model
    fit_until_s: float  # rows with t < this were fitted, the rest held out
    rows: FilteredRows
    predicted: np.ndarray  # (K, n): Ψ θ on every row
    nrmse_held_out: np.ndarray  # (n,)
    theta_standard: np.ndarray | None = None  # the consistent fit's standard parameters
    method: str = "weighted least squares"
    uncertainty: Uncertainty | None = None  # of the least-squares fit
    # (n,): joints whose rows near friction steps were left out (leave_out_friction_steps)
    left_out_joints: np.ndarray | None = None
    # (n,): RMS residual of the first fit near friction steps over that away from them
    step_residual_ratio: np.ndarray | None = None
    # the least-squares θ when its friction was negative and θ is the bounded fit, else None
    theta_least_squares: np.ndarray | None = None


def fit_split(rec: Recording, held_out: float) -> float:
    """The time before which rows are fitted: the first (1 − ``held_out``) of the span."""
    return float(rec.t[0] + (1.0 - held_out) * (rec.t[-1] - rec.t[0]))


def _check_joints(model: UrdfArmModel, rec: Recording) -> None:
    if rec.n_joints != model.n_joints:
        raise ValueError(
            f"{rec.path}: {rec.n_joints} joints in the recording, the model has {model.n_joints}"
        )


def regression_rows(
    model: UrdfArmModel,
    rec: Recording,
    *,
    cutoff_hz: float = DEFAULT_CUTOFF_HZ,
    decimate: int = DEFAULT_DECIMATE,
) -> FilteredRows:
    """The rows τ ≈ Y θ of a recording: smoothed motion, torque regressor, block average."""
    _check_joints(model, rec)
    motion = smoothed_motion(rec, cutoff_hz=cutoff_hz)
    Y = model.torque_regressor(motion.q, motion.dq, motion.ddq)
    return filtered_rows(motion, Y, decimate=decimate)


def torque_nrmse(theta: np.ndarray, rows: FilteredRows) -> np.ndarray:
    """Per-joint NRMSE of the torque θ predicts on ``rows`` (:func:`hil.model.metrics.nrmse`),
    each joint on its rows of weight > 0 (not stuck); nan for a joint with fewer than 2."""
    predicted = np.einsum("knp,p->kn", rows.Y, theta)
    out = np.full(rows.tau.shape[1], np.nan)
    for j in range(len(out)):
        use = rows.weights[:, j] > 0
        if use.sum() >= 2:
            out[j] = nrmse(rows.tau[use, j], predicted[use, j])
    return out


# Confidence with which a scheme's held-out torque prediction must beat the trivial predictor
# (the held-out torque's own mean) on every joint before its θ is reported as identified.
VALIDATION_CONFIDENCE = 0.95


@dataclass(frozen=True)
class HeldOutVerdict:
    """Whether θ's held-out torque prediction is better than predicting each joint's mean:
    per joint the NRMSE (:func:`torque_nrmse`) and its one-sided upper confidence bound
    (:func:`hil.model.metrics.nrmse_upper_bound`); ``passed`` when every bound is below 1;
    ``reason`` one line naming the joints that fail, None when it passed."""

    nrmse: np.ndarray
    nrmse_upper: np.ndarray
    passed: bool
    reason: str | None
    block_s: float

    def as_json(self) -> dict:
        return {
            "torque_nrmse": self.nrmse.tolist(),
            "torque_nrmse_upper_bound": [
                None if not np.isfinite(x) else float(x) for x in self.nrmse_upper
            ],
            "passed": self.passed,
            "reason": self.reason,
            "criterion": f"every joint's held-out torque NRMSE below 1 (better than predicting "
            f"its mean) with {VALIDATION_CONFIDENCE:.0%} one-sided confidence (the error "
            f"sum's scatter by batch means over {self.block_s:.3g} s blocks)",
        }


def held_out_verdict(theta: np.ndarray, rows: FilteredRows, cutoff_hz: float) -> HeldOutVerdict:
    """:class:`HeldOutVerdict` of ``theta`` on the held-out ``rows`` (each joint on its rows of
    weight > 0, as :func:`torque_nrmse`). The rows are smoothed at ``cutoff_hz``, so their
    residuals are correlated; the test's blocks are the bootstrap's
    (:func:`hil.identify.schemes.bootstrap_block_s`, as for the fit's uncertainty). A joint
    with too few rows or blocks to judge fails too: "I cannot tell" is not a pass."""
    error = torque_nrmse(theta, rows)
    span = float(rows.t[-1] - rows.t[0]) if len(rows.t) else 0.0
    block_s = bootstrap_block_s(2 * np.pi * cutoff_hz, span)
    labels = np.floor((rows.t - (rows.t[0] if len(rows.t) else 0.0)) / block_s).astype(int)
    predicted = np.einsum("knp,p->kn", rows.Y, theta)
    upper = np.full(len(error), np.nan)
    for j in range(len(error)):
        use = rows.weights[:, j] > 0
        if use.sum() >= 2:
            upper[j] = nrmse_upper_bound(
                rows.tau[use, j], predicted[use, j], labels[use], confidence=VALIDATION_CONFIDENCE
            )
    worse = [j for j in range(len(error)) if np.isfinite(upper[j]) and upper[j] >= 1.0]
    unjudged = [j for j in range(len(error)) if not np.isfinite(upper[j])]
    parts = []
    if worse:
        parts.append(
            "no better than the held-out mean on joint "
            + ", ".join(f"{j + 1} (NRMSE {error[j]:.3g}, bound {upper[j]:.3g})" for j in worse)
        )
    if unjudged:
        parts.append(
            "too few held-out rows or blocks to judge joint "
            + ", ".join(str(j + 1) for j in unjudged)
        )
    reason = "; ".join(parts) if parts else None
    return HeldOutVerdict(error, upper, reason is None, reason, block_s)


def identify_torque(
    model: UrdfArmModel,
    rec: Recording,
    *,
    cutoff_hz: float = DEFAULT_CUTOFF_HZ,
    decimate: int = DEFAULT_DECIMATE,
    held_out: float = 0.25,
    consistent: bool = False,
) -> TorqueIdentification:
    """Batch least squares of the base parameters and friction on the first (1 − held_out) of
    the recording's time span; the normalized error of the torque prediction on the rest
    (``held_out`` = 0: fit on everything, no held-out error). ``consistent``: the fit is
    constrained to physically consistent standard parameters (:func:`consistent_fit`)."""
    rows = regression_rows(model, rec, cutoff_hz=cutoff_hz, decimate=decimate)
    split = fit_split(rec, held_out)
    fit = rows.t < split if held_out > 0 else np.ones(len(rows.t), dtype=bool)
    held_out_rows = ~fit
    if fit.sum() * model.n_joints < 2 * model.n_params or (
        held_out > 0 and held_out_rows.sum() < 2
    ):
        raise ValueError(
            f"{rec.path}: {len(rows.t)} rows after averaging, too few to fit "
            f"{model.n_params} parameters"
        )
    theta = weighted_least_squares(rows.Y[fit], rows.tau[fit])
    left_out, ratio = leave_out_friction_steps(rows.select(fit), theta)
    if left_out.any():
        rows = rows.leaving_out(left_out)
        theta = weighted_least_squares(rows.Y[fit], rows.tau[fit], rows.weights[fit])
    weights = rows.weights[fit]
    # the smoothing's cutoff plays the row filter's λ in the 2-DOF path's rule for the blocks
    block_s = bootstrap_block_s(2 * np.pi * cutoff_hz, float(rec.t[-1] - rec.t[0]))
    blocks = BlockNormalEquations(model.n_params, model.n_joints, block_s)
    blocks.add(rows.t[fit], rows.tau[fit], rows.Y[fit], weights)
    uncertainty = parameter_uncertainty(blocks, theta)
    theta_standard, method, theta_ls = None, "weighted least squares", None
    if consistent:
        theta_standard = consistent_fit(model, rows.Y[fit], rows.tau[fit], theta, weights)
        theta, method = model.base_theta(theta_standard), "physically consistent least squares"
    else:
        theta_ls, (theta, method) = theta, friction_bounded(
            model, theta, method,
            lambda lower: weighted_least_squares(rows.Y[fit], rows.tau[fit], weights, lower=lower),
        )  # fmt: skip
        if not model.physical_consistency(theta)["consistent"]:  # M(q) ≻ 0 is no linear bound
            theta_standard = consistent_fit(model, rows.Y[fit], rows.tau[fit], theta_ls, weights)
            theta, method = model.base_theta(theta_standard), _consistent_instead(model, theta)
        theta_ls = None if theta is theta_ls else theta_ls
    predicted = np.einsum("knp,p->kn", rows.Y, theta)
    held = (
        torque_nrmse(theta, rows.select(held_out_rows))
        if held_out > 0
        else np.full(model.n_joints, np.nan)
    )
    return TorqueIdentification(
        theta, split, rows, predicted, held, theta_standard, method, uncertainty, left_out, ratio,
        theta_ls,
    )  # fmt: skip


def _consistent_instead(model: UrdfArmModel, theta: np.ndarray) -> str:
    """The method of a fit made physically consistent because ``theta`` (friction bounded) is
    not: its violations named (M(q) not positive definite at a sampled q)."""
    why = "; ".join(model.physical_consistency(theta)["violations"])
    return f"physically consistent least squares (least squares is not: {why})"


def friction_bounded(
    model: UrdfArmModel,
    theta: np.ndarray,
    method: str,
    solve_bounded: Callable[[np.ndarray], np.ndarray],
) -> tuple[np.ndarray, str]:
    """(θ, ``method``) itself when every viscous and Coulomb coefficient of the least-squares
    ``theta`` is ≥ 0; else ``solve_bounded(lower)``: the same fit (same rows, same weights)
    with those coefficients ≥ 0 (BVLS, :meth:`hil.model.estimators.LeastSquaresRows.
    solve_bounded`), as the 2-DOF model path bounds its fit
    (:func:`hil.identify.schemes.identify_model`). A coefficient whose true value is 0 (an arm
    without viscous friction) comes out of least squares below 0 half the time; the bound puts
    it at 0 and refits the rest. Base parameters are combinations of the bodies' (many
    standard vectors share one), so friction signs are the only signs a base vector fixes;
    M(q) ≻ 0 is no linear bound and is checked afterwards
    (:meth:`UrdfArmModel.physical_consistency`)."""
    negative = [i for i in model.friction_columns if not theta[i] >= 0]
    if not negative:
        return theta, method
    lower = np.full(model.n_params, -np.inf)
    lower[list(model.nonnegative_columns)] = 0.0
    names = ", ".join(f"{model.meanings[i]} = {theta[i]:.4g}" for i in negative)
    return solve_bounded(lower), f"{method} bounded to friction >= 0 (unbounded: {names})"


def leave_out_friction_steps(
    rows: FilteredRows, theta: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Which joints' torque equations to leave out near their friction steps, decided by the
    data: per joint, the RMS residual of ``theta`` (a fit on every row) on its rows near a
    friction step over that on the rest. Above :data:`STEP_RESIDUAL_RATIO` the smoothed motion
    does not follow the steps there (:func:`friction_step_samples`), and those rows are left
    out; where the residual is no larger near the steps (the Panda of Gaz et al., whose
    measured torques show no sharp Coulomb step, docs/urdf.md) every row stays. A joint keeps
    its rows when fewer than :data:`MIN_ROWS_AWAY_FROM_STEPS` of them are away from steps.
    Returns (left out (n,) bool, the ratio (n,), nan where not measured)."""
    residual = rows.tau - np.einsum("knp,p->kn", rows.Y, theta)
    n = rows.tau.shape[1]
    ratio = np.full(n, np.nan)
    for j in range(n):
        near = rows.near_step[:, j]
        if near.any() and (~near).mean() >= MIN_ROWS_AWAY_FROM_STEPS:
            away = np.mean(residual[~near, j] ** 2)
            if away > 0:  # an exact fit (noise-free data) has nothing to compare
                ratio[j] = np.sqrt(np.mean(residual[near, j] ** 2) / away)
    return np.nan_to_num(ratio) > STEP_RESIDUAL_RATIO, ratio


# --- the energy schemes: supplied energy and filtered power ---------------------------------------

ENERGY_SCHEMES = ("supplied_energy", "filtered_power")
# Samples either side of each velocity the energy rows take: 1, the three-point derivative on
# the real stamps. The kinetic energy takes q̇ itself, and a wider window biases it: a quadratic
# over ±T lowers a harmonic ω's velocity by about (ωT)²/10, its energy twice that (on a clean
# multisine of cicese3 the 2-DOF model path's window, ±1/(4λ) s, put friction parameters 10 to
# 14 % off, this one within 0.3 %: tests/test_urdf_energy.py). Velocity noise, which the wider
# window is for, enters the supplied energy only at each row's end sample (Δφ_K telescopes)
# and the filtered power through the λ low-pass.
ENERGY_VELOCITY_HALF_WINDOW = 1


# The energy rows take the smoothed positions when the raw velocity (the rows' three-point
# derivative) departs from the smoothed one by more than this share of its RMS on some joint.
ENERGY_VELOCITY_NOISE_MAX = 0.1


def velocity_noise_ratio(rec: Recording, cutoff_hz: float) -> np.ndarray:
    """(n,): RMS of (the energy rows' raw velocity − the smoothed one, :func:`smoothed_positions`)
    over the RMS of the smoothed velocity, per joint, ends (EDGE_S) dropped."""
    t = rec.t
    keep = inside_edges(t)
    raw = local_polynomial_velocity(rec.q, t, ENERGY_VELOCITY_HALF_WINDOW)[keep]
    smooth = smoothed_positions(rec, cutoff_hz)(t[keep], 1)
    scale = np.sqrt(np.mean(smooth**2, axis=0))
    return np.sqrt(np.mean((raw - smooth) ** 2, axis=0)) / np.where(scale > 0, scale, np.inf)


def energy_rows_cutoff(rec: Recording, cutoff_hz: float) -> float | None:
    """The cutoff for :func:`identify_energy`'s positions, decided by the data: ``cutoff_hz``
    when the raw velocity's noise (:func:`velocity_noise_ratio`) exceeds
    :data:`ENERGY_VELOCITY_NOISE_MAX` on some joint, else None (raw positions). The rows are
    quadratic in q̇ (½ q̇ᵀM q̇, ∫q̇² dt), so a noise of r times the velocity's RMS biases them by
    about r² (E[(v + n)²] = v² + σ²): above 1 % at r = 0.1. Below, smoothing costs more than it
    saves: it rounds the true velocity at each friction step, and on the simulated ur5e (r ≤ 1.3 %)
    it moved the weakly determined Izz4 − Ixx4 + Iyy4 of the filtered-power fit by 8 %. The real
    Panda of Gaz et al. has r = 0.21 to 0.24 on every joint (docs/urdf.md)."""
    noisy = velocity_noise_ratio(rec, cutoff_hz).max() > ENERGY_VELOCITY_NOISE_MAX
    return float(cutoff_hz) if noisy else None


@dataclass(frozen=True)
class EnergyIdentification:
    """θ (base parameters) of one energy scheme, fitted on rows with t < ``fit_until_s``."""

    scheme: str
    theta: np.ndarray
    lam: float  # rad/s, the filtered-power row filter's bandwidth (and the velocity window's)
    rows: int  # rows fitted
    fit_until_s: float
    uncertainty: Uncertainty | None = None  # of the least-squares fit
    theta_standard: np.ndarray | None = None  # the consistent fit's standard parameters
    cutoff_hz: float | None = None  # positions smoothed at this cutoff; None: raw
    method: str = "least squares"
    # the least-squares θ when its friction was negative and θ is the bounded fit, else None
    theta_least_squares: np.ndarray | None = None


def identify_energy(
    model: UrdfArmModel,
    rec: Recording,
    scheme: str,
    *,
    lam: float | None = None,
    held_out: float = 0.25,
    half_window: int = ENERGY_VELOCITY_HALF_WINDOW,
    decimate: int = DEFAULT_DECIMATE,
    cutoff_hz: float | None = None,
    consistent: bool = False,
) -> EnergyIdentification:
    """Batch least squares of the base parameters from the rows of ``scheme``
    (``supplied_energy``: eq. (28), ``filtered_power``: eq. (30), in the ``exact`` form of
    :mod:`hil.model.regressors`) on the recording's real time stamps (:func:`iter_rows`:
    velocities by a local quadratic over ±``half_window`` samples, see
    ENERGY_VELOCITY_HALF_WINDOW; interval integrals on each interval's own length), fitted on
    the first (1 − ``held_out``) of the time span. λ defaults to
    :func:`hil.model.regressors.data_bandwidth` (twice the excitation bandwidth). The work of
    interval k is τᵀΔq with the torque of :func:`torque_over_intervals`.
    Rows are averaged over blocks of ``decimate`` consecutive ones before the solve, as the
    torque scheme's are (:func:`filtered_rows`): a mean of exact equations is exact, and the
    QR of the least squares, most of the cost at 1 kHz, shrinks by as much. Streams the rows
    in chunks and keeps only the block-averaged ones (a ``decimate``-th of them, for the
    consistent fit).

    ``cutoff_hz``: the rows are built on the positions smoothed as the torque scheme's
    (:func:`smoothed_positions`, Gautier's parallel filtering; ends EDGE_S dropped) instead of
    the raw ones. The energy rows are quadratic in q̇ (½ q̇ᵀM q̇, ∫q̇² dt), so velocity noise
    biases them rather than averaging out: on the real Panda of Gaz et al. the torque scheme's
    θ leaves 32 % of the raw filtered-power rows unexplained and under 1 % of the smoothed ones
    (docs/urdf.md). `hil identify` decides by :func:`energy_rows_cutoff`.
    ``consistent``: the fit is constrained to physically consistent standard parameters
    (:func:`consistent_fit` on the block-averaged rows, one equation each): the scalar balance
    leaves directions of θ that the torque rows fix undetermined, and the constraint with its
    weak pull towards the URDF's bodies fixes them where least squares drifts."""
    if scheme not in ENERGY_SCHEMES:
        raise ValueError(f"unknown energy scheme {scheme!r}; one of {', '.join(ENERGY_SCHEMES)}")
    _check_joints(model, rec)
    lam = data_bandwidth(rec.q, rec.t) if lam is None else float(lam)
    split = fit_split(rec, held_out)
    ls = LeastSquaresRows(model.n_params)
    blocks = BlockNormalEquations(
        model.n_params, 1, bootstrap_block_s(lam, float(rec.t[-1] - rec.t[0]))
    )
    rows = 0
    t, q, tau = rec.t, rec.q, torque_over_intervals(rec)
    if cutoff_hz is not None:
        keep = inside_edges(t)
        t, q, tau = t[keep], smoothed_positions(rec, cutoff_hz)(t[keep]), tau[keep]
    kept_y, kept_psi = [], []  # the fitted rows, for the consistent fit
    for c in iter_rows(scheme, q, tau, t, lam, model, half_window=half_window):
        fit = c.t < split if held_out > 0 else np.ones(len(c.t), dtype=bool)
        if fit.any():
            # energy rows all have weight 1 (static friction does no work, so no row is
            # dropped for a stuck joint, hil.model.regressors)
            y, Psi = _block_mean(c.y[fit], decimate), _block_mean(c.Psi[fit], decimate)
            ls.add(Psi, y)
            blocks.add(_block_mean(c.t[fit], decimate), y, Psi, np.ones(y.shape))
            rows += len(y)
            kept_y.append(y)  # for the consistent fit, when it is asked or needed
            kept_psi.append(Psi)
    if rows < 2 * model.n_params:
        raise ValueError(
            f"{rec.path}: {rows} {scheme} rows to fit, too few for {model.n_params} parameters"
        )
    theta = ls.solve()
    uncertainty = parameter_uncertainty(blocks, theta, weighted=False)
    theta_standard, method, theta_ls = None, "least squares", None
    if consistent:
        theta_standard = consistent_fit(
            model, np.concatenate(kept_psi), np.concatenate(kept_y), theta
        )
        theta, method = model.base_theta(theta_standard), "physically consistent least squares"
    else:
        theta_ls, (theta, method) = theta, friction_bounded(model, theta, method, ls.solve_bounded)
        if not model.physical_consistency(theta)["consistent"]:  # M(q) ≻ 0 is no linear bound
            theta_standard = consistent_fit(
                model, np.concatenate(kept_psi), np.concatenate(kept_y), theta_ls
            )
            theta, method = model.base_theta(theta_standard), _consistent_instead(model, theta)
        theta_ls = None if theta is theta_ls else theta_ls
    return EnergyIdentification(
        scheme, theta, lam, rows, float(split), uncertainty, theta_standard, cutoff_hz, method,
        theta_ls,
    )  # fmt: skip


def _block_mean(x: np.ndarray, size: int) -> np.ndarray:
    """Means of consecutive blocks of ``size`` rows of ``x`` (the last block may be shorter)."""
    if size <= 1:
        return x
    K = len(x)
    full = K // size * size
    out = x[:full].reshape(K // size, size, *x.shape[1:]).mean(axis=1)
    return out if full == K else np.concatenate([out, x[full:].mean(axis=0, keepdims=True)])


# --- physically consistent fit ------------------------------------------------------------------


# the entries (row, column) of L that x (10,) holds: the diagonal (as logarithms), then the
# strictly lower triangle in numpy's tril_indices order
_L_ENTRIES = (*((i, i) for i in range(4)), *zip(*np.tril_indices(4, -1), strict=True))


def _pseudo_inertia_to_parameters() -> np.ndarray:
    """M (10, 16) with π = M vec(J): m = J₃₃, h = J[:3, 3], I = tr(Σ) 1 − Σ as (xx, xy, yy, xz,
    yz, zz), Pinocchio's order."""
    terms = (
        {(3, 3): 1},
        {(0, 3): 1},
        {(1, 3): 1},
        {(2, 3): 1},
        {(1, 1): 1, (2, 2): 1},
        {(0, 1): -1},
        {(0, 0): 1, (2, 2): 1},
        {(0, 2): -1},
        {(1, 2): -1},
        {(0, 0): 1, (1, 1): 1},
    )
    out = np.zeros((10, 16))
    for row, entries in enumerate(terms):
        for (a, b), c in entries.items():
            out[row, 4 * a + b] = c
    return out


_PI_OF_J = _pseudo_inertia_to_parameters()


def _cholesky_factor(x: np.ndarray) -> np.ndarray:
    """L (..., 4, 4) of log-Cholesky parameters x (..., 10): diagonal exp(x[:4]), the strictly
    lower triangle x[4:]."""
    L = np.zeros((*x.shape[:-1], 4, 4))
    for k, (a, b) in enumerate(_L_ENTRIES):
        L[..., a, b] = np.exp(x[..., k]) if k < 4 else x[..., k]
    return L


def _pi_from_cholesky(x: np.ndarray) -> np.ndarray:
    """Ten dynamic parameters (..., 10) of bodies from their log-Cholesky factors x (..., 10):
    the pseudo-inertia J = L Lᵀ, L lower triangular with diagonal exp(x[:4]) (Rucker & Wensing
    (2022)), so J is positive definite for every x; J = [[Σ, h], [hᵀ, m]], Σ = ½ tr(I) 1 − I ⇒
    I = tr(Σ) 1 − Σ."""
    L = _cholesky_factor(x)
    J = L @ np.swapaxes(L, -1, -2)
    return J.reshape(*J.shape[:-2], 16) @ _PI_OF_J.T


def _pi_jacobian(x: np.ndarray) -> np.ndarray:
    """∂π/∂x (..., 10, 10) of :func:`_pi_from_cholesky`: with L_ab moved by ε (ε = e^{x_k} on
    the diagonal, 1 below it), dJ = ε (E_ab Lᵀ + L E_ba), i.e. dJ_ij = ε (δ_ia L_jb + δ_ja L_ib)."""
    L = _cholesky_factor(x)
    dJ = np.zeros((*x.shape[:-1], 10, 4, 4))
    for k, (a, b) in enumerate(_L_ENTRIES):
        column = L[..., :, b] * (L[..., a, a, None] if a == b else 1.0)  # ε L's column b
        dJ[..., k, a, :] += column
        dJ[..., k, :, a] += column
    return np.swapaxes(dJ.reshape(*dJ.shape[:-2], 16) @ _PI_OF_J.T, -1, -2)


def _cholesky_from_pi(pi: np.ndarray) -> np.ndarray:
    m, h = pi[0], pi[1:4]
    inertia = np.array([[pi[4], pi[5], pi[7]], [pi[5], pi[6], pi[8]], [pi[7], pi[8], pi[9]]])
    J = np.zeros((4, 4))
    J[:3, :3] = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    J[:3, 3] = J[3, :3] = h
    J[3, 3] = m
    w, V = np.linalg.eigh(J)
    J = (V * np.maximum(w, 1e-6 * max(w.max(), 1e-9))) @ V.T  # nudge onto the PD cone
    L = np.linalg.cholesky(J)
    return np.concatenate([np.log(np.diag(L)), L[np.tril_indices(4, -1)]])


def consistent_fit(
    model: UrdfArmModel,
    Y: np.ndarray,
    tau: np.ndarray,
    theta_ls: np.ndarray,
    weights: np.ndarray | None = None,
) -> np.ndarray:
    """Standard parameters minimizing the same weighted error of the rows ``Y`` θ ≈ ``tau``
    ((K, m, p), (K, m): m = n joints for torque rows, 1 for energy rows) as the least squares,
    constrained to physical consistency: every body's pseudo-inertia positive definite (by the
    log-Cholesky parametrization), armature, viscous and Coulomb coefficients ≥ 0 (as squares);
    offsets free. Started from the URDF's bodies and the least-squares friction; solved by
    scipy's trust-region least squares on the QR-reduced problem. Returns θ_std."""
    from scipy.optimize import least_squares as nonlinear_least_squares

    K, n, p = Y.shape
    sw = np.ones((K, n)) if weights is None else np.sqrt(weights)  # 0: a stuck joint's row
    residual = tau - np.einsum("knp,p->kn", Y, theta_ls)
    sigma = np.zeros(n)  # per-joint noise level, on the rows used
    for j in range(n):
        if np.any(sw[:, j] > 0):
            sigma[j] = np.std(residual[sw[:, j] > 0, j])
    sigma[sigma == 0] = 1.0
    A = (Y * (sw / sigma)[:, :, None]).reshape(K * n, p) @ model.base.expand
    b = (tau * sw / sigma).reshape(K * n)
    Q, R = np.linalg.qr(A)  # ‖A π − b‖² = ‖R π − Qᵀ b‖² + const
    c = Q.T @ b
    # the model's joints, not the rows' equations (one per energy row)
    nb = model.n_body_params // 10
    n_pos = model.n_rigid_standard - model.n_body_params + 2 * model.n_joints
    std0 = model.standard_theta.copy()
    # friction from the least squares, clipped to the physical side
    fr = model.term_columns("friction")
    std0[model.n_rigid_standard :] = theta_ls[fr]
    bodies = [_cholesky_from_pi(std0[10 * j : 10 * j + 10]) for j in range(nb)]
    positive = np.sqrt(np.maximum(std0[model.n_body_params : model.n_body_params + n_pos], 1e-8))
    free = std0[model.n_body_params + n_pos :]
    x0 = np.concatenate([*bodies, positive, free])

    def standard(x: np.ndarray) -> np.ndarray:
        pis = _pi_from_cholesky(x[: 10 * nb].reshape(nb, 10)).ravel()
        pos = x[10 * nb : 10 * nb + n_pos] ** 2
        return np.concatenate([pis, pos, x[10 * nb + n_pos :]])

    def jacobian_of_standard(x: np.ndarray) -> np.ndarray:
        # block diagonal: each body's 10 parameters depend on its own 10 numbers only
        Jp = np.zeros((len(x), len(x)))
        for j, block in enumerate(_pi_jacobian(x[: 10 * nb].reshape(nb, 10))):
            Jp[10 * j : 10 * j + 10, 10 * j : 10 * j + 10] = block
        i = np.arange(10 * nb, 10 * nb + n_pos)
        Jp[i, i] = 2 * x[i]
        i = np.arange(10 * nb + n_pos, len(x))
        Jp[i, i] = 1.0
        return Jp

    # A weak pull towards the start (the URDF's bodies) keeps the directions the data do not
    # determine where the URDF puts them, and makes the problem well posed.
    reg = REGULARIZATION * np.linalg.norm(R) / np.sqrt(len(x0))

    def residual(x: np.ndarray) -> np.ndarray:
        return np.concatenate([R @ standard(x) - c, reg * (x - x0)])

    def jacobian(x: np.ndarray) -> np.ndarray:
        return np.vstack([R @ jacobian_of_standard(x), reg * np.eye(len(x))])

    sol = nonlinear_least_squares(residual, x0, jac=jacobian, method="trf", max_nfev=500)
    return standard(sol.x)


__all__ = [
    "ENERGY_SCHEMES",
    "ENERGY_VELOCITY_NOISE_MAX",
    "IDENTIFIED_MAX_RELATIVE_SE",
    "VALIDATION_CONFIDENCE",
    "EnergyIdentification",
    "HeldOutVerdict",
    "TorqueIdentification",
    "Uncertainty",
    "energy_rows_cutoff",
    "fit_split",
    "friction_bounded",
    "friction_step_samples",
    "held_out_verdict",
    "identify_energy",
    "identify_torque",
    "inside_edges",
    "leave_out_friction_steps",
    "regression_rows",
    "smoothed_positions",
    "stuck_samples",
    "torque_at_samples",
    "torque_nrmse",
    "torque_over_intervals",
    "velocity_noise_ratio",
]
