"""`hil control`: track the Khosla & Kanade (1987) trajectory with PD, CT, FED or RFED over a bench.

    hil control --bench virtual-slcan --scheme ct [--params FILE] [--out DIR] [--json]
    hil control --compare [--params [LABEL=]FILE[#SCHEME] ...] [--out DIR] [--json]

``--compare`` runs every scheme with the robot profile's θ and then with each ``--params`` set,
and prints Khosla & Kanade's Table 2 layout (maximum and RMS position and velocity tracking errors
per joint per scheme) per parameter set; ``--json`` prints the same as one JSON document.
"""

from __future__ import annotations

import argparse
from typing import Any

from hil import cli_options as opts
from hil.control.controllers import SCHEME_TITLES, SCHEMES


def add_arguments(p: argparse.ArgumentParser) -> None:
    opts.add_bench_option(p)
    what = p.add_mutually_exclusive_group()
    what.add_argument("--scheme", choices=SCHEMES, help="one controller: pd, ct, fed or rfed")
    what.add_argument(
        "--compare", action="store_true", help="run every scheme and print the Table 2 layout"
    )
    opts.add_schemes_option(
        p, SCHEMES, "with --compare: which schemes, comma-separated (default: all)"
    )
    p.add_argument(
        "--params",
        action="append",
        default=[],
        metavar="[LABEL=]FILE[#SCHEME]",
        help="model parameters from a `hil identify` file (default: the robot profile's); "
        "with --compare repeatable, each one more block of the table after the profile's",
    )
    p.add_argument(
        "--no-profile-params",
        action="store_true",
        help="with --compare: leave out the robot profile's parameters",
    )
    p.add_argument(
        "--robot",
        default=None,
        help="robot profile or file in place of the bench's, e.g. cicese3 (its drives on the "
        "bus, its model in the controllers: the closed form or its URDF's; docs/control.md)",
    )
    p.add_argument(
        "--experiment",
        default=None,
        help="tracking experiment profile or file (trajectory, gains, J, velocity estimate; "
        "default: khosla-kanade-tracking-ROBOT where shipped, else khosla-kanade-tracking)",
    )
    p.add_argument(
        "--duration", type=float, default=None, help="seconds (default: the whole trajectory)"
    )
    p.add_argument(
        "--kp", type=float, nargs="+", metavar="KP", help="position gains, one per joint"
    )
    p.add_argument(
        "--kv", type=float, nargs="+", metavar="KV", help="velocity gains, one per joint"
    )
    opts.add_out_options(p, "directory (default: a new runs/control-SCHEME|compare/<date>T<time>)")
    opts.add_drive_options(p)
    opts.add_report_options(p)
    opts.add_html_report_option(p)


def main(args: argparse.Namespace) -> int:
    from hil.bench.run import UsageError
    from hil.control.tracking import compare_schemes, format_table, run_control

    common: dict[str, Any] = {
        "experiment": args.experiment,
        "duration_s": args.duration,
        "kp": args.kp,
        "kv": args.kv,
        "robot": args.robot,
        **opts.drive_kwargs(args),
    }
    if not args.compare:
        if args.scheme is None:
            raise UsageError("give --scheme pd|ct|fed|rfed, or --compare")
        if len(args.params) > 1:
            raise UsageError("one --params file per run; several need --compare")
        if args.report:
            raise UsageError("--report: an HTML report is written for --compare")
        out = opts.prepare_out_dir(args.out, args.overwrite, default=f"control-{args.scheme}")
        opts.say("control", f"{SCHEME_TITLES[args.scheme]} over {args.bench} -> {out}")
        doc = run_control(
            args.bench, args.scheme, out, params=args.params[0] if args.params else None, **common
        )
        run = doc["run"]
        opts.print_document(args, doc, lambda: _format_run(doc))
        return opts.run_exit(
            "control",
            run["status"],
            f"{run['status']}: {run.get('reason')} ({run['rows']} rows kept in {run['signals']})",
        )

    schemes = opts.split_list(args.schemes)
    out = opts.prepare_out_dir(args.out, args.overwrite, default="control-compare")
    opts.say(
        "control", f"comparing {', '.join(s.upper() for s in schemes)} over {args.bench} -> {out}"
    )

    def report(run: dict[str, Any]) -> None:
        err = run.get("max_position_error_rad")
        detail = "" if err is None else f", max |e| = {' / '.join(f'{e:.4f}' for e in err)} rad"
        opts.say("control", f"{run['params']}/{run['scheme']}: {run['status']}{detail}")

    doc = compare_schemes(
        args.bench,
        out,
        params=args.params,
        include_profile=not args.no_profile_params,
        schemes=schemes,
        progress=False,
        on_run=report,
        **common,
    )
    plots = [f"plots: {', '.join(doc['plots'])}"] if doc["plots"] else []
    text = [format_table(doc), *plots, f"runs and compare.json: {doc['out_dir']}"]
    opts.print_document(args, doc, "\n".join(text))
    opts.write_html_report(args, "control", doc, "\n".join(text), recordings=[], name="compare")
    return opts.run_exit("control", doc["status"], f"{doc['status']}: {'; '.join(doc['failures'])}")


def _format_run(doc: dict[str, Any]) -> str:
    run = doc["run"]
    lines = [f"{SCHEME_TITLES[run['scheme']]}, {run['params']} parameters, over {doc['bench']}"]
    if "max_position_error_rad" in run:
        for j in range(len(run["max_position_error_rad"])):
            lines.append(
                f"  joint {j + 1}: position error max {run['max_position_error_rad'][j]:.4f} "
                f"rad, RMS {run['rms_position_error_rad'][j]:.4f} rad; velocity error max "
                f"{run['max_velocity_error_rad_s'][j]:.3f} rad/s, RMS "
                f"{run['rms_velocity_error_rad_s'][j]:.3f} rad/s"
            )
    peaks = [
        f"{x:.1f}" if lim >= 100 else f"{x:.2f}"
        for x, lim in zip(run["peak_torque_law_Nm"], run["torque_limit_Nm"], strict=True)
    ]
    lines.append(
        f"  clipped cycles: {' / '.join(str(c) for c in run['clipped_cycles'])}; peak torque "
        f"{' / '.join(peaks)} Nm (limits {' / '.join(f'{x:g}' for x in run['torque_limit_Nm'])} Nm)"
    )
    lines.append(
        f"  recording: {run['signals']} ({run['rows']} rows, {run['realtime_factor']}x real time)"
    )
    if run["plots"]:
        lines.append(f"  plots: {', '.join(run['plots'])}")
    return "\n".join(lines)
