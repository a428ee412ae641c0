"""Mismatch diagnosis: find the physics the nominal model (the 9-parameter model of Reyes & Kelly
(1997), or ``ArmModel(profile.terms)``) left out.

The nominal model is the ``exact`` filtered dynamic regression (eq. (24) over sample intervals,
:mod:`hil.model.regressors`) of an :class:`hil.model.closed_form.ArmModel`; the model terms it
lacks (rotor inertia, centre-of-mass offset) are candidates like the effects. Every candidate
of the vocabulary (:mod:`hil.diagnose.columns`) adds columns to it; a candidate is accepted when
it lowers the held-out error of its joint block after block (:mod:`hil.diagnose.stats`),
greedily, strongest first, each later candidate tested on top of those already accepted. Two
candidates that each explain the same residual and neither adds anything on top of the other are
*confounded*: both are reported, with the experiment that would separate them. Pure computation
over arrays; reading files, plots and the CLI live in :mod:`hil.diagnose.cli`.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers.process import release_freed_heap
from hil.diagnose.columns import (
    RecordingRows,
    angle_offset_column,
    cogging_column_chunks,
    cogging_columns,
    gain_column,
    model_term_columns,
    offset_column,
    recording_rows,
    stribeck_column,
    torque_rate_column,
)
from hil.diagnose.stats import (
    BlockStats,
    Columns,
    CrossValidation,
    Evidence,
    ScaledRows,
    block_index,
    block_spans,
    block_stats,
    cross_validate,
    evidence,
    extend_stats_many,
    extended_stats,
    target_block_sums,
)
from hil.model.closed_form import TERMS, ArmModel
from hil.model.estimators import require_finite
from hil.model.protocol import ArmDynamics

VOCABULARY = (
    "coulomb_asymmetry",
    "torque_offset",
    "stribeck",
    "cogging",
    "actuator_lag",
    "transport_delay",
    "angle_offset",
    "torque_gain",
    *TERMS,  # rotor_inertia, com_offset: model terms the nominal model lacks (closed_form)
)
# Decision thresholds (docs/diagnosis.md, "Deciding"): a candidate must lower the held-out error
# of its joint by at least MIN_REDUCTION (relative) and in more blocks than chance allows (sign
# test at FAMILY_ALPHA over the number of candidates). On null recordings (no concealed effect)
# the largest values seen were far below both; see tests/test_diagnose.py.
MIN_REDUCTION = 0.01
FAMILY_ALPHA = 1e-3  # sign test, Bonferroni over the candidates tested in a round
MAX_ROUNDS = 6
# Effects smaller than these are below what matters for this arm (and within what the model's own
# approximations leave behind); a term must also have the physical sign (a lag, not a lead).
PRACTICAL_FLOOR = {
    "offset": 0.02,  # Nm
    "gain": 0.005,  # relative
    "cogging": 0.01,  # Nm amplitude
    "stribeck": 0.03,  # Nm breakaway excess, > 0
    "rate": 1e-4,  # s, > 0
    "angle": 3e-4,  # rad
}
POSITIVE_ONLY = ("stribeck", "rate", "rotor_inertia")
# The model terms (hil.model.closed_form.TERMS) are floored relative to the rigid-body
# parameters they join, since arms differ in size by orders of magnitude: the rotor term against
# θ3 (M22's rigid part), the centre-of-mass offset's θ2⊥ against θ2 and its gravity pair
# (θ4⊥, θ5⊥) against (θ4, θ5) (its largest ratio counts).
RELATIVE_FLOOR = 0.01
# Blocks: about BLOCKS_WANTED per diagnosis, each between these lengths (long against the 20 ms
# correlation of the filtered residual, short enough for a sign test to have power).
BLOCKS_WANTED = 40
BLOCK_SECONDS = (0.15, 0.5)
# ... and at most this many: a long recording's blocks grow beyond BLOCK_SECONDS[1] instead
# (every block is a leave-one-out fit of every variant of every candidate; 400 nearly
# independent blocks already give the sign test far more power than FAMILY_ALPHA asks for).
MAX_BLOCKS = 400
COGGING_PERIODS = np.arange(3, 401)
STRIBECK_VELOCITIES = np.geomspace(0.02, 0.6, 16)
LAG_GRID_S = np.geomspace(5e-5, 0.03, 28)  # lag and delay search, then refined locally


@dataclass(frozen=True)
class Candidate:
    """One term of the vocabulary on one joint (0 or 1): ``variants`` are the values of its
    nonlinear parameter (one None when it has none); ``columns(rows, variant)`` its X."""

    kind: str  # offset | gain | cogging | stribeck | rate | angle | rotor_inertia | com_offset
    joint: int
    variants: tuple[Any, ...]
    columns: Callable[[RecordingRows, Any], np.ndarray]
    # X of many variants on the candidate's joint, ``per`` at a time ((K, ≤per, width) arrays),
    # when that is cheaper than one by one
    chunks: Callable[[RecordingRows, tuple[Any, ...], int], Iterator[np.ndarray]] | None = None
    # the joints whose rows the columns reach, when not :func:`_joints`' 2-DOF rule (an angle
    # offset on an n-joint arm moves the gravity and inertia torques of every joint)
    acts_on: tuple[int, ...] | None = None

    @property
    def key(self) -> str:
        # a model term is one term of the arm's model, not one joint's (it may act on both)
        return self.kind if self.kind in TERMS else f"{self.kind}:{self.joint + 1}"


def cogging_periods(angle_range_rad: float) -> tuple[int, ...]:
    """Periods per revolution worth testing on a joint that swept ``angle_range_rad``: at least
    two whole periods inside the range (fewer is a smooth function of q that gravity, an angle
    offset or a torque offset also make), up to COGGING_PERIODS' top."""
    lowest = max(int(COGGING_PERIODS[0]), int(np.ceil(2 * 2 * np.pi / max(angle_range_rad, 1e-9))))
    return tuple(int(n) for n in COGGING_PERIODS if n >= lowest)


# A Stribeck velocity v_s is tried only where this many usable rows slide slower than 2 v_s:
# fewer, and a handful of rows next to a stick or reversal would decide the fit alone.
STRIBECK_MIN_ROWS = 200


def stribeck_velocities(speeds: np.ndarray | None) -> tuple[float, ...]:
    """The Stribeck velocities the data can support (``speeds``: |q̇| of the usable rows)."""
    if speeds is None:
        return tuple(float(v) for v in STRIBECK_VELOCITIES)
    return tuple(
        float(v) for v in STRIBECK_VELOCITIES if np.sum(speeds < 2 * v) >= STRIBECK_MIN_ROWS
    )


