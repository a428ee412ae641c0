"""Blocked cross-validation for deciding whether a candidate term belongs in the model.

Residuals of a filtered regression are coloured (the filter, quantization, model error) and not
Gaussian, so a per-row F-test would find "significant" terms in pure noise. Instead the rows are
cut into contiguous time blocks, long against the residual's correlation time (seconds against
the filter's 1/λ = 20 ms), and every block is predicted by the model fitted on all the others.
A term belongs in the model when it lowers the held-out squared error of its joint, block after
block: the evidence is the held-out improvement per block, its mean over its spread (a t
statistic over nearly independent blocks) and the relative reduction of the held-out error. Terms
with a nonlinear parameter (cogging periods, Stribeck velocity) pick that parameter inside each
fold, on the training blocks only, so the choice cannot leak into the held-out score.

Pure numpy over a weighted least-squares problem y(k, j) ≈ Z(k, j, :) β with row weights w(k, j)
(0 for rows the model cannot explain, see :mod:`hil.model.regressors`), rows already scaled to unit
noise
per joint.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from hil.model.tails import binomial_upper_tail

# Relative to each column's own squared norm over all the data (not to the design's mean
# diagonal): keeps a fold solvable when a column is (nearly) absent from it. A ridge relative to
# the mean diagonal is not scale-free: the ur5e's 54 base parameters have columns whose squared
# norms span 9 decades, and ε = 1e-9 × mean was 4 % of the smallest column's (the least
# eigenvalue lay below ε), so every cross-validated fit was biased (joint 2's in-sample error
# 2.3× the noise) and any extra columns (the `unexplained` bins) "explained" that bias: three
# false structures on an effect-free run (docs/diagnosis.md, "n joints").
RIDGE = 1e-9
TRIM_FRACTION = 0.05  # of blocks left out of the relative reduction (largest changes)
# A block whose held-out error is below this fraction of the largest block's is round-off: a
# block-paired difference (a recording that reruns its reference's motion) is zero there to
# ~1e-24 of the changed blocks where the change does not act (:func:`evidence`).
ROUND_OFF = 1e-12


def block_index(row_counts: list[int], rows_per_block: int) -> np.ndarray:
    """Block number of every row: each recording (``row_counts`` rows) cut into contiguous blocks
    of about ``rows_per_block`` rows, at least two per recording."""
    out, first = [], 0
    for n in row_counts:
        blocks = max(2, round(n / rows_per_block))
        out.append(first + np.minimum(np.arange(n) * blocks // max(n, 1), blocks - 1))
        first += blocks
    return np.concatenate(out)


@dataclass(frozen=True)
class BlockStats:
    """Per block b and joint j: G = Σ w zzᵀ, r = Σ w z y, s = Σ w y² (shapes (..., B, 2, p, p),
    (..., B, 2, p), (B, 2)); leading axes, when present, are variants of one candidate."""

    G: np.ndarray
    r: np.ndarray
    s: np.ndarray


class ScaledRows:
    """raw (K, 2, p) divided by a per-joint scale (2,), or one joint's raw (K, p) by its scale
    (a number), row ranges computed when asked: a design's column group that is never scaled
    whole (a long recording's Ψ is 86 MB)."""

    def __init__(self, raw: np.ndarray, scale: np.ndarray | float) -> None:
        self.raw, self.scale = raw, scale
        self.shape = raw.shape
        self._divisor = scale[None, :, None] if np.ndim(scale) == 1 else scale

    def __getitem__(self, rows: slice) -> np.ndarray:
        return self.raw[rows] / self._divisor


# Columns (K, m) of one joint's rows, given as groups (K, m_i) joined one block at a time
Columns = Sequence[np.ndarray | ScaledRows]


# (K, 2, p), or its column groups (K, 2, p_i), each an array or ScaledRows
Design = np.ndarray | Sequence[np.ndarray | ScaledRows]


def design_width(Z: Design) -> int:
    """Number of columns p of a design."""
    return Z.shape[-1] if isinstance(Z, np.ndarray) else sum(P.shape[-1] for P in Z)


def design_rows(Z: Design, lo: int, hi: int) -> np.ndarray:
    """Rows lo..hi of a design (K, 2, p): a design given as column groups is never joined
    whole (on a long recording each copy is a hundred megabytes)."""
    if isinstance(Z, np.ndarray):
        return Z[lo:hi]
    return np.concatenate([P[lo:hi] for P in Z], axis=2)


def block_stats(Z: Design, y: np.ndarray, w: np.ndarray, blocks: np.ndarray) -> BlockStats:
    """Sufficient statistics of y ≈ Z β per block and joint (Z (K, 2, p) or its column groups,
    y and w (K, 2)); the rows of a block are contiguous (``blocks`` non-decreasing). One block
    at a time, so memory stays O(K p), not O(K p²)."""
    starts = _starts(blocks)
    ends = np.r_[starts[1:], len(blocks)]
    n_blocks, p, n = len(starts), design_width(Z), y.shape[1]
    G = np.empty((n_blocks, n, p, p))
    r = np.empty((n_blocks, n, p))
    for b, (lo, hi) in enumerate(zip(starts.tolist(), ends.tolist(), strict=True)):
        Zb = design_rows(Z, lo, hi)
        # per joint (leading axis) a (p, k) @ (k, p) product: BLAS, not an einsum loop
        wz = (w[lo:hi, :, None] * Zb).transpose(1, 2, 0)  # (2, p, k)
        np.matmul(wz, Zb.transpose(1, 0, 2), out=G[b])
        np.matmul(wz, y[lo:hi].T[:, :, None], out=r[b][:, :, None])
    s = np.add.reduceat(w * y * y, starts, axis=0)
    return BlockStats(G, r, s)


def _starts(blocks: np.ndarray) -> np.ndarray:
    if np.any(np.diff(blocks) < 0):
        raise ValueError("rows must be ordered by block")
    return np.flatnonzero(np.r_[True, np.diff(blocks) > 0])


def extend_stats_many(
    base: BlockStats,
    Z: Design | Callable[[int], Columns],
    variants: list[np.ndarray] | np.ndarray,
    y: np.ndarray,
    w: np.ndarray,
    blocks: np.ndarray,
) -> BlockStats:
    """Statistics of the designs [Z, X_v] for alternative X_v of the same width (Z, or a function
    giving joint j's columns of it as groups (K, p_i), :data:`Columns`); a candidate's
    variants, a list of (K, 2, q) or one array (K, 2, V, q)), from those of Z (``base``): only
    the new cross terms are computed, those of every variant from one matrix product per block
    and joint, which is what keeps a 400-variant cogging search to a fraction of a second. A
    joint whose rows the variants leave at zero costs nothing. Leading axis of G and r: the
    variant."""
    X = variants if isinstance(variants, np.ndarray) else np.stack(variants, axis=2)
    V, q = X.shape[2], X.shape[3]
    spans = block_spans(blocks)
    n_blocks, p, n = len(spans), base.G.shape[-1], y.shape[1]
    cross = np.zeros((n_blocks, n, p, V * q))
    xx = np.zeros((n_blocks, n, V, q, q))
    rx = np.zeros((n_blocks, n, V, q))
    for j in range(n):
        if not np.any(X[:, j]):
            continue
        if callable(Z):  # joint j's columns, as groups joined a block at a time
            U = list(Z(j))
        else:
            U = [Z[:, j, :]] if isinstance(Z, np.ndarray) else [P[:, j, :] for P in Z]
        uyx, xx[:, j] = target_block_sums([*U, y[:, j, None]], X[:, j], w[:, j], spans)
        cross[:, j], rx[:, j] = uyx[:, :p], uyx[:, p].reshape(n_blocks, V, q)
    cross = cross.reshape(n_blocks, n, p, V, q).transpose(3, 0, 1, 2, 4)  # (V, B, n, p, q)
    return extended_stats(base, cross, xx.transpose(2, 0, 1, 3, 4), rx.transpose(2, 0, 1, 3))


def block_spans(blocks: np.ndarray) -> list[tuple[int, int]]:
    """[first, end) row range of every block (rows ordered by block)."""
    starts = _starts(blocks)
    return list(zip(starts.tolist(), np.r_[starts[1:], len(blocks)].tolist(), strict=True))


def joint_block_sums(
    U: np.ndarray, X: np.ndarray, y: np.ndarray, w: np.ndarray, blocks: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per block, of one joint's rows: Σ w Uᵀ X (B, m, V·q), Σ w XᵀX per variant (B, V, q, q)
    and Σ w Xᵀ y (B, V, q), for columns U (K, m) and variants X (K, V, q)
    (:func:`target_block_sums` with y riding along as U's last column)."""
    V, q = X.shape[1:]
    m = U.shape[1]
    uyx, xx = target_block_sums([U, y[:, None]], X, w, block_spans(blocks))
    return uyx[:, :m], xx, uyx[:, m].reshape(len(uyx), V, q)


def target_block_sums(
    Uy: Columns, X: np.ndarray, w: np.ndarray, spans: Sequence[tuple[int, int]]
) -> tuple[np.ndarray, np.ndarray]:
    """Per block (``spans``: [first, end) rows, :func:`block_spans`) of one joint's rows:
    Σ w Uyᵀ X (B, m, V·q) and Σ w XᵀX per variant (B, V, q, q), for columns Uy (K, m) given
    as groups (the target y as the last gives Σ w yᵀX from the same product) and variants X
    (K, V, q). Per block one dense product Uyᵀ (w X) and one batched Xᵀ (w X) (BLAS; the
    sparse block-selector product used before did the same multiply-adds without it). The
    groups are joined and X weighted one block at a time: no (K, m) or (K, V·q) copy per call,
    which at 600,000 rows cost more than the products (and 90 MB each)."""
    V, q = X.shape[1:]
    uyx = np.empty((len(spans), sum(g.shape[1] for g in Uy), V * q))
    xx = np.empty((len(spans), V, q, q))
    for b, (lo, hi) in enumerate(spans):
        wX = w[lo:hi, None, None] * X[lo:hi]  # (k, V, q)
        Ub = np.concatenate([g[lo:hi] for g in Uy], axis=1)
        np.matmul(Ub.T, wX.reshape(hi - lo, V * q), out=uyx[b])
        # per variant a (q, k) @ (k, q) product
        np.matmul(X[lo:hi].transpose(1, 2, 0), wX.transpose(1, 0, 2), out=xx[b])
    return uyx, xx


def extended_stats(
    base: BlockStats, cross: np.ndarray, xx: np.ndarray, rx: np.ndarray
) -> BlockStats:
    """Statistics of the designs [Z, X_v] from those of Z (``base``) and the variants' own sums
    per block and joint: ``cross`` Σ w Zᵀ X_v (V, B, 2, p, q), ``xx`` Σ w X_vᵀ X_v (V, B, 2, q, q),
    ``rx`` Σ w X_vᵀ y (V, B, 2, q)."""
    V = cross.shape[0]
    G_base = np.broadcast_to(base.G, (V, *base.G.shape))
    top = np.concatenate([G_base, cross], axis=-1)
    bottom = np.concatenate([np.swapaxes(cross, -1, -2), xx], axis=-1)
    r_base = np.broadcast_to(base.r, (V, *base.r.shape))
    return BlockStats(
        np.concatenate([top, bottom], axis=-2), np.concatenate([r_base, rx], axis=-1), base.s
    )


def column_scale(G: np.ndarray) -> np.ndarray:
    """Each column's squared norm, the diagonal of G (..., p, p) → (..., p); a column that is
    zero on every row takes the mean of the diagonal instead (its coefficient is then 0)."""
    diag = np.diagonal(G, axis1=-2, axis2=-1)
    mean = np.maximum(diag.mean(axis=-1, keepdims=True), 1e-300)
    return np.where(diag > 0, diag, mean)


def _solve(G: np.ndarray, r: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """β = (G + ε D)⁻¹ r for stacked systems (..., p, p), D = diag(``scale``) the columns'
    squared norms over all the data (:func:`column_scale`), ε = RIDGE: the same ridge on the
    columns scaled to unit norm, so the fit does not depend on the columns' units."""
    ridge = RIDGE * scale[..., :, None] * np.eye(G.shape[-1])
    return np.linalg.solve(G + ridge, r[..., None])[..., 0]


def _sse(G: np.ndarray, r: np.ndarray, s: np.ndarray, beta: np.ndarray) -> np.ndarray:
    """Σ w (y − zβ)² from the statistics: s − 2βᵀr + βᵀGβ."""
    return (
        s
        - 2 * np.einsum("...p,...p->...", beta, r)
        + np.einsum("...p,...pq,...q->...", beta, G, beta)
    )


def full_fit_sse(G: np.ndarray, r: np.ndarray, s: float) -> np.ndarray:
    """The in-sample squared error of the full-data fit of each of many designs, from their
    sums over all rows and joints G = Σ w zzᵀ (V, p, p), r = Σ w z y (V, p) and s = Σ w y²:
    s − 2βᵀr + βᵀGβ at β from :func:`_solve` with the full data's ridge, the error
    :func:`cross_validate` gives its full-data fit (``CrossValidation.sse``, summed over the
    joints), (V,)."""
    beta = _solve(G, r, column_scale(G))
    return _sse(G, r, np.asarray(s, float), beta)


@dataclass(frozen=True)
class CrossValidation:
    """Held-out squared error of every block and joint (B, 2), the variant each fold chose, and
    the full-data fit (its variant and coefficients)."""

    held_out_sse: np.ndarray
    fold_variant: np.ndarray
    fold_beta: np.ndarray  # (B, p) coefficients fitted without each block
    variant: int
    beta: np.ndarray
    sse: np.ndarray  # (2,) in-sample, full data


def cross_validate(stats: BlockStats | Iterable[BlockStats]) -> CrossValidation:
    """Leave-one-block-out fits of every variant; each fold keeps the variant that fits its
    training blocks best (least training error), and is scored on the block it left out.
    ``stats`` may come in chunks of variants (an iterable, variants numbered in order), so that a
    long grid never has to be held in memory at once."""
    chunks = [stats] if isinstance(stats, BlockStats) else stats
    best: _Folds | None = None
    offset = 0
    for chunk in chunks:
        part = _folds(chunk, offset)
        offset += part.n_variants
        best = part if best is None else best.merge(part)
    if best is None:
        raise ValueError("no variants to cross-validate")
    return best.result()


@dataclass
class _Folds:
    """Per fold: the best variant's training error, held-out error and coefficients; and the
    full-data best. Chunks of variants merge by keeping the lower training error (first on ties,
    as one argmin over all variants would)."""

    train_sse: np.ndarray  # (B,)
    held: np.ndarray  # (B, 2)
    fold_variant: np.ndarray  # (B,)
    fold_beta: np.ndarray  # (B, p)
    full_sse: float
    variant: int
    beta: np.ndarray
    sse: np.ndarray
    n_variants: int

    def merge(self, other: _Folds) -> _Folds:
        better = other.train_sse < self.train_sse
        self.train_sse = np.where(better, other.train_sse, self.train_sse)
        self.held = np.where(better[:, None], other.held, self.held)
        self.fold_variant = np.where(better, other.fold_variant, self.fold_variant)
        self.fold_beta = np.where(better[:, None], other.fold_beta, self.fold_beta)
        if other.full_sse < self.full_sse:
            self.full_sse, self.variant = other.full_sse, other.variant
            self.beta, self.sse = other.beta, other.sse
        self.n_variants += other.n_variants
        return self

    def result(self) -> CrossValidation:
        return CrossValidation(
            self.held, self.fold_variant, self.fold_beta, self.variant, self.beta, self.sse
        )


def _folds(stats: BlockStats, offset: int) -> _Folds:
    """The leave-one-block-out fits of one chunk of variants (numbered from ``offset``), all
    folds at once."""
    G, r, s = stats.G, stats.r, stats.s
    if G.ndim == 4:  # one variant
        G, r = G[None], r[None]
    n_blocks = s.shape[0]
    G_blk, r_blk = G.sum(axis=2), r.sum(axis=2)  # (V, B, p, p), (V, B, p)
    G_all, r_all, s_all = G_blk.sum(axis=1), r_blk.sum(axis=1), s.sum()
    Gt = G_all[:, None] - G_blk
    rt = r_all[:, None] - r_blk
    scale = column_scale(G_all)  # (V, p): every fold's ridge from the full data's columns
    beta = _solve(Gt, rt, scale[:, None])  # (V, B, p)
    train = (s_all - s.sum(axis=1))[None] - np.einsum("vbp,vbp->vb", beta, rt)
    v = np.argmin(train, axis=0)  # (B,)
    b = np.arange(n_blocks)
    fold_beta = beta[v, b]  # (B, p)
    held = _sse(G[v, b], r[v, b], s, fold_beta[:, None, :])
    beta_full = _solve(G_all, r_all, scale)
    full_sse = s_all - np.einsum("vp,vp->v", beta_full, r_all)
    vf = int(np.argmin(full_sse))
    sse = _sse(G[vf].sum(axis=0), r[vf].sum(axis=0), s.sum(axis=0), beta_full[vf])
    return _Folds(
        train[v, b],
        held,
        v + offset,
        fold_beta,
        float(full_sse[vf]),
        vf + offset,
        beta_full[vf],
        sse,
        G.shape[0],
    )


@dataclass(frozen=True)
class Evidence:
    """How much a candidate lowers the held-out error of its joint(s) against the model without
    it: ``reduction`` the relative drop of the total held-out error, ``t`` the mean per-block
    log ratio (before/after) over its standard error, ``blocks_improved`` out of ``blocks``."""

    reduction: float
    t: float
    blocks_improved: int
    blocks: int
    drop: float  # held-out squared error removed, in units of the noise (rows are scaled)

    @property
    def sign_p(self) -> float:
        """One-sided sign test: the chance of at least this many improved blocks if the term
        helped or hurt each block at random (a fair coin per block)."""
        return binomial_upper_tail(self.blocks_improved - 1, self.blocks, 0.5)

    def as_dict(self) -> dict[str, float | int]:
        return {
            "held_out_error_reduction": round(self.reduction, 5),
            "t_statistic": round(self.t, 2),
            "blocks_improved": self.blocks_improved,
            "blocks": self.blocks,
            "sign_test_p": float(f"{self.sign_p:.3g}"),
        }


def evidence(base: CrossValidation, extended: CrossValidation, joints: list[int]) -> Evidence:
    """Held-out improvement of ``extended`` over ``base`` on ``joints``, block by block."""
    before = base.held_out_sse[:, joints].sum(axis=1)
    after = extended.held_out_sse[:, joints].sum(axis=1)
    # Blocks without a usable row on these joints (the joint stood still) say nothing either way,
    # nor do blocks with nothing to explain: a paired difference is round-off where the change
    # does not act (a Coulomb asymmetry written for one direction, in blocks that move the
    # other way: the KUKA's joint 3 changed in 24 blocks of 50, and the 26 ties, counted as
    # failures, kept it from being found)
    has_rows = before > ROUND_OFF * before.max(initial=0.0)
    before, after = before[has_rows], after[has_rows]
    gain = before - after
    # Per-block log ratio: blocks differ a lot in error level (excitation, stick–slip), so the
    # test asks "is the error lower block after block" on a scale-free measure.
    ratio = np.log(np.maximum(before, 1e-300) / np.maximum(after, 1e-300))
    n = len(ratio)
    if n == 0:  # no block has a usable row on these joints: no evidence either way
        return Evidence(reduction=0.0, t=0.0, blocks_improved=0, blocks=0, drop=0.0)
    spread = ratio.std(ddof=1) if n > 1 else 0.0
    mean = ratio.mean()
    t = float(mean / (spread / np.sqrt(n))) if spread > 0 else (np.inf if mean > 0 else 0.0)
    # The relative reduction leaves out the few blocks that changed most either way: a block that
    # the other blocks cannot extrapolate to (the only one with a wide angle range, say) would
    # otherwise decide alone, for or against.
    keep = np.argsort(np.abs(gain))[: max(1, n - max(1, round(TRIM_FRACTION * n)))]
    return Evidence(
        reduction=float(gain[keep].sum() / max(before[keep].sum(), 1e-300)),
        t=t,
        blocks_improved=int(np.sum(gain > 0)),
        blocks=n,
        drop=float(gain.sum()),
    )
