"""From accepted regression terms to findings in the diagnosis vocabulary, with magnitudes.

Some terms need a second look before they can be named (docs/diagnosis.md):

* a torque offset and a direction-dependent Coulomb friction on the same joint are the same
  column: F⁺ = θ_fc − c, F⁻ = θ_fc + c. Both are reported, confounded;
* a torque-rate term is an actuator lag or a transport delay: the two are told apart by fitting
  the exact lagged and delayed shaft torques and comparing their held-out errors;
* a torque gain error on one joint fits the data as well as the opposite error on the other
  joint (the data fix only the ratio (1 + r₁)/(1 + r₂)): the hypothesis whose rigid-body
  parameters θ1..θ5 agree with the robot profile's (or ``--params``) is kept; when neither does
  clearly better, both are reported, confounded.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from hil.diagnose.candidates import LAG_GRID_S, Accepted, term_width
from hil.diagnose.columns import delayed_torque_rows, gain_column, lagged_torque_rows
from hil.diagnose.finding import THETA_FC, Finding, coulomb_column, rounded
from hil.diagnose.physical import FinalFit, rigid_body_deviation
from hil.diagnose.problem import Problem, design_matrix, fit_theta_at
from hil.diagnose.selection import passes
from hil.diagnose.stats import CrossValidation, block_stats, cross_validate, evidence

SEPARATE_REDUCTION = 0.05  # held-out reduction needed to call lag vs delay (see classify_rate)
SAME_DELAY = 0.25  # two joints' delays this close (relative) are reported as one, joint null
# How far apart two gain hypotheses' rigid-body parameters must be from the reference (ratio of
# their relative deviations) before the reference decides between them.
GAIN_REFERENCE_RATIO = 1.5
# The key of a torque gain's estimate read with the rigid-body parameters at the reference.
AT_REFERENCE = "relative_at_reference_theta"


def _cols(prob: Problem, accepted: Sequence[Accepted], skip: set[int]) -> list[np.ndarray]:
    return [prob.chosen(a) for i, a in enumerate(accepted) if i not in skip]


def _cv_with(
    prob: Problem, accepted: Sequence[Accepted], skip: set[int], y_raw: np.ndarray, extra=()
) -> CrossValidation:
    """Cross-validation of the accepted terms (but ``skip``) + ``extra`` against rows
    ``y_raw`` (Nm). A torque gain acts on the shaft torque (after any lag or delay, as in the
    virtual robot's torque path), so its column is rebuilt from ``y_raw``."""
    cols = []
    for i, a in enumerate(accepted):
        if i in skip:
            continue
        if a.cand.spec.is_gain:
            col = np.zeros((len(y_raw), prob.n_joints, 1))
            col[:, a.cand.joint, 0] = -y_raw[:, a.cand.joint] / prob.scale[a.cand.joint]
            cols.append(col)
        else:
            cols.append(prob.chosen(a))
    base = design_matrix(prob, [*cols, *extra])
    return cross_validate(block_stats(base, y_raw / prob.scale, prob.w, prob.blocks))


def _shaft_rows(
    prob: Problem, joints: Sequence[int], kind: str, values: Sequence[float]
) -> np.ndarray:
    """Stacked measured side (Nm) with ``joints`` replaced by the exact lagged (``kind`` = lag)
    or delayed shaft torque, ``values`` the time constant or delay of each joint."""
    shaft = lagged_torque_rows if kind == "lag" else delayed_torque_rows
    return np.concatenate(
        [
            np.column_stack(
                [
                    shaft(rows, values[i])[:, i] if i in joints else rows.y[:, i]
                    for i in range(prob.n_joints)
                ]
            )
            for rows in prob.rows
        ]
    )


def _least_squares_sse(prob: Problem, design: np.ndarray):
    """SSE(y) of the weighted least-squares fit of the fixed ``design`` to rows y (Nm): the Gram
    matrix is factored once, so trying many y (a grid of lags) costs one pass over the rows each."""
    G = np.einsum("kj,kjp,kjq->pq", prob.w, design, design)
    G_inv = np.linalg.pinv(G)

    def sse(y_raw: np.ndarray) -> float:
        y = y_raw / prob.scale
        r = np.einsum("kj,kjp,kj->p", prob.w, design, y)
        return float(np.einsum("kj,kj->", prob.w, y * y) - r @ G_inv @ r)

    return sse


def _search(sse) -> float:
    """Minimise sse(x) over LAG_GRID_S, then on a finer grid around the best point."""
    values = [sse(float(x)) for x in LAG_GRID_S]
    i = int(np.argmin(values))
    lo = LAG_GRID_S[max(i - 1, 0)]
    hi = LAG_GRID_S[min(i + 1, len(LAG_GRID_S) - 1)]
    fine = np.linspace(lo, hi, 11)
    return float(fine[int(np.argmin([sse(float(x)) for x in fine]))])


def classify_rate(
    prob: Problem, accepted: Sequence[Accepted], fit: FinalFit
) -> tuple[list[Finding], np.ndarray | None]:
    """Actuator lag or transport delay for the accepted torque-rate terms (module doc), and
    the exact shaft torque rows of the better of the two (Nm; None without rate terms)."""
    idx = [i for i, a in enumerate(accepted) if a.cand.spec.is_rate]
    if not idx:
        return [], None
    joints = [accepted[i].cand.joint for i in idx]
    skip = set(idx)
    design = design_matrix(prob, _cols(prob, accepted, skip))
    sse_of = _least_squares_sse(prob, design)
    # One time constant (lag) or delay per joint, each searched with the other's as found so
    # far: the two hypotheses get the same freedom, so only the shape of the response decides.
    found = {}
    for kind in ("lag", "delay"):
        values = [0.0] * prob.n_joints
        for j in joints:

            def sse(x: float, j: int = j, kind: str = kind, base: list = values) -> float:
                trial = list(base)
                trial[j] = x
                return sse_of(_shaft_rows(prob, joints, kind, trial))

            values[j] = _search(sse)
        found[kind] = values
    lags, delays = found["lag"], found["delay"]
    lag_rows = _shaft_rows(prob, joints, "lag", lags)
    delay_rows = _shaft_rows(prob, joints, "delay", delays)
    lag_cv = _cv_with(prob, accepted, skip, lag_rows)
    delay_cv = _cv_with(prob, accepted, skip, delay_rows)
    n_tests = 2
    lag_better = evidence(delay_cv, lag_cv, joints)
    delay_better = evidence(lag_cv, delay_cv, joints)
    first_order = {accepted[i].cand.joint: float(np.sum(fit.coefficients[i])) for i in idx}
    out: list[Finding] = []
    ev = {
        "joints_tested": [j + 1 for j in joints],
        "first_order_time_s": {str(j + 1): rounded(v) for j, v in first_order.items()},
        "lag_vs_delay_held_out_reduction": rounded(lag_better.reduction),
        "lag_vs_delay_sign_test_p": rounded(lag_better.sign_p, 3),
        "delay_vs_lag_held_out_reduction": rounded(delay_better.reduction),
        "delay_vs_lag_sign_test_p": rounded(delay_better.sign_p, 3),
    }
    for i in idx:
        ev.setdefault("term_" + accepted[i].cand.key, accepted[i].evidence.as_dict())
    # Separating them needs more than the usual 1 %: the interval model's velocity estimates err
    # a little more around a torque that switches inside an interval (a delay) than around a
    # smooth one (a lag), which on its own favours the lag by ~1-2 % on a pure delay.
    lag_wins = passes(lag_better, n_tests) and lag_better.reduction >= SEPARATE_REDUCTION
    delay_wins = passes(delay_better, n_tests) and delay_better.reduction >= SEPARATE_REDUCTION
    lag_ok, delay_ok = not delay_wins, not lag_wins  # neither wins: both, confounded
    if lag_ok:
        for j in joints:
            out.append(
                Finding("actuator_lag", j + 1, {"time_constant_s": rounded(lags[j])}, dict(ev))
            )
    if delay_ok:
        ds = [delays[j] for j in joints]
        if len(joints) >= 2 and max(ds) - min(ds) <= SAME_DELAY * max(ds):
            # one delay on all of them, as a bus or a shared drive clock gives
            est = {"delay_s": rounded(float(np.mean(ds))), "per_joint_s": [rounded(d) for d in ds]}
            out.append(Finding("transport_delay", None, est, dict(ev)))
        else:
            for j in joints:
                out.append(
                    Finding("transport_delay", j + 1, {"delay_s": rounded(delays[j])}, dict(ev))
                )
    if lag_ok and delay_ok:
        for f in out:
            f.confounded_with = [
                "transport_delay" if f.effect == "actuator_lag" else "actuator_lag"
            ]
    return out, (lag_rows if lag_ok else delay_rows)


# A lag or delay shorter than this fraction of the sample interval is below what the samples
# resolve, and not a finding (issue 26 saw a 50 µs "lag", 1/30 of its 1.5 ms samples). Not a
# half: a command held over an interval is exact in the interval rows, so a delay moves its
# step inside the interval and a fraction of an interval shows in the momentum change (the
# blind-like sets' delays of 1.25-5 ms and lags of 1.5-6 ms on 2.5 ms samples are found,
# docs/diagnosis.md); a quarter keeps those and refuses timing finer than the rows can place.
RESOLVABLE_INTERVALS = 0.25


def unresolved_rate_terms(prob: Problem, findings: Sequence[Finding]) -> dict[str, str]:
    """The rate terms (Candidate keys ``rate:j``) whose lag and delay findings the data do not
    resolve, each with its reason: every one shorter than :data:`RESOLVABLE_INTERVALS` of the
    sample interval (the shortest recording's median); a first-order time ≤ 0 (the shaft torque
    would lead the recorded one, which no lag or delay does, whatever the searches over
    positive times return: a DFKI A.0 copy gave −0.23 ms, then a "16 ms lag"); or every one at
    the end of the searched range (the search bracketed no minimum, so the size is the grid's,
    not the data's: an A.0 copy with an offset written in gave joint 2 a 30 ms "lag" and
    "delay", a slow misfit of the model that any long response smooths). A delay found on all
    joints (joint None) counts for each joint tested with its own per-joint value."""
    times: dict[int, list[float]] = {}
    lead: dict[int, float] = {}
    for f in findings:
        if f.effect == "actuator_lag":
            times.setdefault(f.joint, []).append(float(f.estimate["time_constant_s"]))
        elif f.effect == "transport_delay" and f.joint is not None:
            times.setdefault(f.joint, []).append(float(f.estimate["delay_s"]))
        elif f.effect == "transport_delay":
            per = f.estimate.get("per_joint_s") or []
            tested = f.evidence.get("joints_tested") or list(range(1, len(per) + 1))
            for j, d in zip(tested, per, strict=False):
                times.setdefault(j, []).append(float(d))
        for j, v in (f.evidence.get("first_order_time_s") or {}).items():
            if v is not None and float(v) <= 0:
                lead[int(j)] = float(v)
    if not times:
        return {}
    h = min(float(r.h) for r in prob.rows)
    floor = RESOLVABLE_INTERVALS * h
    longest = float(LAG_GRID_S[-1])
    out = {}
    for j in [*times, *(j for j in lead if j not in times)]:  # the order the reasons were found
        ts = times.get(j, [])
        if ts and min(ts) >= RANGE_END * longest:
            out[f"rate:{j}"] = (
                f"a lag or delay of {1e3 * min(ts):.3g} ms sits at the end of the searched range "
                f"({1e3 * longest:.3g} ms): the data place no optimum inside it"
            )
        elif j in lead:
            out[f"rate:{j}"] = (
                f"its first-order time is {1e3 * lead[j]:.3g} ms: the shaft torque would lead "
                "the recorded one, which no lag or delay does"
            )
        elif ts and max(ts) < floor:
            out[f"rate:{j}"] = (
                f"a lag or delay of {1e3 * max(ts):.3g} ms is under {RESOLVABLE_INTERVALS:g} of "
                f"the {1e3 * h:.3g} ms sample interval: the samples cannot resolve it"
            )
    return out


RANGE_END = 0.999  # a lag or delay at this fraction of the longest time searched sits at its end


def resolve_gain(
    prob: Problem, accepted: Sequence[Accepted], fit: FinalFit, reference_theta: np.ndarray
) -> tuple[dict[int, float], dict[str, Any]]:
    """Which joint a torque gain error belongs to (module doc). Returns {joint (0/1): relative
    gain error} for the joint(s) to report, and the evidence for the choice."""
    i = next(i for i, a in enumerate(accepted) if a.cand.spec.is_gain)
    j = accepted[i].cand.joint
    y = prob.y_raw
    n_rigid = prob.model.rigid_count
    if prob.n_joints > 2:
        # More than two joints: a gain on one joint is not the inverse gain on another single
        # joint (that would be the inverse gain on all the others at once), so it stays where
        # the selection put it; the reference only scales it (gain_at_reference).
        here = _cv_with(prob, accepted, set(), y)
        ref = np.asarray(reference_theta, float)[:n_rigid]
        ev = {
            "decided_by": "the selection (one joint's gain is identifiable with n > 2 joints)",
            "rigid_body_deviation_from_reference": {
                str(j + 1): rounded(rigid_body_deviation(here.beta, ref, n_rigid))
            },
            "relative_at_reference_theta": {
                str(j + 1): rounded(gain_at_reference(prob, accepted, i, j, y, ref))
            },
        }
        r_here = float(here.beta[prob.n_params + sum(term_width(a.cand) for a in accepted[:i])])
        return {j: r_here}, ev
    other = 1 - j
    alt_cols = [
        np.concatenate([gain_column(r, other) for r in prob.rows]) / prob.scale[None, :, None]
    ]
    here = _cv_with(prob, accepted, set(), y)
    there = _cv_with(prob, accepted, {i}, y, alt_cols)
    ref = np.asarray(reference_theta, float)[:5]
    dev_here = float(np.linalg.norm((here.beta[:5] - ref) / ref))
    dev_there = float(np.linalg.norm((there.beta[:5] - ref) / ref))
    # No held-out comparison here: hypothesis "gain on j" has every residual (1 + r) times those
    # of "gain on the other joint", so least squares always prefers the one that shrinks them.
    ev = {
        "decided_by": "rigid-body parameters θ1..θ5 against the reference",
        "rigid_body_deviation_from_reference": {
            str(j + 1): rounded(dev_here),
            str(other + 1): rounded(dev_there),
        },
    }
    # The accepted gain term is the last column of ``here`` only if it was accepted last.
    r_here = float(here.beta[prob.n_params + sum(term_width(a.cand) for a in accepted[:i])])
    r_there = float(there.beta[-1])
    if dev_there >= GAIN_REFERENCE_RATIO * dev_here:
        gains = {j: r_here}
    elif dev_here >= GAIN_REFERENCE_RATIO * dev_there:
        gains = {other: r_there}
    else:
        gains = {j: r_here, other: r_there}
    ev["relative_at_reference_theta"] = {
        str(k + 1): rounded(gain_at_reference(prob, accepted, i, k, y, ref)) for k in gains
    }
    return gains, ev


def gain_at_reference(
    prob: Problem,
    accepted: Sequence[Accepted],
    i: int,
    joint: int,
    y_raw: np.ndarray,
    reference_rigid: np.ndarray,
) -> float:
    """The torque gain error r on ``joint`` refitted with θ1..θ5 held at the reference (friction,
    r and the other accepted terms free). With θ free, θ absorbs part of a gain: on closed-loop
    PD runs the commanded torque follows Ψθ so closely that a 5 % gain came out as 2.9 % (joint
    1) and 4.3 % (joint 2); held at the reference, 4.97 % and 4.99 %
    (tests/benchmarks/closed_loop_bias.py, docs/diagnosis.md "Closed loop"). Only as good as the
    reference, which the choice of joint already trusts."""
    n = len(reference_rigid)  # θ1..θ5, or a URDF model's rigid base parameters (its rigid_count)
    col = np.zeros((len(y_raw), prob.n_joints, 1))
    col[:, joint, 0] = -y_raw[:, joint] / prob.scale[joint]
    cols = [prob.chosen(a) for k, a in enumerate(accepted) if k != i] + [col]
    fixed = np.asarray(reference_rigid, float)[:n]
    return float(fit_theta_at(design_matrix(prob, cols), prob.y, prob.w, fixed, True)[-1])


__all__ = [
    "THETA_FC",
    "Finding",
    "coulomb_column",
    "rounded",
]
