"""The competitor of a change when the recording runs another motion than its reference: θ
itself, refitted.

θ₀ identified from a reference is the best θ for the reference's motion; with the model's own
error (tens of % of the torque on the DFKI arms) another motion of the same, unchanged arm is
best described by another θ. A pattern whose columns θ's own columns can take up (a rotor
inertia, a friction level, a payload on a 2-DOF arm, a gain where few parameters are shared
between joints) then shows a "change" against θ₀ that is only θ₀ failing to transfer: DFKI
design C.0's recording 01 judged against θ₀ from each of the six other recordings of that day
gives a joint-2 rotor-inertia "change" from −0.0075 to +0.0109 kg m², each at 5–12 standard
errors, although nothing changed (θ3 is 0.022 kg m² from recording 02 and 0.038 from 01). Halves
of one recording agree (within 0.0008): the between-motion part is not in any spread the blocks
of one recording give.

So, unpaired, a change must also show with θ free on both sides: the pattern fitted together
with θ on the recording's rows and on the reference's, the difference of its two coefficients
over its blocked jackknife (the two sides independent) must pass the same Student-t quantile.
What θ can take up is then "cannot tell": another θ explains it as well. What θ cannot take up
(a delay, a cogging, an encoder angle's nonlinear part, a gain that breaks the parameters the
joints share) keeps its power. Block-paired comparisons (the same motion on both sides) do not
need it: the model error cancels row by row there.

Where the reference is two or more recordings, the spread itself is measured
(:func:`motion_spread`): each pattern found is fitted on every reference recording alone,
against θ identified from the other references; those sizes differ by what the model's error
projects onto the pattern under each motion, and a change must stand out of that spread
(:func:`spread_check`). One recording's blocks cannot show it (DFKI A.0: the angle of joint 2's
gravity torque, fitted with θ on each of ten recordings of one arm, spreads by 0.045 rad against
a 0.008 rad SE; within one recording its eight segments agree within ±0.017 rad;
tests/benchmarks/dfki_pattern_scatter.py).

Imports :mod:`hil.diagnose.drift.fit` and :mod:`hil.diagnose.drift.terms`.
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import pairwise

import numpy as np

from hil.diagnose.drift.fit import Fit, make_fit
from hil.diagnose.drift.terms import Nominal, Term
from hil.diagnose.physical import jackknife_se
from hil.diagnose.problem import build_problem
from hil.diagnose.selection import FAMILY_ALPHA
from hil.diagnose.stats import (
    RIDGE,
    BlockStats,
    CrossValidation,
    ScaledRows,
    block_stats,
    cross_validate,
)
from hil.model.estimators import bounded_quadratic_fit
from hil.model.tails import t_upper_quantile

# A pattern whose columns keep less than this fraction of their energy outside θ's columns
# (unit-norm columns) is θ's own direction: with θ free its coefficient is set by the fit's
# ridge (:data:`hil.diagnose.stats.RIDGE`), not by the data, and resolves nothing
OUTSIDE_THETA = 100 * RIDGE


def _with_theta(fit: Fit, terms: Sequence[Term]) -> tuple[CrossValidation, BlockStats]:
    """The terms fitted together with a free change of θ (Ψ's columns, scaled as the rows) on
    ``fit``'s rows: coefficients [δθ, β]; and the statistics of that design."""
    Z = [ScaledRows(fit.prob.Psi_raw, fit.scale), fit.design(terms)]  # no joined copy
    stats = block_stats(Z, fit.target(terms), fit.prob.w, fit.prob.blocks)
    return cross_validate(stats), stats


def outside_theta(stats: BlockStats, width: int) -> float:
    """The smallest fraction of the last ``width`` columns' energy (unit-norm columns) that
    θ's columns, the others, cannot take up (:func:`energy_outside`)."""
    return energy_outside(stats.G.sum(axis=(0, 1)), width)


def energy_outside(G: np.ndarray, width: int) -> float:
    """Of a Gram matrix G (p, p), the smallest fraction of the last ``width`` columns' energy
    (unit-norm columns) that the other columns cannot take up: the Schur complement's least
    eigenvalue."""
    d = np.sqrt(np.maximum(np.diag(G), 1e-300))
    G = G / np.outer(d, d)
    a, b = G[:-width, :-width], G[:-width, -width:]
    schur = G[-width:, -width:] - b.T @ np.linalg.pinv(a, rcond=1e-12, hermitian=True) @ b
    return float(np.linalg.eigvalsh(0.5 * (schur + schur.T)).min())


def free_change_in_se(fit: Fit, others: Sequence[Term], term: Term) -> float:
    """How many standard errors ``term``'s coefficients differ between the recording and the
    reference when θ is refitted on each side with them (module doc): the size of the
    difference of its coefficients over the jackknife standard error along that difference."""
    ref = fit.reference
    assert ref is not None
    terms = [*others, term]
    rec, stats = _with_theta(fit, terms)
    back, stats_back = _with_theta(ref, [fit.on_reference(t) for t in terms])
    w = term.width
    if min(outside_theta(stats, w), outside_theta(stats_back, w)) < OUTSIDE_THETA:
        return 0.0  # θ's own direction: another θ explains it exactly
    d = rec.beta[-w:] - back.beta[-w:]
    norm = float(np.linalg.norm(d))
    if not np.isfinite(norm) or norm == 0.0:
        return 0.0
    u = d / norm
    se = float(
        np.hypot(jackknife_se(rec.fold_beta[:, -w:] @ u), jackknife_se(back.fold_beta[:, -w:] @ u))
    )
    return norm / se if se > 0 else np.inf


def motion_spread(fit: Fit, term: Term, nominal: Nominal) -> np.ndarray | None:
    """``term``'s size (:meth:`Effect.estimate`) on each reference recording alone against θ
    identified from the other references (with the nominal model's own departures held), at
    ``term``'s point, Gauss–Newton steps from there for a nonlinear pattern: (R,). Left out of
    θ's fit, each reference is a new motion to θ, as the recording is (against θ₀ fitted on it
    too, five A.0 references' spread was read small enough that the most extreme of ten
    recordings stood out of it). None with fewer than two reference recordings, or for a
    pattern sized by an amplitude (no sign to spread)."""
    ref = nominal.reference
    if ref is None or len(ref.rows) < 2 or term.effect.sized_by_amplitude:
        return None
    model = fit.ctx.model
    theta0 = np.asarray(fit.ctx.theta0, float)
    # the references' torque less the nominal model's own departures, and each one's share of
    # the normal equations of θ (rows scaled to unit noise per joint)
    pooled = make_fit(ref, model, theta0, nominal.terms, nominal.geometry)
    target = (ref.Psi_raw @ theta0 + pooled.residual) / ref.scale
    w, ends = ref.w, np.cumsum([0] + [len(r.y) for r in ref.rows])
    parts = []
    for a, b in pairwise(ends):
        Z = ref.Psi_raw[a:b] / ref.scale[None, :, None]  # one reference's rows at a time
        parts.append(
            (
                np.einsum("knp,knq,kn->pq", Z, Z, w[a:b], optimize=True),
                np.einsum("knp,kn,kn->p", Z, target[a:b], w[a:b], optimize=True),
            )
        )
    H, g = sum(h for h, _ in parts), sum(v for _, v in parts)
    lower = np.full(model.n_params, -np.inf)
    lower[list(model.nonnegative_columns)] = 0.0
    sizes = []
    for r, (H_i, g_i) in zip(ref.rows, parts, strict=True):
        theta_out, _method = bounded_quadratic_fit(H - H_i, g - g_i, lower)
        prob, _ = build_problem([(r.q, r.tau, r.h, r.stamps)], model)
        one = make_fit(prob, model, theta_out, nominal.terms, nominal.geometry)
        t = one.build(Term(term.effect, term.joint, term.at, searched=True))
        one.refine([t], only=t)
        beta = one.cv([t]).beta
        sizes.append(t.effect.estimate(one.ctx, t.joint, beta, 0 * beta, t.at)[1])
    return np.asarray(sizes, float)


def spread_check(
    fit: Fit,
    kept: Sequence[Term],
    estimates: Sequence[tuple[dict, float, float]],
    nominal: Nominal,
) -> dict[str, str]:
    """{key: why it is not a finding} for each of ``kept`` (with its change's ``estimates``:
    numbers, size, SE) whose change does not stand out of the pattern's spread over the
    reference recordings (:func:`motion_spread`): |size| under the Student-t quantile (R − 1
    degrees of freedom, two-sided at the drift gates' family-wise
    :data:`hil.diagnose.selection.FAMILY_ALPHA` over the patterns checked) of its SE
    combined with the spread's SD × √(1 + 1/R) (a new motion's draw against the references'
    mean)."""
    out: dict[str, str] = {}
    if not kept:
        return out
    for t, (_est, size, size_se) in zip(kept, estimates, strict=True):
        sizes = motion_spread(fit, t, nominal)
        if sizes is None or not np.all(np.isfinite(sizes)):
            continue
        R = len(sizes)
        sd = float(np.std(sizes, ddof=1))
        se = float(np.hypot(size_se, sd * np.sqrt(1.0 + 1.0 / R)))
        crit = t_upper_quantile(FAMILY_ALPHA / len(kept) / 2, R - 1)
        if abs(size) < crit * se:
            out[t.key] = (
                f"the pattern's size on each of the {R} reference recordings, against θ "
                f"identified from the others, spreads by "
                f"{sd:.3g} (SD; {', '.join(f'{x:+.3g}' for x in sizes)}): a change of "
                f"{size:+.3g} does not stand out of what another motion of the same arm gives "
                f"({crit:.3g} × {se:.2g} needed); cannot tell"
            )
    return out
