"""The whole judgement of a recording against the nominal model (:func:`judge`): selection,
size gates, simulation gate, the reverse check against the reference, confounding, and the
decision whether θ₀ describes the recording at all; and the nominal model identified from
reference recordings (:func:`nominal_from_reference`).

Imports the other modules of :mod:`hil.diagnose.drift`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from drivers.recording import Recording
from hil.diagnose.drift.fit import Fit, common_prefix, make_fit, same_motion, torque_errors
from hil.diagnose.drift.select import (
    confounded_partners,
    drift_candidates,
    drift_passes,
    select_terms,
    term_estimates,
)
from hil.diagnose.drift.simulate import drift_simulation_gate
from hil.diagnose.drift.terms import (
    GATE_ROUNDS,
    NOMINAL_TOLERANCE,
    RESOLVED_SE,
    DriftResult,
    Nominal,
    Term,
)
from hil.diagnose.drift.unpaired import spread_check
from hil.diagnose.effects import REGISTRY
from hil.diagnose.findings import Finding
from hil.diagnose.heldout import (
    HELD_OUT_FRACTION,
)
from hil.diagnose.physical import bounded_fit
from hil.diagnose.problem import Problem, build_problem
from hil.diagnose.stats import (
    block_stats,
    cross_validate,
    evidence,
)
from hil.model.protocol import ArmDynamics


def problem_inputs(recordings: Sequence[Recording]) -> list[tuple[np.ndarray, ...]]:
    return [(r.q, r.tau, r.period_s, r.t) for r in recordings]


def nominal_from_reference(
    recordings: Sequence[Recording],
    model: ArmDynamics,
    why: str,
    *,
    draws: int = 200,
    progress: Callable[[str], None] | None = None,
    geometry: dict[str, float] | None = None,
) -> Nominal:
    """The nominal model identified from reference ``recordings`` on the diagnosis's own rows:
    weighted least squares (rows scaled to unit noise per joint) bounded to the physical signs
    (friction, rotor inertia ≥ 0; :func:`hil.model.estimators.bounded_quadratic_fit`, as
    ``hil identify``), with blocked-bootstrap standard errors; then the drift patterns the
    references show against that θ (selected as :func:`judge` does) are fitted with θ and kept
    in the nominal model: a departure the reference already had (joint 1's direction-dependent
    Coulomb friction, which θ has no term for) is not a change."""
    say = progress or (lambda _m: None)
    prob, _ = build_problem(problem_inputs(recordings), model)
    theta, boot = bounded_fit(prob, model, None, prob.y, draws)
    fit = make_fit(prob, model, theta, geometry=geometry)
    cands = drift_candidates(fit.ctx, reference=True)
    accepted, _ = select_terms(fit, cands, lambda m: say(m.replace("nominal model", "reference")))
    terms: list[tuple[str, int | None, Any, np.ndarray]] = []
    memo = fit.ctx.memo  # built at this θ: kept while θ stays it
    if accepted:
        memo = {}
        shifts = [t.shift for t in accepted if t.shift is not None]
        target = (prob.y_raw - (sum(shifts) if shifts else 0.0)) / prob.scale
        extra = fit.design(accepted) * (fit.scale / prob.scale)[None, :, None]
        both, boot = bounded_fit(prob, model, extra, target, draws)
        p = model.n_params
        theta, boot = both[:p], boot[:, :p]
        for t, b in zip(accepted, fit.split(both[p:], accepted), strict=True):
            terms.append((t.effect.name, t.joint, t.at, b))
    return Nominal(
        theta, model, "reference", why, boot.std(axis=0), boot, terms, prob, geometry, memo
    )


def _times(x: np.ndarray) -> str:
    return " / ".join(f"{v:.3g}" for v in x)


def _words(x: Sequence[float | None]) -> str:
    return " / ".join("n/a" if e is None or not np.isfinite(e) else f"{100 * e:.3g} %" for e in x)


def reverse_check(
    fit: Fit, kept: list[Term], reference: Problem, say: Callable[[str], None]
) -> dict[str, str]:
    """The reference judged against θ identified from the recording (the comparison the other
    way round): a real change since the reference shows there with the opposite sign (a gain
    g as about 1/g, an offset c as about −c), a misfit of the model that both recordings
    share (another excitation projects the same model error onto the pattern) with the same
    sign. {key: why it is not a finding} for the terms the reverse does not confirm."""
    model = fit.ctx.model
    theta_rec, _ = bounded_fit(fit.prob, model, None, fit.prob.y, 0)
    back = make_fit(reference, model, theta_rec, geometry=fit.ctx.geometry)
    # the recording's own rows against θ_rec: the misfit θ_rec leaves on them is no change
    back.reference = make_fit(fit.prob, model, theta_rec, geometry=fit.ctx.geometry)
    back.paired = fit.paired
    out: dict[str, str] = {}
    forward = term_estimates(fit, kept)[0]
    for t, (est, size, _s) in zip(kept, forward, strict=True):
        # from the point the recording gave where that is the pattern's own choice (a cogging's
        # periods, a payload's centre), else from its start (an encoder angle's increment)
        at = t.effect.change_point(back.ctx, t.joint, t.at)
        term = back.build(Term(t.effect, t.joint, at, searched=True))
        back.refine([term], only=term)
        est_back, size_back, se_back = term_estimates(back, [term])[0][0]
        if not t.effect.opposed(est, est_back, size, size_back):
            out[t.key] = (
                f"the reverse comparison (the reference judged against the recording's own θ) "
                f"shows the same sign ({size_back:+.3g} ± {se_back:.2g} against {size:+.3g}): a "
                "misfit of the model both recordings share, not a change; cannot tell"
            )
            say(f"diagnose: against the nominal model: {t.key} not confirmed the other way round")
    return out


# the words a finding against one reference of another motion carries (:func:`judge`)
SPREAD_UNMEASURED = (
    "not weighed against the model's spread over motions, which one reference of another "
    "motion cannot show: give two or more --reference recordings to weigh it"
)
BELOW_FLOOR = "below the smallest size worth naming"
BELOW_SE = "smaller than its own uncertainty"
# a term whose held-out proof passed but whose size is not resolved (within its SE or under its
# floor): real structure of the change, not named, kept in the fit (module doc)
UNRESOLVED = (BELOW_FLOOR, BELOW_SE)


def size_gates(fit: Fit, accepted: list[Term], nominal: Nominal, tests: int) -> dict[str, str]:
    """Each term's own held-out proof on top of the others, and its size against its SE and
    the effect's floor: {key: why it is not a finding}."""
    failed: dict[str, str] = {}
    estimates, _ = term_estimates(fit, accepted, nominal.theta_draws)
    # whether a term is there at all is weighed against the SE it would have if it were not:
    # the recording running the reference's motion again (paired), θ₀'s error moves both sides'
    # residuals alike and what is left of it in the change moves a term's column with the
    # change itself (an encoder angle's ∂τ/∂q scales with θ₀'s gravity terms): an
    # uncertainty of its size, zero where the change is, no doubt that it is there (a 0.051
    # rad encoder angle on DFKI A.0's joint 1 read -0.0506 ± 0.026 rad, 1.9 SE, its jackknife
    # SE alone far smaller, explaining 99.99 % of the change: left unnamed)
    exists = term_estimates(fit, accepted)[0] if fit.paired else estimates
    for i, (t, (_est, size, size_se), (_e, _s, exist_se)) in enumerate(
        zip(accepted, estimates, exists, strict=True)
    ):
        others = accepted[:i] + accepted[i + 1 :]
        ev = evidence(
            fit.judged_cv(others), fit.judged_cv(accepted), t.effect.acts_on(fit.ctx, t.joint)
        )
        if why := t.effect.unresolvable(fit.ctx, t.joint, t.at):
            failed[t.key] = why
        elif not (np.isfinite(size) and np.isfinite(size_se)):
            failed[t.key] = f"the data give it no finite size ({size:.3g} ± {size_se:.2g})"
        elif not drift_passes(fit, others, t, ev, tests):
            failed[t.key] = "its held-out proof on top of the others failed"
        elif abs(size) < RESOLVED_SE * exist_se:
            failed[t.key] = f"{BELOW_SE} ({size:.3g} ± {size_se:.2g}): below what the data resolve"
        elif abs(size) < (smallest := t.effect.smallest(fit.ctx, t.joint)):
            failed[t.key] = f"{BELOW_FLOOR} ({smallest:.3g})"
    return failed


