"""The regression of a recording's rows against θ₀ (:class:`Fit`): the residual r = y − Ψ θ₀,
the drift patterns' columns on it, blocked cross-validation of the recording's residual or of
the paired difference against the reference's rows (:meth:`Fit.judged_cv`), the Gauss–Newton
refinement of nonlinear patterns, and the held-out torque errors of θ₀ with the patterns.

Imports :mod:`hil.diagnose.drift.terms`, the effects, the held-out stage and the selection's
problem and statistics.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hil.diagnose.drift.terms import SAME_MOTION, Term
from hil.diagnose.effects import REGISTRY, Context
from hil.diagnose.effects.base import REFINE_STEPS
from hil.diagnose.heldout import (
    held_out_masks,
    nrmse_or_none,
)
from hil.diagnose.physical import jackknife_se
from hil.diagnose.problem import Problem, build_problem, fit_theta, robust_scale
from hil.diagnose.stats import (
    CrossValidation,
    block_stats,
    cross_validate,
    full_fit_sse,
    target_block_sums,
)
from hil.model.protocol import ArmDynamics

STEP_HALVINGS = 4  # a Gauss–Newton step that raises the fit's error is halved at most this often
# the starting points fitted one by one after the screen of all of them (:meth:`Fit.screen`):
# the screen's sums and the fit's agree to rounding, which decides only between near-equal
# fits; the fit of each decides among these
SCREEN_KEPT = 3
SCREEN_CHUNK_BYTES = 16 * 2**20  # the starts' columns held at once by the screen


@dataclass
class Fit:
    prob: Problem
    ctx: Context
    residual: np.ndarray  # raw (K, n): y − Ψ θ₀
    scale: np.ndarray  # (n,)
    starts: np.ndarray
    baseline: list[tuple] = field(default_factory=list)  # Nominal.terms
    # the reference recordings' rows against the same θ₀ (:func:`change_in_se`), when θ₀ was
    # identified from them
    reference: Fit | None = None
    paired: bool = False  # the reference ran the same motion, block for block (SAME_MOTION)
    # the reference rows' build of each term, at the one linearisation point last asked: a
    # term stepped by Gauss–Newton leaves its old points behind (twenty builds of a Panda
    # payload's columns kept were 0.2 GB)
    _ref_terms: dict[str, tuple[str, Term]] = field(default_factory=dict)
    # the patterns no torque of the recordings changes with (:func:`select.unseen`), by key
    unseen: dict[str, Term] = field(default_factory=dict)

    def on_reference(self, term: Term) -> Term:
        """``term`` (same effect, joint and linearisation point) built on the reference rows."""
        assert self.reference is not None
        at = repr(term.at)
        kept = self._ref_terms.get(term.key)
        if kept is None or kept[0] != at:
            kept = (at, self.reference.build(Term(term.effect, term.joint, term.at)))
            self._ref_terms[term.key] = kept
        return kept[1]

    def _reference_shift(self, term: Term) -> np.ndarray | None:
        """The model's change at ``term``'s point on the reference rows (:meth:`Effect.shift`),
        without the columns :meth:`on_reference` builds: the paired difference needs only
        that (a cogging's period search built 2,800 reference columns for it on a Panda)."""
        assert self.reference is not None
        kept = self._ref_terms.get(term.key)
        if kept is not None and kept[0] == repr(term.at):
            return kept[1].shift
        return term.effect.shift(self.reference.ctx, term.joint, term.at)

    def target(self, terms: Sequence[Term]) -> np.ndarray:
        r = self.residual
        shifts = [t.shift for t in terms if t.shift is not None]
        if shifts:
            r = r - sum(shifts)
        return r / self.scale

    def design(self, terms: Sequence[Term]) -> np.ndarray:
        cols = [t.cols / self.scale[None, :, None] for t in terms]
        return np.concatenate(cols, axis=-1)

    def cv(self, terms: Sequence[Term], w: np.ndarray | None = None) -> CrossValidation:
        w = self.prob.w if w is None else w
        y = self.target(terms)
        if not terms:  # nothing fitted: every block's error is its own residual
            held = np.add.reduceat(w * y * y, self.starts, axis=0)
            B = len(self.starts)
            return CrossValidation(
                held, np.zeros(B, int), np.zeros((B, 0)), 0, np.zeros(0), held.sum(axis=0)
            )
        return cross_validate(block_stats(self.design(terms), y, w, self.prob.blocks))

    def judged_cv(self, terms: Sequence[Term]) -> CrossValidation:
        """The cross-validation a pattern's held-out proof is read from: of the recording's
        residual; when the recording reruns the reference's motion (:attr:`paired`), of the
        paired difference r_rec − r_ref (each less its terms' model change at their
        linearisation point) against the recording's columns, where the model error both
        share cancels row by row and what is left is the change (a 5 ms delay lowers the
        error of a DFKI recording against θ₀ by 0.5 % in 12 of 39 blocks: the model error, not
        the delay, decides each block there)."""
        if not (self.paired and self.reference is not None):
            return self.cv(terms)
        cols, y, w = self.judged_rows(terms)
        if not terms:
            held = np.add.reduceat(w * y * y, self.starts, axis=0)
            B = len(self.starts)
            return CrossValidation(
                held, np.zeros(B, int), np.zeros((B, 0)), 0, np.zeros(0), held.sum(axis=0)
            )
        return cross_validate(block_stats(np.concatenate(cols, axis=-1), y, w, self.prob.blocks))

    def judged_rows(self, terms: Sequence[Term]) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
        """The scaled columns of each term (K, n, width), the target (K, n) and the weights
        (K, n) that :meth:`judged_cv` fits: the recording's residual, or the paired difference
        against the reference's rows."""
        if not (self.paired and self.reference is not None):
            cols = [t.cols / self.scale[None, :, None] for t in terms]
            return cols, self.target(terms), self.prob.w
        ref = self.reference
        w = np.minimum(self.prob.w, ref.prob.w)
        r = self.residual - ref.residual
        for t in terms:
            if t.shift is not None:
                r = r - t.shift
            if t.effect.shifts_recorded_torque:
                continue  # the recorded torques' own change: on the recording's side alone
            back_shift = self._reference_shift(t)
            if back_shift is not None:
                r = r + back_shift
        recorded = ref.prob.y_raw
        cols = []
        for t in terms:
            c = t.effect.paired_columns(self.ctx, t.joint, t.at, recorded)
            cols.append((t.cols if c is None else c) / self.scale[None, :, None])
        return cols, r / self.scale, w

    def change(
        self, terms: Sequence[Term], beta: np.ndarray, beta_back: np.ndarray, se: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The coefficients of ``terms``' change since the reference and their SE, term by term
        (:meth:`hil.diagnose.effects.base.Effect.change`), from the recording's ``beta``, the
        reference's ``beta_back`` and ``se`` (of their difference)."""
        parts = [
            t.effect.change(b, b_back, s)
            for t, b, b_back, s in zip(
                terms,
                self.split(beta, terms),
                self.split(beta_back, terms),
                self.split(se, terms),
                strict=True,
            )
        ]
        if not parts:
            return beta - beta_back, se
        return np.concatenate([b for b, _ in parts]), np.concatenate([s for _, s in parts])

    def since_reference(
        self, terms: Sequence[Term], cv: CrossValidation, w_back: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, list[Any]]:
        """The change since the reference of ``terms`` fitted in ``cv`` (the recording's rows):
        the same terms fitted on the reference's rows (weights ``w_back``; None: all), their
        coefficients taken off term by term (:meth:`change`), the SE that of the difference
        (:func:`change_se`), and where each change is read (:meth:`Effect.change_point`)."""
        assert self.reference is not None
        back = self.reference.cv([self.on_reference(t) for t in terms], w_back)
        se = change_se(cv.fold_beta, back.fold_beta, self.paired)
        beta, se = self.change(terms, cv.beta, back.beta, se)
        ats = [t.effect.change_point(self.ctx, t.joint, t.at) for t in terms]
        if self.paired and any(t.effect.shifts_recorded_torque for t in terms):
            # the paired difference is that change itself, at the term's own point (the two
            # sides' own residuals carry the model's error, which moved a 1-row delay's change
            # on a DFKI A.0 recording to 0.73 rows at 3.2 SE; the paired fit reads 1.00 row)
            judged = self.judged_cv(terms)
            parts, se_parts = (
                self.split(judged.beta, terms),
                self.split(jackknife_se(judged.fold_beta), terms),
            )
            at = 0
            for i, t in enumerate(terms):
                if t.effect.shifts_recorded_torque:
                    beta[at : at + t.width], se[at : at + t.width] = parts[i], se_parts[i]
                    ats[i] = t.at
                at += t.width
        return beta, se, ats

    def build(self, term: Term) -> Term:
        term.cols = np.nan_to_num(term.effect.columns(self.ctx, term.joint, term.at))
        term.shift = term.effect.shift(self.ctx, term.joint, term.at)
        return term

    def split(self, beta: np.ndarray, terms: Sequence[Term]) -> list[np.ndarray]:
        out, at = [], 0
        for t in terms:
            out.append(beta[at : at + t.width])
            at += t.width
        return out

    def refine(self, terms: list[Term], only: Term | None = None) -> None:
        """Gauss–Newton steps of the nonlinear terms (``only``: of that one, the first time
        from the best-fitting of its starting points, :meth:`Effect.starts`), all terms
        refitted each step."""
        if not any(t.effect.nonlinear for t in terms):
            return
        if only is not None and only.effect.nonlinear and not only.searched:
            only.searched = True
            starts = only.effect.starts(self.ctx, only.joint)
            if len(starts) > 1:
                best = None
                for s in self.screen(terms, only, starts):
                    only.at = s
                    self.build(only)
                    only.cols = only.effect.point_columns(self.ctx, only.cols)
                    sse = float(self.judged_cv(terms).sse.sum())
                    if np.isfinite(sse) and (best is None or sse < best[0]):
                        best = (sse, s)
                only.at = starts[0] if best is None else best[1]
                self.build(only)
                if self.reference is not None:  # the reference's rows of the starts not kept
                    self._ref_terms.pop(only.key, None)
        self._steps(terms, only)

    def screen(self, terms: list[Term], only: Term, starts: list[Any]) -> list[Any]:
        """Of ``only``'s starting points, the :data:`SCREEN_KEPT` whose columns fit best with
        the other ``terms`` (the in-sample error :meth:`refine` compares them by), from one
        pass over the columns of all of them (an effect's ``start_columns``: a cogging's
        hundreds of periods; each built and fitted alone took a column build on both sides
        and a blocked fit per period), in the order given; all of them where the effect has
        no such columns or its columns at a start are not those the fit takes (a model
        change at the point, the paired difference's own columns)."""
        batched = getattr(only.effect, "start_columns", None)
        if batched is None or len(starts) <= SCREEN_KEPT or only.shift is not None:
            return starts
        if self.paired and self.reference is not None:
            recorded = self.reference.prob.y_raw
            if only.effect.paired_columns(self.ctx, only.joint, only.at, recorded) is not None:
                return starts
        cols, y, w = self.judged_rows([t for t in terms if t is not only])
        Z = np.concatenate(cols, axis=-1) if cols else np.zeros((*y.shape, 0))
        p, j = Z.shape[-1], only.joint
        G = np.einsum("kn,knp,knq->pq", w, Z, Z)
        r = np.einsum("kn,knp,kn->p", w, Z, y)
        s_all = float(np.sum(w * y * y))
        # the starts' sums against the other columns and the target on joint j's rows, a
        # chunk of starts at a time (:data:`SCREEN_CHUNK_BYTES`)
        K, width = len(y), only.width
        per = max(1, SCREEN_CHUNK_BYTES // (8 * K * width))
        sse = []
        for X in batched(self.ctx, j, starts, per):  # (K, V, width) on joint j's rows
            X = X / self.scale[j]
            V = X.shape[1]
            uyx, xx = target_block_sums([Z[:, j, :], y[:, j, None]], X, w[:, j], [(0, K)])
            cross = uyx[0, :p].reshape(p, V, width).transpose(1, 0, 2)  # (V, p, width)
            full = np.empty((V, p + width, p + width))
            full[:, :p, :p] = G
            full[:, :p, p:] = cross
            full[:, p:, :p] = cross.transpose(0, 2, 1)
            full[:, p:, p:] = xx[0]
            rhs = np.concatenate([np.broadcast_to(r, (V, p)), uyx[0, p].reshape(V, width)], 1)
            sse.append(full_fit_sse(full, rhs, s_all))
        err = np.concatenate(sse)
        err = np.where(np.isfinite(err), err, np.inf)
        kept = np.sort(np.argsort(err, kind="stable")[:SCREEN_KEPT])
        return [starts[i] for i in kept]

    def _steps(self, terms: list[Term], only: Term | None) -> None:
        # a point that enters only its pattern's columns (a payload's centre) is stepped on
        # what the terms are judged on (:meth:`judged_cv`): against the reference's rerun of the
        # motion, the paired difference, where the model error both sides share cancels (on the
        # recording's own residual that error moved a DFKI C.0 payload's centre from 0.37 m to
        # 0.007 m). One with an exact model change at the point (an encoder angle, a delay:
        # :attr:`Term.shift`) is stepped on the recording's own residual: the paired difference
        # takes that change off both sides alike and does not see the point; unless the change
        # is the recorded torque's own (a delay: :attr:`Effect.shifts_recorded_torque`), which
        # the paired difference holds exactly and the recording's own residual under the
        # model's error (a 1-row delay on a DFKI A.0 recording stepped there fitted 17 % of
        # the change, and a 285-period cogging took the rest)
        stepped = [t for t in terms if t.effect.nonlinear and (only is None or t is only)]
        own = [t for t in stepped if t.shift is not None and not t.effect.shifts_recorded_torque]
        objective = self.cv if own else self.judged_cv
        cv = objective(terms)
        for _ in range(REFINE_STEPS):
            moved = []
            for t, b in zip(terms, self.split(cv.beta, terms), strict=True):
                if t.effect.nonlinear and (only is None or t is only):
                    at = t.effect.update(self.ctx, t.joint, b, t.at)
                    if t.effect.settled(t.at, at):
                        continue  # its columns stand: a rebuild gives them again
                    moved.append((t, t.at, at))
            if not moved:
                break  # nothing moved: the next step's fit is this one's
            # a step that raises the fit's error is halved (Gauss–Newton has no descent
            # guarantee: on a DFKI C.0 recording the 2-DOF payload's (m, m δl) stepped from
            # 0.2 m to a stationary point at 0.04 m that fitted three times worse)
            for _half in range(STEP_HALVINGS + 1):
                for t, _old, at in moved:
                    t.at = at
                    self.build(t)
                trial = objective(terms)
                if float(trial.sse.sum()) <= float(cv.sse.sum()):
                    break
                moved = [(t, old, _midpoint(old, at)) for t, old, at in moved]
            else:
                for t, old, _at in moved:  # no step lowers the error: the point stands
                    t.at = old
                    self.build(t)
                break
            cv = trial


def _midpoint(a: Any, b: Any) -> Any:
    """Half-way between two linearisation points (a number or an array, as ``a``)."""
    mid = 0.5 * (np.asarray(a, dtype=float) + np.asarray(b, dtype=float))
    return float(mid) if np.ndim(a) == 0 and not isinstance(a, np.ndarray) else mid


def make_fit(
    prob: Problem,
    model: ArmDynamics,
    theta0: np.ndarray,
    baseline: Sequence[tuple] = (),
    geometry: dict[str, float] | None = None,
    memo: dict | None = None,
) -> Fit:
    """The regression of ``prob``'s rows against θ₀ (with the ``baseline`` terms of the nominal
    model, :attr:`Nominal.terms`, taken off the residual). ``memo``: rows effects built before
    on the same rows at the same θ₀ (:attr:`Nominal.memo`)."""
    ctx = Context(prob.rows, model, theta0, prob.Psi_raw, geometry=geometry)
    if memo is not None:
        ctx.memo = memo
    residual = prob.y_raw - prob.Psi_raw @ theta0
    for name, joint, at, beta in baseline:
        effect = REGISTRY[name]
        residual = residual - effect.columns(ctx, joint, at) @ beta
        shift = effect.shift(ctx, joint, at)
        if shift is not None:
            residual = residual - shift
    ctx.prediction = prob.y_raw - residual
    scale = robust_scale(residual, prob.w)
    starts = np.flatnonzero(np.r_[True, np.diff(prob.blocks) != 0])
    return Fit(prob, ctx, residual, scale, starts, list(baseline))


def term_sizes(fit: Fit, terms: Sequence[Term], judged: Fit) -> tuple[float, np.ndarray]:
    """The last term's size (:meth:`Effect.estimate`, read in ``judged``'s context so that both
    sides of a comparison use one scale) fitted on ``fit``'s rows with the other ``terms``, and
    its size in every leave-one-block-out fit (B,)."""
    cv = fit.cv(terms)
    last = terms[-1]
    zero = np.zeros(last.width)

    def size(beta: np.ndarray) -> float:
        b = fit.split(beta, terms)[-1]
        return last.effect.estimate(judged.ctx, last.joint, b, zero, last.at)[1]

    return size(cv.beta), np.array([size(b) for b in cv.fold_beta])


def change_se(folds: np.ndarray, folds_back: np.ndarray, paired: bool) -> np.ndarray:
    """Blocked-jackknife standard error of a difference of two fits' coefficients (rows: the
    leave-one-block-out fits of each). ``paired`` (the same motion on both sides, block for
    block): block b is left out of both at once (the delete-a-pair jackknife), which keeps the
    covariance of the model error that falls in the same block on both sides and cancels in the
    difference; else the two jackknives combined as independent."""
    if paired and folds.shape[0] == folds_back.shape[0]:
        return jackknife_se(folds - folds_back)
    return np.hypot(jackknife_se(folds), jackknife_se(folds_back))


def same_motion(a: Problem, b: Problem) -> bool:
    """Whether ``a``'s rows run ``b``'s motion again: the same blocks, and regressor rows that
    differ by at most :data:`SAME_MOTION` of ``b``'s (the torque may differ: that is judged)."""
    if a.Psi_raw.shape != b.Psi_raw.shape or not np.array_equal(a.blocks, b.blocks):
        return False
    return bool(np.linalg.norm(a.Psi_raw - b.Psi_raw) <= SAME_MOTION * np.linalg.norm(b.Psi_raw))


def common_prefix(prob: Problem, reference: Problem, model: ArmDynamics) -> Problem:
    """The reference's rows over the recording's length when the recording is the reference's
    motion cut short (one recording each, the same sampling, the recording's angles those of
    the reference's first samples: a transport delay written into a copy drops its last rows),
    so that the two are compared block for block (:func:`same_motion`); else ``reference``."""
    if len(prob.rows) != 1 or len(reference.rows) != 1:
        return reference
    a, b = prob.rows[0], reference.rows[0]
    n = len(a.q)
    if not (n < len(b.q) and a.h == b.h and np.array_equal(a.q, b.q[:n])):
        return reference
    if (a.stamps is None) != (b.stamps is None) or (
        a.stamps is not None and not np.array_equal(a.stamps, b.stamps[:n])
    ):
        return reference
    t = None if b.stamps is None else b.stamps[:n]
    return build_problem([(b.q[:n], b.tau[:n], b.h, t)], model)[0]


def torque_errors(fit: Fit, terms: Sequence[Term]) -> dict[str, list[float | None]]:
    """Held-out torque NRMSE per joint of θ₀, θ₀ with ``terms`` (fitted on the training rows)
    and θ refitted on the training rows alone."""
    prob = fit.prob
    train, test, _ = held_out_masks(prob)
    w_train = prob.w * train[:, None]
    y = prob.y_raw
    pred0 = prob.y_raw - fit.residual  # θ₀ with the nominal model's baseline terms
    preds = {"nominal": pred0}
    if terms:
        cv = fit.cv(terms, w_train)
        drift = sum(
            (t.cols @ b + (0 if t.shift is None else t.shift))
            for t, b in zip(terms, fit.split(cv.beta, terms), strict=True)
        )
        preds["nominal_with_drift"] = pred0 + drift
    else:
        preds["nominal_with_drift"] = pred0
    theta = fit_theta(prob.Psi, prob.y, w_train, overwrite_design=True)  # Psi: a fresh copy
    preds["refit"] = prob.Psi_raw @ theta
    out: dict[str, list[float | None]] = {}
    for name, pred in preds.items():
        # None where the refit's report has none: too few usable held-out rows (a joint that
        # barely moves: 41 rows of a Panda joint gave "1.21e+03 %") or no spread
        out[name] = [
            nrmse_or_none(y, pred, test & (prob.w[:, j] > 0), j) for j in range(prob.n_joints)
        ]
    return out
