"""The whole diagnosis of a set of recordings, as one JSON-able document plus arrays for plots.

1. nominal fit (9 parameters, the profile's model terms, or an n-joint URDF model's base
   parameters) and where its residual lives (:mod:`hil.diagnose.locate`);
2. candidate selection (:mod:`hil.diagnose.selection`), findings with magnitudes
   (:mod:`hil.diagnose.interpret`, :mod:`hil.diagnose.findings`), a test for structure nothing
   in the vocabulary explains;
3. the simulation gate (:mod:`hil.diagnose.gates`) and the before/after fit on held-out data:
   torque NRMSE and open-loop simulated-position NRMSE (:mod:`hil.diagnose.heldout`);
4. a summary in words (:mod:`hil.diagnose.report`), the timing findings of the time stamps.
Pure computation; files and plots are :mod:`hil.diagnose.cli`'s.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from drivers.process import release_freed_heap
from drivers.recording import Recording
from hil.diagnose.candidates import candidates, joints_of
from hil.diagnose.findings import Finding
from hil.diagnose.gates import pinned_rigid_body, simulation_gate
from hil.diagnose.heldout import HeldOutFit, before_after, read_at_reference
from hil.diagnose.interpret import interpret_with_rate, lack_of_fit, settle_gain_joint, unexplained
from hil.diagnose.locate import Location, locate
from hil.diagnose.physical import held_at_zero, nominal_fit_se, physical_gate, physical_theta
from hil.diagnose.problem import (
    MIN_USABLE_ROWS,
    DiagnosisError,
    build_problem,
    check_recording,
    usable_speeds,
)
from hil.diagnose.report import (
    KIND_NAMES,
    burst_notes,
    detectability_notes,
    rejection_notes,
    simulation_notes,
    summary_words,
)
from hil.diagnose.selection import relinearise_angle, select
from hil.diagnose.stats import Evidence
from hil.model.closed_form import ArmModel
from hil.model.protocol import ArmDynamics


@dataclass
class Diagnosis:
    """What :func:`diagnose` found, as the stages gave it (typed; the JSON document is built
    from it by :meth:`document`, when the command writes or prints it)."""

    findings: list[Finding]
    timing: list[dict[str, str]]  # the time stamps' findings (:func:`timing_findings`)
    confounded: list[list[str]]
    fit: HeldOutFit  # before/after on the held-out data
    summary: str  # in words (:func:`hil.diagnose.report.summary_words`)
    location: Location  # where the nominal residual lives
    nominal_theta: np.ndarray  # the nominal model fitted to the recordings
    model: ArmDynamics
    rows: list[Any]  # the recordings' rows (their noise models)
    candidates_tested: dict[str, Evidence]  # the selection's first round
    not_findings: dict[str, str]  # per term, why it is not a finding
    not_tested: dict[str, str]  # per candidate kind, why it was not tested
    nominal_violations: list[str]  # why the nominal fit is not physical (empty: it is)
    # coefficients held at zero in the nominal fit and every refit, with their least-squares
    # values (:func:`hil.diagnose.physical.held_at_zero`)
    held_at_zero: dict[str, float]
    recordings: list[str]
    notes: list[str]
    timing_s: float  # seconds the diagnosis took

    def document(self) -> dict[str, Any]:
        """The diagnosis document (diagnosis.json, ``hil diagnose --json``)."""
        model = self.model
        return {
            "findings": [f.as_dict() for f in self.findings],
            "timing": self.timing,
            "confounded": self.confounded,
            "fit": self.fit.as_dict(),
            "summary": self.summary,
            "location": self.location.document,
            "nominal_theta": self.nominal_theta.tolist(),
            **({"nominal_model": _model_document(model)} if model.terms else {}),
            "noise": [r.noise.as_dict(r.h) if r.noise else None for r in self.rows],
            "candidates_tested": {k: ev.as_dict() for k, ev in self.candidates_tested.items()},
            "not_findings": self.not_findings,
            **({"not_tested": self.not_tested} if self.not_tested else {}),
            "physical": {
                "nominal_consistent": not self.nominal_violations,
                "nominal_violations": list(self.nominal_violations),
                **({"held_at_zero": self.held_at_zero} if self.held_at_zero else {}),
            },
            "recordings": self.recordings,
            "notes": self.notes,
            "timing_s": self.timing_s,
        }


@dataclass
class DiagnosisResult:
    """:func:`diagnose`'s result: the typed :class:`Diagnosis`, the arrays for plots, and the
    JSON ``document``, built from the diagnosis when first asked and kept (``hil diagnose``
    adds the drift and the torque path to it)."""

    diagnosis: Diagnosis
    arrays: dict[str, Any]  # residuals, states, simulations: for plots

    @cached_property
    def document(self) -> dict[str, Any]:
        return self.diagnosis.document()


# What the reader noticed in the time stamps (drivers/recording/, ``findings_on_read``), by
# the words its notes start with or contain, and the timing finding each is.
TIMING_NOTES = (
    ("irregular sampling", "irregular_sampling"),
    ("gap(s) in t", "gaps"),
    ("loop delay", "loop_delay"),
    ("exact duplicate row", "dropped_samples"),
)


def timing_findings(recordings: Sequence[Recording]) -> list[dict[str, str]]:
    """The reader's notes on the time stamps as timing findings: irregular sampling, gaps
    (stalls or spliced data: segments never joined), the loop delay the torque was shifted by,
    duplicated rows dropped. They come from the stamps, not from a fit, so they stand as they
    are; the diagnosis has already used them (real intervals, gaps left out, torque realigned)."""
    out = []
    for r in recordings:
        for note in r.findings_on_read:
            kind = next((k for needle, k in TIMING_NOTES if needle in note), None)
            if kind is not None:
                out.append({"kind": kind, "recording": str(r.path), "note": note})
        stale = repeated_samples(r.q, r.tau)
        if stale.any():
            out.append(
                {
                    "kind": "repeated_samples",
                    "recording": str(r.path),
                    "note": f"repeated samples: {int(stale.sum())} rows (first at line "
                    f"{int(np.argmax(stale)) + 2}) repeat the previous row's positions on "
                    f"every joint ({int((stale & repeated_torques(r.tau)).sum())} of them the "
                    "torques too) with a new time stamp while every joint moves before and "
                    "after: stale samples of the logger, which the rows take as standstill "
                    "(left out with their neighbours) and as position noise",
                }
            )
    return out


def repeated_torques(tau: np.ndarray) -> np.ndarray:
    """Rows whose every torque equals the previous row's (row 0: False)."""
    return np.r_[False, np.all(np.diff(tau, axis=0) == 0, axis=1)]


