"""Selection of drift patterns against θ₀: a pattern's gate (its held-out proof, and against a
reference its change in standard errors, :func:`change_in_se`), greedy forward selection
(:func:`select_terms`), the patterns' sizes and standard errors (:func:`term_estimates`, θ₀'s
own uncertainty included) and the partners a pattern is confounded with.

Imports :mod:`hil.diagnose.drift.fit` and :mod:`hil.diagnose.drift.terms`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from hil.diagnose.drift.fit import Fit, change_se, term_sizes
from hil.diagnose.drift.terms import Term
from hil.diagnose.drift.unpaired import energy_outside, free_change_in_se
from hil.diagnose.effects import REGISTRY, Context
from hil.diagnose.physical import jackknife_se
from hil.diagnose.selection import FAMILY_ALPHA, MAX_ROUNDS, MIN_REDUCTION, passes
from hil.diagnose.stats import (
    CrossValidation,
    Evidence,
    column_scale,
    evidence,
)
from hil.model.tails import f_upper_tail, t_upper_quantile


def change_in_se(fit: Fit, others: Sequence[Term], term: Term) -> float:
    """How many standard errors ``term``'s size on the recording lies from its size on the
    reference rows, both fitted against the same θ₀ with the same ``others``: the change since
    the reference. A misfit of the model that both recordings share (a departure θ's terms
    cannot express, or the part of the reference residual that the bounded fit of θ₀ leaves
    along a pattern's column) has the same size on both sides and cancels; the per-block sign
    of the held-out improvement cannot tell that apart from a change, and on a model whose
    error is large against the change (30–50 % torque NRMSE on real arms) it misses changes
    that the coefficient resolves many times over: the cross term 2c⟨Ψθ₀, r⟩ of a gain c
    outweighs c²|Ψθ₀|² block by block, though not in total."""
    ref = fit.reference
    assert ref is not None
    if term.effect.sized_by_amplitude:
        return amplitude_change_in_se(fit, others, term)
    if term.effect.tested_jointly and term.width > 1:
        return joint_change_in_se(fit, others, term)
    if fit.paired and term.effect.shifts_recorded_torque:
        # the paired difference is the change itself (:meth:`Fit.since_reference`)
        beta, se, _at = fit.since_reference([*others, term], fit.cv([*others, term]))
        b, s = fit.split(beta, [*others, term])[-1], fit.split(se, [*others, term])[-1]
        _est, size, size_se = term.effect.estimate(fit.ctx, term.joint, b, s, term.at)
        return abs(size) / size_se if size_se > 0 else (np.inf if size != 0 else 0.0)
    rec, folds = term_sizes(fit, [*others, term], fit)
    back, folds_back = term_sizes(ref, [fit.on_reference(t) for t in [*others, term]], fit)
    se = float(change_se(folds[:, None], folds_back[:, None], fit.paired)[0])
    if not (np.isfinite(rec - back) and np.isfinite(se)):
        return 0.0  # a size the data do not bound (a gain β ≥ 1) resolves no change
    return abs(rec - back) / se if se > 0 else (np.inf if rec != back else 0.0)


def joint_change_in_se(fit: Fit, others: Sequence[Term], term: Term) -> float:
    """:func:`change_in_se` of a pattern whose coefficients are tested together
    (:attr:`Effect.tested_jointly`): Hotelling's T² of the change of its k coefficients,
    recording minus reference, over their blocked-jackknife covariance (block-paired: of each
    fold pair's difference; else the two sides' covariances added as independent), given as the
    Student-t quantile (B − 1 degrees of freedom) of the same two-sided p-value, so that one
    critical value judges every pattern."""
    ref = fit.reference
    assert ref is not None
    terms = [*others, term]
    cv, back = fit.cv(terms), ref.cv([fit.on_reference(t) for t in terms])

    def own(beta: np.ndarray) -> np.ndarray:
        return fit.split(beta, terms)[-1]

    change = own(cv.beta) - own(back.beta)

    def covariance(folds: np.ndarray) -> np.ndarray:
        dev = folds - folds.mean(axis=0)
        return (len(folds) - 1) / len(folds) * dev.T @ dev  # the blocked jackknife's

    rec = np.array([own(b) for b in cv.fold_beta])
    ref_folds = np.array([own(b) for b in back.fold_beta])
    if fit.paired and len(rec) == len(ref_folds):
        cov = covariance(rec - ref_folds)
    else:
        cov = covariance(rec) + covariance(ref_folds)
    k, blocks = len(change), len(rec)
    if blocks <= k + 1 or not np.all(np.isfinite(change)) or not np.all(np.isfinite(cov)):
        return 0.0
    t2 = float(change @ np.linalg.lstsq(cov, change, rcond=None)[0])
    f = t2 * (blocks - k) / (k * (blocks - 1))  # Hotelling's T² as F(k, B − k)
    p = f_upper_tail(f, k, blocks - k)
    return t_upper_quantile(max(p, 1e-300) / 2, blocks - 1)


def amplitude_change_in_se(fit: Fit, others: Sequence[Term], term: Term) -> float:
    """:func:`change_in_se` of a pattern whose size is an amplitude (no sign: a cogging's): the size
    of the change of its coefficients, recording minus reference, over its blocked-jackknife
    standard error (block-paired: the size of each fold pair's difference; else the two sides'
    jackknives combined as independent). A difference of two amplitudes would miss a change of
    phase and take the reference's own misfit amplitude off the change."""
    ref = fit.reference
    assert ref is not None
    terms = [*others, term]
    cv, back = fit.cv(terms), ref.cv([fit.on_reference(t) for t in terms])
    zero = np.zeros(term.width)

    def size(b_rec: np.ndarray, b_ref: np.ndarray) -> float:
        b = fit.split(b_rec, terms)[-1] - fit.split(b_ref, terms)[-1]
        return term.effect.estimate(fit.ctx, term.joint, b, zero, term.at)[1]

    full = size(cv.beta, back.beta)
    if fit.paired and len(cv.fold_beta) == len(back.fold_beta):
        se = float(
            jackknife_se(
                np.array([size(a, b) for a, b in zip(cv.fold_beta, back.fold_beta, strict=True)])
            )
        )
    else:
        se = float(
            np.hypot(
                jackknife_se(np.array([size(a, back.beta) for a in cv.fold_beta])),
                jackknife_se(np.array([size(cv.beta, b) for b in back.fold_beta])),
            )
        )
    if not (np.isfinite(full) and np.isfinite(se)):
        return 0.0
    return abs(full) / se if se > 0 else (np.inf if full != 0 else 0.0)


def drift_passes(fit: Fit, others: Sequence[Term], term: Term, ev: Evidence, tests: int) -> bool:
    """The gate of a drift pattern. Against a profile or ``--params`` (no reference rows to
    difference against): the sign test over blocks of :func:`hil.diagnose.selection.passes`.
    Against a nominal model identified from reference rows: the held-out error of its joints
    drops (:data:`MIN_REDUCTION`, as everywhere, and in more blocks than it rises: a change of
    the arm acts on all its motion, not on a few fast blocks carrying another term's misfit),
    and its size differs from the reference's (:func:`change_in_se`) beyond the two-sided Student-t
    quantile at :data:`FAMILY_ALPHA`, Bonferroni-corrected over the ``tests`` (a jackknife over
    B blocks: B − 1 degrees of freedom). Unless the recording runs the reference's motion again
    (:attr:`Fit.paired`), the sign test must pass as well: another motion projects the model's
    error onto a pattern differently, a difference the blocks' spread does not measure."""
    if fit.reference is None:
        return passes(ev, tests)
    if not fit.paired and not passes(ev, tests):
        return False
    if ev.reduction < MIN_REDUCTION or 2 * ev.blocks_improved <= ev.blocks:
        return False
    if fit.paired and ev.drop < MIN_REDUCTION * change_energy(fit, term):
        return False
    crit = t_upper_quantile(FAMILY_ALPHA / tests / 2, max(len(fit.starts) - 1, 1))
    if change_in_se(fit, others, term) < crit:
        return False
    # another motion: θ refitted is the competitor (:mod:`hil.diagnose.drift.unpaired`)
    return fit.paired or free_change_in_se(fit, others, term) >= crit


def change_energy(fit: Fit, term: Term) -> float:
    """The held-out error of the paired difference with no pattern, on ``term``'s joints: the
    whole change since the reference. Block-paired, a pattern on top of others must lower it by
    :data:`MIN_REDUCTION` of this, not of what the others leave: with the model error gone a
    leftover of the written effect that its pattern's columns do not carry exactly (a drag
    written on smoothed velocities) is resolved many times over, and another pattern would be
    named for a part of the change too small to be one."""
    joints = term.effect.acts_on(fit.ctx, term.joint)
    return float(fit.judged_cv([]).held_out_sse[:, joints].sum())


def drift_candidates(ctx: Context, reference: bool = False) -> list[Term]:
    """Every variant of every registered effect that applies (``reference``: those a reference
    identification keeps, :attr:`Effect.in_reference`); partners only included."""
    return [
        Term(e, j, e.start(ctx, j))
        for e in REGISTRY.values()
        if e.applies(ctx) and (e.in_reference or not reference)
        for j in e.variants(ctx)
    ]


# a pattern whose columns are all under this fraction of the largest nominal torque is one no
# torque of the recordings changes with: round-off (Panda joint 1's encoder angle: ~1e-15)
UNSEEN = 1e-9


def unseen(fit: Fit, term: Term) -> bool:
    """Whether ``term`` (built) changes no torque of the recordings: an encoder angle of a first
    axis along gravity (the whole arm turns about it; no inertia, Coriolis or gravity torque
    depends on it). No data of these recordings can show it; the report says so."""
    scale = float(np.max(np.abs(np.nan_to_num(fit.ctx.predicted())), initial=0.0))
    return scale > 0 and float(np.max(np.abs(term.cols), initial=0.0)) <= UNSEEN * scale


def _narrowest_as_good(
    fit: Fit, best: tuple[Term, Evidence], passing: list[tuple[Term, Evidence]]
) -> tuple[Term, Evidence]:
    """Of the passing patterns on the same joints as the best, held within its columns
    (:func:`_inside`), the one with the fewest coefficients whose held-out drop falls short of
    the best's by less than :data:`MIN_REDUCTION` of that drop: the wider pattern's extra
    coefficients add nothing to what it explains (on the DFKI pendulum one encoder angle
    explained 99.99 % of a written 0.033 rad; a point mass, whose three numbers span every
    rigid change of a one-joint arm, 100 %, and was named in its place)."""
    term, ev = best
    joints = set(term.effect.acts_on(fit.ctx, term.joint))
    margin = MIN_REDUCTION * ev.drop
    narrower = [
        (t, e)
        for t, e in passing
        if t.width < term.width
        and set(t.effect.acts_on(fit.ctx, t.joint)) == joints
        and ev.drop - e.drop < margin
        and _inside(fit, t, term)
    ]
    if not narrower:
        return best
    return min(narrower, key=lambda te: (te[0].width, -te[1].drop))


def _inside(fit: Fit, narrow: Term, wide: Term) -> bool:
    """Whether ``narrow``'s columns lie within ``wide``'s on the judged rows (less than
    :data:`MIN_REDUCTION` of their energy outside): the wider pattern holds the narrower one,
    and its extra coefficients are all it adds. A pattern of another shape (a drag beside a
    friction change) is no special case of it, whatever their held-out drops."""
    cols, _y, w = fit.judged_rows([wide, narrow])
    Z = np.concatenate(cols, axis=-1)
    G = np.einsum("kn,knp,knq->pq", w, Z, Z)
    return energy_outside(G, narrow.width) < MIN_REDUCTION


def select_terms(
    fit: Fit, cands: list[Term], say: Callable[[str], None], start: Sequence[Term] = ()
) -> tuple[list[Term], dict[str, dict]]:
    """Greedy forward selection from the terms ``start``: each round the candidate that lowers
    the held-out error of its joints most, among those that pass the gates of
    :func:`hil.diagnose.selection.passes`."""
    accepted: list[Term] = list(start)
    tested: dict[str, dict] = {}
    built: dict[str, Term] = {}
    for _ in range(MAX_ROUNDS + 2):
        base = fit.judged_cv(accepted)
        best = None
        passing: list[tuple[Term, Evidence]] = []
        keys = {t.key for t in accepted}
        for c in cands:
            if c.key in keys or c.key in fit.unseen or not c.effect.primary:
                continue
            if c.key not in built:
                built[c.key] = fit.build(Term(c.effect, c.joint, c.at))
                if unseen(fit, built[c.key]):
                    fit.unseen[c.key] = built.pop(c.key)
                    continue
            term = built[c.key]
            joints = term.effect.acts_on(fit.ctx, c.joint)
            if term.effect.nonlinear and not term.searched:
                fit.refine([*accepted, term], only=term)  # from its best starting point
            ev = evidence(base, fit.judged_cv([*accepted, term]), joints)
            if term.effect.nonlinear and drift_passes(fit, accepted, term, ev, len(cands)):
                # compared at its best linearisation point, not at the nominal one (an encoder
                # angle linearised at zero loses to the three linear columns it explains)
                fit.refine([*accepted, term], only=term)
                ev = evidence(base, fit.judged_cv([*accepted, term]), joints)
            tested.setdefault(term.key, ev.as_dict())
            if drift_passes(fit, accepted, term, ev, len(cands)):
                passing.append((term, ev))
                if best is None or ev.drop > best[1].drop:
                    best = (term, ev)
        if best is None:
            break
        best = _narrowest_as_good(fit, best, passing)
        accepted.append(best[0])
        built.pop(best[0].key)
        fit.refine(accepted)
        say(f"diagnose: against the nominal model: accepted {best[0].key}")
    return accepted, tested


def _cross(w: np.ndarray, Z: np.ndarray, Psi: np.ndarray) -> np.ndarray:
    """Σ_k,n w Z_p Ψ_q (P, p), a few thousand rows at a time (no (K, n, P, p) product)."""
    out = np.zeros((Z.shape[-1], Psi.shape[-1]))
    for a in range(0, len(Z), 4096):
        b = a + 4096
        out += np.einsum("kn,knp,knq->pq", w[a:b], Z[a:b], Psi[a:b], optimize=True)
    return out


def nominal_spread(fit: Fit, terms: Sequence[Term], draws: np.ndarray | None) -> np.ndarray:
    """Standard deviation of the terms' coefficients over the draws of θ₀: the residual moves
    by Ψ (θ₀ − θ_b), which the terms' least squares projects onto their columns."""
    if draws is None or not terms:
        return np.zeros(sum(t.width for t in terms))
    Z = fit.design(terms)  # (K, n, P) scaled
    w = fit.prob.w
    G = np.einsum("kn,knp,knq->pq", w, Z, Z)
    # the residual moves by Ψ (θ₀ − θ_d) / scale: its projection Zᵀ W Ψ (θ₀ − θ_d) summed over
    # the rows first, not the (K, n, D) moves (200 draws of 60 s of a Panda: 0.67 GB)
    delta = (fit.ctx.theta0[None, :] - draws).T  # (p, D)
    rhs = _cross(w / fit.scale[None, :], Z, fit.prob.Psi_raw) @ delta
    # a column zero on every row (a payload centre along an axis no torque sees) keeps a
    # solvable system and a coefficient of 0 (:func:`column_scale`)
    beta = np.linalg.solve(G + 1e-10 * np.diag(column_scale(G)), rhs)  # (P, D)
    if fit.paired and fit.reference is not None:
        # the same motion on both sides: θ₀'s error moves both residuals alike, and the
        # change is the difference of the two projections
        ref = fit.reference
        Zr = (
            ref.design([fit.on_reference(t) for t in terms])
            * (ref.scale / fit.scale)[None, :, None]
        )
        wr = ref.prob.w
        Gr = np.einsum("kn,knp,knq->pq", wr, Zr, Zr)
        rhs_r = _cross(wr / fit.scale[None, :], Zr, ref.prob.Psi_raw) @ delta
        beta = beta - np.linalg.solve(Gr + 1e-10 * np.diag(column_scale(Gr)), rhs_r)
    return beta.std(axis=1)


def term_estimates(
    fit: Fit, terms: Sequence[Term], draws: np.ndarray | None = None
) -> tuple[list[tuple[dict, float, float]], CrossValidation]:
    """Each term's finding numbers, size and SE: the blocked jackknife of the recording's
    rows and, when θ₀ was identified, the spread its own draws cause, combined. With
    reference rows (:attr:`Fit.reference`): the change since the reference, the coefficients
    of the same terms fitted there subtracted (a shared misfit is no part of the change), its
    jackknife that of the difference (:func:`change_se`); a nonlinear term's change is read
    at its starting point (an encoder angle: the difference of the two angles)."""
    cv = fit.cv(terms)
    se = np.hypot(jackknife_se(cv.fold_beta), nominal_spread(fit, terms, draws))
    beta, ats = cv.beta, [t.at for t in terms]
    if fit.reference is not None and terms:
        beta, se, ats = fit.since_reference(terms, cv)
        se = np.hypot(se, nominal_spread(fit, terms, draws))
    out = [
        t.effect.estimate(fit.ctx, t.joint, b, s, at)
        for t, b, s, at in zip(
            terms, fit.split(beta, terms), fit.split(se, terms), ats, strict=True
        )
    ]
    return out, cv


def confounded_partners(
    fit: Fit, accepted: list[Term], cands: list[Term], tests: int
) -> dict[str, list]:
    """For each accepted term, its declared partners that fit as well in its place and to which
    it adds nothing: {term key: [(partner key, partner estimate)]}."""
    out: dict[str, list] = {}
    keys = {t.key for t in accepted}
    for i, a in enumerate(accepted):
        others = accepted[:i] + accepted[i + 1 :]
        base = fit.judged_cv(others)
        for c in cands:
            if c.effect.name not in a.effect.partners or c.key in keys:
                continue
            b = fit.build(Term(c.effect, c.joint, c.effect.start(fit.ctx, c.joint)))
            with_b = [*others, b]
            fit.refine(with_b, only=b)
            cv_b = fit.judged_cv(with_b)
            ev_b = evidence(base, cv_b, b.effect.acts_on(fit.ctx, b.joint))
            if not drift_passes(fit, others, b, ev_b, tests):
                continue
            on_top = fit.judged_cv([*with_b, a])
            ev_a = evidence(cv_b, on_top, a.effect.acts_on(fit.ctx, a.joint))
            if drift_passes(fit, with_b, a, ev_a, tests):
                continue  # a explains something b does not: not confounded
            est = term_estimates(fit, with_b)[0][-1]
            out.setdefault(a.key, []).append((b, est))
    return out
