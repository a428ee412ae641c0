"""The stacked regression the diagnosis selects on (:class:`Problem`), and its fits.

:func:`build_problem` stacks the recordings' rows (:func:`hil.diagnose.columns.recording_rows`:
the ``exact`` filtered dynamic regression, Reyes & Kelly (1997) eq. (24) over sample
intervals) into y, Ψ and weights, fits the nominal θ̂ (:func:`fit_theta`) and cuts the rows
into blocks for the blocked cross-validation (:mod:`hil.diagnose.stats`). A :class:`Problem`
serves each candidate's columns scaled to unit noise per joint and keeps them and the
candidates' grid sums; :func:`design_cv` and :func:`terms_cv` cross-validate Ψ plus term
columns, :func:`rewhiten` re-estimates the noise scale. Also what no diagnosis can use
(:func:`check_recording`, :class:`DiagnosisError`).

Imports: :mod:`hil.diagnose.candidates`, :mod:`hil.diagnose.columns`,
:mod:`hil.diagnose.stats`, :mod:`hil.model`, :mod:`drivers.process`; never the selection or
the stages after it.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers.process import release_freed_heap
from hil.diagnose.candidates import Accepted, Candidate, term_key, term_width
from hil.diagnose.columns import RecordingRows, recording_rows
from hil.diagnose.stats import (
    BlockStats,
    Columns,
    CrossValidation,
    ScaledRows,
    block_index,
    block_spans,
    block_stats,
    cross_validate,
    extend_stats_many,
    extended_stats,
    target_block_sums,
)
from hil.model.closed_form import ArmModel
from hil.model.estimators import least_squares_rows, require_finite
from hil.model.protocol import ArmDynamics

# Blocks: about BLOCKS_WANTED per diagnosis, each between these lengths (long against the 20 ms
# correlation of the filtered residual, short enough for a sign test to have power).
BLOCKS_WANTED = 40
BLOCK_SECONDS = (0.15, 0.5)
# ... and at most this many: a long recording's blocks grow beyond BLOCK_SECONDS[1] instead
# (every block is a leave-one-out fit of every variant of every candidate; 400 nearly
# independent blocks already give the sign test far more power than FAMILY_ALPHA asks for).
MAX_BLOCKS = 400


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
    # a column zero on every row (a coefficient held at zero, hil.diagnose.physical.held_at_zero)
    # gets exactly 0
    return least_squares_rows(A, b)


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


def usable_speeds(prob: Problem) -> list[np.ndarray]:
    """|q̇| (interval means) of the rows the model uses, per joint."""
    v = np.abs(prob.v_mean)
    return [v[prob.w[:, j] > 0, j] for j in range(prob.n_joints)]


def design_matrix(prob: Problem, extra: Sequence[np.ndarray]) -> np.ndarray:
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


def design_cv(
    prob: Problem, extra: Sequence[np.ndarray], cand: Candidate | None = None
) -> CrossValidation:
    """Cross-validation of nominal + ``extra`` (+ each variant of ``cand`` as alternatives)."""
    stats = prob.design_stats(extra)
    if cand is None:
        return cross_validate(stats)
    if len(cand.variants) != 1:
        raise ValueError(f"{cand.key} has {len(cand.variants)} variants: use terms_cv")
    return cross_validate(
        extend_stats_many(
            stats, prob.joint_columns(extra), [prob.column(cand, 0)], prob.y, prob.w, prob.blocks
        )
    )


def terms_cv(prob: Problem, terms: Sequence[Accepted], cand: Candidate) -> CrossValidation:
    """:func:`design_cv` of nominal + the columns of ``terms`` + each variant of ``cand``. A
    candidate with many variants on one joint (a cogging or Stribeck grid) is scored from its
    cached block statistics (:meth:`Problem.grid_stats`), so that its columns are built once per
    diagnosis, not once per round."""
    extra = [prob.chosen(a) for a in terms]
    if len(cand.variants) == 1:
        return design_cv(prob, extra, cand)
    stats = prob.design_stats(extra)
    return cross_validate(prob.grid_stats(cand, [term_key(a) for a in terms], stats))


def rewhiten(prob: Problem, accepted: Sequence[Accepted]) -> None:
    """Noise scale per joint from the residual of the model with the accepted terms."""
    cols = [prob.chosen(a) for a in accepted]

    def unscaled() -> np.ndarray:
        Z = design_matrix(prob, cols)
        Z *= prob.scale[None, :, None]
        return Z

    # the design is weighted in place by the fit and built again for the residual: on a long
    # recording two (K, 2, p) copies fewer while the grids' sums are held
    beta = fit_theta(unscaled(), prob.y_raw, prob.w, overwrite_design=True)
    prob.scale = robust_scale(prob.y_raw - unscaled() @ beta, prob.w)


__all__ = [
    "DiagnosisError",
]