def usable_speeds(prob: Problem) -> list[np.ndarray]:
    """|q̇| (interval means) of the rows the model uses, per joint."""
    v = np.abs(prob.v_mean)
    return [v[prob.w[:, j] > 0, j] for j in range(prob.n_joints)]


# The joint whose rows a model term's columns reach first (its key names no joint): the rotor
# term is M22's (joint 2 row only); the centre-of-mass offset acts on both (see _joints).
MODEL_TERM_JOINT = {"rotor_inertia": 1, "com_offset": 0}


def model_term_candidates(model: ArmDynamics) -> list[Candidate]:
    """The model terms ``model`` lacks, as candidates: their columns are the regressor columns
    the model with the term appends (:func:`hil.diagnose.columns.model_term_columns`)."""
    return [
        Candidate(
            term, MODEL_TERM_JOINT[term], (None,), lambda r, _v, t=term: model_term_columns(r, t)
        )
        for term in model.missing_terms  # none for a URDF model (its refused_terms say why)
    ]


def candidates(
    theta: np.ndarray,
    angle_range_rad: Sequence[float] = (np.pi, np.pi),
    speeds: Sequence[np.ndarray] | None = None,
    model: ArmDynamics | None = None,
) -> list[Candidate]:
    """The candidate library, both joints. ``speeds``: per joint, |q̇| of the usable rows
    (limits the Stribeck velocities tried; without it all are). ``model``: the nominal model
    (default the 9-parameter one); the model terms it lacks are candidates too, after the
    others."""
    out: list[Candidate] = []
    model = ArmModel(()) if model is None else model
    refused = model.refused_terms
    for j in range(model.n_joints):
        stribeck = stribeck_velocities(None if speeds is None else speeds[j])
        if stribeck:
            out.append(
                Candidate("stribeck", j, stribeck, lambda r, v, j=j: stribeck_column(r, j, v))
            )
        if "offset" not in refused:
            out.append(Candidate("offset", j, (None,), lambda r, _v, j=j: offset_column(r, j)))
        out += [
            Candidate("gain", j, (None,), lambda r, _v, j=j: gain_column(r, j)),
            Candidate(
                "cogging",
                j,
                cogging_periods(angle_range_rad[j]),
                lambda r, n, j=j: cogging_columns(r, j, n),
                lambda r, ns, per, j=j: cogging_column_chunks(r, j, ns, per),
            ),
            Candidate("rate", j, (None,), lambda r, _v, j=j: torque_rate_column(r, j)),
            Candidate(
                "angle",
                j,
                (None,),
                lambda r, _v, j=j, th=theta: angle_offset_column(r, j, th),
                acts_on=None if model.closed_form else tuple(range(model.n_joints)),
            ),
        ]
    return out + model_term_candidates(model)


def term_width(cand: Candidate) -> int:
    """Number of coefficients a candidate adds."""
    if cand.kind in TERMS:
        return ArmModel((cand.kind,)).n_params - ArmModel(()).n_params
    return 2 if cand.kind in ("cogging", "rate") else 1


