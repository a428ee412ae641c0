"""Regression columns of the physics a nominal model leaves out (the diagnosis vocabulary).

The nominal model (an :class:`hil.model.closed_form.ArmModel`, default the 9-parameter one) is
the momentum balance of Reyes & Kelly (1997) eq. (24) written over sample intervals as the
``exact`` regressions of :mod:`hil.model.regressors` do: y(k) = F[τ](k) ≈ Ψ(k) θ, one row per
joint, F a moving average over a short window (:func:`recording_rows`), τ_k with the held
torque's bias of the estimated momenta added (:func:`_momentum_rows`). Every candidate
below adds columns X so that y ≈ Ψ θ + X β with β its physical parameters, built over the same
intervals and through the same filter as Ψ, so the extended regression is as consistent as the
nominal one. Equations (τ the
commanded torque, τ_a the torque applied to the shaft, q the encoder reading, q̇ its velocity):

``torque_offset``      τ_a = τ + c                         X = −1,                 β = c [Nm]
``coulomb_asymmetry``  f = F⁺ for q̇ > 0, −F⁻ for q̇ < 0: the same column as a torque offset
                       (F± = θ_fc ∓ c), see :func:`offset_column` and docs/diagnosis.md
``torque_gain``        τ_a = (1 + r) τ                     X = −F[τ_j],            β = r
``cogging``            τ_a = τ + A sin(n q + φ)            X = −[sin nq, cos nq],  β = A(cos, sin)φ
``stribeck``           f += ΔF sgn(q̇) exp(−(|q̇|/v_s)^δ)    X = +that shape,         β = ΔF [Nm]
``actuator_lag``       T τ̇_a + τ_a = τ (first-order lag)   X ≈ F[τ̇], F[τ̈] (two probe lags)
``transport_delay``    τ_a(t) = τ(t − d)                    the same columns (decided later)
``angle_offset``       q = q_true + δ                       X = −∂(Ψθ)/∂q_j,        β = δ [rad]
``rotor_inertia``      M22 = θ3 + θ_rotor                   X = the column ArmModel appends
``com_offset``         centres of mass off the link axes    X = the 3 columns ArmModel appends
                       (model terms, hil.model.closed_form: :func:`model_term_columns`)

Lag and delay share their first-order column; :func:`lagged_torque_rows` and
:func:`delayed_torque_rows` give the exact shaft torques that tell them apart. Pure functions.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from hil.diagnose.finding import rounded
from hil.model.protocol import ArmDynamics
from hil.model.regressors import (
    GL_NODES,
    GL_WEIGHTS,
    NINE_PARAMETERS,
    central_difference,
    gauss_legendre_unit,
    has_velocity_reversal,
    held_torque_momentum_bias,
    hermite_nodes,
    interval_mean_across_reversals,
    kinematics,
    quantized_stick,
    raw_rows,
    stick_weights,
)

# Window of the moving-average filter F, in seconds (20 ms: 8 intervals at 400 Hz, about the
# noise bandwidth of the identification's λ = 50 rad/s low-pass). A finite window matters here:
# a stuck interval spoils only the rows whose window holds it, where the low-pass spreads it over
# ~55 rows, and a joint that reverses often would leave few rows to diagnose. It is a time, not a
# count: at 1 kHz an 8-interval window left the momentum differences so noisy against their
# signal that least squares shrank θ (errors in variables) and a 2 % "gain error" appeared on a
# null recording.
WINDOW_S = 0.02
# Intervals without encoder motion or with a velocity reversal, and those within this time either
# side, are left out: the joint comes to rest or breaks away inside them, so part of each carries
# static friction the model has no term for (tens of σ of residual on joint 2 otherwise).
STICK_GUARD_S = 0.005


def window_intervals(h: float) -> int:
    """The moving-average window for sample period ``h`` (at least 4 intervals)."""
    return max(4, round(WINDOW_S / h))


# Noise from the data (docs/diagnosis.md, "Noise and time stamps"): position noise σ_q is the
# larger of the encoder quantum's Δ/√12 (Δ the smallest step seen) and what the third
# differences hold (Δ³q of a smooth motion is ~0, of white noise has variance 20 σ_q²); a
# velocity fitted over 2m + 1 samples then has noise σ_v(m) = σ_q √(3 / (m(m+1)(2m+1))) / h,
# and a window of W intervals leaves
# √2 σ_v / (W h) in the momentum differences. m grows until σ_v is VELOCITY_NOISE of the
# velocity's RMS (at most MAX_HALF_WINDOW_S either side: the fit's own bias grows as (ω m h)²);
# W until the momentum noise is MOMENTUM_NOISE of the acceleration's RMS (least squares shrinks
# θ by about its square, errors in variables), never below WINDOW_S, at most MAX_WINDOW_S.
VELOCITY_NOISE = 0.01
MOMENTUM_NOISE = 0.02
MAX_HALF_WINDOW_S = 0.005
MAX_WINDOW_S = 0.2
# An interval this many times the median is a gap (a stall, dropped samples): no row spans it.
GAP_FACTOR = 3.0


@dataclass(frozen=True)
class NoiseModel:
    """What the data say about their own noise, per joint, and the windows it implies."""

    quantum_rad: tuple[float, ...]  # per joint
    velocity_noise_rad_s: tuple[float, ...]  # of the velocity estimate actually used
    half_window: int  # samples either side of each velocity estimate
    window: int  # intervals of the moving-average filter F
    irregular_intervals: int  # intervals off the median by more than 1 %
    gaps: int  # intervals over GAP_FACTOR × the median

    def as_dict(self, h: float) -> dict[str, object]:
        return {
            "encoder_quantum_rad": [rounded(x, 3) for x in self.quantum_rad],
            "velocity_noise_rad_s": [rounded(x, 3) for x in self.velocity_noise_rad_s],
            "velocity_half_window": self.half_window,
            "filter_window_s": round(self.window * h, 4),
            "irregular_intervals": self.irregular_intervals,
            "gaps": self.gaps,
        }


def _velocity_noise(sigma_q: np.ndarray, h: float, m: int) -> np.ndarray:
    return sigma_q * np.sqrt(3.0 / (m * (m + 1) * (2 * m + 1))) / h


def _third_difference_noise(q: np.ndarray, t: np.ndarray, dt: np.ndarray, h: float) -> np.ndarray:
    """σ_q from the third differences of q (per joint). Regular stamps: Var Δ³q = 20 σ_q².
    Irregular ones (a realtime run on its real stamps) need the third divided difference
    f[t_i..t_{i+3}] = Σ_j c_j q_j with c_j = 1/∏_{m≠j}(t_j − t_m), whose noise variance is
    σ_q² Σ_j c_j²; Δ³q on the stamps as if they were regular would count the motion between
    unequal intervals as noise (a 7× σ_q, a 175 ms filter, on a 400 Hz realtime run)."""
    if len(q) < 4 or np.all(np.abs(dt / h - 1) <= 0.01):
        return np.sqrt(np.mean(np.diff(q, 3, axis=0) ** 2, axis=0) / 20.0)
    nodes = [t[j : len(t) - 3 + j] for j in range(4)]
    divided = np.zeros((len(t) - 3, q.shape[1]))
    weight = np.zeros(len(t) - 3)
    for j in range(4):
        c = 1.0 / np.prod([nodes[j] - nodes[m] for m in range(4) if m != j], axis=0)
        divided += c[:, None] * q[j : len(q) - 3 + j]
        weight += c**2
    # pooled over all rows: Σ f² / Σ Σ c² (equal stamps: mean(Δ³q²)/20 exactly)
    return np.sqrt(np.sum(divided**2, axis=0) / np.sum(weight))


def noise_model(q: np.ndarray, t: np.ndarray) -> NoiseModel:
    """Encoder quantum, velocity-estimate noise, and the windows they call for (module doc)."""
    dt = np.diff(t)
    h = float(np.median(dt))
    steps = np.abs(np.diff(q, axis=0))
    quantum = np.array([float(s[s > 0].min()) if np.any(s > 0) else 0.0 for s in steps.T])
    sigma_q = np.maximum(quantum / np.sqrt(12.0), _third_difference_noise(q, t, dt, h))
    v = np.diff(q, axis=0) / dt[:, None]
    v_rms = np.sqrt(np.mean(v**2, axis=0))
    s = 10  # acceleration on a 10-sample scale, where quantization is small against motion
    if len(q) > 2 * s + 1:
        a = (q[2 * s :] - 2 * q[s:-s] + q[: -2 * s]) / (s * h) ** 2
        a_rms = np.sqrt(np.mean(a**2, axis=0))
    else:
        a_rms = np.full(q.shape[1], np.inf)
    moving = v_rms > 0
    m = 1
    while m * h < MAX_HALF_WINDOW_S and np.any(
        _velocity_noise(sigma_q, h, m)[moving] > VELOCITY_NOISE * v_rms[moving]
    ):
        m += 1
    sigma_v = _velocity_noise(sigma_q, h, m)
    with np.errstate(divide="ignore", invalid="ignore"):
        need = np.where(a_rms > 0, np.sqrt(2) * sigma_v / (MOMENTUM_NOISE * a_rms * h), 0.0)
    window = max(window_intervals(h), int(np.ceil(np.max(need[np.isfinite(need)], initial=0))))
    window = min(window, max(window_intervals(h), round(MAX_WINDOW_S / h)))
    return NoiseModel(
        tuple(float(x) for x in quantum),
        tuple(float(x) for x in sigma_v),
        m,
        window,
        int(np.sum(np.abs(dt / h - 1) > 0.01)),
        int(np.sum(dt > GAP_FACTOR * h)),
    )


@dataclass(frozen=True)
class RecordingRows:
    """One recording's nominal regression y ≈ Ψ θ (rows (K, 2), Ψ (K, 2, 9), weights (K, 2))
    and what the candidate columns are built from.

    Row i is the momentum balance (Reyes & Kelly 1997, eq. (24) without its filter, over sample
    intervals as :mod:`hil.model.regressors` ``exact`` writes it) averaged over the ``window``
    intervals
    ending at interval ``k[i]``. ``q_nodes``, ``v_nodes`` (nodes, K, 2): positions and velocities
    at the Gauss–Legendre nodes of each interval on the cubic Hermite interpolant (the one
    :func:`hil.model.regressors.interval_integrals` uses)."""

    y: np.ndarray
    Psi: np.ndarray
    weights: np.ndarray
    q: np.ndarray
    tau: np.ndarray
    h: float
    window: int
    k: np.ndarray
    q_nodes: np.ndarray
    v_nodes: np.ndarray
    v: np.ndarray  # sample velocities (N, 2): the Hermite end slopes of q_nodes, v_nodes
    stamps: np.ndarray | None = None  # real sample times when the rows use them (else k·h)
    half_window: int = 1  # samples either side of each velocity estimate
    noise: NoiseModel | None = None
    model: ArmDynamics = NINE_PARAMETERS  # whose columns Ψ holds

    @property
    def rows(self) -> int:
        return len(self.k)

    @property
    def n_joints(self) -> int:
        return self.y.shape[1]

    @property
    def t(self) -> np.ndarray:
        """Time of each row's interval start (s)."""
        return self.k * self.h if self.stamps is None else self.stamps[self.k]

    @property
    def v_mean(self) -> np.ndarray:
        """Mean velocity over each row's interval (K, 2)."""
        return _node_average(self.v_nodes)

    @property
    def q_mean(self) -> np.ndarray:
        """Mean position over each row's interval (K, 2)."""
        return _node_average(self.q_nodes)


