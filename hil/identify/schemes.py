"""Identification of θ1..θ9 from recordings: the three schemes of Reyes & Kelly (1997), their
Table II, and validation on the fitting recording and on a held-out one.

Pure computation over arrays and :class:`~drivers.recording.Recording` objects; running the
experiments over a bench and writing files is :mod:`hil.identify.pipelines` and
:mod:`hil.identify.cli`'s job.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from drivers.recording import Recording
from hil.model.closed_form import THETA_NAMES, ArmModel, physical_consistency
from hil.model.estimators import (
    BlockNormalEquations,
    LeastSquaresRows,
    RecursiveLeastSquaresRows,
    ResidualLevel,
    WeightedRefit,
    bounded_quadratic_fit,
    channel_weights,
    combine,
    solve_normal_equations,
    standard_errors,
)
from hil.model.metrics import NrmseAccumulator
from hil.model.openloop import simulate_open_loop_chunks, simulation_refusal
from hil.model.regressors import (
    ROW_CHUNK,
    SCHEMES,
    data_bandwidth,
    iter_regression,
    iter_rows,
)

ESTIMATORS = ("rls", "ls", "wls")
SCHEME_TITLES = {
    "supplied_energy": "Supplied Energy",
    "filtered_power": "Filtered Power",
    "filtered_dynamic": "Filtered Dynamic",
    # --instruments target: the filtered dynamic rows by instrumental variables (hil.identify.iv)
    "filtered_dynamic_iv": "Filtered Dynamic IV",
}
# Reyes & Kelly (1997) Table II, the real arm: "measured" column and the three schemes'
# estimates at t = 10 s (None where the paper gives none: its supplied-energy run diverged).
PAPER_TABLE_II: dict[str, list[float | None]] = {
    "measured": [2.351, 0.084, 0.102, 38.465, 1.825, 2.288, 0.175, 7.60, 1.734],
    "supplied_energy": [2.14, 0.088, 0.087, 39.04, None, None, None, None, None],
    "filtered_power": [1.99, 0.084, 0.084, 36.20, 2.01, 2.35, 0.192, 4.95, 1.01],
    "filtered_dynamic": [1.98, 0.087, 0.084, 38.48, 1.99, 2.11, 0.120, 6.20, 1.18],
}
HISTORY_POINTS = 500  # θ̂(k) samples kept for plots and JSON


@dataclass
class SchemeResult:
    """One scheme's estimates: ``theta`` is the one reported (per ``estimator``)."""

    scheme: str
    discretization: str
    lam: float
    estimator: str
    theta: np.ndarray
    theta_rls: np.ndarray
    theta_ls: np.ndarray
    theta_wls: np.ndarray
    history_t: np.ndarray
    history: np.ndarray  # θ̂(k) of RLS at history_t, (len(history_t), 9)
    rows: int
    rows_excluded: int
    consistency: dict[str, Any]
    timing_s: dict[str, float] = field(default_factory=dict)

    def relative_error(self, reference: np.ndarray) -> np.ndarray:
        return (self.theta - reference) / reference


# The fewest samples a segment must have to give regression rows (hil.model.regressors).
MIN_SEGMENT_ROWS = 8

# progress(stage, done, total): rows of a stage done so far, called after every chunk of rows
# (the CLI prints it, throttled: hil.cli_options.StageProgress)
Progress = Callable[[str, int, int], None]


def _no_progress(stage: str, done: int, total: int) -> None:
    pass


