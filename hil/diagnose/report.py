"""The diagnosis's report text: findings, confounded groups and the before/after fit in words
(:func:`summary_words`), what a recording could not show (:func:`detectability_notes`,
:func:`burst_notes`), why a candidate is not a finding (:func:`rejection_notes`) and how the
nominal model is named (``ArmDynamics.display_name``). Pure formatting of the stages' results
(:mod:`hil.diagnose.pipeline` calls it); a finding's words are its candidate kind's
(:mod:`hil.diagnose.kinds`); the JSON document is built in the pipeline.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from hil.diagnose.findings import (
    AT_REFERENCE,
    Finding,
)
from hil.diagnose.heldout import SEGMENT_S, HeldOutFit
from hil.diagnose.kinds import finding_words, is_gain_finding
from hil.diagnose.problem import Problem
from hil.model.closed_form import TERMS
from hil.model.protocol import ArmDynamics


def percent(x: float | None) -> str:
    """A fraction as "1.23 %", or "n/a" when there was nothing to compare."""
    return "n/a" if x is None else f"{100 * x:.2f} %"


# --- words ---------------------------------------------------------------------------------------

# the findings of the candidate kinds are in their kinds' words (hil.diagnose.kinds)
UNEXPLAINED_WORDS = "a structured residual no candidate explains, carried by the {carried_by}"


def _phrase(f: Finding, rigid: str = "θ1..θ5 of the 2-DOF arm") -> str:
    """One finding in words; ``rigid``: what the rigid-body parameters are called
    (``ArmDynamics.rigid_words``)."""
    e = dict(f.estimate)
    if f.effect == "coulomb_asymmetry":
        e["neg"] = f"{-e['negative_Nm']:+.2f}"
    if "time_constant_s" in e:
        e["ms"] = f"{1000 * e['time_constant_s']:.3g}"
    if "delay_s" in e:
        e["ms"] = f"{1000 * e['delay_s']:.3g}"
    if "offset_rad" in e:
        e["deg"] = f"{math.degrees(e['offset_rad']):+.3g}"
    if "relative" in e:
        e["pct"] = f"{100 * e[e.get('reading', 'relative')]:+.3g}"
    if "share_of_M22" in e:
        e["share"] = f"{100 * e['share_of_M22']:.3g}"
    words = {**finding_words(), "unexplained": UNEXPLAINED_WORDS}[f.effect].format(**e)
    if e.get("reading") == AT_REFERENCE:
        # docs/diagnosis.md 4a: the θ-free reading failed the simulation gate, this one passed
        words += (
            f" (read with the rigid-body parameters ({rigid}) held at the "
            f"reference; with θ free the estimate is {100 * e['relative']:+.3g} %, biased toward "
            "zero because a free θ absorbs part of the gain (most on closed-loop data), and that "
            f"reading {f.evidence.get('theta_free_reading', 'failed the simulation gate')})"
        )
    elif e.get("relative_at_reference_theta") is not None:
        # docs/diagnosis.md 4a: a free θ absorbs part of a gain (most in closed loop)
        words += (
            f" ({100 * e['relative_at_reference_theta']:+.3g} % with the rigid-body parameters "
            f"({rigid}) held at the reference; with θ free the estimate is "
            "biased toward zero, most on closed-loop data)"
        )
    return words


SEPARATE = {
    frozenset(("coulomb_asymmetry", "torque_offset")): (
        "position and commanded torque alone cannot separate them (an offset c is exactly Coulomb "
        "levels θ_fc ∓ c, sliding or stuck); a torque sensor, or a blocked-rotor test with a load "
        "cell at zero command, would"
    ),
    frozenset(("actuator_lag", "transport_delay")): (
        "a torque step or a chirp with content above 1/(2π T) (tens of Hz) would separate them: "
        "a lag rounds a step, a delay shifts it"
    ),
    frozenset(("angle_offset", "torque_offset")): (
        "a wider sweep of the joint's angle (0.5 rad or more) would separate them: an encoder "
        "offset moves the gravity torque with the angle, a torque offset does not"
    ),
    frozenset(("angle_offset", "com_offset")): (
        "an encoder zero offset moves the gravity torque as a centre of mass across the link "
        "does (θ4 sin(q1 + δ) = θ4 cos δ sin q1 + θ4 sin δ cos q1); a known zero (the arm "
        "hanging at rest, each link levelled) separates them"
    ),
    frozenset(("torque_offset", "com_offset")): (
        "on a joint that stays near one angle a centre of mass across the link gives a nearly "
        "constant torque, as an offset does; a wider sweep of that joint separates them"
    ),
    frozenset(("rotor_inertia", "actuator_lag")): (
        "a lag of the torque and a rotor inertia both add a torque that follows the motion's "
        "rate of change, and in closed loop the commanded torque's rate follows the "
        "acceleration; an open-loop torque step or chirp separates them"
    ),
    frozenset(("torque_gain",)): (  # a gain on joint 1 or the inverse one on joint 2
        "the data fix only the ratio of the two joints' gains; a known load (a calibrated mass) "
        "on one joint would fix the scale"
    ),
}


def _separate(effects: frozenset[str]) -> str:
    """What would separate a confounded group: its own entry, else those of the pairs in it
    (an asymmetry stands for its torque offset: the same column); never empty."""
    if effects in SEPARATE:
        return SEPARATE[effects]
    named = effects | ({"torque_offset"} if "coulomb_asymmetry" in effects else set())
    parts = [why for key, why in SEPARATE.items() if len(key) > 1 and key <= named]
    return "; ".join(parts) or "an experiment that excites them differently would"


def _linked(f: Finding, g: Finding) -> bool:
    """g is an alternative to f: confounded, on the same joint, or across joints when one of
    them is on both (a delay), both are torque gains (only their ratio is known) or one is a
    model term (a term of the whole arm's model, whatever joint its finding names)."""
    if g is f or g.effect not in f.confounded_with:
        return False
    across = f.joint is None or g.joint is None
    across = across or (f.effect == g.effect and is_gain_finding(f.effect))
    across = across or f.effect in TERMS or g.effect in TERMS
    return f.joint == g.joint or across


def _confounded_group(f: Finding, findings: Sequence[Finding]) -> list[Finding]:
    """f and every finding linked to it, directly or through others (lags on two joints and
    the one delay either could be)."""
    group, frontier = [f], [f]
    while frontier:
        x = frontier.pop()
        for g in findings:
            if all(g is not y for y in group) and (_linked(x, g) or _linked(g, x)):
                group.append(g)
                frontier.append(g)
    return sorted(group, key=lambda g: (g.joint is None, g.joint or 0))


def _who(f: Finding, n_joints: int = 2) -> str:
    return f"Joint {f.joint}" if f.joint else ("Both joints" if n_joints == 2 else "All joints")


# Held-out torque NRMSE above which "nothing found" is not called "the model is complete".
MODEL_EXPLAINS = 0.05


def summary_words(
    findings: Sequence[Finding],
    fit: HeldOutFit,
    notes: Sequence[str],
    nominal: str = "9-parameter",
    rigid: str = "θ1..θ5 of the 2-DOF arm",
) -> str:
    """The summary in words; ``nominal``: the model's name (``ArmDynamics.display_name``),
    ``rigid``: its rigid-body parameters' (``ArmDynamics.rigid_words``)."""
    n_joints = len(fit.before.torque_nrmse)
    if not findings and any(n.startswith("I cannot tell") for n in notes):
        lines = []  # the note says why, and that is all there is to say
    elif not findings and (
        any(n.startswith("Not a finding") for n in notes)
        or max((x for x in fit.before.torque_nrmse if x is not None), default=0.0) > MODEL_EXPLAINS
    ):
        before = fit.before.torque_nrmse
        left = f"a held-out torque NRMSE of {' / '.join(percent(x) for x in before)}"
        if all(x is None for x in before):  # e.g. a free swing held out: τ = 0 throughout
            position = fit.before.position_nrmse
            left = (
                "a held-out torque that cannot be scored on any joint (too few usable rows, or "
                "a constant torque with no spread to scale by, as when the motors are off)"
                + (
                    f" and a held-out simulated position NRMSE of "
                    f"{' / '.join(percent(x) for x in position)}"
                    if position and any(x is not None for x in position)
                    else ""
                )
            )
        lines = [
            f"No finding, and I cannot say the model is complete: it leaves {left}, and "
            "nothing in the vocabulary explains that residual on held-out data with a "
            "physical refit."
        ]
    elif not findings:
        lines = [
            f"No missing physics found: the {nominal} model explains the recordings to within "
            "their noise."
        ]
    else:
        lines = []
        order = sorted(findings, key=lambda f: (f.joint is None, f.joint or 0))
        done: set[int] = set()
        for f in order:
            if id(f) in done:
                continue
            group = _confounded_group(f, order)
            done |= {id(g) for g in group}
            first = [g for g in group if g.effect == f.effect]
            others = [g for g in group if g.effect != f.effect]
            if is_gain_finding(f.effect) and len(first) == 2:
                first, others = first[:1], first[1:]
            said = "; ".join(
                f"{_who(g, n_joints) if i == 0 else _who(g, n_joints).lower()}: {_phrase(g, rigid)}"
                for i, g in enumerate(first)
            )
            if not others:
                lines.append(f"{said}.")
                continue
            alt = "; or ".join(
                _phrase(g, rigid)
                if g.joint == f.joint
                else f"{_who(g, n_joints).lower()}: {_phrase(g, rigid)}"
                for g in others
            )
            why = _separate(frozenset(g.effect for g in group))
            lines.append(
                f"{said} — or, equally well, {alt}. The data cannot tell these apart: {why}."
            )
        b, a = fit.before.torque_nrmse, fit.after.torque_nrmse
        pb, pa = fit.before.position_nrmse, fit.after.position_nrmse
        parts = []
        for j in range(len(b)):
            parts.append(f"joint {j + 1} torque {percent(b[j])} → {percent(a[j])}")
        if pb and pa:
            for j in range(len(pb)):
                parts.append(
                    f"joint {j + 1} simulated position {percent(pb[j])} → {percent(pa[j])}"
                )
        lines.append(
            f"Modelling it changes the held-out error ({fit.held_out}): " + "; ".join(parts) + "."
        )
    lines += list(notes)
    return " ".join(lines)


BURST_RATIO = 5.0  # a time window this many times the median RMS is called a burst


def burst_notes(location: dict[str, Any]) -> list[str]:
    """Warn when the nominal residual comes in bursts: no candidate in the vocabulary is
    confined to a few seconds, but a stalled realtime loop, a collision or a drive fault is."""
    notes = []
    for j in location["joints"]:
        bursts = [w for w in j["time_windows"] if w["rms_over_median"] >= BURST_RATIO]
        if bursts:
            when = ", ".join(
                f"{w['t_s'][0]:.2f}-{w['t_s'][1]:.2f} s"
                + (f" of recording {w['recording']}" if "recording" in w else "")
                for w in bursts
            )
            when += " from the start"
            notes.append(
                f"Joint {j['joint']}: the residual comes in bursts ({when}, over "
                f"{BURST_RATIO:g}x the median); check those seconds for a timing stall, a "
                "collision or a fault before trusting findings drawn from them."
            )
    return notes


def detectability_notes(prob: Problem) -> list[str]:
    """What the data cannot show (docs/diagnosis.md, 'What a recording needs')."""
    notes = []
    for j in range(prob.n_joints):
        v, w = prob.v_mean[:, j], prob.w[:, j]
        if not np.any(w > 0):
            continue  # said already: the joint has no usable row
        slow = int(np.sum((w > 0) & (np.abs(v) < 0.3)))
        if slow < 400:
            notes.append(
                f"Joint {j + 1}: only {slow} usable samples slide slower than 0.3 rad/s, "
                "too few to "
                "show Stribeck friction (record slow moves; docs/diagnosis.md)."
            )
        q = np.concatenate([r.q[:, j] for r in prob.rows])
        if np.ptp(q) < 0.5:
            notes.append(
                f"Joint {j + 1}: it swept only {np.ptp(q):.2f} rad, too little to tell an "
                "angle offset "
                "from a torque offset or cogging with few periods per revolution."
            )
        if np.all(v[w > 0] > 0) or np.all(v[w > 0] < 0):
            notes.append(
                f"Joint {j + 1}: it moved one way only, so direction-dependent friction "
                "cannot show."
            )
    return notes


# the vocabulary's names of each candidate kind
KIND_NAMES = {
    "offset": "coulomb_asymmetry / torque_offset",
    "gain": "torque_gain",
    "cogging": "cogging",
    "stribeck": "stribeck",
    "rate": "actuator_lag / transport_delay",
    "angle": "angle_offset",
    **{term: term for term in TERMS},
}


def simulation_notes(fit: HeldOutFit, model: ArmDynamics) -> list[str]:
    """Say when an n-joint model's held-out open-loop simulation could not be scored: then the
    findings stand on the held-out torque alone (:func:`simulation_gate`)."""
    if model.closed_form:
        return []
    if all(
        fit.model(name).position_nrmse and None not in fit.model(name).position_nrmse
        for name in ("before", "after")
        if name not in fit.unphysical
    ):
        return []
    return [
        "The held-out open-loop simulation of this n-joint model leaves the finite numbers "
        f"within a {SEGMENT_S:g} s segment (a closed-loop recording: the torques were computed "
        "from the recorded states, and without that feedback the model's errors grow "
        "unchecked), so simulated motion is no test here: findings are gated on the held-out "
        "torque prediction alone."
    ]


def rejection_notes(rejected: dict[str, str]) -> list[str]:
    out = []
    for key, why in rejected.items():
        kind, _, joint = key.partition(":")
        where = f" on joint {joint}" if joint else ""
        out.append(f"Not a finding: {KIND_NAMES.get(kind, kind)}{where}: {why}.")
    return out
