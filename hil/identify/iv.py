"""Instrumental variables against the closed-loop bias of least squares (IDIM-IV).

In closed loop the torque in a row is the controller's answer to the motion the row's regressor
is built from: a torque disturbance d that the model lacks (cogging, a load, the controller's
own noise fed back from the encoders) moves q, q̇, q̈, so the regressor Y(q, q̇, q̈) is
correlated with the equation error and least squares, E[Yᵀ(τ − Yθ)] = 0, is biased (Gautier,
Janot & Vandanjon (2013), "A new closed-loop output error method for parameter identification
of robot dynamics", IEEE TCST 21(2), Sec. II; Janot, Vandanjon & Gautier (2014), "A generic
instrumental variable approach for industrial robot identification", IEEE TCST 22(1)).

The instrumental-variable estimate replaces Yᵀ on the left by Zᵀ, the same regressor evaluated
on a trajectory the disturbance did not move — the controller's reference q_r(t) (the
"reference-based instruments" of Janot et al. (2014), Sec. III):

    θ_IV = (Σ_k Z_kᵀ W Y_k)⁻¹ Σ_k Z_kᵀ W τ_k            Janot et al. (2014) eq. (17)

consistent when Z is uncorrelated with the equation error and ZᵀY is well conditioned (the
reference tracks the motion: strong instruments). W weights each joint's equation by 1/σ_j²
of its residual (the IDIM-IV weighting of Janot et al. (2014) eq. (19), as the least-squares
path's feasible weighting, :func:`hil.model.estimators.weighted_least_squares`). Covariance
σ² (ZᵀWY)⁻¹ ZᵀWZ (YᵀWZ)⁻¹ (eq. (21), white residuals).

Here: the estimator over regressor matrices (:func:`instrumental_variables`), the reference's
delay and tracking check (:func:`reference_delay`, :func:`reference_tracking`), and the rows of
any arm model (:class:`hil.model.protocol.ArmDynamics`) with their instruments
(:func:`reference_rows`, :func:`identify_torque_iv`, :func:`iv_identification`): a URDF arm's
smoothed, block-averaged torque rows (:func:`hil.identify.urdf.regression_rows`), the 2-DOF
closed form's exact filtered dynamic rows at λ (:func:`hil.model.regressors.iter_rows`, the rows
its least squares fits). Imports numpy, drivers.recording, hil.identify.identification,
hil.identify.schemes (the bootstrap's rule), hil.identify.urdf and hil.model.regressors; no I/O.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from drivers.recording import Recording
from hil.identify.identification import Identification, unusable_reason
from hil.identify.schemes import (
    BOOTSTRAP_DRAWS,
    IDENTIFIED_MAX_RELATIVE_SE,
    Uncertainty,
    bootstrap_block_s,
)
from hil.identify.urdf import (
    DEFAULT_CUTOFF_HZ,
    DEFAULT_DECIMATE,
    FilteredRows,
    fit_split,
    regression_rows,
    torque_nrmse,
)
from hil.model.protocol import ArmDynamics
from hil.model.regressors import data_bandwidth, excitation_bandwidth, iter_rows

# A reference whose RMS distance from the measured positions exceeds this share of their spread
# on some joint is not the trajectory the arm followed. Tracking error only weakens the
# instruments (their correlation with the regressor falls about as 1 − r²/2, the IV variance
# grows as its inverse square: × 1.3 at r = 0.5), it does not bias them; beyond r = 0.5 the
# reference is more likely mislabelled, in other units or misaligned than tracked, and is
# refused rather than used.
MAX_TRACKING_ERROR = 0.5
# Largest delay searched between the reference and the motion, as a share of the recording.
MAX_DELAY_FRACTION = 0.25


def _as_rows(A: np.ndarray) -> np.ndarray:
    A = np.asarray(A, dtype=float)
    return A[:, None, :] if A.ndim == 2 else A


def instrumental_variables(
    Y: np.ndarray, tau: np.ndarray, Z: np.ndarray, weights: np.ndarray | None = None
) -> np.ndarray:
    """θ = (Σ Zᵀ W Y)⁻¹ Σ Zᵀ W τ (Janot et al. (2014) eq. (17)) over rows ``Y``, ``Z``
    (K, n, p) or (K, p) and ``tau`` (K, n) or (K,); ``weights`` (K, n) per row and joint
    (0 leaves an equation out), default 1. Columns are scaled before the solve (the units of θ
    differ by orders of magnitude). Raises ValueError when ZᵀWY is singular (an instrument
    column that is zero, or instruments unrelated to the regressor)."""
    Y, Z = _as_rows(Y), _as_rows(Z)
    tau = np.asarray(tau, dtype=float).reshape(Y.shape[:2])
    if Z.shape != Y.shape:
        raise ValueError(f"instruments of shape {Z.shape}, regressor {Y.shape}")
    w = np.ones(tau.shape) if weights is None else np.asarray(weights, dtype=float)
    A = np.einsum("knp,kn,knq->pq", Z, w, Y)
    b = np.einsum("knp,kn,kn->p", Z, w, tau)
    dz = np.sqrt(np.einsum("knp,kn,knp->p", Z, w, Z))
    dy = np.sqrt(np.einsum("knp,kn,knp->p", Y, w, Y))
    return _solve(A, b, dz, dy)


def _solve(A: np.ndarray, b: np.ndarray, dz: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """θ of A θ = b with the rows scaled by ``dz`` and the columns by ``dy`` (the instruments'
    and the regressor's column norms)."""
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(b))):
        raise ValueError("instrumental variables: a non-finite number in the rows")
    dz, dy = np.where(dz > 0, dz, 1.0), np.where(dy > 0, dy, 1.0)
    As = A / np.outer(dz, dy)
    if np.linalg.matrix_rank(As) < As.shape[0]:
        raise ValueError(
            "instrumental variables: ZᵀWY is singular (instruments unrelated to the regressor)"
        )
    return np.linalg.solve(As, b / dz) / dy


