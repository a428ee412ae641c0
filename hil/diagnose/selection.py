"""Mismatch diagnosis: find the physics the nominal model (the 9-parameter model of Reyes & Kelly
(1997), or ``ArmModel(profile.terms)``) left out.

The nominal model is the ``exact`` filtered dynamic regression (eq. (24) over sample intervals,
:mod:`hil.model.regressors`) of an :class:`hil.model.closed_form.ArmModel`; the model terms it
lacks (rotor inertia, centre-of-mass offset) are candidates like the effects. Every candidate
of the vocabulary (:mod:`hil.diagnose.candidates`) adds columns to it; a candidate is accepted when
it lowers the held-out error of its joint block after block (:mod:`hil.diagnose.stats`),
greedily, strongest first, each later candidate tested on top of those already accepted. Two
candidates that each explain the same residual and neither adds anything on top of the other are
*confounded*: both are reported, with the experiment that would separate them. Pure computation
over arrays; reading files, plots and the CLI live in :mod:`hil.diagnose.cli`.

What lives here: the decision thresholds and the test a candidate passes (:func:`passes`), the
forward rounds (with pairs tried together and a narrower effect preferred to a model term),
backward elimination, the confounding check and the angle offset's relinearisation. The
candidates are :mod:`hil.diagnose.candidates`', the stacked regression and its
cross-validation :mod:`hil.diagnose.problem`'s, the physical gate :mod:`hil.diagnose.physical`'s.

Imports: :mod:`hil.diagnose.candidates`, :mod:`hil.diagnose.problem`,
:mod:`hil.diagnose.physical`, :mod:`hil.diagnose.columns`, :mod:`hil.diagnose.stats`,
:mod:`hil.model`; never the stages after it (interpret, heldout, gates, report, pipeline).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from hil.diagnose.candidates import (
    Accepted,
    Candidate,
    joints_of,
    large_enough,
    term_key,
)
from hil.diagnose.physical import (
    final_fit,
    physical_gate,
    rigid_body_deviation,
    unphysical,
)
from hil.diagnose.problem import Problem, design_cv, rewhiten, terms_cv
from hil.diagnose.stats import CrossValidation, Evidence, evidence

# Decision thresholds (docs/diagnosis.md, "Deciding"): a candidate must lower the held-out error
# of its joint by at least MIN_REDUCTION (relative) and in more blocks than chance allows (sign
# test at FAMILY_ALPHA over the number of candidates). On null recordings (no concealed effect)
# the largest values seen were far below both; see tests/test_diagnose.py.
MIN_REDUCTION = 0.01
FAMILY_ALPHA = 1e-3  # sign test, Bonferroni over the candidates tested in a round
MAX_ROUNDS = 6


def passes(ev: Evidence, tests: int) -> bool:
    return ev.reduction >= MIN_REDUCTION and ev.sign_p <= FAMILY_ALPHA / tests


def _harms_other_joint(base: CrossValidation, cv: CrossValidation, cand: Candidate) -> bool:
    """The term makes the held-out error of a joint it is not about worse by MIN_REDUCTION."""
    others = [j for j in range(base.held_out_sse.shape[1]) if j not in joints_of(cand)]
    return bool(others) and evidence(base, cv, others).reduction <= -MIN_REDUCTION


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
    other = next((c for c in library if c.spec.is_gain and c.joint != cand.joint), None)
    if other is None:  # the other joint is not tested: nothing to weigh the gain against
        return False
    there = design_cv(prob, extra, other)
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
            and large_enough(s[0], s[1])
            and not (effects_only and s[0].spec.model_term)
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
        joints = sorted(set(joints_of(a[0])) | set(joints_of(b[0])))
        ev = evidence(base, design_cv(prob, [*extra, cols_a, cols_b]), joints)
        if passes(ev, tests + len(pairs)):
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
            ev = evidence(design_cv(prob, cols), design_cv(prob, [*cols, own]), joints_of(a.cand))
            verdicts.append((ev, i))
        failing = [(ev.drop, i) for ev, i in verdicts if not passes(ev, tests)]
        if not failing:
            for ev, i in verdicts:
                accepted[i].evidence = ev
            return accepted
        _drop, worst = min(failing)
        if log:
            log(f"eliminated {accepted[worst].cand.key}: redundant given the others")
        del accepted[worst]
        rewhiten(prob, accepted)
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
        without = design_cv(prob, cols)
        with_own = design_cv(prob, [*cols, own])
        for alt in library:
            if alt.key in taken or alt.spec.is_gain != a.cand.spec.is_gain:
                continue
            with_alt = terms_cv(prob, others, alt)
            joints = sorted(set(joints_of(alt)) | set(joints_of(a.cand)))
            if not passes(evidence(without, with_alt, joints_of(alt)), tests):
                continue
            if not large_enough(alt, with_alt):
                continue
            if unphysical(alt, with_alt, prob.model, [b.cand for b in others]):
                continue  # no finding stands on a refit that is not physical
            if passes(evidence(with_alt, with_own, joints), tests):
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
            rewhiten(prob, [])  # the noise scale of the nominal model, as at the start
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
        rewhiten(prob, accepted)
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
    keys = [term_key(a) for a in accepted]
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
        base = design_cv(prob, extra)
        scored = []
        for i, cand in enumerate(remaining):
            if tick is not None:
                tick(f"testing candidates, round {round_no + 1}", i, len(remaining), "candidates")
            cv = terms_cv(prob, accepted, cand)
            ev = evidence(base, cv, joints_of(cand))
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
            if passes(s[2], tests)
            and large_enough(s[0], s[1])
            and not _harms_other_joint(base, s[1], s[0])
            and (
                not s[0].spec.is_gain
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
        if cand.spec.is_gain:  # gains on both joints: θ = 0, r = −1 fits anything (scale)
            remaining = [c for c in remaining if not c.spec.is_gain]
        rewhiten(prob, accepted)
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
    if not best[0].spec.model_term:
        return best
    rivals = [
        s
        for s in passing
        if not s[0].spec.model_term
        and not passes(
            evidence(s[1], best[1], sorted(set(joints_of(s[0])) | set(joints_of(best[0])))), tests
        )
    ]
    if rivals or prob is None:
        return max(rivals, key=lambda s: s[2].drop) if rivals else best
    pairs = _candidate_pairs([*passing, *(s for s in scored if s not in passing)], True)
    for a, b in pairs:
        cols = [*extra, prob.column(a[0], a[1].variant), prob.column(b[0], b[1].variant)]
        joints = sorted(set(joints_of(a[0])) | set(joints_of(b[0])) | set(joints_of(best[0])))
        if not passes(evidence(design_cv(prob, cols), best[1], joints), tests + len(pairs)):
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
        if not a.cand.spec.built_at_theta:
            continue
        for _ in range(RELINEARISE_ANGLE):
            theta = final_fit(prob, out).theta
            j, kind = a.cand.joint, a.cand.spec
            cand = Candidate(
                a.cand.kind,
                j,
                (None,),
                lambda r, _v, j=j, th=theta, k=kind: k.column_at(r, j, th),
                acts_on=a.cand.acts_on,
            )
            prob.forget((cand.key, 0))
            a = Accepted(cand, None, a.evidence, a.confounded_with, a.rival_variants)
            out[i] = a
    return out
