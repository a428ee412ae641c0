"""`hil identify`: run the excitation over a bench (or take a recording), identify θ with the
schemes of Reyes & Kelly (1997), print the result, write identify.json, params.json and plots.

A thin command line: the options (:func:`add_arguments`), the path they choose (the Table II
reproduction, the model-object path or a URDF arm's, :mod:`hil.identify.pipelines`, each fitting
through :func:`hil.identify.identification.identify`), then printing and writing. Exit status:
:func:`main`.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from drivers.recording import write_json_atomic
from drivers.recording.source import fingerprint
from hil.cli_options import (
    EXIT_FAILED,
    add_bench_option,
    add_drive_options,
    add_html_report_option,
    add_out_options,
    add_progress_option,
    add_recording_options,
    add_report_options,
    add_schemes_option,
    error,
    prepare_out_dir,
    print_document,
    split_list,
    write_html_report,
)
from hil.identify import pipelines
from hil.identify.pipelines import PAPER_LAMBDA_NOTE
from hil.identify.schemes import ESTIMATORS
from hil.model.closed_form import TERMS
from hil.model.params import save_params
from hil.model.regressors import DISCRETIZATIONS, SCHEMES


def add_arguments(p: argparse.ArgumentParser) -> None:
    src = p.add_mutually_exclusive_group()
    add_bench_option(
        src, default=None, help="bench profile to run the excitation over (default virtual-slcan)"
    )
    src.add_argument("--from", dest="from_recording", help="identify from this recording instead")
    p.add_argument("--validate", help="held-out recording for validation (not used to fit)")
    p.add_argument(
        "--experiment",
        default=None,
        help="excitation (default: the bench arm's <robot>-excitation where one is shipped, "
        "always for a URDF arm; else eqs. 31-32, reyes-kelly)",
    )
    p.add_argument(
        "--validation-experiment",
        default=None,
        help="held-out excitation run over the bench ('none' to skip; default the arm's "
        "<robot>-validation where one is shipped, else validation-multisine; for a URDF arm "
        "none: the fit run's last quarter is held out)",
    )
    p.add_argument("--duration", type=float, default=None, help="seconds of excitation")
    add_drive_options(p)
    add_schemes_option(
        p, SCHEMES, "comma-separated: filtered_dynamic,supplied_energy,filtered_power"
    )
    p.add_argument(
        "--discretization",
        choices=(*DISCRETIZATIONS, "both"),
        default="exact",
        help="exact (consistent, default), paper (faithful reproduction) or both",
    )
    p.add_argument(
        "--lambda",
        dest="lam",
        type=float,
        default=None,
        help="filter bandwidth λ in rad/s (default 50 for the 9-parameter schemes ("
        + PAPER_LAMBDA_NOTE
        + "); for a model with terms or a foreign recording: twice the excitation bandwidth "
        "read from the data)",
    )
    p.add_argument(
        "--terms",
        default=None,
        help="model terms to identify, comma-separated from "
        + ", ".join(TERMS)
        + " ('' for none); default: the --robot profile's. With terms (or --format), "
        "identification takes the model-object path: exact rows on the real time stamps, "
        "bounded estimates, uncertainty (docs/real-data.md)",
    )
    p.add_argument(
        "--window",
        type=float,
        default=None,
        help="model-object path: seconds per restarted open-loop simulation window "
        "(default 0.1 s: long enough to integrate the dynamics, short enough that a "
        "closed-loop recording's model error cannot grow unchecked)",
    )
    p.add_argument("--estimator", choices=ESTIMATORS, default="rls", help="reported estimate")
    p.add_argument("--robot", default=None, help="robot profile for the reference column")
    p.add_argument(
        "--params-scheme",
        default="filtered_dynamic",
        help="scheme selected in params.json (hil control/diagnose read that one by default); "
        "a URDF arm's scheme that fails its held-out validation is not offered (exit 1)",
    )
    p.add_argument(
        "--instruments",
        choices=("none", "target"),
        default="none",
        help="'target' adds the filtered dynamic rows fitted by instrumental variables on the "
        "recording's target positions (q_target columns or a format's [layouts.targets]), "
        "against the closed-loop bias of least squares (docs/real-data.md), as scheme "
        "filtered_dynamic_iv (URDF arms and the 2-DOF model path)",
    )
    p.add_argument(
        "--consistent",
        action="store_true",
        help="URDF arms (docs/urdf.md): constrain every scheme's fit to physically consistent "
        "parameters",
    )
    add_out_options(p, "output directory (default: a new runs/identify/<date>T<time>)")
    add_recording_options(p)
    add_report_options(p)
    add_html_report_option(p)
    add_progress_option(p)


def parse_args(argv: list[str]) -> argparse.Namespace:
    """`hil identify`'s options from ``argv``, for callers that run it as a function
    (:func:`run_identify`)."""
    parser = argparse.ArgumentParser(prog="hil identify")
    add_arguments(parser)
    return parser.parse_args(argv)


def main(args: argparse.Namespace) -> int:
    """Exit status 0; 1 when the scheme selected by --params-scheme FAILED (its report and
    identify.json are written, its θ marked failed, no params.json): its θ is not physical, or
    it failed the path's verdict (a URDF arm's held-out validation; the model path's
    determination and torque prediction)."""
    args.out = str(
        prepare_out_dir(
            args.out,
            args.overwrite,
            (args.from_recording, args.validate),
            default="identify",
            command="identify",
        )
    )
    report, text = run_identify(args)
    print_document(args, report, text)
    write_html_report(
        args,
        "identify",
        report,
        text,
        paths=(report.get("recording"), report.get("validation_recording")),
    )
    selection = report.get("selection")
    if isinstance(selection, dict) and selection.get("usable") is False:
        # a URDF arm's held-out verdict, said as such; else the reason the θ is no arm
        validation = report.get("validation")
        held = isinstance(validation, dict) and validation.get("passed") is False
        others = validation["schemes_passed"] if held else selection["schemes_usable"]
        error(
            "identify",
            f"--params-scheme {selection['scheme']} "
            + (
                f"failed held-out validation ({validation['reason']})"
                if held
                else f"FAILED ({selection['reason']})"
            )
            + ": no identified parameters"
            + ("" if report.get("model") == "urdf" else ", no params.json")
            + (
                f"; {'schemes that passed' if held else 'usable schemes'}: {', '.join(others)}"
                if others
                else "; no scheme is usable"
            ),
        )
        return EXIT_FAILED
    return 0


def run_identify(args: argparse.Namespace) -> tuple[dict[str, Any], str]:
    """Everything `hil identify` does but printing: the path the options choose, then its
    parameter files and identify.json written; returns the JSON report and the text to print."""
    schemes = split_list(args.schemes)
    unknown = [s for s in schemes if s not in SCHEMES]
    if unknown or not schemes:
        raise ValueError(
            f"unknown scheme(s) {', '.join(unknown) or '(none given)'}; "
            f"expected some of {', '.join(SCHEMES)}"
        )
    iv = getattr(args, "instruments", "none") == "target"
    if iv and "filtered_dynamic" not in schemes:
        raise ValueError("--instruments target needs filtered_dynamic among --schemes")
    if args.params_scheme not in schemes and not (
        iv and args.params_scheme == "filtered_dynamic_iv"
    ):
        raise ValueError(f"--params-scheme {args.params_scheme} is not among --schemes")
    if args.lam is not None and not args.lam > 0:
        raise ValueError(f"--lambda must be > 0 rad/s, got {args.lam}")
    out = Path(args.out)
    if pipelines.urdf_robot(args):
        outcome = pipelines.run_identify_urdf(args)
    elif getattr(args, "consistent", False):
        raise ValueError(
            "--consistent is for arms described by a URDF with --from (docs/urdf.md); the "
            "2-DOF model path bounds its fit when least squares is not physical"
        )
    elif args.from_recording and (iv or pipelines.model_path(args)):
        outcome = pipelines.run_identify_model(args)
    elif iv:
        raise ValueError(
            "--instruments target: from a recording (--from) that holds the target positions"
        )
    elif not args.from_recording and pipelines.bench_model_path(args):
        outcome = pipelines.record_then_identify_model(args)
    else:
        outcome = pipelines.run_table_ii(args)
    out.mkdir(parents=True, exist_ok=True)
    # the data identified from, fingerprinted: `hil diagnose --params` finds it again and
    # compares a new recording with it (drivers.recording.source)
    source = fingerprint(outcome.report.get("recording"))
    outcome.report.update(source)
    for path, schemes_, options in outcome.params:
        save_params(path, schemes_, **options, **(source if "recording" in options else {}))
    write_json_atomic(out / "identify.json", outcome.report)
    return outcome.report, outcome.text
