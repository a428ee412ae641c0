"""Estimators for linear regressions y(k) = Ψ(k)ᵀ θ + e(k): recursive, batch and weighted least
squares (Reyes & Kelly 1997, Section 4.1).

Shapes follow :class:`hil.model.regressors.Regression`: ``y`` (K, m), ``Psi`` (K, m, p) holding
Ψ(k)ᵀ
(m = 2 for the vector prediction error of the filtered dynamic model, 1 for the scalar ones).
Pure numpy; no I/O.
"""

from __future__ import annotations

import contextlib

import numpy as np

PAPER_P0 = 1000.0  # P(0) = 1000·I, θ̂(0) = 0 (Section 6)

try:  # np.linalg.solve's own LAPACK gufunc (gesv), the same bits without its per-call checks
    # and error-state context, which cost three times the solve of RLS's m×m S (S = I + ΨᵀPΨ is
    # positive definite: nothing to check); private to numpy, hence the fallback
    from numpy.linalg import _umath_linalg

    def _SOLVE(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return _umath_linalg.solve(a, b, signature="dd->d")

except ImportError:  # pragma: no cover - another numpy layout
    _SOLVE = np.linalg.solve


class RecursiveLeastSquares:
    """Recursive least squares, eqs. (20)-(22), for vector or scalar prediction errors.

    Online use: call :meth:`update` once per sample (e.g. every control cycle) with Ψ(k)ᵀ and
    y(k); ``theta`` is θ̂(k). ``forgetting`` < 1 gives exponential forgetting (1 = the paper's).
    """

    def __init__(
        self,
        n_params: int,
        *,
        p0: float = PAPER_P0,
        theta0: np.ndarray | None = None,
        forgetting: float = 1.0,
    ) -> None:
        if not 0 < forgetting <= 1:
            raise ValueError(f"forgetting factor must be in (0, 1], got {forgetting}")
        if not p0 > 0:
            raise ValueError(f"P(0) scale must be > 0, got {p0}")
        self.P = np.eye(n_params) * p0
        self.theta = np.zeros(n_params) if theta0 is None else np.array(theta0, dtype=float)
        self.forgetting = forgetting
        self.updates = 0

    def update(
        self, psi_t: np.ndarray, y: np.ndarray, weight: float | np.ndarray = 1.0
    ) -> np.ndarray:
        """One step: ``psi_t`` is Ψ(k)ᵀ (m, p), ``y`` is y(k) (m,); returns θ̂(k).

        e(k) = y(k) − Ψ(k)ᵀ θ̂(k−1)                                      eq. (22)
        θ̂(k) = θ̂(k−1) + P(k−1) Ψ(k) [I + Ψ(k)ᵀ P(k−1) Ψ(k)]⁻¹ e(k)       eq. (20)
        P(k) = P(k−1) − P(k−1) Ψ(k) [I + Ψ(k)ᵀ P(k−1) Ψ(k)]⁻¹ Ψ(k)ᵀ P(k−1)  eq. (21)
        A ``weight`` w scales the row (Ψ, y) by √w (0 skips it).
        """
        psi_t = np.atleast_2d(psi_t)
        y = np.atleast_1d(y)
        w = np.sqrt(np.broadcast_to(np.asarray(weight, dtype=float), y.shape))
        if not w.any():
            return self.theta
        psi_t = psi_t * w[:, None]
        y = y * w
        e = y - psi_t @ self.theta  # eq. (22)
        PPsi = self.P @ psi_t.T  # P(k−1) Ψ(k), (p, m)
        S = self.forgetting * np.eye(len(y)) + psi_t @ PPsi
        gain = PPsi / S[0, 0] if len(y) == 1 else np.linalg.solve(S, PPsi.T).T
        self.theta = self.theta + gain @ e  # eq. (20)
        self.P = (self.P - gain @ PPsi.T) / self.forgetting  # eq. (21)
        self.P = 0.5 * (self.P + self.P.T)  # keep it symmetric against round-off
        self.updates += 1
        return self.theta


def recursive_least_squares(
    Psi: np.ndarray,
    y: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    p0: float = PAPER_P0,
    forgetting: float = 1.0,
    keep: np.ndarray | None = None,
) -> np.ndarray:
    """Run RLS (eqs. (20)-(22)) over a whole regression; returns θ̂(k) for every k, (K, p), or
    only at the rows ``keep`` (increasing indices), (len(keep), p): a long recording's report
    needs a few hundred points of the history, not K of them (issue 13: memory)."""
    Psi = np.asarray(Psi, dtype=float)
    K, m, p = Psi.shape
    rls = RecursiveLeastSquaresRows(p, m, K, keep=keep, p0=p0, forgetting=forgetting)
    rls.add(Psi, y, weights)
    return rls.history


class RecursiveLeastSquaresRows:
    """RLS (eqs. (20)-(22)) over the rows of a regression given chunk after chunk (P, θ̂ carried),
    keeping θ̂(k) only at the rows ``keep`` (increasing indices in [0, ``rows``); None: all):
    memory O(p² + len(keep)·p) whatever the number of rows (issue 13)."""

    def __init__(
        self,
        n_params: int,
        n_outputs: int,
        rows: int,
        *,
        keep: np.ndarray | None = None,
        p0: float = PAPER_P0,
        forgetting: float = 1.0,
    ) -> None:
        keep = np.arange(rows) if keep is None else np.asarray(keep, dtype=int)
        if len(keep) and (keep[0] < 0 or keep[-1] >= rows or np.any(np.diff(keep) <= 0)):
            raise ValueError(f"keep must be increasing row indices in [0, {rows}), got {keep}")
        self.keep = keep
        self.history = np.empty((len(keep), n_params))
        self.scalar = n_outputs == 1 and forgetting == 1.0
        self.rls = RecursiveLeastSquares(n_params, p0=p0, forgetting=forgetting)
        self.row = 0  # rows seen
        self.slot = 0  # history entries filled

    def add(self, Psi: np.ndarray, y: np.ndarray, weights: np.ndarray | None = None) -> None:
        """The next rows: Psi (K, m, p), y (K, m), weights (K, m) (None: 1)."""
        Psi = np.asarray(Psi, dtype=float)
        y = np.asarray(y, dtype=float)
        K, m, _p = Psi.shape
        w = np.ones((K, m)) if weights is None else np.asarray(weights, dtype=float)
        end = self.row + K
        stop = int(np.searchsorted(self.keep, end))
        local = self.keep[self.slot : stop] - self.row
        if self.scalar:
            rls = self.rls
            rls.theta, rls.P = _scalar_rls(
                Psi[:, 0, :], y[:, 0], w[:, 0], rls.theta, rls.P, local,
                self.history[self.slot : stop],
            )  # fmt: skip
        else:
            rls = self.rls
            rls.theta, rls.P, updates = _vector_rls(
                Psi, y, w, rls.theta, rls.P, rls.forgetting, local,
                self.history[self.slot : stop],
            )  # fmt: skip
            rls.updates += updates
        self.row, self.slot = end, stop


def _vector_rls(
    Psi: np.ndarray,
    y: np.ndarray,
    w: np.ndarray,
    theta: np.ndarray,
    P: np.ndarray,
    forgetting: float,
    keep: np.ndarray,
    out: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Vector-error RLS, eqs. (20)-(22), over rows Psi (K, m, p), y (K, m), weights w (K, m)
    from θ̂ and P: :meth:`RecursiveLeastSquares.update` row after row, the same floating-point
    operations in the same order (so the same bits), with what does not depend on θ̂ or P (the
    rows' √w scaling, I) done for the whole chunk at once and no per-row argument checks: the
    per-row Python cost is most of the 2-DOF identification's (issue 13). θ̂(k) at the rows
    ``keep`` into ``out``. Returns the final (θ̂, P) and the number of updates."""
    K, m, _p = Psi.shape
    sw = np.sqrt(w)
    phi_rows = Psi * sw[:, :, None]  # Ψ(k)ᵀ√w, each row as update() scales it
    y_rows = y * sw
    used = sw.any(axis=1)
    eye = forgetting * np.eye(m)
    solve, matmul = _SOLVE, np.matmul
    slot = updates = 0
    for k in range(K):
        if used[k]:
            phi = phi_rows[k]
            e = y_rows[k] - matmul(phi, theta)  # eq. (22)
            PPsi = matmul(P, phi.T)
            S = eye + matmul(phi, PPsi)
            gain = solve(S, PPsi.T).T
            theta = theta + matmul(gain, e)  # eq. (20)
            P = (P - matmul(gain, PPsi.T)) / forgetting  # eq. (21)
            P = 0.5 * (P + P.T)
            updates += 1
        if slot < len(keep) and keep[slot] == k:
            out[slot] = theta
            slot += 1
    return theta, P, updates


def _scalar_rls(
    psi: np.ndarray,
    y: np.ndarray,
    w: np.ndarray,
    theta: np.ndarray,
    P: np.ndarray,
    keep: np.ndarray,
    out: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Scalar-error RLS, eqs. (20)-(22) with m = 1, as a tight loop (no m×m solve) from θ̂ and
    P; θ̂(k) at the rows ``keep`` into ``out``. Returns the final (θ̂, P)."""
    K = len(psi)
    sw = np.sqrt(w)
    phi_rows = psi * sw[:, None]  # the rows' √w scaling for the whole chunk: the same products
    y_rows = y * sw
    used = sw != 0
    slot = 0
    for k in range(K):
        if used[k]:
            phi = phi_rows[k]
            Pphi = P @ phi
            gain = Pphi / (1.0 + phi @ Pphi)
            theta = theta + gain * (y_rows[k] - phi @ theta)
            P = P - gain[:, None] * Pphi  # np.outer(gain, Pphi) without its Python wrapper
        if slot < len(keep) and keep[slot] == k:
            out[slot] = theta
            slot += 1
    return theta, P


class LeastSquaresRows:
    """Least squares over the rows of a regression given chunk after chunk, in O(p²) memory
    whatever the number of rows (issue 13): the triangular factor R of the weighted rows
    [A | b] is updated by a QR factorization of [R; next chunk] (a tall-skinny QR), so the
    solve is as well conditioned as a QR of all rows at once (the normal equations would square
    the condition number: 1e-10 relative on the supplied-energy model). ``rows`` counts the
    rows seen (K), ``used`` the (row, channel) pairs of weight > 0."""

    def __init__(self, n_params: int) -> None:
        self.p = n_params
        self.R = np.zeros((0, n_params + 1))
        self.rows = 0
        self.used = 0

    def add(self, Psi: np.ndarray, y: np.ndarray, weights: np.ndarray | None = None) -> None:
        """Rows Psi (K, m, p), y (K, m), weights (K, m) ≥ 0 (None: 1; 0 leaves a row out)."""
        Psi = np.asarray(Psi, dtype=float)
        K, m, p = Psi.shape
        rows = np.empty((K * m, p + 1))
        rows[:, :p] = Psi.reshape(K * m, p)
        rows[:, p] = np.asarray(y, dtype=float).reshape(K * m)
        if weights is not None:
            sw = np.sqrt(np.asarray(weights, dtype=float).reshape(K * m))
            rows *= sw[:, None]
            self.used += int(np.count_nonzero(sw))
        else:
            self.used += K * m
        require_finite(rows, "least-squares rows")
        self.R = np.linalg.qr(np.vstack([self.R, rows]), mode="r")
        self.rows += K

    def solve(self) -> np.ndarray:
        """argmin Σ w (y − Ψᵀθ)² (minimum norm if rank deficient), columns scaled so the solve
        does not depend on the units of θ (θ4 ~ 40 Nm, θ2 ~ 0.08 kg m²)."""
        R, z = self.R[:, : self.p], self.R[:, self.p]
        scale = np.linalg.norm(R, axis=0)  # = the columns' norms over all rows
        scale[scale == 0] = 1.0
        sol, *_ = np.linalg.lstsq(R / scale, z, rcond=None)
        return sol / scale

    def solve_bounded(self, lower: np.ndarray) -> np.ndarray:
        """argmin Σ w (y − Ψᵀθ)² subject to θ ≥ ``lower`` (−inf: free), the same rows'
        normal equations RᵀR θ = Rᵀz given to :func:`bounded_quadratic_fit` (BVLS)."""
        R, z = self.R[:, : self.p], self.R[:, self.p]
        return bounded_quadratic_fit(R.T @ R, R.T @ z, np.asarray(lower, dtype=float))[0]


def least_squares(Psi: np.ndarray, y: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Batch (weighted) least squares: argmin Σ w (y − Ψᵀθ)², the limit of eqs. (18)-(19) with
    P(0)⁻¹ → 0 (:class:`LeastSquaresRows`). Rows with weight 0 are left out."""
    ne = LeastSquaresRows(np.shape(Psi)[-1])
    ne.add(Psi, y, weights)
    return ne.solve()


WLS_WINDOW = 200  # rows of the moving mean of squared residuals (feasible WLS)


def weighted_least_squares(
    Psi: np.ndarray,
    y: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    window: int = WLS_WINDOW,
    lower: np.ndarray | None = None,
) -> np.ndarray:
    """Feasible weighted least squares: fit by least squares, estimate each row's noise variance
    from the residuals (per output channel, as a moving mean of squared residuals over
    ``window`` rows, so slowly changing noise levels are followed), refit with weights 1/σ².

    For the filtered dynamic model this balances the two joints (joint 1's torques are ten
    times joint 2's, so plain least squares all but ignores joint 2's equation); for the
    scalar models it down-weights stretches where the residual is large. The same three steps
    over rows in chunks: :class:`ResidualLevel`, :class:`WeightedRefit`. ``lower``: the refit
    bounded below (−inf: free; :meth:`LeastSquaresRows.solve_bounded`) on the same weighted
    rows, when the unbounded one is not within the bounds.
    """
    Psi = np.asarray(Psi, dtype=float)
    y = np.asarray(y, dtype=float)
    theta = least_squares(Psi, y, weights)
    level = ResidualLevel(theta, y.shape[1])
    level.add(Psi, y, weights)
    refit = WeightedRefit(theta, level.level(), len(y), window=window)
    refit.add(Psi, y, weights)
    theta = refit.solve()
    if lower is None or np.all(theta >= lower):
        return theta
    return refit.ne.solve_bounded(lower)


class ResidualLevel:
    """Feasible WLS, step 2: the mean squared residual of θ per output channel over the rows of
    weight > 0 (1 where a channel has none), the floor of the variance estimate."""

    def __init__(self, theta: np.ndarray, n_outputs: int) -> None:
        self.theta = np.asarray(theta, dtype=float)
        self.sum = np.zeros(n_outputs)
        self.count = np.zeros(n_outputs, dtype=int)

    def add(self, Psi: np.ndarray, y: np.ndarray, weights: np.ndarray | None = None) -> None:
        r2 = (np.asarray(y, dtype=float) - np.einsum("kmp,p->km", Psi, self.theta)) ** 2
        base = np.ones(r2.shape) if weights is None else np.asarray(weights, dtype=float)
        for j in range(r2.shape[1]):
            used = base[:, j] > 0
            self.sum[j] += np.sum(r2[used, j])
            self.count[j] += int(used.sum())

    def level(self) -> np.ndarray:
        return np.where(self.count > 0, self.sum / np.maximum(self.count, 1), 1.0)


class WeightedRefit:
    """Feasible WLS, step 3: each row's noise variance per channel, the moving mean of θ's
    squared residuals over ``window`` rows centred as ``np.convolve(..., "same")`` (floored at
    1e-6 of ``level``), and the least squares refit with weights base/σ². Rows come chunk after
    chunk; a chunk's variances wait for the next ``window``/2 rows, so memory is a few chunks
    whatever the number of rows. ``rows``: the regression's total (a window longer than the
    rows is cut to them, as a whole-array convolution would)."""

    def __init__(
        self, theta: np.ndarray, level: np.ndarray, rows: int, *, window: int = WLS_WINDOW
    ) -> None:
        self.theta = np.asarray(theta, dtype=float)
        self.floor = 1e-6 * np.asarray(level, dtype=float) + 1e-300
        self.window = max(1, min(int(window), int(rows)))
        self.right = (self.window - 1) // 2  # rows after a row in its mean
        self.left = self.window - 1 - self.right  # rows before it
        self.before: np.ndarray | None = None  # squared residuals of the last `left` rows
        self.pending: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self.ne = LeastSquaresRows(len(self.theta))

    def add(self, Psi: np.ndarray, y: np.ndarray, weights: np.ndarray | None = None) -> None:
        Psi = np.asarray(Psi, dtype=float)
        y = np.asarray(y, dtype=float)
        base = np.ones(y.shape) if weights is None else np.asarray(weights, dtype=float)
        r2 = (y - np.einsum("kmp,p->km", Psi, self.theta)) ** 2
        if self.before is None:
            self.before = np.zeros((0, y.shape[1]))
        self.pending.append((Psi, y, base, r2))
        while len(self.pending) > 1 and sum(len(c[3]) for c in self.pending[1:]) >= self.right:
            self._refit_first(end=False)

    def _refit_first(self, *, end: bool) -> None:
        Psi, y, base, r2 = self.pending.pop(0)
        after = [c[3] for c in self.pending]
        m = r2.shape[1]
        ahead = np.concatenate([*after, np.zeros((0, m))])[: self.right]
        if len(ahead) < self.right:  # past the last row: zeros, as the convolution's edge
            assert end or not self.pending
            ahead = np.vstack([ahead, np.zeros((self.right - len(ahead), m))])
        behind = self.before
        if len(behind) < self.left:  # before the first row: zeros
            behind = np.vstack([np.zeros((self.left - len(behind), m)), behind])
        context = np.vstack([behind, r2, ahead])
        kernel = np.ones(self.window) / self.window
        var = np.empty_like(r2)
        for j in range(m):
            smooth = np.convolve(context[:, j], kernel, mode="valid")
            var[:, j] = np.maximum(smooth, self.floor[j])
        self.ne.add(Psi, y, base / var)
        self.before = np.vstack([self.before, r2])[max(0, len(self.before) + len(r2) - self.left) :]

    def solve(self) -> np.ndarray:
        while self.pending:
            self._refit_first(end=True)
        return self.ne.solve()


# ---- normal equations in blocks: bounded memory, bounded estimates, uncertainty -----------------


class BlockNormalEquations:
    """Σ ΨᵀΨ, Σ Ψᵀy, Σ yᵀy per output channel and per time block, accumulated chunk by chunk.

    Memory is O(blocks · m · p²) whatever the number of rows, and everything the estimates and
    their uncertainty need is here: a (weighted) least-squares solve sums the blocks; a blocked
    bootstrap resamples them (rows within a block stay together, so residual correlation shorter
    than a block is kept).
    """

    def __init__(self, n_params: int, n_outputs: int, block_s: float) -> None:
        if not block_s > 0:
            raise ValueError(f"block length must be > 0 s, got {block_s}")
        self.p, self.m, self.block_s = n_params, n_outputs, float(block_s)
        self._H: dict[int, np.ndarray] = {}
        self._g: dict[int, np.ndarray] = {}
        self._yy: dict[int, np.ndarray] = {}
        self._n: dict[int, np.ndarray] = {}
        self.t0: float | None = None

    def add(self, t: np.ndarray, y: np.ndarray, Psi: np.ndarray, weights: np.ndarray) -> None:
        """Add rows (t (K,), y (K, m), Psi (K, m, p), weights (K, m) in {0, 1} or ≥ 0)."""
        if len(t) == 0:
            return
        if self.t0 is None:
            self.t0 = float(t[0])
        block = np.floor((np.asarray(t) - self.t0) / self.block_s).astype(int)
        sw = np.sqrt(np.asarray(weights, dtype=float))
        A = Psi * sw[..., None]
        b = y * sw
        for blk in np.unique(block):
            sel = block == blk
            Ab, bb = A[sel], b[sel]
            H = np.einsum("kmp,kmq->mpq", Ab, Ab)
            g = np.einsum("kmp,km->mp", Ab, bb)
            yy = np.einsum("km,km->m", bb, bb)
            n = np.sum(sw[sel] > 0, axis=0)
            if blk in self._H:
                self._H[blk] += H
                self._g[blk] += g
                self._yy[blk] += yy
                self._n[blk] += n
            else:
                self._H[blk], self._g[blk], self._yy[blk], self._n[blk] = H, g, yy, n

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(H (B, m, p, p), g (B, m, p), yy (B, m), n (B, m)) over the non-empty blocks."""
        keys = sorted(k for k in self._H if self._n[k].sum() > 0)
        if not keys:
            raise ValueError("no usable rows (every row excluded)")
        return (
            np.stack([self._H[k] for k in keys]),
            np.stack([self._g[k] for k in keys]),
            np.stack([self._yy[k] for k in keys]),
            np.stack([self._n[k] for k in keys]),
        )


def require_finite(a: np.ndarray, what: str) -> None:
    """ValueError unless every entry of ``a`` is finite. LAPACK given a NaN or an infinity
    prints "On entry to DLASCL parameter number 4 had an illegal value" on stdout (Fortran's
    unit 6, out of Python's reach) and fails with no cause named; checked before every solve.
    The recording reader bounds its values (drivers.recording.MAX_ABS_VALUE), so this is a
    guard for rows that overflowed in between."""
    if not np.all(np.isfinite(a)):
        bad = np.argwhere(~np.isfinite(a))[0]
        raise ValueError(
            f"{what}: a non-finite number at index {tuple(int(i) for i in bad)} (an overflow "
            "from values out of range?); nothing solved"
        )


def solve_normal_equations(H: np.ndarray, g: np.ndarray) -> np.ndarray:
    """argmin θᵀHθ − 2gᵀθ with column scaling (units of θ differ by orders of magnitude)."""
    require_finite(H, "normal equations")
    require_finite(g, "normal equations")
    d = np.sqrt(np.diag(H))
    d[d == 0] = 1.0
    Hs = H / np.outer(d, d)
    sol, *_ = np.linalg.lstsq(Hs, g / d, rcond=None)
    return sol / d


# Above this condition number of the column-scaled normal matrix (a design conditioned worse
# than 1e5) the normal equations are not trusted (:func:`least_squares_rows`).
NORMAL_EQUATIONS_MAX_COND = 1e10
# An eigenvalue of the column-scaled normal matrix below this fraction of the largest is zero
# to its rounding (~5 ε): a direction the design does not see at all (dependent columns).
NULL_EIGENVALUE = 1e-15


def least_squares_rows(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """argmin ‖A θ − b‖ for a tall A (K, p): the corrected semi-normal equations (Björck (1996)
    §6.6.5: the column-scaled normal equations by Cholesky, then one refinement step on the
    residual, as accurate as QR for a design conditioned better than ~1e7, for a tenth of its
    time on 10⁵ rows); a column zero on every row gets 0. Where the scaled normal matrix is
    singular because columns are exactly dependent (its eigenvalues either zero to rounding or
    conditioned better than :data:`NORMAL_EQUATIONS_MAX_COND`), the same equations on the
    directions the rows see, then the minimum-norm θ (numpy's SVD least squares' answer, for a
    fifth of its time); otherwise that SVD itself. A and b finite (:func:`require_finite`: the
    caller names them)."""
    from scipy.linalg import LinAlgError, cho_factor, cho_solve

    G = A.T @ A
    used = np.diag(G) > 0.0
    d = np.sqrt(np.diag(G)[used])
    Gs = G[np.ix_(used, used)] / np.outer(d, d)
    theta = np.zeros(A.shape[1])
    if not used.any():
        return theta
    solve = None
    if np.linalg.cond(Gs) <= NORMAL_EQUATIONS_MAX_COND:
        with contextlib.suppress(LinAlgError):
            factor = cho_factor(Gs)
            solve = lambda rhs: cho_solve(factor, rhs)  # noqa: E731
    null = None
    if solve is None:
        w, V = np.linalg.eigh(Gs)
        seen = w > NULL_EIGENVALUE * w[-1]
        if not seen.all() and w[-1] <= NORMAL_EQUATIONS_MAX_COND * w[seen][0]:
            Vs, ws = V[:, seen], w[seen]
            solve = lambda rhs: Vs @ ((Vs.T @ rhs) / ws)  # noqa: E731
            null = V[:, ~seen] / d[:, None]  # the unscaled directions A does not see
    if solve is None:
        theta = np.linalg.lstsq(A, b, rcond=None)[0]
        theta[~used] = 0.0
        return theta
    theta[used] = solve((A.T @ b)[used] / d) / d
    residual = b - A @ theta
    theta[used] += solve((A.T @ residual)[used] / d) / d
    if null is not None:  # the minimum-norm θ: no part along what the rows cannot see
        part = theta[used]
        part -= null @ np.linalg.solve(null.T @ null, null.T @ part)
        theta[used] = part
    return theta


def channel_weights(H, g, yy, n, theta) -> np.ndarray:
    """1/σ_j² per output channel from the residuals of θ (feasible weighted least squares, so a
    joint with ten times the torque does not drown the other's equation)."""
    rss = np.einsum("bm->m", yy) - 2 * np.einsum("bmp,p->m", g, theta)
    rss = rss + np.einsum("p,bmpq,q->m", theta, H, theta)
    var = np.maximum(rss, 1e-300) / np.maximum(n.sum(axis=0), 1)
    return 1.0 / var


def combine(H, g, yy, w) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted sums over channels, per block: (H (B, p, p), g (B, p), yy (B,))."""
    return (
        np.einsum("m,bmpq->bpq", w, H),
        np.einsum("m,bmp->bp", w, g),
        np.einsum("m,bm->b", w, yy),
    )


def bounded_quadratic_fit(
    H: np.ndarray,
    g: np.ndarray,
    lower: np.ndarray,
    constraints: list | None = None,
    x0: np.ndarray | None = None,
) -> tuple[np.ndarray, str]:
    """argmin θᵀHθ − 2gᵀθ subject to θ ≥ ``lower`` (−inf for free) and optional nonlinear
    inequality constraints c(θ) ≥ 0 (scipy form). Bounds alone: a bounded linear least-squares
    problem on the Cholesky factor of H (scipy ``lsq_linear``); with constraints: SLSQP from
    the bounded solution. Returns (θ, method)."""
    from scipy.optimize import lsq_linear, minimize

    p = len(g)
    d = np.sqrt(np.diag(H))
    d[d == 0] = 1.0
    Hs = H / np.outer(d, d)
    gs = g / d
    # Hs = V diag(w) Vᵀ: ‖diag(√w) Vᵀx − diag(1/√w) Vᵀg‖² = xᵀHx − 2gᵀx + const; directions
    # the data leave flat (w ≈ 0, a column of zeros or exact collinearity) drop out
    w, V = np.linalg.eigh(0.5 * (Hs + Hs.T))
    keep = w > 1e-12 * max(float(w.max()), 1e-300)
    A = np.sqrt(w[keep])[:, None] * V[:, keep].T
    rhs = (V[:, keep].T @ gs) / np.sqrt(w[keep])
    lo = np.where(np.isfinite(lower), lower * d, -np.inf)
    res = lsq_linear(A, rhs, bounds=(lo, np.full(p, np.inf)), method="bvls")
    xs = res.x
    if not constraints:
        return xs / d, "bounded least squares (lsq_linear, BVLS)"
    scaled = [{"type": "ineq", "fun": (lambda x, f=c["fun"]: f(x / d))} for c in constraints]
    if all(c["fun"](xs) >= 0 for c in scaled):
        return xs / d, "bounded least squares (lsq_linear, BVLS)"
    out = minimize(
        lambda x: float(x @ Hs @ x - 2 * gs @ x),
        xs if x0 is None else x0 * d,
        jac=lambda x: 2 * (Hs @ x) - 2 * gs,
        bounds=[(lo_i, None) for lo_i in lo],
        constraints=scaled,
        method="SLSQP",
        options={"maxiter": 500, "ftol": 1e-14},
    )
    return out.x / d, f"constrained least squares (SLSQP: {out.message})"


def blocked_bootstrap(
    H: np.ndarray, g: np.ndarray, *, draws: int = 200, seed: int = 0
) -> np.ndarray:
    """θ of ``draws`` resamples of the blocks (with replacement); shape (draws, p)."""
    rng = np.random.default_rng(seed)
    B = len(H)
    out = np.empty((draws, H.shape[-1]))
    for i in range(draws):
        pick = np.bincount(rng.integers(0, B, B), minlength=B).astype(float)
        out[i] = solve_normal_equations(np.einsum("b,bpq->pq", pick, H), pick @ g)
    return out


def standard_errors(
    Hw: np.ndarray,
    gw: np.ndarray,
    yyw: np.ndarray,
    rows: int,
    theta: np.ndarray,
    *,
    draws: int = 200,
) -> tuple[np.ndarray, np.ndarray]:
    """Standard errors of the least-squares θ of per-block weighted normal equations
    (Hw (B, p, p), gw (B, p), yyw (B,), :func:`combine`; ``rows`` (row, channel) pairs in all):
    ``se_white``, σ² (Σ Hw)⁻¹ with σ² the weighted residual variance (the rows' covariance if
    the residuals were white), and ``se_block``, the spread of :func:`blocked_bootstrap`'s θ
    (rows within a block stay together, so residual correlation shorter than a block is kept;
    inf with fewer than 5 blocks)."""
    p = Hw.shape[-1]
    H_tot, g_tot = Hw.sum(0), gw.sum(0)
    dof = max(int(rows) - p, 1)
    rss_w = float(yyw.sum() - 2 * theta @ g_tot + theta @ H_tot @ theta)
    s2 = rss_w / dof  # ≈ 1 when the channel weights are right
    try:
        cov = s2 * np.linalg.pinv(H_tot)
        se_white = np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        se_white = np.full(p, np.inf)
    if len(Hw) >= 5:
        se_block = blocked_bootstrap(Hw, gw, draws=draws).std(axis=0, ddof=1)
    else:
        se_block = np.full(p, np.inf)
    return se_white, se_block


__all__ = [
    "LeastSquaresRows",
    "RecursiveLeastSquares",
    "RecursiveLeastSquaresRows",
    "ResidualLevel",
    "WeightedRefit",
    "blocked_bootstrap",
    "bounded_quadratic_fit",
    "least_squares",
    "recursive_least_squares",
    "require_finite",
    "standard_errors",
    "weighted_least_squares",
]
