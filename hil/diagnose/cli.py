"""`hil diagnose RECORDING [RECORDING ...] --robot cicese [--params FILE] [--out DIR] [--json]`:
find the physics the 9-parameter model leaves out (docs/diagnosis.md); with a robot described by
a URDF (``--robot cicese3``, ``panda``), the physics its n-joint model leaves out.

Reads recordings in the standard format (a run directory or a CSV with t,q1,q2,tau1,tau2, or
t,q1..qN,tau1..tauN for an N-joint robot), from this bench or a real one; prints the findings
and the before/after fit in words, or one JSON document with ``--json``; writes
``diagnosis.json`` and plots to ``--out``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from drivers.recording import write_json_atomic
from hil.cli_options import (
    PROGRESS_EVERY_S,
    StageProgress,
    add_out_options,
    add_recording_options,
    add_report_options,
    prepare_out_dir,
    print_document,
    read_recording,
    recorded_urdf_robot,
    say,
)
from hil.diagnose.report import diagnose, percent
from hil.model.closed_form import ArmModel
from hil.model.params import check_inertia, load_params, robot_params
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
        help="params.json (hil identify): the nominal model's θ for the before/after fit and the "
        "reference for telling which joint a torque gain error is on",
    )
    add_out_options(p, "write diagnosis.json and plots here")
    add_recording_options(p)
    add_report_options(p, plot="skip the PNG plots", plot_flag="--no-plots")
    p.add_argument(
        "--progress-every",
        type=float,
        default=PROGRESS_EVERY_S,
        metavar="SECONDS",
        help="seconds between the progress lines of a long recording's stages on stderr "
        f"(default {PROGRESS_EVERY_S:g}; -q: none)",
    )


def _progress(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def main(args: argparse.Namespace) -> int:
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
    if describes_urdf_only(args.robot):
        # an n-joint arm described by a URDF (docs/urdf.md): the model object from the
        # profile, its base parameters at the URDF's bodies and the profile's friction as the
        # reference
        if args.params:
            raise ValueError(
                f"--params: for the 2-DOF closed-form model; {args.robot} is a URDF arm, "
                "diagnosed against its own least-squares fit (docs/diagnosis.md)"
            )
        from hil.model.urdf import UrdfArmModel  # Pinocchio: loaded only for a URDF arm

        model: Any = UrdfArmModel.from_profile(args.robot)
        reference, joints = model.base_theta(), model.n_joints
    else:
        profile = robot_params(args.robot)
        reference, model, joints = profile.theta, ArmModel(profile.terms), 2
    recs = [
        read_recording(args, path, command="diagnose", min_rows=2, joints=joints, allow_gaps=True)
        for path in args.recordings
    ]
    nominal = None
    if args.params:  # the nominal model is the one the parameters were identified in
        params = load_params(args.params)
        check_inertia(params)  # a non-physical nominal model cannot be simulated
        nominal, reference, model = params.theta, params.theta, ArmModel(params.terms)
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
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        write_json_atomic(out / "diagnosis.json", doc)
        if not args.no_plot:
            from hil.diagnose.plots import plot_diagnosis

            doc["plots"] = [str(p) for p in plot_diagnosis(result, out)]
            write_json_atomic(out / "diagnosis.json", doc)
    print_document(args, doc, lambda: format_report(doc))
    return 0


def format_report(doc: dict) -> str:
    lines = ["Mismatch diagnosis", ""]
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
    lines += ["", "Where the nominal model's residual lives:"]
    for j in doc["location"]["joints"]:
        carried = ", ".join(j["carried_by"]) or "nothing in particular (noise-like)"
        lines.append(
            f"  joint {j['joint']}: RMS {j['residual_rms_Nm']:.3g} Nm "
            f"(robust scale {j['robust_scale_Nm']:.3g} Nm), "
            f"carried by {carried}"
        )
    lines += ["", doc["summary"]]
    return "\n".join(lines)