def moving_average(x: np.ndarray, window: int, *, overwrite_input: bool = False) -> np.ndarray:
    """F: the mean of the last ``window`` rows (fewer at the start), along the first axis.
    ``overwrite_input``: x (float) may hold the cumulative sums afterwards (no third array)."""
    # Two arrays of x's size, the sums and the result: the in-place out[w:] -= out[:-w] this
    # replaces held as much (numpy copies an overlapping operand first) and took three times
    # the cumulative sum's time doing it (a long diagnosis filters hundreds of cogging chunks).
    in_place = overwrite_input and x.dtype == float
    sums = np.cumsum(x, axis=0, dtype=float, out=x if in_place else None)
    out = np.empty_like(sums)
    out[:window] = sums[:window]
    np.subtract(sums[window:], sums[:-window], out=out[window:])
    del sums
    n = np.minimum(np.arange(1, len(x) + 1), window).reshape((-1,) + (1,) * (x.ndim - 1))
    out /= n
    return out


# Samples per piece when the interval rows are built: the regressor at every interval's nodes
# is (nodes, K, 2, 9) floats, 350 MB for 10 minutes at 1 kHz at once.
ROW_CHUNK = 50_000


def _momentum_rows(
    q: np.ndarray,
    tau: np.ndarray,
    h: float,
    t: np.ndarray | None = None,
    half_window: int = 1,
    model: ArmDynamics = NINE_PARAMETERS,
    torque_side: bool = True,
    v: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Unfiltered interval rows: k, τ_k + (b_{k+1} − b_k)/h_k (K, 2) (b the held torque's bias
    of the estimated momentum, :func:`hil.model.regressors.held_torque_momentum_bias`),
    [ΔP + ∫R dt]/h_k (K, 2, p) of ``model``'s p
    parameters, interval stuck (K, 2), sample velocities (N, 2). ``t``: real time stamps (each
    interval its own h_k). Built ROW_CHUNK samples at a time, each piece with enough neighbours
    either side for its velocities (an interval's row depends only on the samples around it),
    so memory is O(N·p). ``torque_side`` False: the y returned is τ_k alone (for a caller of
    Ψ only: the bias takes a local fit per sample); ``v``: the sample velocities (N, n), when
    known (:func:`hil.model.regressors.kinematics`)."""
    n = len(q)
    margin = half_window + 2
    parts = []
    v_all = np.full(q.shape, np.nan)
    # The held torque's corners in q̈ bias M v̂ by b_k (hil.model.regressors): moved to the
    # torque side, y_k = τ_k + (b_{k+1} − b_k)/h_k, so Ψ keeps the velocities it had.
    bias = held_torque_momentum_bias(tau, h, t, half_window) if torque_side else None
    for a in range(0, n, ROW_CHUNK):
        b = min(a + ROW_CHUNK, n)
        lo, hi = max(0, a - margin), min(n, b + margin)
        piece_t = None if t is None else t[lo:hi]
        kin = kinematics(
            "exact",
            q[lo:hi],
            h,
            model=model,
            t=piece_t,
            half_window=half_window,
            v=None if v is None else v[lo:hi],
        )
        raw = raw_rows("filtered_dynamic", "exact", q[lo:hi], tau[lo:hi], h, kin)
        assert kin.intervals is not None
        k = kin.intervals.k + lo
        keep = (k >= a) & (k < b)
        hk = h if t is None else (t[k + 1] - t[k])[:, None]
        y = raw.y if bias is None else raw.y + (bias[k + 1] - bias[k]) / hk
        parts.append((k[keep], y[keep], raw.parts[0][1][keep], kin.intervals.stuck[keep]))
        v_all[a:b] = kin.v[a - lo : b - lo]
    k, y, psi, stuck = (np.concatenate([p[i] for p in parts]) for i in range(4))
    return k, y, psi, stuck, v_all


class _TorqueOf:
    """``model`` with θ fixed, as a model of 1 + 2n parameters for :func:`_momentum_rows`: its
    column 0 holds P θ and R θ without the viscous and Coulomb terms (the model's ``momentum``
    and ``static_torque``: one torque per sample, not p regressor columns), the friction
    columns stay the model's own (the interval integrals write them exactly), so that
    Ψ' ``theta`` = Ψ θ with ``theta`` = [1, θ_friction]."""

    terms: tuple[str, ...] = ()

    def __init__(self, model: ArmDynamics, theta: np.ndarray) -> None:
        self._model = model
        friction = list(model.friction_columns)
        self._rigid = np.array(theta, float)  # θ without viscous and Coulomb friction
        self._rigid[friction] = 0.0
        self.theta = np.concatenate([[1.0], np.asarray(theta, float)[friction]])
        self.n_params = len(self.theta)
        self.friction_columns = tuple(range(1, self.n_params))

    def _columns(self, torque: np.ndarray) -> np.ndarray:
        out = np.zeros((*torque.shape, self.n_params))
        out[..., 0] = torque
        return out

    def momentum_regressor(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        return self._columns(self._model.momentum(self._rigid, q, dq))

    def static_regressor(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        return self._columns(self._model.static_torque(self._rigid, q, dq))


def model_torque_rows(
    rows: RecordingRows, theta: np.ndarray, offset: np.ndarray | None = None
) -> np.ndarray:
    """Ψ θ (K, n) of ``rows``' intervals before the filter F, with the encoder readings shifted
    by the constant ``offset`` (n,) (default none): the model's torque rows, built from its
    torques (:class:`_TorqueOf`) over the same intervals, velocities and time stamps as Ψ, not
    from Ψ's p columns (an n-joint arm's regressor is its costliest step). A constant shift
    leaves every velocity as it is: the recording's are used, not estimated again."""
    fixed = _TorqueOf(rows.model, np.asarray(theta, float)[: rows.model.n_params])
    args = (rows.h, rows.stamps, rows.half_window, fixed)
    if offset is None:
        q, v = rows.q, None
    else:
        q, v = rows.q + np.asarray(offset, float)[None, :], rows.v
    psi = _momentum_rows(q, rows.tau, *args, torque_side=False, v=v)[2]
    return psi @ fixed.theta


def rigid_torque_rows(
    rows: RecordingRows,
    theta: np.ndarray,
    joint: int | None = None,
    shifts: Sequence[float] = (),
    nodes: int = len(GL_NODES),
) -> np.ndarray:
    """The rigid bodies' part of Ψ θ (K, n) before F:
    [P(q_{k+1}, q̇_{k+1}) − P(q_k, q̇_k)]/h_k + Σ_g w_g R(q_g, q̇_g), the momentum balance of
    :func:`_momentum_rows` (Reyes & Kelly (1997) eq. (24) over each interval) on the rows' own
    samples, velocities and Gauss–Legendre nodes, with θ's friction left out (a constant shift
    of the readings leaves every velocity, hence the friction columns, as they are). The
    model's torques alone: the intervals' kinematics are not built again. With ``joint``:
    (S, K, n), the rows at the readings with that joint's shifted by each of ``shifts`` (S,)
    (the model's ``*_at_shifts``: what precedes the joint is built once). ``nodes``: the
    Gauss–Legendre nodes per interval on the same cubic Hermite path (Ψ's own: four; two are
    exact for cubics, an O(h⁴) difference, for rows only ever differenced with rows of the
    same rule)."""
    model = rows.model
    rigid = np.array(theta, float)[: model.n_params]
    rigid[list(model.friction_columns)] = 0.0
    k = rows.k
    at = np.union1d(
        k, k + 1
    )  # each sample's momentum once: the end of one interval, the next's start
    hk = rows.h if rows.stamps is None else np.diff(rows.stamps)[k][:, None]
    if nodes == len(GL_NODES):
        q_nodes, v_nodes, weights = rows.q_nodes, rows.v_nodes, GL_WEIGHTS
    else:
        s, weights = gauss_legendre_unit(nodes)
        q_nodes, v_nodes = hermite_nodes(rows.q, rows.v, k, hk, s)
    K, n = len(k), rows.q.shape[1]
    q_flat, v_flat = q_nodes.reshape(-1, n), v_nodes.reshape(-1, n)
    if joint is None:
        P = model.momentum(rigid, rows.q[at], rows.v[at])[None]
        R = model.static_torque(rigid, q_flat, v_flat)[None]
    else:
        P = model.momentum_at_shifts(rigid, rows.q[at], rows.v[at], joint, shifts)
        R = model.static_torque_at_shifts(rigid, q_flat, v_flat, joint, shifts)
    P0, P1 = P[:, np.searchsorted(at, k)], P[:, np.searchsorted(at, k + 1)]
    R = R.reshape(len(R), len(weights), K, n)
    out = (P1 - P0) / hk + np.tensordot(weights, R, axes=(0, 1))
    return out if joint is not None else out[0]


def row_weights(still: np.ndarray, h: float, window: int) -> np.ndarray:
    """Weights (K, n) of the filtered rows: 0 for a row whose window holds an interval that is
    ``still`` (K, n) or within STICK_GUARD_S of one, and for the first ``window`` − 1 rows
    (windows not yet full); 1 otherwise."""
    guarded = still.copy()
    for shift in range(1, max(1, round(STICK_GUARD_S / h)) + 1):
        guarded[:-shift] |= still[shift:]
        guarded[shift:] |= still[:-shift]
    weights = stick_weights(guarded, window - 1)
    weights[: window - 1] = 0.0
    return weights


def recording_rows(
    q: np.ndarray,
    tau: np.ndarray,
    h: float,
    window: int | None = None,
    t: np.ndarray | None = None,
    model: ArmDynamics = NINE_PARAMETERS,
) -> RecordingRows:
    """The nominal regression of one recording and its interval nodes (``window``: intervals
    of F, default from the data's noise, :func:`noise_model`). ``t``: the real sample times;
    when they are regular and the encoder fine, the rows are those of equal intervals h.
    ``model``: the nominal model whose columns Ψ holds (default the 9-parameter model)."""
    q, tau = np.asarray(q, float), np.asarray(tau, float)
    times = np.arange(len(q)) * h if t is None else np.asarray(t, float)
    noise = noise_model(q, times) if len(q) > 2 else None
    if window is None:
        window = noise.window if noise is not None else window_intervals(h)
    if len(q) < 4 * window:
        raise ValueError(f"need at least {4 * window} samples to diagnose, got {len(q)}")
    regular = noise is None or (noise.irregular_intervals == 0 and noise.half_window == 1)
    if regular:
        k, y_raw, psi_raw, _stuck, _v = _momentum_rows(q, tau, h, model=model)
        v = central_difference(q, h)
        # No encoder motion over the interval, or the velocity reverses in it: the joint may
        # stick for part of it.
        still = (q[k + 1] == q[k]) | (np.sign(v[k]) != np.sign(v[k + 1]))
        hk: float | np.ndarray = h
        stamps, half = None, 1
    else:
        assert noise is not None
        half = noise.half_window
        k, y_raw, psi_raw, _stuck, v = _momentum_rows(q, tau, h, times, half, model)
        # A coarse encoder stays on one count through a reversal: a stick only when the run
        # of unchanged counts outlasts that (hil.model.regressors.quantized_stick). A gap (a stall,
        # dropped samples) is left out like a stick: nothing is known inside it.
        dt = np.diff(times)
        still = quantized_stick(q, times)[k] | (np.sign(v[k]) != np.sign(v[k + 1]))
        still |= (dt[k] > GAP_FACTOR * h)[:, None]
        hk = dt[k][:, None]
        stamps = times
    weights = row_weights(still, h, window)
    q_nodes, v_nodes = hermite_nodes(q, v, k, hk, GL_NODES)
    return RecordingRows(
        moving_average(y_raw, window),
        moving_average(psi_raw, window),
        weights,
        q,
        tau,
        h,
        window,
        k,
        q_nodes,
        v_nodes,
        v,
        stamps,
        half,
        noise,
        model,
    )


def _filtered(rows: RecordingRows, raw: np.ndarray) -> np.ndarray:
    """F of per-interval averages ``raw`` (K, ...), as Ψ and y have."""
    return moving_average(raw, rows.window)


def _node_average(values: np.ndarray) -> np.ndarray:
    """(1/h)∫ over each interval by Gauss–Legendre on the nodes: (nodes, K, ...) → (K, ...)."""
    return np.tensordot(GL_WEIGHTS, values, axes=(0, 0))


def _on_joint(column: np.ndarray, joint: int, n_joints: int) -> np.ndarray:
    """(K, p) column(s) of one joint's row → (K, n, p) with zeros in the other rows."""
    out = np.zeros((column.shape[0], n_joints, column.shape[1]))
    out[:, joint, :] = column
    return out


def offset_column(rows: RecordingRows, joint: int) -> np.ndarray:
    """Torque offset c on ``joint`` (τ_a = τ + c): X = −F[1]. A direction-dependent Coulomb
    friction gives the same column on every row the model uses (rows with the joint stuck carry
    weight 0): F⁺ = θ_fc − c, F⁻ = θ_fc + c."""
    return _on_joint(-_filtered(rows, np.ones((rows.rows, 1))), joint, rows.n_joints)


def drag_column(rows: RecordingRows, joint: int) -> np.ndarray:
    """Velocity-squared drag c q̇|q̇| on ``joint`` (fluid or fan drag, τ = Ψθ + c q̇|q̇|):
    X = F[q̇|q̇|], the interval mean at the Gauss–Legendre nodes like Ψ's viscous column."""
    v = rows.v_nodes[:, :, joint]
    return _on_joint(_filtered(rows, _node_average(v * np.abs(v))[:, None]), joint, rows.n_joints)


def gain_column(rows: RecordingRows, joint: int) -> np.ndarray:
    """Torque gain error r on ``joint`` (τ_a = (1 + r) τ): X = −F[τ_j] = −y_j."""
    return _on_joint(-rows.y[:, joint : joint + 1], joint, rows.n_joints)


def cogging_columns(rows: RecordingRows, joint: int, periods_per_rev: float) -> np.ndarray:
    """Cogging A sin(n q + φ) added to the shaft torque: X = −F[sin n q, cos n q] (K, 2, 2)."""
    return _on_joint(
        next(cogging_column_chunks(rows, joint, [periods_per_rev], 1))[:, 0], joint, rows.n_joints
    )


def cogging_column_chunks(
    rows: RecordingRows, joint: int, periods_per_rev: list[float] | tuple[float, ...], per: int
) -> Iterator[np.ndarray]:
    """The cogging columns of many periods on ``joint``'s rows, ``per`` periods at a time:
    (K, ≤per, 2) arrays −F[sin n q, cos n q]. e^{i n q} at the nodes by one complex power and
    then a rotation per step of n, carried from chunk to chunk (no sine per variant), one node
    average per period and one filter pass per chunk: memory O(K·per), not O(K·V)."""
    q = rows.q_nodes[:, :, joint]  # (nodes, K)
    n = np.asarray(periods_per_rev, float)
    z = np.exp(1j * n[0] * q)
    once = np.exp(1j * q)
    mean = np.empty(q.shape[1], complex)  # the node average of e^{i n q}, one period's
    sin_cos = mean.view(float).reshape(-1, 2)[:, ::-1]  # its (imag, real): one copy per period
    for lo in range(0, len(n), per):
        hi = min(lo + per, len(n))
        raw = np.empty((q.shape[1], hi - lo, 2))  # (K, chunk, sin|cos): node averages
        for i in range(lo, hi):
            if i:
                step = n[i] - n[i - 1]
                z *= once if step == 1 else np.exp(1j * step * q)
            np.matmul(GL_WEIGHTS, z, out=mean)
            raw[:, i - lo] = sin_cos
        # F (as _filtered), its sums taken in raw's place: one chunk-sized array fewer at the
        # selection's peak
        out = moving_average(raw, rows.window, overwrite_input=True)
        del raw  # not held while the caller sums the chunk
        yield np.negative(out, out=out)


def stribeck_shape(v: np.ndarray, velocity_rad_s: float, exponent: float = 2.0) -> np.ndarray:
    """sgn(q̇) exp(−(|q̇|/v_s)^δ): the Stribeck excess of friction per Nm of breakaway excess."""
    return np.sign(v) * np.exp(-((np.abs(v) / velocity_rad_s) ** exponent))


def stribeck_column(
    rows: RecordingRows, joint: int, velocity_rad_s: float, exponent: float = 2.0
) -> np.ndarray:
    """Stribeck friction ΔF sgn(q̇) exp(−(|q̇|/v_s)^δ) on ``joint``: X = +F[shape] (K, 2, 1).

    Each interval's mean of the shape, (1/h_k)∫ sgn(q̇) exp(−(|q̇|/v_s)^δ) dt, is taken on the
    same cubic Hermite q̇ as the Coulomb column, cut where q̇ changes sign
    (:func:`hil.model.regressors.interval_mean_across_reversals`): in an interval holding a
    velocity reversal the shape jumps from +1 to −1, which Gauss–Legendre nodes across the
    jump would integrate with an error of up to the whole interval's excess."""
    shape = lambda v: stribeck_shape(v, velocity_rad_s, exponent)  # noqa: E731
    mean = _node_average(shape(rows.v_nodes[:, :, joint]))
    k = rows.k
    hk = rows.h if rows.stamps is None else np.diff(rows.stamps)[k]
    ends = (rows.q[k, joint], rows.q[k + 1, joint], rows.v[k, joint], rows.v[k + 1, joint])
    cut = has_velocity_reversal(*ends, hk)
    if np.any(cut):  # the rest are smooth: the 4 nodes of v_nodes, as every other column
        mean[cut] = interval_mean_across_reversals(
            shape, *(e[cut] for e in ends), hk if np.ndim(hk) == 0 else hk[cut]
        )
    return _on_joint(_filtered(rows, mean[:, None]), joint, rows.n_joints)


def lagged_torque_rows(rows: RecordingRows, time_constant_s: float) -> np.ndarray:
    """F[τ_a] for τ_a the first-order lag of the held torque (exact under zero-order hold), (K, 2).

    The lag state x_k at t_k obeys x_{k+1} = e^{−h/T} x_k + (1 − e^{−h/T}) τ_k and the average of
    τ_a over [t_k, t_{k+1}) is τ_k + (x_k − τ_k) (T/h)(1 − e^{−h/T}) (the virtual robot's
    ``amplifier_lag_step``); x_0 = τ_0 (the recording starts settled). On real stamps each
    interval has its own h_k."""
    if time_constant_s <= 0:
        return rows.y.copy()
    means = lagged_torque_means(rows.tau, rows.h, time_constant_s, rows.stamps)
    return _filtered(rows, means[rows.k])


def lagged_torque_means(
    tau: np.ndarray, h: float, time_constant_s: float, t: np.ndarray | None = None
) -> np.ndarray:
    """The mean over each interval [t_k, t_{k+1}) of the first-order lag of the held torque
    ``tau`` (N, n), exact under zero-order hold (:func:`lagged_torque_rows`), (N, n). ``t``: the
    real sample times, each interval its own h_k (default every interval ``h``)."""
    tau = np.asarray(tau, float)
    if t is None:
        dt = np.full(len(tau), float(h))
    else:
        dt = np.diff(np.asarray(t, float))
        dt = np.append(dt, dt[-1:])  # the last sample starts no interval: any h serves
    decay = np.exp(-dt / time_constant_s)
    x = first_order_states(decay, tau)
    return tau + (x - tau) * ((time_constant_s / dt) * (1.0 - decay))[:, None]


def first_order_states(
    decay: np.ndarray, tau: np.ndarray, x0: np.ndarray | None = None
) -> np.ndarray:
    """x_0 = ``x0`` (default τ_0), x_{k+1} = a_k x_k + (1 − a_k) τ_k for a_k = ``decay[k]``,
    (N, n): a first-order lag's states over equal or unequal intervals. The steps compose as
    affine maps, (a, b)∘(a', b') = (a a', a b' + b), so a prefix scan (Hillis & Steele) gives
    every x_k = A_k x_0 + B_k in log₂ N passes; A only shrinks and B stays within the torques'
    range (no overflow, whatever h_k/T)."""
    A = decay[:-1].copy()
    B = (1.0 - A)[:, None] * tau[:-1]
    d = 1
    while d < len(A):
        B[d:] = A[d:, None] * B[:-d] + B[d:]
        A[d:] = A[d:] * A[:-d]
        d *= 2
    x = np.empty_like(tau)
    x[0] = tau[0] if x0 is None else x0
    x[1:] = A[:, None] * x[0] + B
    return x


def delayed_torque_rows(rows: RecordingRows, delay_s: float) -> np.ndarray:
    """F[τ_a] for τ_a(t) = τ(t − d) of the held torque (exact under zero-order hold), (K, 2):
    with d = (m + f) h, the average over [t_k, t_{k+1}) is (1 − f) τ_{k−m} + f τ_{k−m−1}. On
    real stamps, the held torque's integral over [t_k − d, t_{k+1} − d) over h_k."""
    return _filtered(rows, delayed_torque_means(rows.tau, rows.h, delay_s, rows.stamps)[rows.k])


def delayed_torque_means(
    tau: np.ndarray, h: float, delay_s: float, t: np.ndarray | None = None
) -> np.ndarray:
    """The mean over each interval of the held torque ``tau`` (N, n) delayed by ``delay_s``
    (:func:`delayed_torque_rows`), (N, n). ``t``: the real sample times (default every
    interval ``h``); before the first sample the torque is τ_0."""
    if t is None:
        m = int(np.floor(delay_s / h))
        f = delay_s / h - m
        idx = np.arange(len(tau))
        a = tau[np.clip(idx - m, 0, None)]
        b = tau[np.clip(idx - m - 1, 0, None)]
        return (1.0 - f) * a + f * b
    tau, t = np.asarray(tau, float), np.asarray(t, float)
    dt = np.diff(t)
    # the held torque's integral from t_0, piecewise linear between the stamps
    held = np.vstack([np.zeros((1, tau.shape[1])), np.cumsum(tau[:-1] * dt[:, None], axis=0)])

    def integral(s: np.ndarray) -> np.ndarray:
        out = np.column_stack([np.interp(s, t, held[:, j]) for j in range(tau.shape[1])])
        before = s < t[0]
        out[before] = (s[before] - t[0])[:, None] * tau[0]
        return out

    means = (integral(t[1:] - delay_s) - integral(t[:-1] - delay_s)) / dt[:, None]
    return np.vstack([means, means[-1:]])  # the last sample starts no interval


# Probe lags for the rate columns: F[τ − τ_a]/T → F[τ̇] as T → 0; a second, longer probe spans
# the second-order term (T² τ̈), so a lag of a few ms leaves no residual for another candidate
# to pick up while the exact lag or delay is decided later.
RATE_PROBES_S = (1e-4, 4e-3)


def torque_rate_column(rows: RecordingRows, joint: int) -> np.ndarray:
    """Columns of a lag or delay on ``joint``: X = F[τ − τ_a(T_i)]/T_i for the two probe lags
    (K, 2, 2); for a small lag T, β₁ + β₂ ≈ T (both columns tend to F[τ̇])."""
    cols = [(rows.y - lagged_torque_rows(rows, T)) / T for T in RATE_PROBES_S]
    return _on_joint(np.stack([c[:, joint] for c in cols], axis=-1), joint, rows.n_joints)


def angle_offset_column(
    rows: RecordingRows, joint: int, theta: np.ndarray, step_rad: float = 1e-4
) -> np.ndarray:
    """Encoder zero offset δ on ``joint`` (reading = true angle + δ): the model holds at q − δ,
    Ψ(q − δ e_j) θ ≈ Ψ(q) θ − δ ∂(Ψθ)/∂q_j, so X = −∂(Ψθ)/∂q_j (central difference), (K, 2, 1).
    A constant shift leaves every velocity unchanged, so the rows are rebuilt exactly."""
    shift = np.zeros(rows.q.shape[1])
    shift[joint] = step_rad
    # Ψθ before the filter (F is linear): (K, 2), not two (K, 2, 9) filtered copies
    plus = model_torque_rows(rows, theta, shift)
    minus = model_torque_rows(rows, theta, -shift)
    return -moving_average((plus - minus) / (2 * step_rad), rows.window)[:, :, None]


def model_term_columns(rows: RecordingRows, term: str) -> np.ndarray:
    """A model term the nominal model lacks (``rotor_inertia``, ``com_offset``,
    :mod:`hil.model.closed_form`): its columns of Ψ, i.e. the regressor columns
    ``ArmModel(rows.model.terms + (term,))`` appends, over the same intervals and through the
    same filter F (the terms are linear in their parameters), (K, 2, width)."""
    extended = rows.model.with_terms((term,))
    args = (rows.h, rows.stamps, rows.half_window, extended)
    psi = _momentum_rows(rows.q, rows.tau, *args, torque_side=False)[2]
    return moving_average(psi[:, :, extended.term_columns(term)], rows.window)
