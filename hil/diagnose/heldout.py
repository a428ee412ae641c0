"""The held-out stage of the diagnosis: the before/after fit on data no fit has seen.

The training and held-out rows (:func:`held_out_masks`: a single recording's last quarter, else the
last recording), the findings as the open-loop simulators take them (:func:`simulated_effects`,
:func:`openloop_extras` for the 2-DOF simulator, :func:`_shaft_effects` for an n-joint model), the
restarted segment simulations (:func:`simulated_segments`, :func:`segment_simulation`), and
:func:`before_after`: torque NRMSE and simulated-position NRMSE per joint, nominal model and
with the accepted terms.

Typed result: :class:`HeldOutFit` (one :class:`ModelFit` per model); its ``as_dict`` is the
diagnosis document's ``fit``.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from hil.diagnose.candidates import Accepted, term_key, term_width
from hil.diagnose.columns import (
    GAP_FACTOR,
    delayed_torque_means,
    lagged_torque_means,
    stribeck_shape,
)
from hil.diagnose.findings import (
    Finding,
)
from hil.diagnose.interpret import cogging_at_true_angle, term_findings
from hil.diagnose.kinds import kind_of_finding
from hil.diagnose.physical import model_columns, physical_theta
from hil.diagnose.problem import Problem, design_matrix, fit_theta, fit_theta_at
from hil.model.closed_form import TERMS
from hil.model.metrics import nrmse
from hil.model.openloop import OpenLoopExtras, simulate_open_loop, simulate_segments
from hil.model.protocol import ArmDynamics

HELD_OUT_FRACTION = 0.25  # of a single recording: its last quarter


# --- before / after ------------------------------------------------------------------------------


@dataclass
class SimulatedEffects:
    """The findings' magnitudes as a simulation takes them, per joint (list index 0..n−1)."""

    offset: list[float]
    gain: list[float]
    lag: list[float]
    angle: list[float]
    delay: list[float]  # per joint (a delay on all joints sets every one)
    last_delay: float  # the 2-DOF simulator's one delay: the last delay finding's
    cogging: list[tuple[float, float, float]]  # periods per revolution, amplitude, phase
    stribeck_ratio: list[float]
    stribeck_velocity: list[float]
    stribeck_excess: list[tuple[float, float]]  # breakaway excess, velocity (n-joint)
    has_stribeck: bool  # a Stribeck finding with its breakaway ratio


def simulated_effects(findings: Sequence[Finding], n_joints: int) -> SimulatedEffects:
    """Read the findings a simulation applies. Of a confounded pair one is used: they fit alike
    (a torque offset stands for the Coulomb asymmetry, a lag for a lag-or-delay)."""
    n = n_joints
    fx = SimulatedEffects(
        [0.0] * n, [0.0] * n, [0.0] * n, [0.0] * n, [0.0] * n, 0.0,
        [(0.0, 0.0, 0.0)] * n, [1.0] * n, [1.0] * n, [(0.0, 1.0)] * n, False,
    )  # fmt: skip
    for f in findings:
        if f.term in TERMS and f.effect != f.term:
            continue  # the rival of an accepted model term: the term is in θ already
        kind = kind_of_finding(f.effect)
        if kind is not None:
            kind.simulate(f, fx)
    return fx


def openloop_extras(findings: Sequence[Finding]) -> OpenLoopExtras:
    """The findings as the 2-DOF open-loop simulator's extras (:func:`simulated_effects`)."""
    fx = simulated_effects(findings, 2)
    stribeck = (
        {
            "stribeck_breakaway_ratio": tuple(fx.stribeck_ratio),
            "stribeck_velocity_rad_s": tuple(fx.stribeck_velocity),
        }
        if fx.has_stribeck
        else {}
    )
    return OpenLoopExtras(
        torque_offset_Nm=tuple(fx.offset),
        torque_gain=tuple(fx.gain),
        actuator_lag_s=tuple(fx.lag),
        transport_delay_s=fx.last_delay,
        cogging_periods_per_rev=tuple(c[0] for c in fx.cogging),
        cogging_amplitude_Nm=tuple(abs(c[1]) for c in fx.cogging),
        cogging_phase_rad=tuple(c[2] for c in fx.cogging),
        angle_offset_rad=tuple(fx.angle),
        **stribeck,
    )


