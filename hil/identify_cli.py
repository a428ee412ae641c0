"""`hil identify`: run the excitation over a bench (or take a recording), identify θ1..θ9 with
the three schemes of Reyes & Kelly (1997), print Table II, validate, write params.json and plots.

Over a bench, recursive least squares also runs online, one update per control cycle while the
experiment runs (:class:`hil.online.OnlineIdentifier`); the report checks that its final θ̂
equals the batch computation on the recording.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from drivers.arm import Sample
from drivers.recording import Recording, read_signals, write_json_atomic
from hil.cli_options import (
    add_out_options,
    add_recording_options,
    prepare_out_dir,
    read_recording,
)
from hil.identify import (
    ESTIMATORS,
    PAPER_TABLE_II,
    SchemeResult,
    format_table_ii,
    identify,
    table_ii_rows,
    validate,
)
from hil.model import THETA_NAMES
from hil.online import OnlineIdentifier
from hil.params import robot_params, save_params
from hil.regressors import DISCRETIZATIONS, SCHEMES

PAPER_LAMBDA_NOTE = (
    'the paper\'s "λ = 50 Hz" is read as λ = 50 rad/s in f(s) = λ/(s + λ) (about twice its '
    "highest excitation frequency, 26 rad/s); --lambda 314.16 is the 2π·50 rad/s reading"
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    src = p.add_mutually_exclusive_group()
    src.add_argument(
        "--bench", help="bench profile to run the excitation over (default virtual-slcan)"
    )
    src.add_argument("--from", dest="from_recording", help="identify from this recording instead")
    p.add_argument("--validate", help="held-out recording for validation (not used to fit)")
    p.add_argument("--experiment", default="reyes-kelly", help="excitation (default: eqs. 31-32)")
    p.add_argument(
        "--validation-experiment",
        default="validation-multisine",
        help="held-out excitation run over the bench ('none' to skip)",
    )
    p.add_argument("--duration", type=float, default=None, help="seconds of excitation")
    p.add_argument("--mode", choices=("lockstep", "realtime"), default=None)
    p.add_argument("--effects", default=None, help="virtual bench: concealed effects profile")
    p.add_argument("--seed", type=int, default=None, help="virtual bench: seed")
    p.add_argument("--confirm-real", action="store_true", help="required for a real arm")
    p.add_argument(
        "--schemes",
        default=",".join(SCHEMES),
        help="comma-separated: filtered_dynamic,supplied_energy,filtered_power",
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
        default=50.0,
        help="filter bandwidth λ in rad/s (default 50; " + PAPER_LAMBDA_NOTE + ")",
    )
    p.add_argument("--estimator", choices=ESTIMATORS, default="rls", help="reported estimate")
    p.add_argument("--robot", default=None, help="robot profile for the reference column")
    p.add_argument(
        "--params-scheme",
        default="filtered_dynamic",
        help="scheme selected in params.json (hil control/diagnose read that one by default)",
    )
    p.add_argument("--out", default="runs/identify", help="output directory")
    add_out_options(p)
    add_recording_options(p)
    p.add_argument("--no-plot", action="store_true", help="skip the plots")
    p.add_argument("--json", action="store_true", help="print one JSON document on stdout")


def _say(msg: str) -> None:
    print(f"hil identify: {msg}", file=sys.stderr)


def _record(
    args: argparse.Namespace,
    bench: str,
    experiment: str,
    out: Path,
    online: OnlineIdentifier | None,
) -> Recording:
    from hil.run import run_experiment

    last: dict[str, Any] = {}

    def observer(k: int, sample: Sample) -> None:
        # sample k: q_k and the quantized torque of period k − 1, so row k − 1 is complete now
        if online is not None and k > 0:
            online.push(last["q"], sample.tau_Nm)
        last["q"] = sample.q_rad

    _say(f"running {experiment} over {bench} -> {out}")
    run = run_experiment(
        bench,
        experiment,
        out,
        duration_s=args.duration,
        mode=args.mode,
        effects=args.effects,
        seed=args.seed,
        confirm_real=args.confirm_real,
        plot=not args.no_plot,
        progress=not args.json,
        observer=observer,
    )
    if run["status"] != "complete":
        raise RuntimeError(
            f"{experiment} over {bench} {run['status']}: {run['reason']} "
            f"({run['rows']} rows kept in {run['signals']})"
        )
    rec = read_signals(out)
    if online is not None:
        online.push(rec.q[-1], rec.tau[-1])  # the last row's torque is only in the recording
    return rec


def _scheme_json(res: SchemeResult, reference: np.ndarray, validation: dict) -> dict[str, Any]:
    return {
        "theta": res.theta.tolist(),
        "relative_error": res.relative_error(reference).tolist(),
        "estimator": res.estimator,
        "theta_rls": res.theta_rls.tolist(),
        "theta_ls": res.theta_ls.tolist(),
        "theta_wls": res.theta_wls.tolist(),
        "rows": res.rows,
        "rows_excluded_stick": res.rows_excluded,
        "physical_consistency": res.consistency,
        "validation": {
            name: {k: v for k, v in val.items() if k != "simulated_q"}
            for name, val in validation.items()
        },
        "timing_s": res.timing_s,
        "history": {"t": res.history_t.tolist(), "theta": res.history.tolist()},
    }


def main(args: argparse.Namespace) -> int:
    prepare_out_dir(args.out, args.overwrite, inputs=(args.from_recording, args.validate))
    report, text = run_identify(args)
    print(json.dumps(report) if args.json else text)
    return 0


def run_identify(args: argparse.Namespace) -> tuple[dict[str, Any], str]:
    """Everything `hil identify` does; returns the JSON report and the text to print."""
    schemes = [s.strip() for s in args.schemes.split(",") if s.strip()]
    unknown = [s for s in schemes if s not in SCHEMES]
    if unknown or not schemes:
        raise ValueError(
            f"unknown scheme(s) {', '.join(unknown) or '(none given)'}; "
            f"expected some of {', '.join(SCHEMES)}"
        )
    if args.params_scheme not in schemes:
        raise ValueError(f"--params-scheme {args.params_scheme} is not among --schemes")
    if not args.lam > 0:
        raise ValueError(f"--lambda must be > 0 rad/s, got {args.lam}")
    discretizations = ["exact", "paper"] if args.discretization == "both" else [args.discretization]
    out = Path(args.out)

    online = None
    if args.from_recording:
        fit = read_recording(args, args.from_recording, command="identify", min_rows=8)
        held_out = (
            read_recording(args, args.validate, command="identify", min_rows=2)
            if args.validate
            else None
        )
        robot = args.robot or fit.meta.get("robot") or "cicese"
    else:
        bench = args.bench or "virtual-slcan"
        from profiles.bench import load_bench

        robot = args.robot or load_bench(bench).robot
        online = OnlineIdentifier(
            load_bench(bench).period_s, schemes=schemes, discretization=discretizations[0],
            lam=args.lam,
        )  # fmt: skip
        fit = _record(args, bench, args.experiment, out / "fit", online)
        if args.validate:
            held_out = read_recording(args, args.validate, command="identify", min_rows=2)
        elif args.validation_experiment != "none":
            held_out = _record(args, bench, args.validation_experiment, out / "validation", None)
        else:
            held_out = None
    if len(fit) < 8:
        raise ValueError(f"{fit.path}: only {len(fit)} rows, too short to identify")
    out.mkdir(parents=True, exist_ok=True)  # after reading: a refused run writes nothing
    reference = robot_params(robot)
    h = fit.period_s

    report: dict[str, Any] = {
        "recording": str(fit.path),
        "validation_recording": str(held_out.path) if held_out is not None else None,
        "robot": robot,
        "reference": {"source": reference.source, "theta": reference.theta.tolist()},
        "names": list(THETA_NAMES),
        "lambda_rad_s": args.lam,
        "lambda_note": PAPER_LAMBDA_NOTE,
        "estimator": args.estimator,
        "period_s": h,
        "rows": len(fit),
        "paper_table_ii": PAPER_TABLE_II,
        "discretizations": {},
        "plots": [],
    }
    texts = []
    all_results: dict[str, dict[str, SchemeResult]] = {}
    for disc in discretizations:
        _say(f"identifying ({disc}, λ = {args.lam:g} rad/s, {', '.join(schemes)})")
        t0 = time.perf_counter()
        results = identify(
            fit.q, fit.tau, h, schemes=schemes, discretization=disc, lam=args.lam,
            estimator=args.estimator,
        )  # fmt: skip
        elapsed = time.perf_counter() - t0
        all_results[disc] = results
        entry: dict[str, Any] = {
            "table_ii": table_ii_rows(reference.theta, results),
            "schemes": {},
            "timing_s": {
                "total": elapsed,
                "batch_least_squares": sum(
                    r.timing_s["regression"] + r.timing_s["least_squares"] for r in results.values()
                ),
                "recursive_least_squares": sum(
                    r.timing_s["regression"] + r.timing_s["recursive_least_squares"]
                    for r in results.values()
                ),
            },
        }
        for scheme, res in results.items():
            validation = {"fit": validate(res.theta, fit, lam=args.lam)}
            if held_out is not None:
                validation["held_out"] = validate(res.theta, held_out, lam=args.lam)
            entry["schemes"][scheme] = _scheme_json(res, reference.theta, validation)
            if not args.no_plot:
                from hil.identify_plots import plot_estimates, plot_validation

                p1 = plot_estimates(res, reference.theta, out / f"theta-{disc}-{scheme}.png")
                panels = [
                    (name, rec, validation[name]["simulated_q"],
                     validation[name]["position_nrmse"])
                    for name, rec in (("fit", fit), ("held_out", held_out))
                    if rec is not None
                ]  # fmt: skip
                p2 = plot_validation(scheme, disc, panels, out / f"validation-{disc}-{scheme}.png")
                report["plots"] += [str(p1), str(p2)]
        report["discretizations"][disc] = entry
        texts.append(
            format_table_ii(
                reference.theta,
                results,
                title=f"Table II layout — {disc} discretization, λ = {args.lam:g} rad/s, "
                f"estimator {args.estimator} (relative error to {robot} profile)",
            )
        )

    profile_validation = {"fit": validate(reference.theta, fit, lam=args.lam)}
    if held_out is not None:
        profile_validation["held_out"] = validate(reference.theta, held_out, lam=args.lam)
    report["profile_validation"] = {
        name: {k: v for k, v in val.items() if k != "simulated_q"}
        for name, val in profile_validation.items()
    }

    if online is not None:
        primary = all_results[discretizations[0]]
        diffs = {
            s: float(
                np.max(
                    np.abs(online.theta[s] - primary[s].theta_rls) / np.abs(primary[s].theta_rls)
                )
            )
            for s in schemes
        }
        report["online"] = {
            "discretization": discretizations[0],
            "samples": online.samples,
            "theta": {s: v.tolist() for s, v in online.theta.items()},
            "max_relative_difference_to_batch_rls": diffs,
            "cost_per_cycle_us": online.cost_per_sample_s() * 1e6,
        }

    params_files = []
    for i, disc in enumerate(discretizations):
        path = out / ("params.json" if i == 0 else f"params-{disc}.json")
        save_params(
            path,
            {s: {"theta": r.theta, "discretization": disc, "lambda_rad_s": args.lam,
                 "estimator": args.estimator, "physical_consistency": r.consistency}
             for s, r in all_results[disc].items()},
            selected=args.params_scheme,
            robot=robot,
            recording=str(fit.path),
            discretization=disc,
        )  # fmt: skip
        params_files.append(str(path))
    report["params_files"] = params_files
    write_json_atomic(out / "identify.json", report)

    lines = [
        "\n\n".join(texts),
        "",
        _validation_text(report, discretizations, schemes, held_out is not None),
    ]
    if online is not None:
        o = report["online"]
        worst = max(o["max_relative_difference_to_batch_rls"].values())
        lines.append(
            f"\nonline RLS ({o['discretization']}, updated every cycle during the run): "
            f"{o['cost_per_cycle_us']:.0f} µs per cycle for {len(schemes)} schemes; final θ̂ "
            f"matches the batch RLS to {worst:.1e} (relative)"
        )
    lines.append(f"\nparameters: {', '.join(params_files)} (selected: {args.params_scheme})")
    lines.append(f"report:     {out / 'identify.json'}")
    if report["plots"]:
        lines.append(f"plots:      {out}/theta-*.png, {out}/validation-*.png")
    return report, "\n".join(lines)


def _validation_text(
    report: dict[str, Any], discretizations: list[str], schemes: list[str], held: bool
) -> str:
    lines = ["Validation (NRMSE per joint, %): position = open-loop simulation driven by the "
             "recorded torques; torque = filtered torque prediction"]  # fmt: skip
    head = f"{'':28s}{'fit position':>18s}"
    if held:
        head += f"{'held-out position':>22s}{'held-out torque':>20s}"
    lines.append(head)

    def row(label: str, val: dict[str, Any]) -> str:
        fp = val["fit"]["position_nrmse"]
        text = f"{label:28s}{100 * fp[0]:>8.2f}{100 * fp[1]:>10.2f}"
        if held:
            hp, ht = val["held_out"]["position_nrmse"], val["held_out"]["torque_nrmse"]
            text += (
                f"{100 * hp[0]:>11.2f}{100 * hp[1]:>11.2f}{100 * ht[0]:>10.2f}{100 * ht[1]:>10.2f}"
            )
        return text

    lines.append(row("profile parameters", report["profile_validation"]))
    for disc in discretizations:
        for s in schemes:
            lines.append(
                row(f"{s} ({disc})", report["discretizations"][disc]["schemes"][s]["validation"])
            )
    return "\n".join(lines)