def iv_blocked_bootstrap(
    Y: np.ndarray,
    tau: np.ndarray,
    Z: np.ndarray,
    weights: np.ndarray,
    t: np.ndarray,
    block_s: float,
    *,
    draws: int = BOOTSTRAP_DRAWS,
    seed: int = 0,
) -> np.ndarray:
    """Standard errors of θ_IV by the blocked bootstrap of the least-squares path
    (:func:`hil.model.estimators.blocked_bootstrap`): ZᵀWY and ZᵀWτ summed per time block of
    ``block_s``, the blocks resampled with replacement ``draws`` times; inf with fewer than 5
    blocks. Rows within a block stay together, so residual correlation shorter than a block
    (the filtered rows') is kept."""
    Y, Z = _as_rows(Y), _as_rows(Z)
    labels = np.floor((t - t[0]) / block_s).astype(int)
    B = int(labels.max()) + 1
    p = Y.shape[-1]
    if B < 5:
        return np.full(p, np.inf)
    A = np.zeros((B, p, p))
    b = np.zeros((B, p))
    np.add.at(A, labels, np.einsum("knp,kn,knq->kpq", Z, weights, Y))
    np.add.at(b, labels, np.einsum("knp,kn,kn->kp", Z, weights, tau))
    dz = np.sqrt(np.einsum("knp,kn,knp->p", Z, weights, Z))
    dy = np.sqrt(np.einsum("knp,kn,knp->p", Y, weights, Y))
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(draws):
        pick = np.bincount(rng.integers(0, B, B), minlength=B).astype(float)
        try:
            out.append(_solve(np.einsum("b,bpq->pq", pick, A), pick @ b, dz, dy))
        except (ValueError, np.linalg.LinAlgError):
            continue  # a resample that leaves a column unexcited
    if len(out) < draws // 2:
        return np.full(p, np.inf)
    return np.std(out, axis=0, ddof=1)