def identify(
    q: np.ndarray,
    tau: np.ndarray,
    period_s: float,
    *,
    schemes: Sequence[str] = SCHEMES,
    discretization: str = "exact",
    lam: float = 50.0,
    estimator: str = "rls",
    t: np.ndarray | None = None,
    segments: Sequence[slice] | None = None,
    chunk: int = ROW_CHUNK,
    progress: Progress | None = None,
) -> dict[str, SchemeResult]:
    """Identify θ with each scheme: regression (eqs. (24), (28), (30)), then recursive least
    squares (eqs. (20)-(22), P(0) = 1000·I, θ̂(0) = 0), batch and weighted least squares.
    ``t``: the samples' real times when they are not k·h (:func:`irregular_times`); the
    ``exact`` rows then use each interval's own length, and ``paper`` is the paper's method
    written over each interval (backward difference over Δt_k, each filter's ZOH equivalent
    e^{−λΔt_k}: :func:`hil.model.regressors.filter_over_intervals`), never k·h.
    ``segments``: row ranges between gaps (:meth:`drivers.recording.Recording.segments`); the
    rows of each are built on its own (filters started afresh, never an interval across a gap)
    and all of them enter one fit; a segment too short for a row (< 8 samples) is left out.

    Memory is O(``chunk`` rows) beyond ``q``, ``tau``: every estimator runs over the rows of
    :func:`iter_regression` chunk after chunk, in three passes that rebuild them (least
    squares; RLS and the residual level; the weighted refit), never the whole regression
    (issue 13). ``progress``: told the rows done after every chunk of each pass."""
    if estimator not in ESTIMATORS:
        raise ValueError(
            f"unknown estimator {estimator!r}; expected one of {', '.join(ESTIMATORS)}"
        )
    parts = [slice(0, len(q))] if segments is None else list(segments)
    parts = [p for p in parts if len(range(*p.indices(len(q)))) >= MIN_SEGMENT_ROWS]
    if not parts:
        raise ValueError(
            f"no segment between gaps has the {MIN_SEGMENT_ROWS} samples a regression row needs"
        )
    report = progress or _no_progress
    samples = sum(len(range(*p.indices(len(q)))) for p in parts)  # ≈ rows, before pass 1 counts
    out = {}
    for scheme in schemes:
        times = t

        def rows(scheme: str = scheme, times: np.ndarray | None = times):
            # the regression in chunks, built afresh for each pass: memory O(chunk), not O(rows);
            # segment after segment, each with its own filters (a gap is never bridged)
            for part in parts:
                chunks = iter_regression(
                    scheme, q[part], tau[part], period_s, lam, discretization,
                    t=None if times is None else times[part], chunk=chunk,
                )  # fmt: skip
                start = part.indices(len(q))[0]
                if times is not None or start == 0:
                    yield from chunks
                else:  # rows at k·h from the segment's start: on the recording's k·h
                    yield from (replace(c, t=c.t + start * period_s) for c in chunks)

        # pass 1: batch least squares and the number of rows
        t0 = time.perf_counter()
        ne = None
        for c in rows():
            ne = ne or LeastSquaresRows(c.Psi.shape[-1])
            ne.add(c.Psi, c.y, c.weights)
            report(f"{scheme}: least squares", ne.rows, max(samples, ne.rows))
        assert ne is not None
        theta_ls = ne.solve()
        K, m = ne.rows, c.y.shape[1]
        excluded = K * m - ne.used
        t1 = time.perf_counter()
        # pass 2: RLS, θ̂(k) only at the rows the report and plots show (a (K, 9) history is
        # 72 B a row), and feasible WLS's residual level
        pick = np.unique(np.r_[np.arange(0, K, max(1, K // HISTORY_POINTS)), K - 1])
        rls = RecursiveLeastSquaresRows(len(theta_ls), m, K, keep=pick)
        level = ResidualLevel(theta_ls, m)
        history_t = np.empty(len(pick))
        row = 0
        for c in rows():
            rls.add(c.Psi, c.y, c.weights)
            level.add(c.Psi, c.y, c.weights)
            here = (pick >= row) & (pick < row + len(c.t))
            history_t[here] = c.t[pick[here] - row]
            row += len(c.t)
            report(f"{scheme}: recursive least squares", row, K)
        hist = rls.history
        t2 = time.perf_counter()
        # pass 3: feasible weighted least squares (weighted_least_squares, in chunks)
        refit = WeightedRefit(theta_ls, level.level(), K)
        row = 0
        for c in rows():
            refit.add(c.Psi, c.y, c.weights)
            row += len(c.t)
            report(f"{scheme}: weighted least squares", row, K)
        theta_wls = refit.solve()
        t3 = time.perf_counter()
        chosen = {"rls": hist[-1], "ls": theta_ls, "wls": theta_wls}[estimator]
        out[scheme] = SchemeResult(
            scheme=scheme,
            discretization=discretization,
            lam=lam,
            estimator=estimator,
            theta=chosen,
            theta_rls=hist[-1],
            theta_ls=theta_ls,
            theta_wls=theta_wls,
            history_t=history_t,
            history=hist,
            rows=int(K),
            rows_excluded=int(excluded),
            consistency=physical_consistency(chosen),
            timing_s={
                "least_squares": t1 - t0,  # each pass builds the rows anew
                "recursive_least_squares": t2 - t1,
                "weighted_least_squares": t3 - t2,
            },
        )
    return out


def irregular_times(rec: Recording, tolerance: float = 1e-6) -> np.ndarray | None:
    """The recording's real sample times if any interval differs from its nominal period by
    more than ``tolerance`` (relative), else None: equal intervals take the k·h formulas, whose
    numbers are the ones every earlier result was computed with."""
    t = np.asarray(rec.t, dtype=float)
    if len(t) < 2:
        return None
    dt = np.diff(t)
    h = rec.period_s
    return t if np.max(np.abs(dt - h)) > tolerance * h else None


def initial_velocity(rec: Recording) -> tuple[float, float]:
    """q̇(0) from the first two samples (zero for a recording that starts at rest), over their
    real interval when it is not the nominal period (:func:`irregular_times`)."""
    if len(rec) < 2:
        return (0.0, 0.0)
    first = rec.segment(slice(0, 2))  # rec.q would stack every row to read two
    q, times = first.q, irregular_times(first)
    dq = (q[1] - q[0]) / (rec.period_s if times is None else times[1] - times[0])
    return (float(dq[0]), float(dq[1]))


# Simulated positions kept for the validation plot: every row up to this many, else every
# n-th (a plot of 5 million points shows nothing more and costs 80 MB a recording).
PLOT_POINTS = 20000


def validate(
    theta: np.ndarray,
    rec: Recording,
    *,
    lam: float = 50.0,
    chunk: int = ROW_CHUNK,
    progress: Progress | None = None,
    stage: str = "validation",
) -> dict[str, Any]:
    """How well θ explains a recording, both ways (per joint, NRMSE as a fraction):

    * ``position_nrmse``: the model simulated open loop from the recording's first sample,
      driven by its recorded torques (:func:`hil.model.openloop.simulate_open_loop`), against the
      recorded positions — the paper's Figs. 2, 4, 7;
    * ``torque_nrmse``: torque prediction, the filtered torque F[τ] against Ψθ of the
      ``exact`` filtered dynamic regression (rows with a stuck joint left out), i.e. the torque
      the model says was needed for the recorded motion, filtered at λ to keep differentiation
      noise out.

    A recording with gaps is validated segment by segment (each simulated from its own first
    sample), the errors pooled. Irregular sample times (:func:`irregular_times`: a realtime
    run read on its real times) are simulated on their real intervals and give the torque
    rows their own interval lengths, as the fit's rows have them. Both streamed in chunks of
    ``chunk`` rows (simulation and regression), so memory does not grow with the recording
    (issue 13). ``simulated_q`` (for plots) holds the simulated
    positions at the rows ``simulated_rows``: all of them up to PLOT_POINTS, else every n-th.
    ``progress`` is told the rows simulated, then the torque rows, as ``stage``: ...

    A θ the simulator refuses (:func:`hil.model.openloop.simulation_refusal`: M(q) not
    positive definite, a negative Coulomb level — a least-squares fit on short or quantized
    data) is not simulated: ``position_nrmse``, ``position_max_error_rad`` and ``simulated_q``
    are None and ``simulation_not_possible`` says why; its torque prediction is still given.
    A joint with no torque row to compare (every row holds a stuck interval within the
    filter's memory: a short recording from rest) has ``torque_nrmse`` None.
    """
    return validate_many([theta], rec, lam=lam, chunk=chunk, progress=progress, stages=[stage])[0]


def validate_many(
    thetas: Sequence[np.ndarray],
    rec: Recording,
    *,
    lam: float = 50.0,
    chunk: int = ROW_CHUNK,
    progress: Progress | None = None,
    stages: Sequence[str] | None = None,
    stage: str = "validation",
) -> list[dict[str, Any]]:
    """:func:`validate` of each θ of ``thetas`` on one recording, the same numbers, with the
    torque rows Ψ built once for all of them (a pass over the recording per θ saved: issue 13's
    long recordings); each θ still has its own open-loop simulation. ``progress`` is told
    each simulation as ``stages[i]: open-loop simulation`` (default: ``stage``) and the shared
    rows as ``stage: torque prediction``."""
    report = progress or _no_progress
    stages = [stage] * len(thetas) if stages is None else list(stages)
    if len(stages) != len(thetas):
        raise ValueError(f"{len(thetas)} parameter sets but {len(stages)} stage names")
    n = len(rec)
    q, tau = rec.q, rec.tau
    times = irregular_times(rec)
    every = max(1, -(-n // PLOT_POINTS))
    position = [NrmseAccumulator() for _ in thetas]
    worst = [np.zeros(2) for _ in thetas]
    shown: list[list[np.ndarray]] = [[] for _ in thetas]
    torque = [[NrmseAccumulator(), NrmseAccumulator()] for _ in thetas]
    refused = [simulation_refusal(theta) for theta in thetas]  # not simulated: why
    for part in rec.segments():  # a gap is never bridged: each segment from its own start
        a, b = part.indices(n)[:2]
        dq0 = initial_velocity(rec.segment(slice(a, min(a + 2, b))))
        intervals = None if times is None else np.diff(times[a:b])
        for i, theta in enumerate(thetas):
            if refused[i]:
                continue
            first = a
            for c in simulate_open_loop_chunks(
                theta, tau[a:b], rec.period_s, q0=q[a], dq0=dq0, chunk=chunk,
                intervals_s=intervals,
            ):  # fmt: skip
                recorded = q[first : first + len(c.q)]
                position[i].add(recorded, c.q)
                worst[i] = np.maximum(worst[i], np.max(np.abs(recorded - c.q), axis=0))
                # a copy: a view would keep the whole chunk alive until the end (1 MB a chunk)
                shown[i].append(c.q[(-first) % every :: every].copy())
                first += len(c.q)
                report(f"{stages[i]}: open-loop simulation", first, n)
        if b - a < MIN_SEGMENT_ROWS:
            continue  # too short for a filtered row
        for c in iter_regression(
            "filtered_dynamic", q[a:b], tau[a:b], rec.period_s, lam, "exact",
            t=None if times is None else times[a:b], chunk=chunk,
        ):  # fmt: skip
            for theta, acc in zip(thetas, torque, strict=True):
                predicted = np.einsum("kmp,p->km", c.Psi, theta)
                for j in range(2):
                    used = c.weights[:, j] > 0
                    acc[j].add(c.y[used, j], predicted[used, j])
            report(f"{stage}: torque prediction", a + round(c.t[-1] / rec.period_s) + 1, n)
    out = []
    for i in range(len(thetas)):
        simulated = refused[i] is None
        result: dict[str, Any] = {
            "recording": str(rec.path),
            "position_nrmse": [float(x) for x in position[i].result()] if simulated else None,
            "position_max_error_rad": [float(x) for x in worst[i]] if simulated else None,
            # None: no row of that joint free of a stuck interval in the filter's memory
            "torque_nrmse": [float(acc.result()) if acc.n else None for acc in torque[i]],
            # for plots; dropped from JSON
            "simulated_q": np.concatenate(shown[i]) if simulated else None,
            "simulated_rows": np.arange(0, n, every),
        }
        if not simulated:
            result["simulation_not_possible"] = refused[i]
        out.append(result)
    return out


def table_ii_rows(reference: np.ndarray, results: dict[str, SchemeResult]) -> list[dict[str, Any]]:
    """Table II layout: per parameter, the reference ("measured") value and each scheme's
    estimate with its relative error."""
    rows = []
    for i, name in enumerate(THETA_NAMES):
        row: dict[str, Any] = {"parameter": name, "measured": float(reference[i])}
        for scheme, res in results.items():
            row[scheme] = float(res.theta[i])
            row[f"{scheme}_error"] = float((res.theta[i] - reference[i]) / reference[i])
        rows.append(row)
    return rows


def format_table_ii(reference: np.ndarray, results: dict[str, SchemeResult], *, title: str) -> str:
    """The Table II layout as text: measured column, then estimate (relative error %)."""
    schemes = [s for s in ("supplied_energy", "filtered_power", "filtered_dynamic") if s in results]
    head = f"{'':8s}{'Measured':>10s}" + "".join(f"{SCHEME_TITLES[s]:>24s}" for s in schemes)
    lines = [title, head]
    for i in range(len(THETA_NAMES)):
        cells = f"θ{i + 1:<7d}{reference[i]:>10.4g}"
        for s in schemes:
            value = results[s].theta[i]
            err = 100 * (value - reference[i]) / reference[i]
            cells += f"{value:>14.4g} ({err:+6.1f}%)"
        lines.append(cells)
    consistent = "".join(
        f"{'':>13s}{'consistent' if results[s].consistency['consistent'] else 'NOT PHYSICAL':>11s}"
        for s in schemes
    )
    lines.append(f"{'physical':18s}{consistent}")
    return "\n".join(lines)


# ---- real recordings: any model, real time stamps, bounded estimates, uncertainty -------------

# A parameter whose blocked-bootstrap standard error exceeds this fraction of its magnitude is
# reported as not determined by the data, not as a number.
IDENTIFIED_MAX_RELATIVE_SE = 0.5
# Columns the others explain this well (variance inflation factor 1/(1 − R²) of the column on
# the rest; > 100 is the usual "severe collinearity") are named in a note: their estimates are
# sound only as far as the model is right. A systematic model error shared by every block (a
# single-frequency swing: q̈ ≈ −ω² q makes inertia and gravity columns alike in every block)
# moves them without showing in the blocked bootstrap. Not a verdict by itself: with a right
# model and little noise a VIF of 1000 still gives good estimates (tests/test_identify_real.py).
COLLINEAR_VIF = 100.0
BOOTSTRAP_DRAWS = 200


@dataclass(frozen=True)
class Uncertainty:
    """Per parameter, the one uncertainty type of every arm and scheme: ``se_white``
    (σ² (ΨᵀWΨ)⁻¹, white residuals), ``se_block`` (blocked bootstrap over ``blocks`` blocks of
    ``block_s``; the residuals of smoothed or filtered rows are correlated), and
    ``identified``: se_block < IDENTIFIED_MAX_RELATIVE_SE · |θ|."""

    se_white: np.ndarray
    se_block: np.ndarray
    identified: np.ndarray
    block_s: float
    blocks: int

    def as_json(self) -> dict:
        return {
            "se_white": self.se_white.tolist(),
            "se_blocked_bootstrap": self.se_block.tolist(),
            "identified": self.identified.tolist(),
            "rule": f"identified when the blocked-bootstrap SE < {IDENTIFIED_MAX_RELATIVE_SE:.0%}"
            " of |value|",
            "block_s": self.block_s,
            "blocks": self.blocks,
        }


@dataclass
class ModelIdentification:
    """θ of a model object from one recording, with the reason when plain least squares is not
    physical, and per-parameter uncertainty.

    ``theta`` is the reported (physically bounded) estimate; ``theta_ls`` the unconstrained
    weighted least-squares one, ``ls_consistency`` says whether it is physical and why not.
    ``se_white``: standard errors if the residuals were white (σ from the residuals);
    ``se_block``: blocked-bootstrap standard errors (residuals are correlated: filter memory
    and unmodelled dynamics); ``identified``: se_block < IDENTIFIED_MAX_RELATIVE_SE·|θ|;
    ``variance_inflation``: per column, see COLLINEAR_VIF.
    """

    model: ArmModel
    scheme: str
    lam: float
    block_s: float
    blocks: int
    rows: int
    rows_excluded: int
    theta: np.ndarray
    theta_ls: np.ndarray
    method: str
    ls_consistency: dict[str, Any]
    consistency: dict[str, Any]
    se_white: np.ndarray
    se_block: np.ndarray
    identified: np.ndarray
    channel_weights: np.ndarray
    variance_inflation: np.ndarray
    notes: list[str] = field(default_factory=list)

    @property
    def uncertainty(self) -> Uncertainty:
        """Its standard errors and identifiability as every identification gives them."""
        return Uncertainty(self.se_white, self.se_block, self.identified, self.block_s, self.blocks)

    def parameter_rows(self) -> list[dict[str, Any]]:
        """One dict per parameter: name, unit, value (None when not identified), ± both SEs."""
        out = []
        for i, name in enumerate(self.model.names):
            out.append(
                {
                    "parameter": name,
                    "unit": self.model.units[i],
                    "estimate": float(self.theta[i]),
                    "value": float(self.theta[i]) if self.identified[i] else None,
                    "least_squares": float(self.theta_ls[i]),
                    "se_white": float(self.se_white[i]),
                    "se_blocked_bootstrap": float(self.se_block[i]),
                    "variance_inflation": float(self.variance_inflation[i]),
                    "identified": bool(self.identified[i]),
                }
            )
        return out

    def to_json(self) -> dict[str, Any]:
        return {
            "model_terms": list(self.model.terms),
            "names": list(self.model.names),
            "units": list(self.model.units),
            "scheme": self.scheme,
            "lambda_rad_s": self.lam,
            "block_s": self.block_s,
            "blocks": self.blocks,
            "rows": self.rows,
            "rows_excluded_stick": self.rows_excluded,
            "theta": self.theta.tolist(),
            "method": self.method,
            "theta_least_squares": self.theta_ls.tolist(),
            "least_squares_physical": self.ls_consistency,
            "physical_consistency": self.consistency,
            "parameters": self.parameter_rows(),
            "notes": self.notes,
        }


def bootstrap_block_s(lam: float, duration_s: float) -> float:
    """Length of the blocked bootstrap's blocks: they must outlast the residual's correlation
    (the row filter's 1/λ and the slowest excitation) and still leave enough of them to
    resample."""
    block_s = max(10.0 / lam, 0.5)
    return min(block_s, max(duration_s / 10.0, 10.0 / lam))


def mass_matrix_constraints(model: ArmModel, scale: float) -> list[dict[str, Any]]:
    """c(θ) ≥ 0 constraints (scipy form) for M(q) ≻ 0 at every q2, the closed form of
    :meth:`ArmModel.physical_consistency` with a margin of 1e-6·``scale`` (kg m²)."""
    eps = 1e-6 * scale
    rot = model.term_columns("rotor_inertia").start if "rotor_inertia" in model.terms else None
    perp = model.term_columns("com_offset").start if "com_offset" in model.terms else None

    def parts(th):
        rho = np.hypot(th[1], th[perp] if perp is not None else 0.0)
        m22 = th[2] + (th[rot] if rot is not None else 0.0)
        return rho, m22

    def m22_pos(th):
        return parts(th)[1] - eps

    def det(sign):
        def f(th):
            rho, m22 = parts(th)
            x = sign * rho
            return (th[0] + 2 * x) * m22 - (th[2] + x) ** 2 - eps * scale

        return f

    return [{"type": "ineq", "fun": f} for f in (m22_pos, det(1.0), det(-1.0))]


def identify_model(
    t: np.ndarray,
    q: np.ndarray,
    tau: np.ndarray,
    model: ArmModel,
    *,
    lam: float | None = None,
    scheme: str = "filtered_dynamic",
    block_s: float | None = None,
    chunk: int = 20000,
) -> ModelIdentification:
    """Identify ``model``'s θ from one recording with real time stamps ``t``.

    Rows: the ``exact`` regression of ``scheme`` built in chunks (:func:`iter_rows`), summed
    into per-block normal equations (:class:`BlockNormalEquations`), so memory is bounded by
    the chunk, not the recording. λ defaults to :func:`data_bandwidth` (twice the excitation's
    bandwidth read from the data). Estimate: feasible weighted least squares (per-joint noise
    from the residuals), then, if that is not physical, the bounded fit: friction and rotor
    inertia ≥ 0 (BVLS) and M(q) ≻ 0 for all q (SLSQP on the closed-form condition). Never
    raises on data it can read; an estimate that cannot be made physical says so."""
    t, q, tau = (np.asarray(a, dtype=float) for a in (t, q, tau))
    notes: list[str] = []
    if lam is None:
        lam = data_bandwidth(q, t)
        notes.append(f"lambda = {lam:.3g} rad/s from the data (twice its excitation bandwidth)")
    duration = float(t[-1] - t[0])
    if block_s is None:
        block_s = bootstrap_block_s(lam, duration)
    ne = BlockNormalEquations(model.n_params, 2 if scheme == "filtered_dynamic" else 1, block_s)
    rows = excluded = 0
    for c in iter_rows(scheme, q, tau, t, lam, model, chunk=chunk):
        ne.add(c.t, c.y, c.Psi, c.weights)
        rows += c.weights.size
        excluded += int(np.sum(c.weights == 0))
    H, g, yy, n = ne.arrays()
    # feasible weighted least squares: per-channel noise level from the unweighted residuals
    Hs, gs, _ = combine(H, g, yy, np.ones(H.shape[1]))
    theta0 = solve_normal_equations(Hs.sum(0), gs.sum(0))
    w = channel_weights(H, g, yy, n, theta0)
    Hw, gw, yyw = combine(H, g, yy, w)
    H_tot, g_tot = Hw.sum(0), gw.sum(0)
    theta_ls = solve_normal_equations(H_tot, g_tot)
    ls_consistency = model.physical_consistency(theta_ls)
    lower = np.full(model.n_params, -np.inf)
    lower[list(model.nonnegative_columns)] = 0.0
    if ls_consistency["consistent"]:
        theta, method = theta_ls, "weighted least squares (physical as it is)"
    else:
        scale = max(abs(theta_ls[0]), abs(theta_ls[2]), 1e-9)
        theta, method = bounded_quadratic_fit(
            H_tot, g_tot, lower, mass_matrix_constraints(model, scale)
        )
        notes.append(
            "plain least squares is not physical ("
            + "; ".join(ls_consistency["violations"])
            + f"); reported: {method}"
        )
    consistency = model.physical_consistency(theta)
    if not consistency["consistent"]:
        notes.append(
            "the bounded fit is still not physical: " + "; ".join(consistency["violations"])
        )
    # uncertainty: white-residual covariance (weights are 1/σ²) and blocked bootstrap
    se_white, se_block = standard_errors(Hw, gw, yyw, int(n.sum()), theta_ls, draws=BOOTSTRAP_DRAWS)
    if len(H) < 5:
        notes.append(f"only {len(H)} blocks of {block_s:.3g} s: no bootstrap uncertainty")
    d = np.sqrt(np.diag(H_tot))
    d[d == 0] = 1.0
    with np.errstate(all="ignore"):
        vif = np.diag(np.linalg.pinv(H_tot / np.outer(d, d)))
    vif = np.where(np.isfinite(vif) & (vif > 0), vif, np.inf)
    precise = se_block < IDENTIFIED_MAX_RELATIVE_SE * np.abs(theta)
    identified = precise
    weak = [model.names[i] for i in np.flatnonzero(~precise)]
    if weak:
        notes.append(
            "not determined by this data (blocked-bootstrap SE > "
            f"{IDENTIFIED_MAX_RELATIVE_SE:.0%} of the value): " + ", ".join(weak)
        )
    tangled = [f"{model.names[i]} ({vif[i]:.0f})" for i in np.flatnonzero(vif > COLLINEAR_VIF)]
    if tangled:
        notes.append(
            f"nearly collinear columns (variance inflation > {COLLINEAR_VIF:.0f}): "
            + ", ".join(tangled)
            + "; their estimates hold only as far as the model does (a model error shared by "
            "every block moves them without widening the bootstrap SE)"
        )
    return ModelIdentification(
        model=model,
        scheme=scheme,
        lam=float(lam),
        block_s=float(block_s),
        blocks=len(H),
        rows=rows,
        rows_excluded=excluded,
        theta=np.asarray(theta, dtype=float),
        theta_ls=theta_ls,
        method=method,
        ls_consistency=ls_consistency,
        consistency=consistency,
        se_white=se_white,
        se_block=se_block,
        identified=identified,
        channel_weights=w,
        variance_inflation=vif,
        notes=notes,
    )


def torque_prediction_error(
    theta: np.ndarray,
    model: ArmModel,
    t: np.ndarray,
    q: np.ndarray,
    tau: np.ndarray,
    lam: float,
    *,
    chunk: int = 20000,
) -> list[float]:
    """Held-out torque prediction, per joint NRMSE: the filtered torque F[τ] against Ψθ of the
    ``exact`` filtered-dynamic rows at bandwidth ``lam`` (rows with a stuck joint left out).
    Same rows and same filter for every model compared; streamed in chunks."""
    sse = np.zeros(2)
    sy = np.zeros(2)
    syy = np.zeros(2)
    cnt = np.zeros(2)
    for c in iter_rows("filtered_dynamic", q, tau, t, lam, model, chunk=chunk):
        pred = c.Psi @ theta
        w = c.weights > 0
        sse += np.sum(w * (c.y - pred) ** 2, axis=0)
        sy += np.sum(w * c.y, axis=0)
        syy += np.sum(w * c.y**2, axis=0)
        cnt += w.sum(axis=0)
    spread = syy - sy**2 / np.maximum(cnt, 1)
    return [float(np.sqrt(sse[j] / spread[j])) if spread[j] > 0 else float("nan") for j in range(2)]


__all__ = [
    "ESTIMATORS",
    "PAPER_TABLE_II",
    "SCHEME_TITLES",
    "ModelIdentification",
    "SchemeResult",
    "Uncertainty",
    "format_table_ii",
    "identify",
    "identify_model",
    "initial_velocity",
    "irregular_times",
    "table_ii_rows",
    "torque_prediction_error",
    "validate",
    "validate_many",
]