def finite_or_none(values: Sequence[float]) -> list[float | None]:
    """``values`` as floats, None where not finite (JSON has no nan or inf)."""
    return [float(v) if np.isfinite(v) else None for v in values]


# Fewer usable held-out rows than this on a joint, and its NRMSE is not reported (a handful of
# rows with nearly equal torque divide by a range of ~0).
MIN_HELD_OUT_ROWS = 50


def nrmse_or_none(y: np.ndarray, pred: np.ndarray, rows: np.ndarray, j: int) -> float | None:
    """NRMSE of joint j over ``rows``; None when the held-out part has too few usable rows for
    it (the joint stood still throughout) or no spread to scale by (:func:`nrmse` gives nan:
    DFKI A.0 trajectory_05's joint 1 printed 1e17 %, then nan, and JSON has no nan)."""
    if rows.sum() < MIN_HELD_OUT_ROWS or np.ptp(y[rows, j]) == 0:
        return None
    value = float(nrmse(y[rows, j], pred[rows, j]))
    return value if np.isfinite(value) else None


def _training_findings(
    accepted: Sequence[Accepted],
    beta: np.ndarray,
    findings: Sequence[Finding],
    model: ArmDynamics = None,
) -> list[Finding]:
    """``findings`` with the magnitudes of the linear terms re-estimated from ``beta`` (θ then
    the accepted terms' coefficients): fitted on the training part only, so that nothing
    fitted on the held-out data enters the held-out comparison (:func:`read_at_reference`
    gives it a fit on all rows). Lag, delay and the joint of a gain error keep
    their whole-data values (a grid search and a choice, not a fit)."""
    out = list(findings)
    p = len(beta) - sum(term_width(a.cand) for a in accepted)  # the nominal model's θ
    at = p
    refreshed: set[int] = set()
    for a in accepted:
        width = term_width(a.cand)
        coef = beta[at : at + width]
        at += width
        if not a.cand.spec.refit_on_training:  # a model term is simulated in θ itself
            continue
        fresh = {f.effect: f for f in term_findings(a.cand, a.variant, coef, beta[:p], model)}
        for i, f in enumerate(out):
            if f.effect in fresh and f.joint == a.cand.joint + 1:
                out[i] = replace(f, estimate=fresh[f.effect].estimate)
                refreshed.add(i)
    # the fresh cogging phases are on the recorded angle, as term_findings gives them
    return cogging_at_true_angle(out, refreshed)


def held_out_masks(prob: Problem) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int, int]]]:
    """Training and held-out row masks, and the held-out spans (recording, first, last sample)."""
    n_rec = len(prob.rows)
    sizes = [r.rows for r in prob.rows]
    train = np.zeros(sum(sizes), bool)
    spans = []
    start = 0
    for i, r in enumerate(prob.rows):
        if n_rec > 1:
            cut = r.rows if i < n_rec - 1 else 0
        else:
            cut = round(r.rows * (1 - HELD_OUT_FRACTION))
        train[start : start + cut] = True
        if cut < r.rows:
            spans.append((i, int(r.k[cut]), len(r.q) - 1))
        start += r.rows
    return train, ~train, spans


SEGMENT_S = 1.0  # open-loop simulations restart from the recorded state this often
# At most this many segments are simulated, spread evenly over the held-out part: enough for
# the NRMSE of a long recording (a quarter of 10 minutes is 150 segments) to settle, and the
# simulation gate reruns it for every term.
MAX_SEGMENTS = 40


def simulated_segments(
    h: float, first: int, last: int, stamps: np.ndarray | None, n_samples: int
) -> list[tuple[int, int]]:
    """The [a, b) sample ranges the held-out simulation runs over: SEGMENT_S long, also cut at
    every gap (an interval over GAP_FACTOR × h: a stall, dropped samples), at most MAX_SEGMENTS
    of them evenly spread over samples first..last. Inside a segment the simulation runs on the
    real intervals (:func:`segment_simulation`)."""
    step = max(4, round(SEGMENT_S / h))
    # interval i (samples i → i+1) is a gap
    gaps = np.zeros(0, int) if stamps is None else np.flatnonzero(np.diff(stamps) > GAP_FACTOR * h)
    cuts = sorted({*range(first, last + 1, step), *(int(i) + 1 for i in gaps)})
    cuts = [c for c in cuts if first <= c <= last] + [last + 1]
    pairs = list(itertools.pairwise(cuts))
    if len(pairs) > MAX_SEGMENTS:
        pick = np.unique(np.linspace(0, len(pairs) - 1, MAX_SEGMENTS).round().astype(int))
        pairs = [pairs[i] for i in pick]
    return pairs