@dataclass
class Problem:
    """The stacked regression of all recordings. ``y``, ``Psi`` and candidate columns are served
    scaled to unit noise per joint (``scale``, Nm), re-estimated as terms are accepted so that a
    joint whose residual was mostly model error is not later treated as noise-free."""

    rows: list[RecordingRows]
    y_raw: np.ndarray  # (K, 2) Nm
    Psi_raw: np.ndarray  # (K, 2, p): p = model.n_params
    w: np.ndarray  # (K, 2)
    scale: np.ndarray  # (2,) noise scale per joint [Nm]
    blocks: np.ndarray  # (K,)
    cache: dict[tuple[str, int], np.ndarray] = field(default_factory=dict)
    grids: dict[str, GridSums] = field(default_factory=dict)
    # (key, variant) of the one-variant candidates: summed against a grid when it is first built
    anticipated: list[tuple[str, int]] = field(default_factory=list)
    # Block statistics of designs Ψ + term columns, by the scale and the terms' keys: every
    # candidate of a round is tested on top of the same design, whose statistics are then summed
    # once, not once per candidate. ``_served`` tells which served column an array is (by id,
    # checked through a weak reference: a column may be dropped by its user and its id reused).
    _design_stats: dict[tuple[Any, ...], BlockStats] = field(default_factory=dict, repr=False)
    _served: dict[int, tuple[weakref.ref, tuple[str, int]]] = field(
        default_factory=dict, repr=False
    )

    @property
    def model(self) -> ArmDynamics:
        """The nominal model whose columns Ψ holds (every recording's rows use the same)."""
        return self.rows[0].model

    @property
    def n_params(self) -> int:
        return self.Psi_raw.shape[-1]

    @property
    def n_joints(self) -> int:
        return self.y_raw.shape[1]

    @property
    def y(self) -> np.ndarray:
        return self.y_raw / self.scale

    @property
    def Psi(self) -> np.ndarray:
        return self.Psi_raw / self.scale[None, :, None]

    def _served_key(self, x: np.ndarray) -> tuple[str, int] | None:
        entry = self._served.get(id(x))
        return entry[1] if entry is not None and entry[0]() is x else None

    def joint_columns(self, extra: Sequence[np.ndarray]) -> Callable[[int], Columns]:
        """Joint j's columns of the design Ψ + ``extra`` (scaled), (K, p) as groups that are
        joined a block at a time (:func:`hil.diagnose.stats.target_block_sums`): not the whole
        (K, 2, 9) scaled Ψ for one joint's rows, nor a joined (K, p) copy."""

        def columns(j: int) -> Columns:
            return [ScaledRows(self.Psi_raw[:, j, :], self.scale[j]), *(x[:, j, :] for x in extra)]

        return columns

    def design_groups(self, extra: Sequence[np.ndarray]) -> list[np.ndarray | ScaledRows]:
        """The design Ψ + ``extra`` (scaled rows) as its column groups, Ψ scaled a block at a
        time when read: :func:`block_stats` takes it without a joined (K, 2, p) copy."""
        return [ScaledRows(self.Psi_raw, self.scale), *extra]

    def design_stats(self, extra: Sequence[np.ndarray]) -> BlockStats:
        """:func:`block_stats` of Ψ + ``extra`` (scaled rows), kept for the scale when every
        column in ``extra`` is one this problem served (:meth:`column`)."""
        keys = [self._served_key(x) for x in extra]
        key = (self.scale.tobytes(), *keys) if None not in keys else None
        if key is not None and key in self._design_stats:
            return self._design_stats[key]
        if key is not None and any(k[0] != key[0] for k in self._design_stats):
            self._design_stats = {}  # the scale changed: those designs are not asked for again
        stats = block_stats(self.design_groups(extra), self.y, self.w, self.blocks)
        if key is not None:
            self._design_stats[key] = stats
        return stats

    @property
    def v_mean(self) -> np.ndarray:
        """Mean velocity over each row's interval, all recordings (K, 2)."""
        return np.concatenate([r.v_mean for r in self.rows])

    @property
    def q_mean(self) -> np.ndarray:
        """Mean position over each row's interval, all recordings (K, 2)."""
        return np.concatenate([r.q_mean for r in self.rows])

    def _raw(self, cand: Candidate, index: int) -> np.ndarray:
        return np.concatenate([cand.columns(r, cand.variants[index]) for r in self.rows])

    def column(self, cand: Candidate, index: int) -> np.ndarray:
        """X of one variant (by index), stacked over recordings and scaled like the rows. Kept
        for the next call: the terms in the model are asked for again every round."""
        key = (cand.key, index)
        if key not in self.cache:
            self.cache[key] = self._raw(cand, index)
        scaled = self.cache[key] / self.scale[None, :, None]
        scaled.flags.writeable = False  # its block statistics may be kept (design_stats)
        if len(self._served) > 256:  # forget the columns no one holds any more
            self._served = {i: e for i, e in self._served.items() if e[0]() is not None}
        self._served[id(scaled)] = (weakref.ref(scaled), key)
        return scaled

    def chosen(self, a: Accepted) -> np.ndarray:
        """X of an accepted term, at the variant it was accepted with."""
        return self.column(a.cand, a.cand.variants.index(a.variant))

    def keep_only(self, keys: Sequence[tuple[str, int]]) -> None:
        """The selection is over: drop the grids' sums and every column but those of ``keys``
        (the accepted terms and their rivals); a column asked for again is rebuilt, identical.
        On a long recording they are hundreds of megabytes the refit and the simulations need
        room for."""
        self.grids.clear()
        self.cache = {k: v for k, v in self.cache.items() if k in keys}
        self._design_stats.clear()

    def forget(self, key: tuple[str, int]) -> None:
        """A term's column is rebuilt (an angle offset relinearised): drop the old one and every
        grid's sums against it."""
        self.cache.pop(key, None)
        self._design_stats = {k: v for k, v in self._design_stats.items() if key not in k}
        for sums in self.grids.values():
            sums.terms.pop(key, None)

    def grid_stats(
        self, cand: Candidate, term_keys: Sequence[tuple[str, int]], base: BlockStats
    ) -> Iterator[BlockStats]:
        """Block statistics of [Z, X_v] for every variant v of a one-joint candidate, a chunk of
        variants at a time, Z being Ψ and the columns of the terms ``term_keys`` (``base``: the
        statistics of Z). Assembled from the candidate's raw sums (:class:`GridSums`, built once
        and extended when a new term joins): rows scaled by 1/s_j scale every sum of joint j by
        1/s_j², so a new noise scale costs nothing."""
        j = cand.joint
        sums = self._grid_sums(cand, term_keys)
        n_var, n_blocks, p, q = len(cand.variants), base.G.shape[0], base.G.shape[-1], sums.q
        per = max(1, int(CHUNK_BYTES // (8 * n_blocks * 2 * (p + q) ** 2 * 3)))
        s2 = self.scale[j] ** 2
        for lo in range(0, n_var, per):
            hi = min(lo + per, n_var)
            cross = np.zeros((hi - lo, n_blocks, self.n_joints, p, q))
            parts = [sums.PX[lo:hi], *(sums.terms[k][lo:hi] for k in term_keys)]
            cross[:, :, j] = np.concatenate(parts, axis=2) / s2
            xx = np.zeros((hi - lo, n_blocks, self.n_joints, q, q))
            xx[:, :, j] = sums.XX[lo:hi] / s2
            rx = np.zeros((hi - lo, n_blocks, self.n_joints, q))
            rx[:, :, j] = sums.Xy[lo:hi] / s2
            yield extended_stats(base, cross, xx, rx)

    def _grid_sums(self, cand: Candidate, term_keys: Sequence[tuple[str, int]]) -> GridSums:
        """The raw sums of a candidate's variants against Ψ, y and the terms ``term_keys``;
        columns are built only for what is not summed yet."""
        sums = self.grids.get(cand.key)
        j = cand.joint
        n_var = len(cand.variants)
        missing = [k for k in term_keys if sums is None or k not in sums.terms]
        if sums is not None:
            for k in [k for k in missing if not np.any(self.cache[k][:, j])]:
                # a term on the other joint's rows only: nothing to sum
                sums.terms[k] = np.zeros((n_var, sums.PX.shape[1], self.cache[k].shape[-1], sums.q))
                missing.remove(k)
            if not missing:
                return sums
        else:  # the terms likely to join later too, so that their arrival costs no rebuild
            missing += [
                k
                for k in self.anticipated
                if k not in missing and k in self.cache and np.any(self.cache[k][:, j])
            ]
        U = [self.cache[k][:, j, :] for k in missing]  # (K, width) raw, on the joint's rows
        if sums is None:
            U = [self.Psi_raw[:, j, :], *U]
        # the columns and y, joined a block at a time: joined once for all the grid's chunks
        # they would save a third of a cogging chunk's block sums, but the (K, m + 1) copy
        # (90 MB at 600,000 rows) lifted a 10-minute diagnosis's peak beyond 1 GB
        Uy = [*U, self.y_raw[:, j : j + 1]]
        w, spans = self.w[:, j], block_spans(self.blocks)
        n_blocks, q = len(spans), term_width(cand)
        # where each group of U's columns goes: Ψ's to a new grid's PX, a term's to its own
        widths = [u.shape[1] for u in U]
        fresh = sums is None
        if sums is None:
            p = self.n_params
            sums = GridSums(
                np.empty((n_var, n_blocks, p, q)),
                np.empty((n_var, n_blocks, q, q)),
                np.empty((n_var, n_blocks, q)),
                q,
            )
        for k in missing:
            sums.terms[k] = np.empty((n_var, n_blocks, self.cache[k].shape[-1], q))
        dest = ([sums.PX] if fresh else []) + [sums.terms[k] for k in missing]
        edges = np.cumsum([0, *widths])
        lo = 0
        for X in self._grid_columns(cand):
            uyx, xx = target_block_sums(Uy, X, w, spans)  # (B, m + 1, n·q), (B, n, q, q)
            hi = lo + X.shape[1]
            uyx = uyx.reshape(n_blocks, -1, hi - lo, q).transpose(2, 0, 1, 3)  # (n, B, m + 1, q)
            for out, a, b in zip(dest, edges[:-1], edges[1:], strict=True):
                out[lo:hi] = uyx[:, :, a:b]
            if fresh:
                sums.XX[lo:hi] = xx.transpose(1, 0, 2, 3)
                sums.Xy[lo:hi] = uyx[:, :, -1]
            lo = hi
            del X  # not held while the next chunk is built
        assert lo == n_var
        if fresh:
            self.grids[cand.key] = sums
        release_freed_heap()  # the chunks' columns and working arrays (drivers.process)
        return sums

    def _grid_columns(self, cand: Candidate) -> Iterator[np.ndarray]:
        """Raw X of every variant on the candidate's joint, (K, ≤per, width) chunks of at most
        CHUNK_BYTES: a 400-period cogging grid over a long recording would not fit at once."""
        j, width = cand.joint, term_width(cand)
        # per variant and row: its columns, and what they are built from (the unfiltered node
        # averages of a cogging chunk); the chunk is weighted a block at a time when summed
        per_row = 8 * width * 2
        per = max(1, int(CHUNK_BYTES // (per_row * max(len(self.y_raw), 1))))
        if cand.chunks is not None:
            streams = [cand.chunks(r, cand.variants, per) for r in self.rows]
            if len(streams) == 1:  # one recording: its chunks, not a copy of each
                yield from streams[0]
                return
            for pieces in zip(*streams, strict=True):
                yield np.concatenate(pieces)
            return
        for lo in range(0, len(cand.variants), per):
            hi = min(lo + per, len(cand.variants))
            yield np.stack([self._raw(cand, i)[:, j] for i in range(lo, hi)], axis=1)


@dataclass
class GridSums:
    """Raw (unscaled) per-block sums of a one-joint candidate's variants X_v over its joint's
    rows: Σ w Ψᵀ X_v (V, B, 9, q), Σ w X_vᵀ X_v (V, B, q, q), Σ w X_vᵀ y (V, B, q), and against
    each term's columns E, Σ w Eᵀ X_v (V, B, width, q), by the term's (key, variant index)."""

    PX: np.ndarray
    XX: np.ndarray
    Xy: np.ndarray
    q: int
    terms: dict[tuple[str, int], np.ndarray] = field(default_factory=dict)


# Memory for one chunk of a candidate's variants: its columns, or its statistics (bytes).
CHUNK_BYTES = 64e6


def _stack(rows: Sequence[RecordingRows]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if len(rows) == 1:  # one recording: its arrays, not a second copy of them
        return rows[0].y, rows[0].Psi, rows[0].weights
    y = np.concatenate([r.y for r in rows])
    Psi = np.concatenate([r.Psi for r in rows])
    w = np.concatenate([r.weights for r in rows])
    return y, Psi, w


def fit_theta(
    Psi: np.ndarray, y: np.ndarray, w: np.ndarray, overwrite_design: bool = False
) -> np.ndarray:
    """Weighted least squares over both joints' rows. ``overwrite_design``: weight ``Psi`` in
    place (the caller's throw-away design; on a long recording one copy fewer of it)."""
    sw = np.sqrt(w)[..., None]
    A = (np.multiply(Psi, sw, out=Psi) if overwrite_design else Psi * sw).reshape(-1, Psi.shape[-1])
    b = (y * sw[..., 0]).reshape(-1)
    require_finite(A, "diagnosis fit rows")
    require_finite(b, "diagnosis fit torques")
    return np.linalg.lstsq(A, b, rcond=None)[0]


def fit_theta_at(
    Z: np.ndarray,
    y: np.ndarray,
    w: np.ndarray,
    fixed: np.ndarray,
    overwrite_design: bool = False,
) -> np.ndarray:
    """:func:`fit_theta` with the first ``len(fixed)`` parameters held at ``fixed`` and the
    rest fitted to what they leave of ``y``: a torque gain read with the rigid-body
    parameters at the reference (docs/diagnosis.md 4, 4a). Returns all of them."""
    n = len(fixed)
    rest = y - Z[:, :, :n] @ fixed
    return np.concatenate([fixed, fit_theta(Z[:, :, n:], rest, w, overwrite_design)])


def robust_scale(residual: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Per-joint noise scale: 1.4826 · median absolute residual of the usable rows (1 Nm for a
    joint without any: its rows carry no weight, so the scale only has to be finite)."""
    out = np.ones(residual.shape[1])
    for j in range(residual.shape[1]):
        used = residual[w[:, j] > 0, j]
        if len(used):
            out[j] = 1.4826 * np.median(np.abs(used)) + 1e-12
    return out


class DiagnosisError(ValueError):
    """The recordings cannot be diagnosed (one line, naming the reason)."""


# A joint needs this many usable rows (moving, not stuck) before anything about it is tested;
# fewer, and the blocked cross-validation has next to nothing to hold out.
MIN_USABLE_ROWS = 200


def check_recording(name: str, t: np.ndarray, q: np.ndarray, tau: np.ndarray) -> None:
    """Refuse what no diagnosis can use, with the row (CSV line) at fault: non-finite values,
    time stamps that do not increase, too few rows. The reader rejects most of these already;
    this guards arrays from anywhere."""
    data = np.column_stack([t, q, tau])
    if len(data) < 3:
        raise DiagnosisError(f"{name}: {len(data)} rows, too few to diagnose")
    bad = np.flatnonzero(~np.isfinite(data).all(axis=1))
    if len(bad):
        raise DiagnosisError(f"{name}: NaN or inf at line {bad[0] + 2}")
    step = np.flatnonzero(np.diff(t) <= 0)
    if len(step):
        raise DiagnosisError(
            f"{name}: time stamps do not increase at line {step[0] + 3} "
            f"(t = {t[step[0] + 1]:g} after {t[step[0]]:g}): shuffled or duplicated rows?"
        )


def build_problem(
    recordings: Sequence[tuple[np.ndarray, ...]],
    model: ArmDynamics | None = None,
    *,
    rows: Sequence[RecordingRows] | None = None,
) -> tuple[Problem, np.ndarray]:
    """Nominal regression of (q, τ, h) or (q, τ, h, t) recordings (t: the real sample times)
    and its fit θ̂, in ``model``'s parameters (default the 9 of the 2-DOF model). ``rows``:
    the recordings' rows already built in ``model`` (a :class:`Problem`'s, which does not
    change them): used as they are, the regressor not built again."""
    model = ArmModel(()) if model is None else model
    if rows is not None and (
        len(rows) != len(recordings) or any(r.model is not model for r in rows)
    ):
        raise ValueError("build_problem: the rows given are not the recordings' in this model")
    rows = (
        list(rows)
        if rows is not None
        else [
            recording_rows(r[0], r[1], r[2], t=r[3] if len(r) > 3 else None, model=model)
            for r in recordings
        ]
    )
    y, Psi, w = _stack(rows)
    theta = fit_theta(Psi, y, w)
    scale = robust_scale(y - Psi @ theta, w)
    total_s = sum(r.rows * r.h for r in rows)
    longest = max(BLOCK_SECONDS[1], total_s / MAX_BLOCKS)
    block_s = min(max(total_s / BLOCKS_WANTED, BLOCK_SECONDS[0]), longest)
    blocks = block_index([r.rows for r in rows], round(block_s / min(r.h for r in rows)))
    return Problem(rows, y, Psi, w, scale, blocks), theta


@dataclass
class Accepted:
    cand: Candidate
    variant: Any
    evidence: Evidence
    confounded_with: list[str] = field(default_factory=list)
    rival_variants: dict[str, Any] = field(default_factory=dict)


def _design(prob: Problem, extra: Sequence[np.ndarray]) -> np.ndarray:
    """Ψ + ``extra``, scaled, (K, 2, p): Ψ scaled straight into it (no scaled copy to join)."""
    if not extra:
        return prob.Psi
    p0 = prob.Psi_raw.shape[-1]
    out = np.empty((*prob.Psi_raw.shape[:2], p0 + sum(x.shape[-1] for x in extra)))
    np.divide(prob.Psi_raw, prob.scale[None, :, None], out=out[:, :, :p0])
    at = p0
    for x in extra:
        out[:, :, at : at + x.shape[-1]] = x
        at += x.shape[-1]
    return out


def _cv(
    prob: Problem, extra: Sequence[np.ndarray], cand: Candidate | None = None
) -> CrossValidation:
    """Cross-validation of nominal + ``extra`` (+ each variant of ``cand`` as alternatives)."""
    stats = prob.design_stats(extra)
    if cand is None:
        return cross_validate(stats)
    if len(cand.variants) != 1:
        raise ValueError(f"{cand.key} has {len(cand.variants)} variants: use _cv_terms")
    return cross_validate(
        extend_stats_many(
            stats, prob.joint_columns(extra), [prob.column(cand, 0)], prob.y, prob.w, prob.blocks
        )
    )


def _term_key(a: Accepted) -> tuple[str, int]:
    return (a.cand.key, a.cand.variants.index(a.variant))


def _cv_terms(prob: Problem, terms: Sequence[Accepted], cand: Candidate) -> CrossValidation:
    """:func:`_cv` of nominal + the columns of ``terms`` + each variant of ``cand``. A candidate
    with many variants on one joint (a cogging or Stribeck grid) is scored from its cached block
    statistics (:meth:`Problem.grid_stats`), so that its columns are built once per diagnosis,
    not once per round."""
    extra = [prob.chosen(a) for a in terms]
    if len(cand.variants) == 1:
        return _cv(prob, extra, cand)
    stats = prob.design_stats(extra)
    return cross_validate(prob.grid_stats(cand, [_term_key(a) for a in terms], stats))


def _rewhiten(prob: Problem, accepted: Sequence[Accepted]) -> None:
    """Noise scale per joint from the residual of the model with the accepted terms."""
    cols = [prob.chosen(a) for a in accepted]

    def unscaled() -> np.ndarray:
        Z = _design(prob, cols)
        Z *= prob.scale[None, :, None]
        return Z

    # the design is weighted in place by the fit and built again for the residual: on a long
    # recording two (K, 2, p) copies fewer while the grids' sums are held
    beta = fit_theta(unscaled(), prob.y_raw, prob.w, overwrite_design=True)
    prob.scale = robust_scale(prob.y_raw - unscaled() @ beta, prob.w)


def _harms_other_joint(base: CrossValidation, cv: CrossValidation, cand: Candidate) -> bool:
    """The term makes the held-out error of a joint it is not about worse by MIN_REDUCTION."""
    others = [j for j in range(base.held_out_sse.shape[1]) if j not in _joints(cand)]
    return bool(others) and evidence(base, cv, others).reduction <= -MIN_REDUCTION


def _large_enough(cand: Candidate, cv: CrossValidation) -> bool:
    """The full-data estimate is above the practical floor and has the physical sign (the
    candidate's coefficients are the last of ``cv.beta``, θ its first ones)."""
    coef = cv.beta[-term_width(cand) :]
    if cand.kind in TERMS:
        return _relative_size(cand.kind, coef, cv.beta) >= RELATIVE_FLOOR
    # cogging: the amplitude; rate: β₁ + β₂ ≈ T; the others have one coefficient
    size = float(np.hypot(*coef)) if cand.kind == "cogging" else float(np.sum(coef))
    if cand.kind in POSITIVE_ONLY and size <= 0:
        return False
    return abs(size) >= PRACTICAL_FLOOR[cand.kind]


def _relative_size(term: str, coef: np.ndarray, theta: np.ndarray) -> float:
    """A model term's size against the rigid-body parameters it joins (RELATIVE_FLOOR); a
    rotor inertia that is not positive has size 0 (no physical arm has it)."""
    t = np.abs(np.asarray(theta, float)[:5]) + 1e-12
    if term == "rotor_inertia":
        return float(coef[0]) / t[2]
    return max(abs(float(coef[0])) / t[1], float(np.hypot(coef[1], coef[2]) / np.hypot(t[3], t[4])))


# A torque gain error below this (the shaft gets less than half the command) is not a gain
# error but a model that has stopped describing the arm.
MIN_GAIN = -0.5


# A friction coefficient is called negative only when it is below zero by more than this many
# of its own (blocked jackknife) standard errors: a viscous term the recording cannot determine
# scatters around zero, and -0.002 ± 0.004 Nm s is not a verdict on the arm.
SE_TOLERANCE = 2.0


def jackknife_se(fold_beta: np.ndarray) -> np.ndarray:
    """Standard error of each coefficient from the leave-one-block-out fits."""
    n = fold_beta.shape[0]
    return np.sqrt((n - 1) / n * np.sum((fold_beta - fold_beta.mean(0)) ** 2, axis=0))


def physical_theta(
    theta: np.ndarray, se: np.ndarray | None = None, model: ArmDynamics | None = None
) -> tuple[np.ndarray, list[str]]:
    """θ of ``model`` (default the 9-parameter one; its first parameters of ``theta``) with
    coefficients that must be ≥ 0 (friction, a rotor inertia) but are negative within
    SE_TOLERANCE of their standard errors ``se`` set to zero, and what is still not physical
    about it (``model.physical_consistency``: M(q) positive definite for every q, friction and
    rotor inertia ≥ 0)."""
    model = ArmModel(()) if model is None else model
    th = np.array(theta[: model.n_params], float)
    if se is not None:
        cols = [i for i in model.nonnegative_columns if i < len(se)]
        bound = -SE_TOLERANCE * np.asarray(se, float)[cols]
        fr = th[cols]
        fr[(fr < 0) & (fr >= bound)] = 0.0
        th[cols] = fr
    return th, list(model.physical_consistency(th)["violations"])


def model_columns(model: ArmDynamics, cands: Sequence[Candidate]) -> tuple[ArmDynamics, np.ndarray]:
    """The model a fit of the nominal ``model`` with the terms ``cands`` (in design order,
    after Ψ) describes: ``model`` with the model terms among ``cands`` appended, and which
    coefficients of the fit's β are its θ."""
    p = model.n_params
    index, terms, at = list(range(p)), [], p
    for c in cands:
        width = term_width(c)
        if c.kind in TERMS:
            terms.append(c.kind)
            index += range(at, at + width)
        at += width
    return (model.with_terms(tuple(terms)) if terms else model), np.array(index)


def unphysical(
    cand: Candidate | None,
    cv: CrossValidation,
    model: ArmDynamics | None = None,
    terms: Sequence[Candidate] = (),
) -> list[str]:
    """Why a fit of the nominal ``model`` (default the 9-parameter one) + the columns of
    ``terms`` (+ ``cand``) is not physical (empty when it is): M(q) not positive definite or
    negative friction in θ beyond its uncertainty (:func:`physical_theta`, with the model terms
    among ``terms`` and ``cand`` in θ), or a gain that removes most of the torque."""
    cands = [*terms, cand] if cand is not None else list(terms)
    full, index = model_columns(ArmModel(()) if model is None else model, cands)
    se = jackknife_se(cv.fold_beta)
    reasons = physical_theta(cv.beta[index], se[index], full)[1]
    if cand is not None and cand.kind == "gain":
        r = float(cv.beta[-1])
        if r <= MIN_GAIN:
            reasons.append(f"a torque gain of {100 * r:+.0f} % removes most of the torque")
    return reasons


def _passes(ev: Evidence, tests: int) -> bool:
    return ev.reduction >= MIN_REDUCTION and ev.sign_p <= FAMILY_ALPHA / tests


def _joints(cand: Candidate) -> list[int]:
    """The rows a candidate's columns act on: an angle offset moves gravity on both joints, a
    centre-of-mass offset the inertia and gravity of both (on an n-joint arm: ``acts_on``)."""
    if cand.acts_on is not None:
        return list(cand.acts_on)
    return [0, 1] if cand.kind in ("angle", "com_offset") else [cand.joint]


def rigid_body_deviation(theta: np.ndarray, reference: np.ndarray, n_rigid: int = 5) -> float:
    """‖(θ_rigid − reference)/reference‖: how far a fit's rigid-body parameters (θ1..θ5 of
    the 2-DOF model, the first ``n_rigid``) are from the reference's (robot profile or
    --params)."""
    ref = np.asarray(reference, float)[:n_rigid]
    # a URDF arm's base parameters can be zero (the offset moment of a symmetric link): those
    # are measured against the parameters' RMS instead
    scale = np.where(np.abs(ref) > 0, np.abs(ref), np.sqrt(np.mean(ref**2)))
    return float(np.linalg.norm((np.asarray(theta, float)[:n_rigid] - ref) / scale))


# A torque gain error is only believed when modelling it brings θ1..θ5 at least this much closer
# to the reference than the nominal fit is: the data alone fix only the ratio of the two joints'
# gains, and in closed loop the commanded torque correlates with the velocity-estimate noise, so
# a gain column "explains" a percent or so of noise that no reference supports.
GAIN_SUPPORT_RATIO = 0.5


def _gain_supported(
    prob: Problem,
    extra: Sequence[np.ndarray],
    cand: Candidate,
    cv: CrossValidation,
    base: CrossValidation,
    reference: np.ndarray | None,
    library: Sequence[Candidate],
) -> bool:
    if reference is None:
        return True
    other = next((c for c in library if c.kind == "gain" and c.joint != cand.joint), None)
    if other is None:  # the other joint is not tested: nothing to weigh the gain against
        return False
    there = _cv(prob, extra, other)
    n = prob.model.rigid_count
    best = rigid_body_deviation(cv.beta, reference, n)
    if prob.n_joints == 2:  # only the ratio of the two gains is known: either hypothesis
        best = min(best, rigid_body_deviation(there.beta, reference, n))
    return best <= GAIN_SUPPORT_RATIO * rigid_body_deviation(base.beta, reference, n)


PAIR_POOL = 4  # strongest single candidates tried in pairs when no single one passes


def _candidate_pairs(
    scored: Sequence[tuple[Candidate, CrossValidation, Evidence]], effects_only: bool = False
) -> list[tuple[tuple[Candidate, CrossValidation, Evidence], ...]]:
    """The pairs tried together: of the PAIR_POOL strongest candidates that each lower the
    error by the least reduction counted (``effects_only``: vocabulary effects, no model
    terms), strongest first."""
    pool = sorted(
        (
            s
            for s in scored
            if s[2].reduction >= MIN_REDUCTION
            and _large_enough(s[0], s[1])
            and not (effects_only and s[0].kind in TERMS)
        ),
        key=lambda s: -s[2].drop,
    )[:PAIR_POOL]
    return [(a, b) for i, a in enumerate(pool) for b in pool[i + 1 :]]


def _passing_pair(
    prob: Problem,
    extra: Sequence[np.ndarray],
    base: CrossValidation,
    scored: Sequence[tuple[Candidate, CrossValidation, Evidence]],
    tests: int,
) -> list[tuple[Candidate, CrossValidation, Evidence]]:
    """Two effects on one joint can each leave the other's residual in the way, so that neither
    passes alone (a torque offset and a lag on joint 2, say). The strongest few candidates are
    then tried in pairs; when a pair passes (the family now counting the pairs too), its stronger
    member is returned as passing and the other gets its chance in the next round."""
    pairs = _candidate_pairs(scored)
    for a, b in pairs:
        cols_a = prob.column(a[0], a[1].variant)
        cols_b = prob.column(b[0], b[1].variant)
        joints = sorted(set(_joints(a[0])) | set(_joints(b[0])))
        ev = evidence(base, _cv(prob, [*extra, cols_a, cols_b]), joints)
        if _passes(ev, tests + len(pairs)):
            return [a]
    return []


def _eliminate(
    prob: Problem,
    accepted: list[Accepted],
    tests: int,
    log: Callable[[str], None] | None,
) -> list[Accepted]:
    """Backward elimination after the greedy pass: a term accepted early as the best single
    explanation (an angle offset standing in for a torque offset plus something on the other
    joint) can become redundant once the real terms are in. Each term must still pass the test on
    top of all the others; the weakest that does not is dropped, until all do. The evidence kept
    for each term is this conditional one."""
    accepted = list(accepted)
    while accepted:
        verdicts = []
        for i, a in enumerate(accepted):
            others = [b for k, b in enumerate(accepted) if k != i]
            cols = [prob.chosen(b) for b in others]
            own = prob.chosen(a)
            ev = evidence(_cv(prob, cols), _cv(prob, [*cols, own]), _joints(a.cand))
            verdicts.append((ev, i))
        failing = [(ev.drop, i) for ev, i in verdicts if not _passes(ev, tests)]
        if not failing:
            for ev, i in verdicts:
                accepted[i].evidence = ev
            return accepted
        _drop, worst = min(failing)
        if log:
            log(f"eliminated {accepted[worst].cand.key}: redundant given the others")
        del accepted[worst]
        _rewhiten(prob, accepted)
    return accepted


def _confounding(
    prob: Problem,
    accepted: list[Accepted],
    library: Sequence[Candidate],
    tests: int,
    log: Callable[[str], None] | None,
) -> None:
    """Mark the candidates the data cannot tell from an accepted term: put in its place, the
    alternative explains the data on its own merit (it passes the test on top of the other
    terms) and the accepted term is not significantly better than it (the same test, the other
    way round). Fills ``Accepted.confounded_with``."""
    taken = {a.cand.key for a in accepted}
    for i, a in enumerate(accepted):
        others = [b for k, b in enumerate(accepted) if k != i]
        cols = [prob.chosen(b) for b in others]
        own = prob.chosen(a)
        without = _cv(prob, cols)
        with_own = _cv(prob, [*cols, own])
        for alt in library:
            if alt.key in taken or (alt.kind == "gain") != (a.cand.kind == "gain"):
                continue
            with_alt = _cv_terms(prob, others, alt)
            joints = sorted(set(_joints(alt)) | set(_joints(a.cand)))
            if not _passes(evidence(without, with_alt, _joints(alt)), tests):
                continue
            if not _large_enough(alt, with_alt):
                continue
            if unphysical(alt, with_alt, prob.model, [b.cand for b in others]):
                continue  # no finding stands on a refit that is not physical
            if _passes(evidence(with_alt, with_own, joints), tests):
                continue  # the accepted term is clearly better
            a.confounded_with.append(alt.key)
            a.rival_variants[alt.key] = alt.variants[with_alt.variant]
            if log:
                log(f"{a.cand.key} confounded with {alt.key}")


# Forward selections at most: a term the physical gate removes after the forward pass (a gain
# that drifted to removing most of the torque) may have kept others out on its way in, so the
# selection is redone without it.
RESELECT = 3


def select(
    prob: Problem,
    library: Sequence[Candidate],
    log: Callable[[str], None] | None = None,
    reference: np.ndarray | None = None,
    rejected: dict[str, str] | None = None,
    tick: Callable[..., None] | None = None,
) -> tuple[list[Accepted], dict[str, Evidence]]:
    """Greedy forward selection with blocked cross-validation (module doc). ``reference``: θ
    that a torque gain error must be supported by (:data:`GAIN_SUPPORT_RATIO`). ``rejected``
    collects candidates that passed the test but whose refit is not physical, with the reason.
    ``tick(stage, done, total, unit)``: told after every candidate tested (the long stage of a
    long recording: each is a cross-validated fit over all its rows)."""
    first_round: dict[str, Evidence] = {}
    rejected = {} if rejected is None else rejected
    # one-variant candidates first, so that their columns exist when a grid is first summed
    prob.anticipated = [(c.key, 0) for c in library if len(c.variants) == 1]
    excluded: set[str] = set()
    for _attempt in range(RESELECT):
        if excluded:
            _rewhiten(prob, [])  # the noise scale of the nominal model, as at the start
            if log:
                log(f"reselecting without {sorted(excluded)} (not physical)")
        pool = [c for c in library if c.key not in excluded]
        accepted = _forward(prob, pool, library, log, reference, rejected, first_round, tick)
        # Terms are judged redundant only against a physical model: a gain accepted while its
        # refit was physical can drift to removing most of the torque once a lag joins, and
        # would then "explain" the terms accepted before it (on DFKI A.0 trajectories 03 → 04
        # it eliminated the rotor inertia and was itself dropped as not physical afterwards).
        kept = physical_gate(prob, accepted, rejected)
        gone = {a.cand.key for a in accepted} - {a.cand.key for a in kept}
        accepted = kept
        if not gone:
            break
        excluded |= gone
    if excluded:  # the noise scale of the model kept, not of one with the terms gone
        _rewhiten(prob, accepted)
    accepted = _eliminate(prob, accepted, len(library), log)
    for a in accepted:  # refused on top of a term that is gone, accepted without it
        rejected.pop(a.cand.key, None)
    _confounding(prob, accepted, [c for c in library if c.key in first_round], len(library), log)
    prob.keep_only(_kept_columns(accepted, library))
    return accepted, first_round


def _kept_columns(
    accepted: Sequence[Accepted], library: Sequence[Candidate]
) -> list[tuple[str, int]]:
    """The columns the report asks for after the selection: the accepted terms' and their
    rivals' (report.interpret refits each rival in its term's place; a model term's columns,
    rebuilt, cost a pass over every interval's regressor)."""
    by_key = {c.key: c for c in library}
    keys = [_term_key(a) for a in accepted]
    for a in accepted:
        for key in a.confounded_with:
            rival = by_key[key]
            keys.append((key, rival.variants.index(a.rival_variants.get(key, rival.variants[0]))))
    return keys


def _forward(
    prob: Problem,
    pool: Sequence[Candidate],
    library: Sequence[Candidate],
    log: Callable[[str], None] | None,
    reference: np.ndarray | None,
    rejected: dict[str, str],
    first_round: dict[str, Evidence],
    tick: Callable[..., None] | None = None,
) -> list[Accepted]:
    """The forward rounds of :func:`select` over the candidates ``pool`` (the family of tests
    is the whole ``library``); fills ``first_round`` with each candidate's first evidence."""
    accepted: list[Accepted] = []
    extra: list[np.ndarray] = []
    tests = len(library)
    remaining = sorted(pool, key=lambda c: len(c.variants) > 1)
    for round_no in range(MAX_ROUNDS):
        base = _cv(prob, extra)
        scored = []
        for i, cand in enumerate(remaining):
            if tick is not None:
                tick(f"testing candidates, round {round_no + 1}", i, len(remaining), "candidates")
            cv = _cv_terms(prob, accepted, cand)
            ev = evidence(base, cv, _joints(cand))
            if not first_round.get(cand.key):
                first_round[cand.key] = ev
            scored.append((cand, cv, ev))
            if log:
                log(
                    f"  {cand.key:12s} red {ev.reduction:+.4f} t {ev.t:7.2f} "
                    f"{ev.blocks_improved}/{ev.blocks} p {ev.sign_p:.1e} "
                    f"variant {cand.variants[cv.variant]}"
                )
        passing = [
            s
            for s in scored
            if _passes(s[2], tests)
            and _large_enough(s[0], s[1])
            and not _harms_other_joint(base, s[1], s[0])
            and (
                s[0].kind != "gain"
                or _gain_supported(prob, extra, s[0], s[1], base, reference, library)
            )
        ]
        # never the basis of a finding: a refit that is not physical (said in the report)
        for s in list(passing):
            reasons = unphysical(s[0], s[1], prob.model, [a.cand for a in accepted])
            if reasons:
                passing.remove(s)
                if s[0].key not in rejected:
                    rejected[s[0].key] = "its refit is not physical: " + "; ".join(reasons)
        if not passing:
            passing = _passing_pair(prob, extra, base, scored, tests)
            if not passing:
                break
        cand, cv, ev = _prefer_effect(
            max(passing, key=lambda s: s[2].drop), passing, tests, prob, extra, scored
        )
        chosen_cols = prob.column(cand, cv.variant)
        acc = Accepted(cand, cand.variants[cv.variant], ev)
        accepted.append(acc)
        extra.append(chosen_cols)
        remaining.remove(cand)
        if cand.kind == "gain":  # gains on both joints: θ = 0, r = −1 fits anything (scale)
            remaining = [c for c in remaining if c.kind != "gain"]
        _rewhiten(prob, accepted)
        extra = [prob.chosen(a) for a in accepted]
        if log:
            log(f"accepted {cand.key} variant {acc.variant} confounded {acc.confounded_with}")
    return accepted


def _prefer_effect(
    best: tuple[Candidate, CrossValidation, Evidence],
    passing: Sequence[tuple[Candidate, CrossValidation, Evidence]],
    tests: int,
    prob: Problem | None = None,
    extra: Sequence[np.ndarray] = (),
    scored: Sequence[tuple[Candidate, CrossValidation, Evidence]] = (),
) -> tuple[Candidate, CrossValidation, Evidence]:
    """A model term (several parameters, hil.model.closed_form) is taken before a passing
    effect of the vocabulary only when it explains the data clearly better (the test, the term
    against the effect): an encoder zero offset on joint 1 is exactly a centre-of-mass offset
    with θ2⊥ = 0, and the narrower explanation goes in first (the other is then reported as
    confounded with it, :func:`_confounding`). Narrower also means two passing effects taken
    together (two parameters against the term's three): a centre-of-mass offset took up an
    encoder offset on joint 2 together with joint 1's Coulomb asymmetry and beat each of them
    alone (blind-like sets, rec-25 of every seed); it must beat the pair too (with ``prob``).
    The pair's members are drawn as :func:`_passing_pair` draws them
    (:func:`_candidate_pairs` of ``scored``), since one of the two may pass only once the
    other is in."""
    if best[0].kind not in TERMS:
        return best
    rivals = [
        s
        for s in passing
        if s[0].kind not in TERMS
        and not _passes(
            evidence(s[1], best[1], sorted(set(_joints(s[0])) | set(_joints(best[0])))), tests
        )
    ]
    if rivals or prob is None:
        return max(rivals, key=lambda s: s[2].drop) if rivals else best
    pairs = _candidate_pairs([*passing, *(s for s in scored if s not in passing)], True)
    for a, b in pairs:
        cols = [*extra, prob.column(a[0], a[1].variant), prob.column(b[0], b[1].variant)]
        joints = sorted(set(_joints(a[0])) | set(_joints(b[0])) | set(_joints(best[0])))
        if not _passes(evidence(_cv(prob, cols), best[1], joints), tests + len(pairs)):
            # the stronger of the pair if it passes alone; the other gets its chance next round
            return a if a in passing else b if b in passing else best
    return best


# An angle offset's column is −∂(Ψθ)/∂q_j at a θ; relinearised this many times about the refit.
RELINEARISE_ANGLE = 3


def relinearise_angle(prob: Problem, accepted: list[Accepted]) -> list[Accepted]:
    """Rebuild an accepted angle-offset column about the θ refitted with it (a Gauss–Newton
    step). The candidate's column is built with the nominal θ̂, which the offset itself biases
    (it moves gravity torque between sin and cos of the angles); one δ then cannot fit both
    joints' rows, and what is left on the other joint looks like another effect there (issue
    12: an encoder offset on joint 1 left a position-dependent residual on joint 2)."""
    out = list(accepted)
    for i, a in enumerate(out):
        if a.cand.kind != "angle":
            continue
        for _ in range(RELINEARISE_ANGLE):
            theta = final_fit(prob, out).theta
            j = a.cand.joint
            cand = Candidate(
                "angle",
                j,
                (None,),
                lambda r, _v, j=j, th=theta: angle_offset_column(r, j, th),
                acts_on=a.cand.acts_on,
            )
            prob.forget((cand.key, 0))
            a = Accepted(cand, None, a.evidence, a.confounded_with, a.rival_variants)
            out[i] = a
    return out


# --- the final model ---------------------------------------------------------------------------


@dataclass
class FinalFit:
    """Nominal + accepted terms fitted on all rows: θ, each term's coefficients, their spread
    over the leave-one-block-out fits (a jackknife standard error)."""

    theta: np.ndarray
    coefficients: list[np.ndarray]
    standard_errors: list[np.ndarray]
    cv: CrossValidation


def final_fit(prob: Problem, accepted: Sequence[Accepted]) -> FinalFit:
    cols = [prob.chosen(a) for a in accepted]
    cv = _cv(prob, cols)
    n_blocks = cv.fold_beta.shape[0]
    jack = np.sqrt(
        (n_blocks - 1) / n_blocks * np.sum((cv.fold_beta - cv.fold_beta.mean(0)) ** 2, 0)
    )
    coefs, ses, at = [], [], prob.n_params
    for c in cols:
        p = c.shape[-1]
        coefs.append(cv.beta[at : at + p])
        ses.append(jack[at : at + p])
        at += p
    return FinalFit(cv.beta[: prob.n_params], coefs, ses, cv)


def physical_gate(
    prob: Problem, accepted: list[Accepted], rejected: dict[str, str]
) -> list[Accepted]:
    """The final model must be physical too: a term accepted early can drift once others join
    (a gain error that ends up removing most of the torque). While the refit with every
    accepted term is not physical, the last accepted term goes (the others stood without it),
    with the reason in ``rejected``."""
    accepted = list(accepted)
    while accepted:
        fit = final_fit(prob, accepted)
        reasons = unphysical(None, fit.cv, prob.model, [a.cand for a in accepted])
        for a, coef in zip(accepted, fit.coefficients, strict=True):
            if a.cand.kind == "gain" and float(coef[0]) <= MIN_GAIN:
                reasons.append(
                    f"a torque gain of {100 * float(coef[0]):+.0f} % removes most of the torque"
                )
        if not reasons:
            break
        last = accepted.pop()
        rejected[last.cand.key] = "its refit is not physical: " + "; ".join(reasons)
    return accepted


__all__ = [
    "DiagnosisError",
]