def refit_ratio(fit: Fit, prob: Any, terms: list[Term]) -> np.ndarray:
    """Per joint, the leave-one-block-out torque error of θ₀ + ``terms`` over that of θ
    refitted from the rows of ``prob`` alone (RMS ratio, (n,)). Per joint, not pooled: the
    rows are scaled by θ₀'s own residual scale, so a pooled ratio weighs each joint by
    1/scale² and the joint θ₀ describes worst counts least (an A.0 recording judged against
    another one's model: 86 % held-out NRMSE on joint 1 against a refit's 10 %, a pooled ratio
    of 1.2).

    The refit weighs each joint by the recording's own noise (``prob.scale``, the scale of its
    own least-squares residual, as ``hil identify`` does), not by θ₀'s residual scale: θ₀'s
    residual carries the very change judged, so its scale would weigh the changed joints down
    and the shared θ would buy the other joints' fit with them (a 0.057 rad encoder angle on a
    KUKA LWR4+'s joint 2 scaled joint 2's rows by 1/3.2: the refit then predicted joint 5's
    held-out blocks 1.75 times better than the same refit of the unmodified recording, and θ₀
    with the exact angle was ruled not to describe the recording). Its per-joint error is then
    put in ``fit.scale``'s units, the same as θ₀'s."""
    own = cross_validate(
        block_stats(prob.design_groups([]), prob.y_raw / prob.scale, prob.w, prob.blocks)
    ).held_out_sse.sum(axis=0) * np.square(prob.scale / fit.scale)
    mine = fit.cv(terms).held_out_sse.sum(axis=0)
    return np.sqrt(mine / np.maximum(own, 1e-300))