def segment_simulation(
    theta: np.ndarray,
    extras: OpenLoopExtras | Sequence[Finding] | None,
    q: np.ndarray,
    tau: np.ndarray,
    h: float,
    segments: Sequence[tuple[int, int]],
    stamps: np.ndarray | None = None,
    model: ArmDynamics | None = None,
) -> np.ndarray:
    """Open-loop simulation of the sample ranges ``segments`` (:func:`simulated_segments`),
    each started from the recorded position and central-difference velocity: an arm this
    underdamped diverges from any model over many seconds, so one long run would measure chaos,
    not the model. ``stamps``: the real sample times; each segment is integrated over its
    true intervals (a realtime run's 0.3 ms catch-up steps after a stall, a real arm's jitter).
    ``model``: the :class:`ArmModel` θ is written in (default the 9-parameter one)."""
    t = np.arange(len(q)) * h if stamps is None else stamps
    if model is not None and not model.closed_form:
        return _segment_simulation_n(theta, extras, q, tau, h, segments, t, model, stamps)
    out = []
    for a, b in segments:
        inside = 0 < a < len(q) - 1
        dq0 = (q[a + 1] - q[a - 1]) / (t[a + 1] - t[a - 1]) if inside else np.zeros(2)
        ex = extras
        if extras is not None and a > 0:  # the lag and delay line start settled, not at rest
            ex = replace(extras, initial_command_Nm=(float(tau[a - 1, 0]), float(tau[a - 1, 1])))
        intervals = None if stamps is None else np.diff(stamps[a:b])
        out.append(
            simulate_open_loop(
                theta,
                tau[a:b],
                h,
                q0=q[a],
                dq0=dq0,
                extras=ex,
                intervals_s=intervals,
                model=model,
            ).q
        )
    return np.concatenate(out)


def _kept_simulation(
    memo: dict,
    rec_i: int,
    theta: np.ndarray,
    extras: OpenLoopExtras | Sequence[Finding] | None,
    r: Any,
    segments: Sequence[tuple[int, int]],
    model: ArmDynamics,
) -> np.ndarray:
    """:func:`segment_simulation` of recording ``rec_i``'s rows ``r``, kept in ``memo`` by its
    inputs (:func:`before_after`): the simulation gate's last round and the final comparison
    simulate the same model, and so do "before" and "after" when nothing is accepted. An
    n-joint model's simulation takes the findings, and is kept by what it takes of them
    (:func:`simulated_effects`, as :func:`_shaft_effects` reads them)."""
    if model.closed_form:
        if not (extras is None or isinstance(extras, OpenLoopExtras)):
            return segment_simulation(theta, extras, r.q, r.tau, r.h, segments, r.stamps, model)
        how: Any = (model.terms, extras)
    else:  # one diagnosis's memo: one robot, its model named by its terms
        effects = simulated_effects(extras or (), r.q.shape[1])
        how = (model.name, model.terms, model.n_params, repr(effects))
    key = ("simulation", rec_i, tuple(segments), theta.tobytes(), how)
    if key not in memo:
        simulated = segment_simulation(theta, extras, r.q, r.tau, r.h, segments, r.stamps, model)
        simulated.flags.writeable = False  # shared by the calls that reuse it
        memo[key] = simulated
    return memo[key]


def torque_spread(tau: np.ndarray) -> np.ndarray:
    """Per joint, std(τ) / rms(τ): a gain of ε times this moves τ by ε of its spread in RMS, the
    scale an NRMSE of ε is measured in."""
    rms = np.sqrt(np.mean(tau**2, axis=0))
    return np.divide(np.std(tau, axis=0), rms, out=np.zeros_like(rms), where=rms > 0)