def repeated_samples(q: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Rows k that repeat row k − 1's positions on every joint while every joint moved from
    k − 2 to k − 1 and moves from k to k + 1: a logger that wrote a stale state with a new
    stamp (a joint at rest, or a hold, repeats its positions over many rows and is not this)."""
    step = np.diff(q, axis=0) != 0  # (N−1, n): interval i = rows i → i+1 moved
    out = np.zeros(len(q), bool)
    if len(q) >= 4:
        still = ~step[1:-1].any(axis=1)  # interval k−1 → k, for k = 2..N−2
        out[2:-1] = still & step[:-2].all(axis=1) & step[2:].all(axis=1)
    return out


def _model_document(model: ArmDynamics) -> dict[str, Any]:
    return {"terms": list(model.terms), "names": list(model.names), "units": list(model.units)}


def diagnose(
    recordings: Sequence[Recording],
    reference_theta: np.ndarray,
    *,
    nominal_theta: np.ndarray | None = None,
    progress: Callable[[str], None] | None = None,
    model: ArmDynamics | None = None,
    tick: Callable[..., None] | None = None,
) -> DiagnosisResult:
    """Diagnose ``recordings`` against ``model`` (module doc; default the 9-parameter model,
    else e.g. ``ArmModel(profile.terms)``: the nominal fit, its physical checks and the
    held-out simulation are that model's, and the model terms it lacks are candidates).
    ``nominal_theta``, when given, is in ``model``'s parameters. ``progress`` is told each
    stage as it starts; ``tick(stage, done, total, unit)`` the progress within the long ones
    (:class:`hil.cli_options.StageProgress` throttles it)."""
    model = ArmModel(()) if model is None else model
    if nominal_theta is not None and len(nominal_theta) != model.n_params:
        raise DiagnosisError(
            f"the nominal theta holds {len(nominal_theta)} numbers; the model "
            f"({', '.join(model.terms) or 'no extra terms'}) has {model.n_params}"
        )
    started = time.perf_counter()
    say = progress or (lambda _m: None)
    say(f"diagnose: {len(recordings)} recording(s), fitting the nominal model")
    for r in recordings:
        check_recording(str(r.path), r.t, r.q, r.tau)
    prob, theta_fit = build_problem([(r.q, r.tau, r.period_s, r.t) for r in recordings], model)
    release_freed_heap()  # the rows' building blocks, before the selection's peak
    usable = (prob.w > 0).sum(axis=0)
    n_joints = prob.n_joints
    live = [j for j in range(n_joints) if usable[j] >= MIN_USABLE_ROWS]
    if not live:
        raise DiagnosisError(
            f"{'neither' if n_joints == 2 else 'no'} joint moves enough to diagnose "
            f"({' / '.join(str(u) for u in usable)} usable rows, "
            f"need {MIN_USABLE_ROWS}): constant or stuck signals?"
        )
    dead_notes = [
        f"Joint {j + 1}: only {usable[j]} usable rows (it barely moves or stays stuck): "
        "I cannot tell what its model leaves out."
        for j in range(n_joints)
        if j not in live
    ]
    nominal_se = nominal_fit_se(prob)
    nominal_unphysical = physical_theta(theta_fit, nominal_se, model)[1]
    held: dict[int, float] = {}
    least_squares_unphysical: list[str] = []
    if nominal_unphysical:
        # a coefficient the recording cannot tell from zero may come out negative and the fit
        # unphysical by that alone: hold it at zero, as bounded least squares does, and build on
        # that fit when it is physical (DFKI A.0 trajectory 00: θ6, θ8 < 0 and M(q) not positive
        # definite; both go with θ6 = θ8 = 0)
        pinned = held_at_zero(prob, theta_fit, model)
        if pinned is not None and not physical_theta(pinned.theta, pinned.se, model)[1]:
            least_squares_unphysical, nominal_unphysical = nominal_unphysical, []
            prob, theta_fit, nominal_se, held = pinned.prob, pinned.theta, pinned.se, pinned.held
            say(
                "diagnose: the nominal fit holds "
                + ", ".join(model.names[i] for i in held)
                + " at zero (least squares put them below)"
            )
    where = locate(prob, theta_fit)
    ranges = np.ptp(np.concatenate([r.q for r in recordings]), axis=0)
    library = [
        c
        for c in candidates(theta_fit, ranges, usable_speeds(prob), model)
        # a gain error shows only as the ratio of the joints' gains (docs/diagnosis.md, 4)
        if all(j in live for j in joints_of(c)) and (not c.spec.is_gain or len(live) >= 2)
    ]
    rejected: dict[str, str] = {}
    memo: dict = {}  # before_after's fits and simulations, from the gate to the final comparison
    if nominal_unphysical:
        # nothing built on an unphysical fit is a finding: say so and stop there
        say("diagnose: the nominal fit is not physical; no candidates tested")
        accepted, first, findings, confounded = [], {}, [], []
        shaft = None
        cannot = [
            "I cannot tell what the model leaves out: the nominal "
            f"{model.display_name} fit of these "
            "recordings is not physical (" + "; ".join(nominal_unphysical) + "), so no finding "
            "could stand on it. Record more varied motion of "
            f"{ {1: 'the joint', 2: 'both joints'}.get(n_joints, 'all joints') }, or check the "
            "torque and angle columns."
        ]
    else:
        cannot = []
        said = "both joints" if n_joints == 2 else f"{n_joints} joints"
        say(f"diagnose: testing {len(library)} candidates ({said})")
        accepted, first = select(
            prob, library, reference=reference_theta, rejected=rejected, tick=tick
        )
        release_freed_heap()  # the grids and columns the selection dropped (Problem.keep_only)
        accepted = physical_gate(prob, relinearise_angle(prob, accepted), rejected)
        accepted = lack_of_fit(prob, accepted, rejected, say)
        accepted = settle_gain_joint(prob, accepted, library, reference_theta)
        say(f"diagnose: accepted {[a.cand.key for a in accepted] or 'nothing'}; refitting")
        accepted, findings, confounded, shaft = interpret_with_rate(
            prob, accepted, library, reference_theta, rejected, say
        )
        held_columns = (
            np.concatenate([r.Psi[:, :, list(held)] for r in prob.rows]) / prob.scale[None, :, None]
            if held
            else None
        )
        findings += unexplained(prob, accepted, shaft, held_columns)
        accepted, findings, dropped, shaft = simulation_gate(
            prob,
            accepted,
            findings,
            nominal_theta,
            say,
            nominal_se,
            shaft,
            memo=memo,
            reference=reference_theta,
        )
        rejected.update(dropped)
        pinned = pinned_rigid_body(prob, findings, reference_theta)
        if pinned is not None:
            findings = read_at_reference(prob, accepted, findings, shaft, pinned)
        kept = {f.effect for f in findings}
        confounded = [pair for pair in confounded if set(pair) <= kept]
    fit, fit_arrays = before_after(
        prob,
        accepted,
        findings,
        nominal_theta,
        friction_se=nominal_se,
        shaft=shaft,
        memo=memo,
        rigid_reference=pinned_rigid_body(prob, findings, reference_theta),
    )
    refused = model.refused_terms
    if len(live) == 1:  # the library leaves the gain out (above): say so
        refused["gain"] = (
            "one joint moves, and a torque gain error on it scales every parameter alike "
            "(only the ratio of two joints' gains shows; docs/diagnosis.md)"
        )

    def called(i: int) -> str:  # a URDF arm's base parameter by what it is too (fv1)
        name, meaning = model.names[i], model.meanings[i]
        return name if meaning == name else f"{name} = {meaning}"

    held_notes = (
        [
            "Held at zero in every fit: "
            + ", ".join(
                f"{called(i)} (least squares {v:.4g} {model.units[i]})" for i, v in held.items()
            )
            + ": least squares put them below zero, which no arm has (the recording cannot tell "
            "them from zero), and with them the fit was not physical ("
            + "; ".join(least_squares_unphysical)
            + "); held there, as bounded least squares does, it is."
        ]
        if held
        else []
    )
    notes = (
        cannot
        + held_notes
        + dead_notes
        + [f"Not tested: {KIND_NAMES.get(k, k)}: {why}." for k, why in refused.items()]
        + simulation_notes(fit, model)
        + rejection_notes(rejected)
        + detectability_notes(prob)
        + burst_notes(where.document)
    )
    timing = timing_findings(recordings)
    summary = summary_words(findings, fit, notes, model.display_name, model.rigid_words)
    if timing:
        kinds = sorted({t["kind"].replace("_", " ") for t in timing})
        summary += f" Timing, from the time stamps: {', '.join(kinds)} (see timing)."
    diagnosis = Diagnosis(
        findings=findings,
        timing=timing,
        confounded=confounded,
        fit=fit,
        summary=summary,
        location=where,
        nominal_theta=theta_fit,
        model=model,
        rows=prob.rows,
        candidates_tested=first,
        not_findings=rejected,
        not_tested=refused,
        nominal_violations=list(nominal_unphysical),
        held_at_zero={model.names[i]: v for i, v in held.items()},
        recordings=[str(r.path) for r in recordings],
        notes=notes,
        timing_s=round(time.perf_counter() - started, 2),
    )
    return DiagnosisResult(diagnosis, {"location": where.arrays, **fit_arrays})


__all__ = [
    "Diagnosis",
    "DiagnosisResult",
    "diagnose",
]