def weighted_instrumental_variables(
    Y: np.ndarray, tau: np.ndarray, Z: np.ndarray, weights: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """IDIM-IV with per-joint weights (Janot et al. (2014) eq. (19)): an IV fit, σ_j² of each
    joint's residual, the IV fit again with weights 1/σ_j². Returns (θ, σ_j² (n,))."""
    Y, Z = _as_rows(Y), _as_rows(Z)
    tau = np.asarray(tau, dtype=float).reshape(Y.shape[:2])
    w = np.ones(tau.shape) if weights is None else np.asarray(weights, dtype=float)
    theta = instrumental_variables(Y, tau, Z, w)
    sigma2 = residual_variance(Y, tau, theta, w)
    return instrumental_variables(Y, tau, Z, w / sigma2), sigma2


def residual_variance(
    Y: np.ndarray, tau: np.ndarray, theta: np.ndarray, weights: np.ndarray
) -> np.ndarray:
    """Per joint, the mean squared residual of θ over its rows of weight > 0 (1 when none)."""
    r = tau - np.einsum("knp,p->kn", _as_rows(Y), theta)
    use = weights > 0
    count = use.sum(axis=0)
    var = np.where(count > 0, (np.where(use, r, 0.0) ** 2).sum(axis=0) / np.maximum(count, 1), 1)
    return np.maximum(var, 1e-300)


def iv_standard_errors(
    Y: np.ndarray, tau: np.ndarray, Z: np.ndarray, theta: np.ndarray, weights: np.ndarray
) -> np.ndarray:
    """Standard errors of θ_IV for white residuals: the diagonal of
    (ZᵀWY)⁻¹ ZᵀW Σ W Z (YᵀWZ)⁻¹ with Σ = diag(σ_j²) from the residuals (Janot et al. (2014)
    eq. (21)). Filtered rows have correlated residuals, so this is a lower bound."""
    Y, Z = _as_rows(Y), _as_rows(Z)
    sigma2 = residual_variance(Y, tau, theta, weights)
    A = np.einsum("knp,kn,knq->pq", Z, weights, Y)
    S = np.einsum("knp,kn,kn,knq->pq", Z, weights**2, np.broadcast_to(sigma2, weights.shape), Z)
    Ainv = np.linalg.pinv(A)
    return np.sqrt(np.maximum(np.diag(Ainv @ S @ Ainv.T), 0.0))


def shifted(t: np.ndarray, x: np.ndarray, delay_s: float) -> np.ndarray:
    """x(t − delay) at the stamps ``t`` by linear interpolation, nan outside x's span."""
    out = np.full(x.shape, np.nan)
    s = t - delay_s
    inside = (s >= t[0]) & (s <= t[-1])
    for j in range(x.shape[1]):
        out[inside, j] = np.interp(s[inside], t, x[:, j])
    return out


def _misfit(t: np.ndarray, q: np.ndarray, q_ref: np.ndarray, delay_s: float) -> float:
    r = q - shifted(t, q_ref, delay_s)
    ok = np.all(np.isfinite(r), axis=1)
    return float(np.sqrt(np.mean(r[ok] ** 2))) if ok.sum() > 2 else np.inf


def reference_delay(t: np.ndarray, q: np.ndarray, q_ref: np.ndarray) -> float:
    """The delay s (seconds) by which the motion follows the reference, q(t) ≈ q_r(t − s):
    the minimum over all joints of the RMS of q(t) − q_r(t − s) within
    ±:data:`MAX_DELAY_FRACTION` of the span. Searched coarse to fine so that a long recording
    costs seconds, not its length squared: on at most :data:`DELAY_SEARCH_POINTS` samples with a
    grid of a twentieth of the reference's shortest period of note (its excitation bandwidth,
    :func:`hil.model.regressors.excitation_bandwidth`; a tenth of a radian of phase), the
    nearest of equally good minima (a periodic reference matches again a period later); then
    around it at one median interval, then at a tenth of one on every sample. A tracking
    controller's lag is a few samples; a reference logged with another clock's offset is found
    the same way. One number from the whole recording, so its correlation with any row's noise
    is negligible."""
    period = float(np.median(np.diff(t)))
    limit = MAX_DELAY_FRACTION * float(t[-1] - t[0])
    omega = excitation_bandwidth(q_ref, t)
    step = max(period, min(0.1 / omega if omega > 0 else limit, limit / 10))
    sub = slice(None, None, max(1, len(t) // DELAY_SEARCH_POINTS))
    grid = np.arange(-limit, limit + step, step)
    costs = np.array([_misfit(t[sub], q[sub], q_ref[sub], s) for s in grid])
    found = []  # (shift, cost on every sample) of each promising coarse minimum, refined
    for start in _coarse_minima(grid, costs):
        sub = slice(None, None, max(1, len(t) // (10 * DELAY_SEARCH_POINTS)))
        near = start + np.arange(-step, step + period, period)
        best = float(near[int(np.argmin([_misfit(t[sub], q[sub], q_ref[sub], s) for s in near]))])
        fine = best + np.arange(-1.0, 1.0 + 1e-9, 0.1) * period
        fine_costs = [_misfit(t, q, q_ref, s) for s in fine]
        found.append((float(fine[int(np.argmin(fine_costs))]), float(np.min(fine_costs))))
    # a periodic reference matches the motion again a period later: the nearest of the equally
    # good matches (within 20 %, or 1 % of the positions' spread) is the controller's lag (or
    # the log's offset)
    tolerance = 1.2 * min(c for _, c in found) + 0.01 * float(np.sqrt(np.mean(np.var(q, axis=0))))
    return min((s for s, c in found if c <= tolerance), key=abs)


def _coarse_minima(grid: np.ndarray, costs: np.ndarray, keep: int = 5) -> list[float]:
    """The ``keep`` best local minima of ``costs`` over ``grid`` within 4 times the least (a
    coarse grid can miss a true minimum by a few times its depth)."""
    finite = np.where(np.isfinite(costs), costs, np.inf)
    left = np.r_[np.inf, finite[:-1]]
    right = np.r_[finite[1:], np.inf]
    local = np.flatnonzero((finite <= left) & (finite <= right) & (finite <= 4 * finite.min()))
    return [float(grid[i]) for i in local[np.argsort(finite[local])][:keep]]


# Samples the coarse stage of reference_delay's search uses (the next stage 10x more).
DELAY_SEARCH_POINTS = 2000


@dataclass(frozen=True)
class ReferenceTracking:
    """How well the aligned reference follows the measured positions: ``delay_s`` (q(t) ≈
    q_r(t − delay_s)), per joint the RMS of q − q_r (rad) and its ratio to the RMS spread of q;
    ``usable`` when every ratio is below :data:`MAX_TRACKING_ERROR`, else ``reason``."""

    delay_s: float
    rms_error: np.ndarray
    relative_error: np.ndarray
    usable: bool
    reason: str | None

    def as_json(self) -> dict:
        return {
            "delay_s": self.delay_s,
            "rms_error_rad": self.rms_error.tolist(),
            "relative_error": self.relative_error.tolist(),
            "usable": self.usable,
            "reason": self.reason,
            "rule": f"every joint's RMS(q - q_ref) below {MAX_TRACKING_ERROR:.0%} of q's spread",
        }


def reference_tracking(
    t: np.ndarray, q: np.ndarray, q_ref: np.ndarray, *, delay_s: float | None = None
) -> ReferenceTracking:
    """:class:`ReferenceTracking` of ``q_ref`` against ``q`` (N, n), the delay searched
    (:func:`reference_delay`) unless given."""
    delay = reference_delay(t, q, q_ref) if delay_s is None else float(delay_s)
    r = q - shifted(t, q_ref, delay)
    ok = np.all(np.isfinite(r), axis=1)
    rms = np.sqrt(np.mean(r[ok] ** 2, axis=0))
    spread = np.std(q[ok], axis=0)
    rel = rms / np.where(spread > 0, spread, np.inf)
    bad = [j for j in range(len(rel)) if not rel[j] < MAX_TRACKING_ERROR]
    reason = None
    if bad:
        reason = (
            "the reference does not track the measured positions on joint "
            + ", ".join(f"{j + 1} (RMS {rms[j]:.3g} rad, {rel[j]:.0%} of its spread)" for j in bad)
            + f" at the best delay {delay:+.3f} s: not the trajectory the arm followed"
        )
    return ReferenceTracking(delay, rms, rel, not bad, reason)


def closed_form_rows(model: ArmDynamics, rec: Recording, lam: float) -> FilteredRows:
    """The 2-DOF closed form's rows y = Ψ θ as its least squares fits them
    (:func:`hil.identify.schemes.identify_model`): the ``exact`` filtered dynamic regression at
    bandwidth ``lam`` on the real time stamps (:func:`hil.model.regressors.iter_rows`, the
    momentum balance of Reyes & Kelly (1997) eq. (24) over each interval), as
    :class:`~hil.identify.urdf.FilteredRows`: ``tau`` the filtered torque, ``weights`` 0 where a
    joint sticks (``near_step`` there)."""
    chunks = list(iter_rows("filtered_dynamic", rec.q, rec.tau, rec.t, lam, model))
    t, y, Psi, w = (
        np.concatenate([getattr(c, f) for c in chunks]) for f in ("t", "y", "Psi", "weights")
    )
    return FilteredRows(t, y, Psi, w == 0, w)


def torque_rows(
    model: ArmDynamics,
    rec: Recording,
    *,
    cutoff_hz: float = DEFAULT_CUTOFF_HZ,
    decimate: int = DEFAULT_DECIMATE,
    lam: float | None = None,
) -> FilteredRows:
    """The rows τ ≈ Yθ each arm's least squares fits: a URDF arm's smoothed, block-averaged
    torque rows (:func:`hil.identify.urdf.regression_rows`, ``cutoff_hz``, ``decimate``), the
    2-DOF closed form's filtered dynamic rows at ``lam`` (:func:`closed_form_rows`; default
    :func:`hil.model.regressors.data_bandwidth` of the recording)."""
    if model.closed_form:
        return closed_form_rows(model, rec, data_bandwidth(rec.q, rec.t) if lam is None else lam)
    return regression_rows(model, rec, cutoff_hz=cutoff_hz, decimate=decimate)


def reference_rows(
    model: ArmDynamics,
    rec: Recording,
    q_ref: np.ndarray,
    *,
    cutoff_hz: float = DEFAULT_CUTOFF_HZ,
    decimate: int = DEFAULT_DECIMATE,
    lam: float | None = None,
) -> tuple[FilteredRows, FilteredRows]:
    """The rows τ ≈ Yθ of ``rec`` and their instruments: the same rows (:func:`torque_rows`:
    the same smoothing or filter, regressor and averaging) built on ``q_ref`` (N, n), already
    aligned to the recording's stamps (nan where it has no value). Only the stretch where the
    reference is defined is kept, the same stamps for both, so row k of the instruments belongs
    to row k of the regression (the regression's weights are the ones to use: the reference
    does not stick)."""
    ok = np.all(np.isfinite(q_ref), axis=1)
    idx = np.flatnonzero(ok)
    if idx.size < 8:
        raise ValueError(f"{rec.path}: the reference covers {idx.size} samples, too few")
    part = rec.segment(slice(int(idx[0]), int(idx[-1]) + 1))
    ref = replace(
        part,
        columns={
            **part.columns,
            **{f"q{j + 1}": q_ref[idx[0] : idx[-1] + 1, j] for j in range(rec.n_joints)},
        },
    )
    options = {"cutoff_hz": cutoff_hz, "decimate": decimate, "lam": lam}
    rows = torque_rows(model, part, **options)
    inst = torque_rows(model, ref, **options)
    return rows, inst


@dataclass(frozen=True)
class IvIdentification:
    """θ by instrumental variables on an arm's filtered rows: ``theta``, ``se_white``
    (:func:`iv_standard_errors`), ``se_block`` (:func:`iv_blocked_bootstrap`) and which
    parameters the data determine, the rows and instruments used, the reference's
    ``tracking``, ``fit_until_s`` and the held-out NRMSE (nan without a held-out part)."""

    theta: np.ndarray
    se_white: np.ndarray
    se_block: np.ndarray  # blocked bootstrap (iv_blocked_bootstrap)
    identified: np.ndarray  # se_block < IDENTIFIED_MAX_RELATIVE_SE · |θ| (issue 12's rule)
    block_s: float
    blocks: int  # of the bootstrap
    rows: FilteredRows
    instruments: FilteredRows
    tracking: ReferenceTracking
    fit_until_s: float
    nrmse_held_out: np.ndarray
    lam: float | None = None  # the 2-DOF rows' filter bandwidth, rad/s (None: a URDF arm's)
    method: str = "instrumental variables on the reference trajectory (IDIM-IV)"


def identify_torque_iv(
    model: ArmDynamics,
    rec: Recording,
    *,
    cutoff_hz: float = DEFAULT_CUTOFF_HZ,
    decimate: int = DEFAULT_DECIMATE,
    held_out: float = 0.25,
    left_out_joints: np.ndarray | None = None,
    lam: float | None = None,
) -> IvIdentification:
    """IDIM-IV of θ on the first (1 − ``held_out``) of the recording, the instruments the
    rows of its target positions (``rec.q_target``; :func:`reference_rows`), aligned by
    :func:`reference_delay` and checked by :func:`reference_tracking`. A URDF arm's rows are
    smoothed at ``cutoff_hz`` and averaged over ``decimate``; the 2-DOF closed form's are
    filtered at ``lam`` rad/s (its least squares' λ; default from the data). ``left_out_joints``
    (n,): joints whose equations near friction steps are left out, as the least-squares fit
    decided (:func:`hil.identify.urdf.leave_out_friction_steps`). Uncertainty: the blocked
    bootstrap of the least-squares path, its blocks by the same rule
    (:func:`hil.identify.schemes.bootstrap_block_s` of λ, or of 2π·``cutoff_hz`` for the
    smoothed rows). Raises ValueError with one line when the recording has no target positions
    or they do not track the motion."""
    if rec.q_target is None:
        raise ValueError(
            f"{rec.path}: no target positions (q_target1.. columns or a format's "
            "[layouts.targets]): instrumental variables need the controller's reference"
        )
    tracking = reference_tracking(rec.t, rec.q, rec.q_target)
    if not tracking.usable:
        raise ValueError(f"{rec.path}: {tracking.reason}")
    q_ref = shifted(rec.t, rec.q_target, tracking.delay_s)
    if model.closed_form and lam is None:
        lam = data_bandwidth(rec.q, rec.t)
    rows, inst = reference_rows(model, rec, q_ref, cutoff_hz=cutoff_hz, decimate=decimate, lam=lam)
    if left_out_joints is not None:
        rows = rows.leaving_out(left_out_joints)
    split = fit_split(rec, held_out)
    fit = rows.t < split if held_out > 0 else np.ones(len(rows.t), dtype=bool)
    if fit.sum() * model.n_joints < 2 * model.n_params:
        raise ValueError(
            f"{rec.path}: {int(fit.sum())} rows where the reference is defined, too few to fit "
            f"{model.n_params} parameters"
        )
    w = rows.weights[fit]
    theta, _ = weighted_instrumental_variables(rows.Y[fit], rows.tau[fit], inst.Y[fit], w)
    sigma2 = residual_variance(rows.Y[fit], rows.tau[fit], theta, w)
    se = iv_standard_errors(rows.Y[fit], rows.tau[fit], inst.Y[fit], theta, w / sigma2)
    # the least-squares path's blocks (a URDF arm's smoothing cutoff plays the row filter's λ)
    rate = lam if model.closed_form and lam is not None else 2 * np.pi * cutoff_hz
    block_s = bootstrap_block_s(rate, float(rec.t[-1] - rec.t[0]))
    se_block = iv_blocked_bootstrap(
        rows.Y[fit], rows.tau[fit], inst.Y[fit], w / sigma2, rows.t[fit], block_s
    )
    identified = se_block < IDENTIFIED_MAX_RELATIVE_SE * np.abs(theta)
    blocks = int(np.floor((rows.t[fit][-1] - rows.t[fit][0]) / block_s)) + 1
    held = (
        torque_nrmse(theta, rows.select(~fit)) if held_out > 0 else np.full(model.n_joints, np.nan)
    )
    return IvIdentification(
        theta, se, se_block, identified, block_s, blocks, rows, inst, tracking, split, held,
        lam if model.closed_form else None,
    )  # fmt: skip


# --instruments target: the filtered dynamic rows fitted by IV, reported as this scheme
IV_SCHEME = "filtered_dynamic_iv"


def iv_identification(
    model: ArmDynamics,
    recording: Recording,
    *,
    held_out: float,
    cutoff_hz: float = DEFAULT_CUTOFF_HZ,
    lam: float | None = None,
    left_out_joints: np.ndarray | None = None,
) -> tuple[Identification, dict[str, Any]]:
    """``--instruments target``: the filtered dynamic rows (the least-squares fit's smoothing
    cutoff or λ, and its equations left out) fitted by instrumental variables on the
    recording's target positions (:func:`identify_torque_iv`), as an :class:`Identification`
    (scheme filtered_dynamic, estimator ``iv``) and its entry of identify.json's ``schemes``
    (one layout for every arm); not constrained by --consistent or bounded."""
    start = time.process_time()
    res = identify_torque_iv(
        model, recording, held_out=held_out, cutoff_hz=cutoff_hz, lam=lam,
        left_out_joints=left_out_joints,
    )  # fmt: skip
    uncertainty = Uncertainty(res.se_white, res.se_block, res.identified, res.block_s, res.blocks)
    method = (
        f"{res.method}, filtered dynamic rows; the motion follows the reference by "
        f"{res.tracking.delay_s:+.3f} s, within {res.tracking.relative_error.max():.1%} of its "
        "spread"
    )
    # the 2-DOF path counts its rows per joint equation, the URDF path per time
    rows = res.rows.weights.size if res.lam is not None else len(res.rows.t)
    consistency = model.physical_consistency(res.theta)
    ident = Identification(
        model=model, scheme="filtered_dynamic", discretization="exact", estimator="iv",
        lam=res.lam, theta=res.theta, method=method, rows=rows,
        consistency=consistency, uncertainty=uncertainty,
        failed_reason=unusable_reason(res.theta, consistency), result=res,
    )  # fmt: skip
    rows_filter: dict[str, Any] = (
        {"lambda_rad_s": res.lam} if res.lam is not None else {"smoothing_cutoff_hz": cutoff_hz}
    )
    entry = {
        "method": method,
        **rows_filter,
        "rows": rows,
        "reference": res.tracking.as_json(),
        "cpu_s": time.process_time() - start,
        "uncertainty": uncertainty.as_json(),
    }
    return ident, entry