def _shaft_effects(
    findings: Sequence[Finding] | None,
    tau: np.ndarray,
    h: float,
    stamps: np.ndarray | None = None,
) -> tuple[np.ndarray, Callable[[np.ndarray, np.ndarray], np.ndarray] | None, np.ndarray]:
    """The findings as an n-joint simulation takes them (what :func:`openloop_extras` is for the
    2-DOF simulator, by the same choices among confounded findings): the shaft torque of the
    torque path (delay or lag, then gain, then offset) for every recorded row, the
    state-dependent shaft torque (cogging, minus the Stribeck excess of friction) and the angle
    offsets.
    ``stamps``: the real sample times (the delay and lag over each true interval)."""
    n = tau.shape[1]
    fx = simulated_effects(findings or (), n)
    cogging = [(j, *c) for j, c in enumerate(fx.cogging) if c[1] != 0]
    stribeck = [(j, *x) for j, x in enumerate(fx.stribeck_excess) if x[0] != 0]
    delay, lag = fx.delay, fx.lag
    gain, off, ang = np.array(fx.gain), np.array(fx.offset), np.array(fx.angle)
    shaft = tau.astype(float).copy()
    for j in range(n):
        if delay[j] > 0:
            shaft[:, j] = delayed_torque_means(tau[:, j : j + 1], h, delay[j], stamps)[:, 0]
        if lag[j] > 0:
            shaft[:, j] = lagged_torque_means(shaft[:, j : j + 1], h, lag[j], stamps)[:, 0]
    shaft = (1.0 + gain) * shaft + off

    def state_torque(q: np.ndarray, v: np.ndarray) -> np.ndarray:
        out = np.zeros_like(q)
        for j, periods, amplitude, phase in cogging:
            out[:, j] += amplitude * np.sin(periods * q[:, j] + phase)
        for j, excess, velocity in stribeck:
            out[:, j] -= excess * stribeck_shape(v[:, j], velocity)
        return out

    return shaft, (state_torque if cogging or stribeck else None), ang


def _segment_simulation_n(
    theta: np.ndarray,
    findings: Sequence[Finding] | None,
    q: np.ndarray,
    tau: np.ndarray,
    h: float,
    segments: Sequence[tuple[int, int]],
    t: np.ndarray,
    model: ArmDynamics,
    stamps: np.ndarray | None = None,
) -> np.ndarray:
    """:func:`segment_simulation` of an n-joint model object (a URDF model): each segment
    from the recorded state, the findings as :func:`_shaft_effects` gives them, integrated by
    :func:`hil.model.openloop.simulate_segments` (the 2-DOF simulation's stick–slip over the
    model object)."""
    shaft, state_torque, ang = _shaft_effects(findings, tau, h, stamps)
    dq0 = np.array(
        [
            (q[a + 1] - q[a - 1]) / (t[a + 1] - t[a - 1])
            if 0 < a < len(q) - 1
            else np.zeros(q.shape[1])
            for a, _b in segments
        ]
    )
    sims = simulate_segments(
        model, theta, t, q, shaft, segments, dq0, shaft_torque=state_torque, angle_offset=ang
    )
    return np.concatenate(sims)


def _refit(
    prob: Problem,
    cols: Sequence[np.ndarray],
    target: np.ndarray,
    w: np.ndarray,
    rigid_reference: np.ndarray | None = None,
) -> np.ndarray:
    """θ and the coefficients of the term columns ``cols`` fitted to ``target`` with row
    weights ``w``; with ``rigid_reference``, θ's first parameters held at it and the rest
    fitted (:func:`hil.diagnose.findings.gain_at_reference`'s model). The design is weighted
    in place by the fit: on a long recording a (K, 2, p) copy fewer at the memory peak."""
    if rigid_reference is None:
        return fit_theta(design_matrix(prob, cols), target, w, overwrite_design=True)
    return fit_theta_at(
        design_matrix(prob, cols), target, w, rigid_reference, overwrite_design=True
    )


def read_at_reference(
    prob: Problem,
    accepted: Sequence[Accepted],
    findings: Sequence[Finding],
    shaft: np.ndarray | None,
    rigid_reference: np.ndarray,
) -> list[Finding]:
    """``findings`` with the magnitudes of the linear terms refitted on all rows with the
    rigid-body parameters at ``rigid_reference``: the model a torque gain read at the
    reference is judged in (:func:`simulation_gate`), so that the other findings beside it
    are read in that model too. With θ free a closed-loop gain on joint 1 was 2.9 % of 5 % and
    joint 1's Coulomb levels 1.6 % low with it (the free θ absorbs the rest of the gain)."""
    if shaft is not None:
        accepted = [a for a in accepted if not a.cand.spec.is_rate]
    target = prob.y if shaft is None else shaft / prob.scale
    cols = [prob.chosen(a) for a in accepted]
    beta = _refit(prob, cols, target, prob.w, rigid_reference)
    return _training_findings(accepted, beta, findings, prob.model)