def judge(
    recordings: Sequence[Recording],
    nominal: Nominal,
    progress: Callable[[str], None] | None = None,
    *,
    rows: Sequence[Any] | None = None,
) -> DriftResult:
    """Judge ``recordings`` against ``nominal`` (module doc). ``rows``: the recordings' rows in
    ``nominal.model`` already built (:func:`hil.diagnose.pipeline.diagnose`'s
    ``Diagnosis.rows``): the regressor is then not built a second time."""
    say = progress or (lambda _m: None)
    model = nominal.model
    theta0 = np.asarray(nominal.theta, float)
    if len(theta0) != model.n_params:
        raise ValueError(
            f"the nominal θ holds {len(theta0)} numbers; the model has {model.n_params}"
        )
    prob, _ = build_problem(problem_inputs(recordings), model, rows=rows)
    fit = make_fit(prob, model, theta0, nominal.terms, nominal.geometry)
    if nominal.reference is not None:
        ref_prob = common_prefix(prob, nominal.reference, model)
        memo = nominal.memo if ref_prob is nominal.reference else None
        fit.reference = make_fit(
            ref_prob, model, theta0, nominal.terms, nominal.geometry, memo=memo
        )
        fit.paired = same_motion(prob, ref_prob)
    ctx = fit.ctx
    cands = drift_candidates(ctx)
    if fit.reference is not None:
        # a variant the reference cannot show has no "since": a torque gain on a joint the
        # reference records no torque on (DFKI C.0 trajectory 06 drives joint 1 only; 03 and 04
        # judged against it gave a joint-2 gain of 1.2)
        ref_ctx = fit.reference.ctx
        cands = [c for c in cands if c.joint in c.effect.variants(ref_ctx)]
    say(f"diagnose: against the {nominal.source} model: testing {len(cands)} drift patterns")
    not_findings: dict[str, str] = {}
    tested: dict[str, dict] = {}
    # terms proven (their held-out proof passed) but with a size the data do not resolve (under
    # twice its SE or under the smallest size worth naming): kept in the fit and not named, so
    # that no other pattern stands in for them (a 0.01 Nm Coulomb asymmetry that explained
    # 99.99 % of the change was left out, and a gain, an encoder angle and a rotor inertia took
    # its place, each above its own floor; a 0.05 rad encoder angle on A.0's joint 1 at 1.9 SE
    # left out, and a 0.017 Nm offset on joint 2, part of its gravity torque, was named)
    silent: list[Term] = []
    for _ in range(GATE_ROUNDS):
        # a term that fails a gate is left out and the selection run again: it may have stood
        # in the way of one that passes (an encoder angle that beat a gain in the torque and
        # then worsened the simulated motion)
        before = {t.key for t in silent}
        pool = [c for c in cands if c.key not in not_findings]
        accepted, seen = select_terms(fit, pool, say, start=silent)
        for k, v in seen.items():
            tested.setdefault(k, v)
        failed = size_gates(fit, accepted, nominal, len(cands))
        silent = [t for t in accepted if failed.get(t.key, "").startswith(UNRESOLVED)]
        quiet = {t.key for t in silent}
        kept = [t for t in accepted if t.key not in failed or t.key in quiet]
        if len(kept) < len(accepted):
            fit.refine(kept)
        kept, dropped, position = drift_simulation_gate(fit, kept, say, nominal.source)
        failed.update(dropped)
        silent = [t for t in kept if t.key in quiet]
        not_findings.update(failed)
        if not set(failed) - before:
            break
    quiet = {t.key for t in silent}
    for t in silent:
        not_findings[t.key] += "; kept in the fit, so that no other pattern stands in for it"
    if nominal.reference is not None and kept:
        named = [t for t in kept if t.key not in quiet]
        reversed_ = reverse_check(fit, named, fit.reference.prob, say) if named else {}
        not_findings.update(reversed_)
        kept = [t for t in kept if t.key not in reversed_]
        fit.refine(kept)
        if not fit.paired and len(nominal.reference.rows) > 1:
            named = [t for t in kept if t.key not in quiet]
            spread = spread_check(
                fit, named, term_estimates(fit, named, nominal.theta_draws)[0], nominal
            )
            for key in spread:
                say(f"diagnose: against the nominal model: {key} within the references' spread")
            not_findings.update(spread)
            kept = [t for t in kept if t.key not in spread]
            fit.refine(kept)
    estimates, _cv = term_estimates(fit, kept, nominal.theta_draws)
    confounded = confounded_partners(fit, kept, cands, len(cands))
    # one reference of another motion: the model's own spread over motions (which moved a
    # DFKI A.0 joint-2 encoder angle by 0.045 rad SD between recordings of one arm, against
    # a 0.008 rad SE) cannot be measured, so no finding is weighed against it; say so
    unweighed = (
        nominal.reference is not None and not fit.paired and len(nominal.reference.rows) == 1
    )
    findings = []
    unresolved = []  # proven but not resolved: said, not named (a user asks what it was)
    for i, (t, (est, _size, _se)) in enumerate(zip(kept, estimates, strict=True)):
        if t.key in quiet:
            unresolved.append(
                {
                    "term": t.key,
                    "effect": t.effect.name,
                    "joint": None if t.joint is None else t.joint + 1,
                    "estimate": est,
                    "words": t.effect.words(est),
                    "why": not_findings[t.key],
                }
            )
            continue
        others = kept[:i] + kept[i + 1 :]
        ev = evidence(
            fit.judged_cv(others), fit.judged_cv(kept), t.effect.acts_on(ctx, t.joint)
        ).as_dict()
        ev["against"] = nominal.source
        ev["joints"] = [j + 1 for j in t.effect.acts_on(ctx, t.joint)]  # whose torque it reaches
        rivals = confounded.get(t.key, [])
        words = t.effect.words(est)
        if rivals:
            est = {
                **est,
                "confounded_estimates": {b.key: e for b, (e, _s, _x) in rivals},
            }
            words += "; it fits as well as " + "; ".join(
                f"{b.effect.words(e)}" for b, (e, _s, _x) in rivals
            )
            words += f" (to separate them: {t.effect.separate})"
        if unweighed:
            ev["spread"] = SPREAD_UNMEASURED
            words += f" ({SPREAD_UNMEASURED})"
        ev["words"] = words
        findings.append(
            Finding(
                t.effect.name,
                None if t.joint is None else t.joint + 1,
                est,
                ev,
                [b.effect.name for b, _ in rivals],
                term=t.key,
            )
        )
    errors = torque_errors(fit, kept)
    # held-out error of every block (leave-one-block-out), θ₀ + drift against a refit of θ
    ratios = refit_ratio(fit, prob, kept)
    # the reference model is a bounded fit of its own recording: the error it already has
    # there against an unbounded refit (≥ 1) is no sign that it fails to describe this one
    own_ratios = (
        np.ones_like(ratios)
        if fit.reference is None
        else np.maximum(refit_ratio(fit.reference, fit.reference.prob, []), 1.0)
    )
    # θ₀ must describe every joint that records a torque: the worst against its own tolerance
    # decides (an unactuated joint's rows, τ ≡ 0, have no torque scale: DFKI C.0's joint 2
    # leaves θ₀ 12 times a refit's error on the reference itself, 31 times on a recording of
    # the same arm with a gain on joint 1)
    judged = ctx.driven() or list(range(len(ratios)))
    worst = judged[int(np.argmax((ratios / own_ratios)[judged]))]
    ratio, own_ratio = float(ratios[worst]), float(own_ratios[worst])
    used = not (ratio > NOMINAL_TOLERANCE * own_ratio)
    decision = (
        f"the {nominal.source} model with the drift found predicts the recording's held-out "
        f"blocks with {_times(ratios)} times the torque error of θ refitted from the recording "
        f"alone (last {int(100 * HELD_OUT_FRACTION)} %: {_words(errors['nominal_with_drift'])} "
        f"against {_words(errors['refit'])})"
    )
    if fit.reference is not None and own_ratios.max() > 1.0:
        decision += f"; on its own reference recording {_times(own_ratios)} times"
    if used:
        decision += ": judged against it"
    else:
        decision += (
            f" (joint {worst + 1}: more than {NOMINAL_TOLERANCE:g} times "
            f"{'that' if own_ratio == 1.0 else f'its own {own_ratio:.3g}'}): it does not "
            "describe this recording, so no drift against it is reported; the diagnosis below "
            "refits θ"
        )
        findings = []
    doc = {
        "source": nominal.source,
        "why": nominal.why,
        "used": used,
        "decision": decision,
        "model": getattr(model, "name", None) or "2-DOF closed form",
        "theta": [float(x) for x in theta0],
        **(
            {"theta_se": [float(x) for x in nominal.theta_se]}
            if nominal.theta_se is not None
            else {}
        ),
        "baseline": [
            {
                "effect": name,
                "joint": None if joint is None else joint + 1,
                "estimate": REGISTRY[name].estimate(ctx, joint, beta, 0 * beta, at)[0],
            }
            for name, joint, at, beta in nominal.terms
        ],
        "held_out_error_ratio": ratio,
        "held_out_error_ratios": [float(x) for x in ratios],
        "held_out_torque_nrmse": errors,
        "held_out_position_nrmse": position,
        "findings": [f.as_dict() for f in findings],
        "unresolved": unresolved if used else [],
        "unseen": [
            {
                "term": t.key,
                "effect": t.effect.name,
                "joint": None if t.joint is None else t.joint + 1,
                "why": t.effect.when_unseen or "no torque of the recordings changes with it",
            }
            for t in fit.unseen.values()
            if used  # with the model refused, no drift is read at all (as unresolved)
        ],
        "tested": tested,
        "not_findings": not_findings,
    }
    arrays = change_arrays(fit, kept, np.concatenate([r.t for r in prob.rows]))
    return DriftResult(doc, findings, used, theta_shares(prob.Psi_raw), arrays)


