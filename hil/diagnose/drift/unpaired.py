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

Imports :mod:`hil.diagnose.drift.fit` and :mod:`hil.diagnose.drift.terms`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from hil.diagnose.drift.fit import Fit
from hil.diagnose.drift.terms import Term
from hil.diagnose.physical import jackknife_se
from hil.diagnose.stats import RIDGE, BlockStats, CrossValidation, block_stats, cross_validate

# A pattern whose columns keep less than this fraction of their energy outside θ's columns
# (unit-norm columns) is θ's own direction: with θ free its coefficient is set by the fit's
# ridge (:data:`hil.diagnose.stats.RIDGE`), not by the data, and resolves nothing
OUTSIDE_THETA = 100 * RIDGE


def _with_theta(fit: Fit, terms: Sequence[Term]) -> tuple[CrossValidation, BlockStats]:
    """The terms fitted together with a free change of θ (Ψ's columns, scaled as the rows) on
    ``fit``'s rows: coefficients [δθ, β]; and the statistics of that design."""
    Psi = fit.prob.Psi_raw / fit.scale[None, :, None]
    Z = np.concatenate([Psi, fit.design(terms)], axis=-1)
    stats = block_stats(Z, fit.target(terms), fit.prob.w, fit.prob.blocks)
    return cross_validate(stats), stats


def outside_theta(stats: BlockStats, width: int) -> float:
    """The smallest fraction of the last ``width`` columns' energy (unit-norm columns) that
    θ's columns, the others, cannot take up: the Schur complement's least eigenvalue."""
    G = stats.G.sum(axis=(0, 1))
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