@dataclass
class ModelFit:
    """One model on the held-out data: per joint its torque NRMSE and simulated-position NRMSE
    (None where it cannot be scored; the positions empty when it was not simulated), and its θ."""

    torque_nrmse: list[float | None]
    position_nrmse: list[float | None]
    theta: np.ndarray

    def as_dict(self) -> dict[str, Any]:
        return {
            "torque_nrmse": self.torque_nrmse,
            "position_nrmse": self.position_nrmse,
            "theta": self.theta.tolist(),
        }


@dataclass
class HeldOutFit:
    """:func:`before_after`'s comparison: the nominal model (``before``) and the model with the
    accepted terms (``after``) on the held-out data (``held_out`` says which); ``unphysical``:
    per model ("before", "after") the reasons its fit is not physical (then not simulated)."""

    held_out: str
    before: ModelFit
    after: ModelFit
    unphysical: dict[str, list[str]] = field(default_factory=dict)

    def model(self, name: str) -> ModelFit:
        """``before`` or ``after`` by name."""
        return {"before": self.before, "after": self.after}[name]

    def as_dict(self) -> dict[str, Any]:
        """The document's ``fit``."""
        doc: dict[str, Any] = {
            "held_out": self.held_out,
            "before": self.before.as_dict(),
            "after": self.after.as_dict(),
        }
        if self.unphysical:
            doc["unphysical"] = self.unphysical
        return doc