def change_arrays(fit: Fit, kept: Sequence[Term], t: np.ndarray) -> dict[str, np.ndarray]:
    """The change the patterns were judged on and the kept patterns' model of it, in Nm per
    row (:attr:`DriftResult.arrays`): the paired difference r_rec − r_ref when the recording
    reruns the reference's motion, else the recording's residual against θ₀; the model is
    that less what the kept patterns (fitted on all rows, :meth:`Fit.judged_cv`) leave."""
    _cols, change, w = fit.judged_rows([])
    left = change
    if kept:
        cols, y, _w = fit.judged_rows(list(kept))
        beta = fit.judged_cv(list(kept)).beta
        left = y - np.concatenate(cols, axis=-1) @ beta
    return {
        "t": t,
        "change": change * fit.scale,
        "modelled": (change - left) * fit.scale,
        "weight": w,
    }


def theta_shares(Psi: np.ndarray) -> dict[int, set[int]]:
    """Joint (1-based) -> the joints whose rows of Ψ (K, n, p) share a column with its own:
    where a change on one joint, taken up by a refit of θ, moves the other's residual too (on
    the 2-DOF arm θ1..θ5 are in both joints' rows; on a serial URDF arm a body's parameters are
    in the rows of every joint before it)."""
    used = np.zeros(Psi.shape[1:], bool)
    for start in range(0, len(Psi), 4096):  # no (K, n, p) temporary
        used |= np.any(Psi[start : start + 4096] != 0.0, axis=0)
    share = (used.astype(int) @ used.T.astype(int)) > 0
    return {i + 1: {int(j) + 1 for j in np.flatnonzero(share[i])} for i in range(len(share))}
