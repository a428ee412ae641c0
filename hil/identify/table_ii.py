"""The Table II path of `hil identify` (:func:`run_table_ii`): a 2-DOF arm without model terms,
a run over a bench or a recording in this project's layout; the paper's three schemes and
recursive estimators, its two discretizations, Table II, validation on the fit and a held-out
recording, and over a bench the online RLS (:class:`hil.identify.online.OnlineIdentifier`) with
its check against the batch computation. A realtime run is read as `--from` reads it, on its
real sample times (drivers/realtime_times.py); the online RLS takes each row on its real
interval too, from the host's stamps as they come
(:class:`drivers.realtime_times.HostStampRows`).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

from drivers.realtime_times import ROBOT_EVENTS
from drivers.recording import Recording
from hil.cli_options import (
    PROGRESS_EVERY_S,
    StageProgress,
    read_recording,
    say,
    split_list,
)
from hil.identify.identification import Identification, unusable_reason
from hil.identify.identification import identify as identify_arm
from hil.identify.online import STAMP_UNCERTAINTY_MAX, OnlineIdentifier
from hil.identify.outcome import (
    PAPER_EXCITATION,
    PAPER_LAMBDA_NOTE,
    PAPER_VALIDATION,
    Outcome,
    arm_experiment,
    record_run,
)
from hil.identify.schemes import (
    PAPER_TABLE_II,
    SchemeResult,
    format_table_ii,
    irregular_times,
    table_ii_rows,
    validate_many,
)
from hil.model.closed_form import THETA_NAMES, ArmModel
from hil.model.params import robot_params

PLOT_ONLY = ("simulated_q", "simulated_rows")  # validate()'s arrays for plots, not for JSON


def _scheme_json(res: SchemeResult, reference: np.ndarray, validation: dict) -> dict[str, Any]:
    reason = unusable_reason(res.theta, res.consistency)
    return {
        "theta": res.theta.tolist(),
        # false: FAILED, not offered in params.json (`hil identify` exits 1 when it was the
        # --params-scheme)
        "usable": reason is None,
        "failed_reason": reason,
        "relative_error": res.relative_error(reference).tolist(),
        "estimator": res.estimator,
        "theta_rls": res.theta_rls.tolist(),
        "theta_ls": res.theta_ls.tolist(),
        "theta_wls": res.theta_wls.tolist(),
        "rows": res.rows,
        "rows_excluded_stick": res.rows_excluded,
        "physical_consistency": res.consistency,
        "validation": {
            name: {k: v for k, v in val.items() if k not in PLOT_ONLY}
            for name, val in validation.items()
        },
        "timing_s": res.timing_s,
        "history": {"t": res.history_t.tolist(), "theta": res.history.tolist()},
    }


def _validations(
    thetas: dict[str, np.ndarray],
    recordings: dict[str, Recording],
    lam: float,
    progress: StageProgress,
) -> dict[str, dict[str, dict[str, Any]]]:
    """:func:`validate_many` of every named θ (``who`` → θ) on each named recording (fit,
    held_out), its torque rows built once per recording: ``who`` → recording → validation.
    Progress told as ``<who>: validation on <name>: open-loop simulation`` and ``validation
    on <name>: torque prediction``."""
    out: dict[str, dict[str, dict[str, Any]]] = {who: {} for who in thetas}
    for name, rec in recordings.items():
        on = f"validation on {name.replace('_', '-')}"
        results = validate_many(
            list(thetas.values()), rec, lam=lam, progress=progress,
            stages=[f"{who}: {on}" for who in thetas], stage=on,
        )  # fmt: skip
        for who, result in zip(thetas, results, strict=True):
            out[who][name] = result
    return out


def run_table_ii(args: argparse.Namespace) -> Outcome:
    """The Table II path: θ1..θ9 by the paper's schemes over a bench or from a recording (module
    docstring)."""
    schemes = split_list(args.schemes)
    if args.lam is None:
        args.lam = 50.0
    discretizations = ["exact", "paper"] if args.discretization == "both" else [args.discretization]
    out = Path(args.out)
    progress = StageProgress(
        "identify",
        every_s=getattr(args, "progress_every", PROGRESS_EVERY_S),
        enabled=not getattr(args, "quiet", False),  # -q, errors only
    )

    online = None
    if args.from_recording:
        fit = read_recording(
            args, args.from_recording, command="identify", min_rows=8, joints=2, allow_gaps=True
        )
        held_out = (
            read_recording(
                args, args.validate, command="identify", min_rows=2, joints=2, allow_gaps=True
            )
            if args.validate
            else None
        )
        robot = args.robot or fit.meta.get("robot") or "cicese"
    else:
        bench = args.bench or "virtual-slcan"
        from profiles.bench import load_bench

        robot = args.robot or load_bench(bench).robot
        args.experiment = args.experiment or arm_experiment(robot, "excitation", PAPER_EXCITATION)
        args.validation_experiment = args.validation_experiment or arm_experiment(
            robot, "validation", PAPER_VALIDATION
        )
        online = OnlineIdentifier(
            load_bench(bench).period_s, schemes=schemes, discretization=discretizations[0],
            lam=args.lam,
        )  # fmt: skip
        fit = record_run(args, bench, args.experiment, out / "fit", online)
        if args.validate:
            held_out = read_recording(
                args, args.validate, command="identify", min_rows=2, joints=2, allow_gaps=True
            )
        elif args.validation_experiment != "none":
            held_out = record_run(args, bench, args.validation_experiment, out / "validation", None)
        else:
            held_out = None
    if len(fit) < 8:
        raise ValueError(f"{fit.path}: only {len(fit)} rows, too short to identify")
    out.mkdir(parents=True, exist_ok=True)  # after reading: a refused run writes nothing
    recordings = {"fit": fit} if held_out is None else {"fit": fit, "held_out": held_out}
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
    idents: dict[str, dict[str, Identification]] = {}
    for disc in discretizations:
        say("identify", f"identifying ({disc}, λ = {args.lam:g} rad/s, {', '.join(schemes)})")
        t0 = time.perf_counter()
        times = irregular_times(fit)
        if times is not None and disc == "exact":
            say("identify", "irregular sample intervals: exact rows use each interval's own length")
        elif times is not None:
            say(
                "identify",
                "irregular sample intervals: the paper's filters written over each interval "
                "(backward difference over Δt_k, a_k = e^{−λΔt_k}, trapezoid over Δt_k)",
            )
        segments = fit.segments()
        if len(segments) > 1 and disc == discretizations[0]:
            say(
                "identify",
                f"{len(segments)} segments between gaps: each gives its own rows, one fit over "
                "all of them, no interval across a gap",
            )
        if len(segments) > 1 and disc == "paper":
            say(
                "identify",
                "the paper's rows assume each segment starts at rest (ℰ(0) = 0 in eq. (28), "
                "filters from zero): the rows after a gap start in motion and are biased; "
                "--discretization exact writes every balance over its interval and is not",
            )
        idents[disc] = {
            s: identify_arm(
                ArmModel(),
                fit,
                s,
                discretization=disc,
                estimator=args.estimator,
                lam=args.lam,
                progress=progress,
            )
            for s in schemes
        }
        results = {s: ident.result for s, ident in idents[disc].items()}
        elapsed = time.perf_counter() - t0
        all_results[disc] = results
        entry: dict[str, Any] = {
            "table_ii": table_ii_rows(reference.theta, results),
            "schemes": {},
            "timing_s": {
                "total": elapsed,
                "batch_least_squares": sum(r.timing_s["least_squares"] for r in results.values()),
                "recursive_least_squares": sum(
                    r.timing_s["recursive_least_squares"] for r in results.values()
                ),
            },
        }
        report["discretizations"][disc] = entry
        texts.append(
            format_table_ii(
                reference.theta,
                results,
                title=f"Table II layout — {disc} discretization, λ = {args.lam:g} rad/s, "
                f"estimator {args.estimator} (relative error to {robot} profile)",
            )
        )

    # every θ (each discretization's schemes, then the profile's) validated together: the
    # torque rows of a recording are built once for all of them (issue 13)
    who = {
        (disc, scheme): scheme if len(discretizations) == 1 else f"{disc} {scheme}"
        for disc in discretizations
        for scheme in all_results[disc]
    }
    thetas = {who[key]: all_results[key[0]][key[1]].theta for key in who}
    thetas[f"{robot} profile"] = reference.theta
    validations = _validations(thetas, recordings, args.lam, progress)
    for (disc, scheme), label in who.items():
        res, validation = all_results[disc][scheme], validations[label]
        report["discretizations"][disc]["schemes"][scheme] = _scheme_json(
            res, reference.theta, validation
        )
        if not args.no_plot:
            from hil.identify.plots import plot_estimates, plot_validation

            p1 = plot_estimates(res, reference.theta, out / f"theta-{disc}-{scheme}.png")
            report["plots"].append(str(p1))
            if "simulation_not_possible" in validation["fit"]:
                continue  # nothing simulated to plot: the text and JSON say why
            panels = [
                (name, rec, validation[name]["simulated_rows"],
                 validation[name]["simulated_q"], validation[name]["position_nrmse"])
                for name, rec in (("fit", fit), ("held_out", held_out))
                if rec is not None
            ]  # fmt: skip
            p2 = plot_validation(scheme, disc, panels, out / f"validation-{disc}-{scheme}.png")
            report["plots"].append(str(p2))
    profile_validation = validations[f"{robot} profile"]
    report["profile_validation"] = {
        name: {k: v for k, v in val.items() if k not in PLOT_ONLY}
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
        if online.real_times:  # a realtime run: rows on the host's stamps as they came
            after = (
                f"the robot's clock ({ROBOT_EVENTS})"
                if (Path(fit.path) / ROBOT_EVENTS).is_file()
                else "the host's stamps (sync_sent_s, feedback_s)"
            )
            report["online"]["sample_times"] = (
                "the host's stamps as the run went (SYNC sent; feedback received + compute "
                "time + the update's own): each row on its real interval, its torque the mean "
                "acting in it"
            )
            report["online"]["batch_sample_times"] = after
            report["online"]["rows_left_out_uncertain_times"] = online.rows_uncertain
            report["online"]["stamp_uncertainty_max_s"] = STAMP_UNCERTAINTY_MAX * online.period_s
            report["online"]["segments"] = online.segments

    # a scheme whose θ is not an arm is FAILED: reported, never written as parameters; no
    # parameter file at all when the selected scheme failed (main exits 1)
    params_files = []
    to_write: list[tuple[Path, dict[str, dict[str, Any]], dict[str, Any]]] = []
    failed_lines = []
    for i, disc in enumerate(discretizations):
        entries = report["discretizations"][disc]["schemes"]
        usable = [s for s in all_results[disc] if entries[s]["usable"]]
        for s in all_results[disc]:
            if not entries[s]["usable"]:
                failed_lines.append(
                    f"{s} ({disc}) FAILED: {entries[s]['failed_reason']}; its θ is not offered"
                )
        if i == 0:
            selected_reason = entries[args.params_scheme]["failed_reason"]
            report["selection"] = {
                "scheme": args.params_scheme,
                "discretization": disc,
                "usable": selected_reason is None,
                "reason": selected_reason,
                "schemes_usable": usable,
            }
        if args.params_scheme not in usable:
            continue
        path = out / ("params.json" if i == 0 else f"params-{disc}.json")
        to_write.append((
            path,
            {
                s: {
                    "theta": all_results[disc][s].theta,
                    "discretization": disc,
                    "lambda_rad_s": args.lam,
                    "estimator": args.estimator,
                    "physical_consistency": all_results[disc][s].consistency,
                }
                for s in usable
            },
            {
                "selected": args.params_scheme,
                "robot": robot,
                "recording": str(fit.path),
                "discretization": disc,
            },
        ))  # fmt: skip
        params_files.append(str(path))
    report["params_files"] = params_files
    # one layout for every arm (hil.identify.identification): each scheme of each discretization
    report["identifications"] = [i.to_json() for d in discretizations for i in idents[d].values()]

    lines = [
        "\n\n".join(texts),
        "",
        _validation_text(report, discretizations, schemes, held_out is not None),
    ]
    if online is not None:
        o = report["online"]
        worst = max(o["max_relative_difference_to_batch_rls"].values())
        compared = (
            f"matches the batch RLS to {worst:.1e} (relative)"
            if "sample_times" not in o
            else f"differs from the batch RLS by {worst:.1e} (relative): both on real sample "
            "times, online the host's stamps as they came, the batch "
            + o["batch_sample_times"]
            + f"; {o['rows_left_out_uncertain_times']} online rows left out, a sample time not "
            f"known to within {o['stamp_uncertainty_max_s'] * 1e3:.2g} ms"
        )
        lines.append(
            f"\nonline RLS ({o['discretization']}, updated every cycle during the run): "
            f"{o['cost_per_cycle_us']:.0f} µs per cycle for {len(schemes)} schemes; final θ̂ "
            + compared
        )
    lines += ["", *failed_lines] if failed_lines else []
    lines.append(
        f"\nparameters: {', '.join(params_files)} (selected: {args.params_scheme})"
        if params_files
        else f"\nparameters: none ({args.params_scheme} FAILED)"
    )
    lines.append(f"report:     {out / 'identify.json'}")
    if report["plots"]:
        lines.append(f"plots:      {out}/theta-*.png, {out}/validation-*.png")
    return Outcome(report, "\n".join(lines), to_write)


def _validation_text(
    report: dict[str, Any], discretizations: list[str], schemes: list[str], held: bool
) -> str:
    lines = ["Validation (NRMSE per joint, %): position = open-loop simulation driven by the "
             "recorded torques; torque = filtered torque prediction"]  # fmt: skip
    head = f"{'':28s}{'fit position':>18s}"
    if held:
        head += f"{'held-out position':>22s}{'held-out torque':>20s}"
    lines.append(head)

    def cells(values: list[float | None] | None, widths: tuple[int, int]) -> str:
        values = values or [None] * len(widths)  # not simulated
        return "".join(
            f"{'–':>{w}s}" if x is None else f"{100 * x:>{w}.2f}"
            for x, w in zip(values, widths, strict=True)
        )

    def row(label: str, val: dict[str, Any]) -> str:
        refused = val["fit"].get("simulation_not_possible")  # θ the simulator cannot take
        text = f"{label:28s}" + cells(val["fit"]["position_nrmse"], (8, 10))
        if held:
            text += cells(val["held_out"]["position_nrmse"], (11, 11))
            text += cells(val["held_out"]["torque_nrmse"], (10, 10))
        if refused:
            text += f"  simulation not possible: {refused}"
        return text

    lines.append(row("profile parameters", report["profile_validation"]))
    for disc in discretizations:
        for s in schemes:
            lines.append(
                row(f"{s} ({disc})", report["discretizations"][disc]["schemes"][s]["validation"])
            )
    return "\n".join(lines)