def before_after(
    prob: Problem,
    accepted: Sequence[Accepted],
    findings: Sequence[Finding],
    nominal_theta: np.ndarray | None,
    simulate_before: bool = True,
    friction_se: np.ndarray | None = None,
    shaft: np.ndarray | None = None,
    sensitivity: bool = False,
    memo: dict | None = None,
    rigid_reference: np.ndarray | None = None,
) -> tuple[HeldOutFit, dict[str, Any]]:
    """Torque NRMSE and open-loop position NRMSE per joint on held-out data, nominal model
    (``nominal_theta`` when given, else fitted on the training part) and with the accepted terms.
    A fit that is not physical is not simulated (its position NRMSE stays empty) and is named
    in ``unphysical`` with the reasons. ``shaft``: the exact lagged or delayed torque rows (Nm)
    of a found lag or delay; the refit then explains them instead of carrying the first-order
    rate columns, so θ is the one the simulation with that lag or delay needs.
    ``sensitivity``: also the arrays' ``position_sensitivity`` (:func:`simulation_sensitivity`)
    of the model with the accepted terms. ``memo``: a dict kept over the calls of one diagnosis
    (the simulation gate's rounds, then the final comparison), in which the fits and the
    simulations are kept by what they depend on and reused, not computed again.
    ``rigid_reference``: the rigid-body parameters (θ1..θ5) the refit with the accepted terms
    holds fixed, the rest fitted: the model of a torque gain read at the reference
    (:func:`simulation_gate`)."""
    memo = {} if memo is None else memo
    train, test, spans = held_out_masks(prob)
    if shaft is not None:
        accepted = [a for a in accepted if not a.cand.spec.is_rate]
    cols = [prob.chosen(a) for a in accepted]
    w_train = prob.w * train[:, None]
    if nominal_theta is None:
        key0 = ("nominal fit", prob.scale.tobytes())
        if key0 not in memo:
            memo[key0] = fit_theta(prob.Psi, prob.y, w_train, overwrite_design=True)
        theta0 = memo[key0].copy()
    else:
        theta0 = np.asarray(nominal_theta, float)
    target = prob.y if shaft is None else shaft / prob.scale
    # the design is built again for the prediction (the fit weights its copy in place); the
    # refit is kept by the terms' columns and the shaft rows themselves (a rebuilt column is a
    # new array) and by the rigid-body parameters it holds
    pinned = None if rigid_reference is None else np.asarray(rigid_reference, float).tobytes()
    key1 = ("refit", tuple(a.cand.key for a in accepted), prob.scale.tobytes(), pinned)
    inputs = (shaft, *(prob.cache[term_key(a)] for a in accepted))
    kept = memo.get(key1)
    if kept is None or any(x is not y for x, y in zip(kept[0], inputs, strict=True)):
        beta = _refit(prob, cols, target, w_train, rigid_reference)
        kept = memo[key1] = (inputs, beta)
    beta = kept[1].copy()
    Z = design_matrix(prob, cols)
    y = prob.y_raw
    pred0 = prob.Psi_raw @ theta0
    # the model's torque prediction: what it leaves of the measured side, on the recorded rows
    pred1 = y - (target - Z @ beta) * prob.scale
    torque = {}
    for name, pred in (("before", pred0), ("after", pred1)):
        torque[name] = [
            nrmse_or_none(y, pred, test & (prob.w[:, j] > 0), j) for j in range(prob.n_joints)
        ]
    trained = _training_findings(accepted, beta, findings, prob.model)
    # the 2-DOF simulator's extras; an n-joint model's simulation takes the findings
    extras = openloop_extras(trained) if prob.model.closed_form else trained
    # the model the refit describes: the nominal one with the accepted model terms in θ
    # (friction_se: the nominal fit's standard errors, for θ's first columns)
    model1, index1 = model_columns(prob.model, [a.cand for a in accepted])
    clipped1, reasons1 = physical_theta(beta[index1], friction_se, model1)
    theta1 = beta[index1] if reasons1 else clipped1
    model0 = prob.model
    position: dict[str, list[float | None]] = {"before": [], "after": []}
    sims: dict[str, Any] = {}
    unphysical_fit: dict[str, list[str]] = {}
    clipped0, reasons0 = physical_theta(theta0, friction_se, model0)
    for name, reasons in (("before", reasons0), ("after", reasons1)):
        if reasons:  # it cannot be simulated, and is never the basis of a finding
            unphysical_fit[name] = reasons
    if not reasons0:
        theta0 = clipped0  # friction within its uncertainty of zero simulated as zero
    for rec_i, first, last in spans[-1:]:
        r = prob.rows[rec_i]
        segments = simulated_segments(r.h, first, last, r.stamps, len(r.q))
        index = np.concatenate([np.arange(a, b) for a, b in segments])
        q, h = r.q[index], r.h
        times = np.arange(len(r.q)) * h if r.stamps is None else r.stamps
        sims = {"t": times[index], "q": q}
        for name, theta, ex, model in (
            ("before", theta0, None, model0),
            ("after", theta1, extras, model1),
        ):
            if name in unphysical_fit or (name == "before" and not simulate_before):
                continue
            sims[name] = _kept_simulation(memo, rec_i, theta, ex, r, segments, model)
            position[name] = finite_or_none(nrmse(q, sims[name]))
        if sensitivity and "after" in sims:
            # the same simulation driven by a torque off by the model's own held-out error
            error = np.array([np.nan if e is None else e for e in torque["after"]])
            tau = r.tau * (1.0 + np.nan_to_num(error * torque_spread(r.tau[index])))
            moved = segment_simulation(theta1, extras, r.q, tau, h, segments, r.stamps, model1)
            sims["position_sensitivity"] = finite_or_none(
                simulation_sensitivity(moved, sims["after"], q)
            )
    held = (
        f"recording {len(prob.rows)}, not used for fitting"
        if len(prob.rows) > 1
        else f"the last {HELD_OUT_FRACTION:.0%} of the recording, not used for fitting"
    )
    fit = HeldOutFit(
        held,
        ModelFit(torque["before"], position["before"], theta0),
        ModelFit(torque["after"], position["after"], theta1),
        unphysical_fit,
    )
    return fit, {
        "torque": y,
        "pred_before": pred0,
        "pred_after": pred1,
        "test": test,
        "simulation": sims,
    }


def simulation_sensitivity(moved: np.ndarray, simulated: np.ndarray, recorded: np.ndarray):
    """Per joint, how far the held-out simulation moves (as an NRMSE against ``recorded``: the
    RMS change over the spread of the recorded angle) when its torque is off by the model's own
    held-out torque NRMSE (``moved`` against ``simulated``, :func:`before_after` with
    ``sensitivity``). Two models whose torque predictions differ by less than the error both
    make cannot be told apart by simulated motion that differs by less than this."""
    return nrmse(recorded, recorded + moved - simulated)
