"""`hil diagnose RECORDING [RECORDING ...] --robot cicese [--params FILE | --reference REC ... |
--refit] [--out DIR] [--json]`: find the physics the 9-parameter model leaves out
(docs/diagnosis.md); with a robot described by a URDF (``--robot cicese3``, ``panda``), the
physics its n-joint model leaves out. The recordings are judged against the model the user has
(:mod:`hil.diagnose.drift`): the robot profile's, a ``--params`` file's, or one identified from
``--reference`` recordings of the same arm; ``--refit`` judges them against their own fit only.

Reads recordings in the standard format (a run directory or a CSV with t,q1,q2,tau1,tau2, or
t,q1..qN,tau1..tauN for an N-joint robot), from this bench or a real one; prints the findings
and the before/after fit in words, or one JSON document with ``--json``; where the file's
format holds both a commanded and a measured torque, the path between them and which torque
is judged (:mod:`hil.diagnose.torque_path`); writes
``diagnosis.json`` and plots to ``--out``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from drivers.recording import Recording, RecordingError, write_json_atomic
from hil.cli_options import (
    PROGRESS_EVERY_S,
    StageProgress,
    add_html_report_option,
    add_out_options,
    add_progress_option,
    add_recording_options,
    add_report_options,
    prepare_out_dir,
    print_document,
    read_recording,
    recorded_urdf_robot,
    say,
    write_html_report,
)
from hil.diagnose.drift import DriftResult, Nominal, judge, nominal_from_reference
from hil.diagnose.heldout import MIN_HELD_OUT_ROWS
from hil.diagnose.pipeline import diagnose
from hil.diagnose.report import percent
from hil.diagnose.torque_path import describe as describe_torque_path
from hil.diagnose.torque_path import torque_path_of
from hil.model.closed_form import ArmModel
from hil.model.params import check_inertia, load_params, robot_params
from hil.model.protocol import ArmDynamics
from profiles.robot import describes_urdf_only


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "recordings",
        nargs="+",
        help="run directories or CSV files (t,q1,q2,tau1,tau2; t,q1..qN,tau1..tauN for an "
        "N-joint --robot)",
    )
    p.add_argument(
        "--robot",
        default=None,
        help="robot profile: the reference θ and the nominal model's terms (default: the "
        "recording's own URDF arm from its meta.json, else cicese); a URDF arm (cicese3, "
        "panda) is diagnosed over its n-joint model",
    )
    p.add_argument(
        "--params",
        default=None,
        help="params.json or identify.json (hil identify, of a 2-DOF or a URDF arm): the nominal "
        "model the recordings are judged against (what changed since it), also the before/after "
        "fit's θ and the reference for telling which joint a torque gain error is on; when the "
        "recording it was identified from is found unchanged, the recordings are compared with "
        "that recording (as --reference)",
    )
    p.add_argument(
        "--reference",
        nargs="+",
        default=None,
        metavar="REC",
        help="recordings of the same arm (read with the same --format/--columns) from which the "
        "nominal model is identified first: the recordings are judged against it ('what "
        "changed since REC?')",
    )
    p.add_argument(
        "--refit",
        action="store_true",
        help="judge the recordings against θ refitted from them alone (no nominal model: "
        "missing physics only, no drift)",
    )
    add_out_options(p, "write diagnosis.json and plots here")
    add_recording_options(p)
    add_report_options(p, plot="skip the PNG plots", plot_flag="--no-plots")
    add_html_report_option(p)
    add_progress_option(p)


def _progress(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def main(args: argparse.Namespace) -> int:
    doc, recs = run_diagnose(args)
    print_document(args, doc, lambda: format_report(doc))
    write_html_report(args, "diagnose", doc, lambda: format_report(doc), recordings=recs)
    return 0


def run_diagnose(args: argparse.Namespace) -> tuple[dict, list[Recording]]:
    """`hil diagnose` without its printing: the diagnosis document (written into ``--out``
    with its plots when given) and the recordings it judged (``hil demo`` calls it as a user
    runs the command)."""
    if args.out:
        prepare_out_dir(args.out, args.overwrite, inputs=args.recordings)
    if args.robot is None:
        recorded = {recorded_urdf_robot(path) for path in args.recordings}
        if len(recorded) > 1:
            raise ValueError(
                "the recordings were made with different robots "
                f"({', '.join(sorted(r or 'a 2-DOF arm' for r in recorded))}): give --robot"
            )
        args.robot = recorded.pop() or "cicese"
    given = [o for o, v in (("--params", args.params), ("--reference", args.reference)) if v]
    if len(given) > 1 or (given and args.refit):
        raise ValueError(
            f"{' and '.join(given + (['--refit'] if args.refit else []))}: give one nominal model"
        )
    nominal = None
    geometry = None
    urdf = describes_urdf_only(args.robot)
    if urdf:
        # an n-joint arm described by a URDF (docs/urdf.md): the model object from the
        # profile, its base parameters at the URDF's bodies and the profile's friction as the
        # reference
        from hil.model.urdf import UrdfArmModel  # Pinocchio: loaded only for a URDF arm

        model: ArmDynamics = UrdfArmModel.from_profile(args.robot)
        if args.params:
            model, nominal = urdf_params(args.params, args.robot, model)
        reference, joints = (model.base_theta() if nominal is None else nominal), model.n_joints
        source = f"the {args.robot} profile: the URDF's base parameters with the profile's friction"
    else:
        profile = robot_params(args.robot)
        reference, model, joints = profile.theta, ArmModel(profile.terms), 2
        geometry = arm_geometry(args.robot)
        source = f"the {args.robot} profile's θ ({profile.source})"
        if args.params:  # the nominal model is the one the parameters were identified in
            params = load_params(args.params)
            check_inertia(params)  # a non-physical nominal model cannot be simulated
            nominal, reference, model = params.theta, params.theta, ArmModel(params.terms)

    def read(path: str) -> Recording:
        return read_recording(
            args, path, command="diagnose", min_rows=2, joints=joints, allow_gaps=True
        )

    recs = [read(path) for path in args.recordings]
    judged_against = None
    refs, why = _references(args, read)
    if refs:
        _progress(
            f"diagnose: identifying the nominal model from {len(refs)} reference recording(s)"
        )
        judged_against = nominal_from_reference(
            refs,
            model,
            why + " (bounded least squares on the same rows, blocked-bootstrap standard errors, "
            "with the departures the references already show): what changed since then",
            progress=_progress,
            geometry=geometry,
        )
    elif args.params:
        judged_against = Nominal(
            np.asarray(reference, float),
            model,
            "params",
            f"--params {args.params}" + (f": {why}" if why else ""),
            geometry=geometry,
        )
    elif not args.refit:
        judged_against = Nominal(
            np.asarray(reference, float),
            model,
            "profile",
            source + ": the user's model",
            geometry=geometry,
        )
    for rec in recs:
        if rec.meta.get("status") not in (None, "complete"):
            say(
                "diagnose",
                f"note: {rec.path} is a {rec.meta.get('status')} recording; "
                f"using its {len(rec)} rows",
            )
    tick = StageProgress(
        "diagnose",
        every_s=getattr(args, "progress_every", PROGRESS_EVERY_S),
        enabled=not getattr(args, "quiet", False),  # -q, errors only
    )
    result = diagnose(
        recs, reference, nominal_theta=nominal, progress=_progress, model=model, tick=tick
    )
    doc = result.document
    if args.columns is None and args.loop_delay is None:  # the format's own torque sources
        paths = [torque_path_of(rec, args.recording_format) for rec in recs]
        if any(paths):
            doc["torque_path"] = [p for p in paths if p]
    drift = None
    if judged_against is not None:
        # the rows diagnose built, when in the nominal model's parameters: not built again
        same = all(r.model is judged_against.model for r in result.diagnosis.rows)
        rows = result.diagnosis.rows if same else None
        drift = judge(recs, judged_against, progress=_progress, rows=rows)
        merge_drift(doc, drift)
    else:
        doc["nominal"] = {
            "source": "refit",
            "used": False,
            "decision": "--refit: judged against θ refitted from the recordings alone",
        }
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        write_json_atomic(out / "diagnosis.json", doc)
        if not args.no_plot:
            from hil.diagnose.plots import plot_change, plot_diagnosis

            plots = plot_diagnosis(result, out)
            if drift is not None and drift.used and drift.arrays:
                plots.append(plot_change(drift.arrays, doc["nominal"], out))
            doc["plots"] = [str(p) for p in plots]
            write_json_atomic(out / "diagnosis.json", doc)
    return doc, recs


def _references(
    args: argparse.Namespace, read: Callable[[str], Recording]
) -> tuple[list[Recording], str]:
    """The reference recordings the nominal model is identified from, and what the report
    calls it (with none: why ``--params``'s recording was not used, or ""): ``--reference``,
    or the recording ``--params`` was identified from when `hil identify` fingerprinted it and
    it is found unchanged (drivers.recording.source). That
    recording, not θ alone, is the model the parameters stand for: re-identified on the
    diagnosis's own rows it is compared row by row with a recording that reruns its motion,
    where θ from another estimator's rows and filter differs from it by more than the changes
    sought (a 5 % gain written into a DFKI A.0 file was missed against its own `hil identify`
    θ, found against the file)."""
    if args.reference:
        named = ", ".join(args.reference)
        return [read(p) for p in args.reference], f"the model identified from {named}"
    if not args.params:
        return [], ""
    from drivers.recording.source import SHA256, find_source
    from hil.model.params import read_json_object

    document = read_json_object(Path(args.params))
    source = find_source(document, args.params)
    if source is None:
        if not document.get(SHA256):
            return [], ""
        # fingerprinted, but moved or changed since: said here and in the report's `why`
        missing = (
            f"identified from {document.get('recording')}, not found unchanged (as named, "
            "beside the parameter file, at its absolute path); judged against its θ alone"
        )
        say("diagnose", f"note: --params {args.params} was {missing}")
        return [], missing
    try:
        rec = read(str(source))
    except (RecordingError, ValueError) as exc:  # read differently from --format/--columns
        missing = f"identified from {source}, not read ({exc}); judged against its θ alone"
        say("diagnose", f"note: --params {args.params} was {missing}")
        return [], missing
    say(
        "diagnose",
        f"note: --params {args.params} was identified from {source} (unchanged): the "
        "recordings are compared with that recording",
    )
    why = f"--params {args.params}, re-identified from the recording it was identified from"
    return [rec], f"{why} ({source}, unchanged since)"


def _article(word: str) -> str:
    return "an" if word[:1] in "aeiou" else "a"


def arm_geometry(robot: str) -> dict[str, float] | None:
    """l1 and g of a 2-DOF robot profile (the payload pattern's), and link 2's mass, first
    moments (along, across) and inertia about joint 2 (what a load taken off must leave, :meth:
    `hil.diagnose.effects.payload.Payload.unphysical`); None when it has no l1."""
    from profiles.robot import load_robot

    p = load_robot(robot)
    if p.link1.length_m is None:
        return None
    link2 = p.link2
    return {
        "link1_m": float(p.link1.length_m),
        "gravity_m_s2": float(p.gravity_m_s2),
        "link2_kg": float(link2.mass_kg),
        "link2_moment_kgm": float(link2.mass_kg * link2.com_m),
        "link2_moment_across_kgm": float(link2.mass_kg * link2.com_across_m),
        "link2_inertia_kgm2": float(link2.inertia_about_joint()),
    }


def urdf_params(path: str, robot: str, model: ArmDynamics) -> tuple[Any, np.ndarray]:
    """The model and θ of a URDF arm's ``hil identify`` output (identify.json): its selected
    scheme's base parameters, in the model of its terms."""
    from hil.model.params import read_json_object
    from hil.model.urdf import UrdfArmModel

    doc = read_json_object(Path(path))
    if doc.get("model") != "urdf":
        raise ValueError(
            f"--params {path}: not the identification of a URDF arm ({robot} is one): "
            "give the identify.json of `hil identify --robot " + robot + "`"
        )
    if doc.get("robot") not in (None, robot):
        raise ValueError(f"--params {path}: identified for {doc['robot']}, not {robot}")
    terms = tuple(doc.get("terms") or ())
    if terms != tuple(model.terms):
        model = UrdfArmModel.from_profile(robot, terms=terms)
    scheme = doc.get("params_scheme")
    entry = (doc.get("schemes") or {}).get(scheme) or {}
    theta = entry.get("theta")
    if not isinstance(theta, list) or len(theta) != model.n_params:
        raise ValueError(
            f"--params {path}: scheme {scheme!r} holds no theta of {model.n_params} base "
            f"parameters of {robot}"
        )
    theta = np.asarray(theta, float)
    violations = model.physical_consistency(theta)["violations"]
    if violations:
        raise ValueError(f"--params {path}: not physical ({'; '.join(violations)})")
    return model, theta


# The refit's findings of the same physics as a drift against the nominal model, on the same
# joint: against a profile they stay, with the drift's reading beside them ("against_nominal");
# against reference recordings the drift's finding is listed (what changed), theirs beside it
# ("refit_findings": the recording's own departure with θ refitted, which carries the model's
# error along the pattern: an A.0 offset of −0.042 Nm read −0.081 there, beside an asymmetry) ...
SAME = {
    "torque_gain": ("torque_gain",),
    "torque_offset": ("torque_offset", "coulomb_asymmetry"),
    "rotor_inertia_change": ("rotor_inertia",),
}
# ... and those the drift names better: an encoder offset shows as a centre-of-mass offset (or
# the refit's angle offset) in a refitted θ.
REPLACED = {"encoder_offset": ("angle_offset", "com_offset")}


def merge_drift(doc: dict, drift: DriftResult) -> None:
    """The drift against the nominal model into the refit's document: its findings beside the
    refit's (of the same physics on the same joint: against a profile the refit's with the
    drift's as ``against_nominal``, against references the drift's with the refit's as
    ``refit_findings``; those it names better replaced, those the references already show set
    aside; against references the refit's others on joints a change found reaches set aside:
    ``within_change``), the decision in the summary."""
    doc["nominal"] = drift.document
    head = f"Judged against {drift.document['why']}; {drift.document['decision']}."
    if drift.used:
        gone, known, same = set(), set(), {}
        for f in drift.findings:
            for old in REPLACED.get(f.effect, ()):
                gone |= {(old, f.joint), (old, None)}
            for old in SAME.get(f.effect, ()):
                same[(old, f.joint)] = f
        for b in drift.document["baseline"]:  # the references show it: not a change
            for old in (*SAME.get(b["effect"], ()), *REPLACED.get(b["effect"], ())):
                known |= {(old, b["joint"]), (old, None)}
        # the joints whose torque a change found reaches: there the refit of the recording
        # alone (θ free, no vocabulary of changes) takes the change as whatever it can name (an
        # encoder angle on A.0's joint 2 became a lag and a delay on joint 1)
        # Against reference recordings the question is what changed since them, which the
        # drift alone measures (the refit of the recording carries the model error both share).
        # Against a profile or --params the refit's findings answer what the model leaves out,
        # the drift's numbers stand beside them.
        # The refit moves θ, and with it every joint whose rows share a θ column with a joint
        # the change reaches (a 0.016 Nm Coulomb asymmetry written on A.0's joint 1 gave the
        # refit an `unexplained` structure on joint 2 that the unmodified file lacks).
        since = drift.document["source"] == "reference"
        reached = (
            {
                k
                for f in drift.findings
                for j in f.evidence.get("joints", [f.joint])
                for k in drift.shares.get(j, {j})
            }
            if since
            else set()
        )
        changes = {id(f): f.as_dict() for f in drift.findings}
        kept, joined = [], set()
        for f in doc["findings"]:
            key = (f["effect"], f["joint"])
            if key in same and since:
                changes[id(same[key])].setdefault("refit_findings", []).append(f)
            elif key in same:
                f["against_nominal"] = changes[id(same[key])]
                joined.add(id(same[key]))
                kept.append(f)
            elif key in known and key not in gone:
                drift.document.setdefault("in_reference", []).append(f)
            elif key in gone:
                continue
            elif f["joint"] in reached or (f["joint"] is None and reached):
                drift.document.setdefault("within_change", []).append(f)
            else:
                kept.append(f)
        doc["findings"] = kept + [changes[id(f)] for f in drift.findings if id(f) not in joined]
        if drift.findings:
            head += (
                " What changed: "
                + "; ".join(
                    f"{f.effect.replace('_', ' ')}"
                    + (f" on joint {f.joint}" if f.joint else "")
                    + f": {f.evidence['words']}"
                    for f in drift.findings
                )
                + "."
            )
        else:
            head += " Nothing changed against it beyond what the data resolve."
        if drift.document.get("unresolved"):
            head += (
                " Proven on the held-out blocks but not resolved in size, so not named (kept in "
                "the fit, that no other pattern stands in for it): "
                + "; ".join(
                    f"{u['effect'].replace('_', ' ')}"
                    + (f" on joint {u['joint']}" if u["joint"] else "")
                    + f": {u['words']} ({u['why'].split(';')[0]})"
                    for u in drift.document["unresolved"]
                )
                + "."
            )
        for u in drift.document.get("unseen", []):
            head += (
                f" These recordings cannot show {_article(u['effect'])} "
                f"{u['effect'].replace('_', ' ')}"
                + (f" on joint {u['joint']}" if u["joint"] else "")
                + f": {u['why']}."
            )
        if drift.document.get("in_reference"):
            head += (
                " The references show "
                + ", ".join(
                    f"{f['effect'].replace('_', ' ')} on joint {f['joint']}"
                    for f in drift.document["in_reference"]
                )
                + " as well: not a change."
            )
        if drift.document.get("within_change"):
            head += (
                " The refit of the recording alone also takes "
                + ", ".join(
                    f"{f['effect'].replace('_', ' ')}"
                    + (f" on joint {f['joint']}" if f["joint"] else "")
                    for f in drift.document["within_change"]
                )
                + ", where the change found reaches: not told apart from it, not named."
            )
    # after the refit's summary, which keeps its first words (a null's "No missing physics
    # found: ..." is about the model's structure; this is about what changed)
    doc["summary"] = doc["summary"] + " " + head


def format_report(doc: dict) -> str:
    lines = ["Mismatch diagnosis", ""]
    nominal = doc.get("nominal")
    if nominal:
        lines += [f"Nominal model: {nominal.get('why', nominal['source'])}"]
        lines += [f"  {nominal['decision']}", ""]
    every = "both" if len(doc["fit"]["before"]["torque_nrmse"]) == 2 else "all"
    if not doc["findings"]:
        lines.append("Findings: none.")
    else:
        lines.append("Findings:")
        for f in doc["findings"]:
            est = ", ".join(f"{k} {v}" for k, v in f["estimate"].items())
            ev = f["evidence"]
            conf = (
                f"  (confounded with {', '.join(f['confounded_with'])})"
                if f.get("confounded_with")
                else ""
            )
            lines.append(
                f"  {f['effect']:18s} joint {f['joint'] or every}: {est}; held-out error "
                f"-{100 * ev.get('held_out_error_reduction', 0):.1f} % in "
                f"{ev.get('blocks_improved', '?')}/{ev.get('blocks', '?')} blocks{conf}"
            )
            if ev.get("words"):
                lines.append(f"    {ev['words']}")
    if doc.get("timing"):
        lines += ["", "Timing (from the time stamps):"]
        lines += [f"  {t['note']}" for t in doc["timing"]]  # each note names its kind
    fit = doc["fit"]
    lines += ["", f"Fit on held-out data ({fit['held_out']}), NRMSE per joint:"]
    for name in ("before", "after"):
        t = fit[name]["torque_nrmse"]
        pz = fit[name]["position_nrmse"]
        pos = f"; simulated position {' / '.join(percent(x) for x in pz)}" if pz else ""
        lines.append(f"  {name:6s}: torque {' / '.join(percent(x) for x in t)}{pos}")
    if any(x is None for name in ("before", "after") for x in fit[name]["torque_nrmse"]):
        lines.append(
            f"  (torque n/a: fewer than {MIN_HELD_OUT_ROWS} usable held-out rows on that joint, "
            "or no torque spread to scale by: a longer recording scores it)"
        )
    lines += ["", "Where the nominal model's residual lives:"]
    for j in doc["location"]["joints"]:
        carried = ", ".join(j["carried_by"]) or "nothing in particular (noise-like)"
        lines.append(
            f"  joint {j['joint']}: RMS {j['residual_rms_Nm']:.3g} Nm "
            f"(robust scale {j['robust_scale_Nm']:.3g} Nm), "
            f"carried by {carried}"
        )
    for path in doc.get("torque_path", []):
        lines += ["", *describe_torque_path(path)]
    lines += ["", doc["summary"]]
    return "\n".join(lines)
