"""The three paths of `hil identify`, each from its options to its report, its text and the
parameter files to write (:class:`Outcome`); :mod:`hil.identify.cli` parses, calls one, prints
and writes. Every path fits through :func:`hil.identify.identification.identify`:

* the Table II path (:func:`run_table_ii`): a 2-DOF arm without model terms, a run over a bench
  or a recording in this project's layout; the paper's three schemes and recursive estimators,
  its two discretizations, Table II, validation on the fit and a held-out recording, and over a
  bench the online RLS (:class:`hil.identify.online.OnlineIdentifier`) with its check against
  the batch computation. A realtime run is read as `--from` reads it, on its real sample times
  (drivers/realtime_times.py); the online RLS takes each row on its real interval too, from the
  host's stamps as they come (:class:`drivers.realtime_times.HostStampRows`);
* the model-object path (:func:`run_identify_model`): a 2-DOF arm with model terms or a foreign
  recording; bounded estimate, uncertainty, the profile's θ side by side;
* the URDF path (:func:`run_identify_urdf`): the base parameters of an n-joint arm by each scheme,
  each validated on the same held-out torque rows.

Imports :mod:`hil.bench` (to record over a bench), :mod:`hil.cli_options`, :mod:`hil.model` and
:mod:`drivers`; writes plots (:mod:`hil.identify.plots`), not identify.json or params.json.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drivers.arm import Sample
from drivers.realtime_times import COMPUTE_S, ROBOT_EVENTS, HostStampRows
from drivers.recording import Recording
from hil.cli_options import (
    PROGRESS_EVERY_S,
    StageProgress,
    drive_kwargs,
    read_recording,
    recorded_urdf_robot,
    require_complete,
    say,
    split_list,
)
from hil.identify.identification import Identification, unusable_reason
from hil.identify.identification import identify as identify_arm
from hil.identify.online import STAMP_UNCERTAINTY_MAX, OnlineIdentifier
from hil.identify.schemes import (
    PAPER_TABLE_II,
    SCHEME_TITLES,
    SchemeResult,
    Uncertainty,
    format_table_ii,
    irregular_times,
    table_ii_rows,
    validate_many,
)
from hil.model.closed_form import THETA_NAMES, ArmModel
from hil.model.params import robot_params

PAPER_LAMBDA_NOTE = (
    'the paper\'s "λ = 50 Hz" is read as λ = 50 rad/s in f(s) = λ/(s + λ) (about twice its '
    "highest excitation frequency, 26 rad/s); --lambda 314.16 is the 2π·50 rad/s reading"
)


@dataclass
class Outcome:
    """What a path of `hil identify` made: the JSON report (identify.json, --json), the text to
    print, and the parameter files to write: ``(path, schemes, options)`` each, written by
    :func:`hil.model.params.save_params` ``(path, schemes, **options)``."""

    report: dict[str, Any]
    text: str
    params: list[tuple[Path, dict[str, dict[str, Any]], dict[str, Any]]] = field(
        default_factory=list
    )


PAPER_EXCITATION, PAPER_VALIDATION = "reyes-kelly", "validation-multisine"


def arm_experiment(robot: str, kind: str, paper: str) -> str:
    """The default experiment of ``kind`` (excitation, validation) over a bench with ``robot``:
    the arm's own ``<robot>-<kind>`` profile where one is shipped (designed by `hil excite
    --bench` within that bench's limits), else ``paper`` (Reyes & Kelly's, for the CICESE arm:
    its torques, up to 97 Nm, drive a lighter arm far past its velocity limits)."""
    from profiles import ProfileError, resolve

    own = f"{Path(robot).stem}-{kind}"
    try:
        resolve("experiments", own)
    except ProfileError:
        return paper
    return own


def _record(
    args: argparse.Namespace,
    bench: str,
    experiment: str,
    out: Path,
    online: OnlineIdentifier | None,
    robot: str | None = None,
) -> Recording:
    """Run ``experiment`` over ``bench`` (with ``robot`` in place of the bench's arm if given)
    into ``out``, feeding ``online`` as it runs; the recording."""
    from hil.bench.run import run_experiment
    from profiles.bench import load_bench

    last: dict[str, Any] = {"late_s": 0.0}
    realtime = (getattr(args, "mode", None) or load_bench(bench).mode) == "realtime"
    # realtime: the rows on the host's stamps as they come (what is known online; the robot's
    # own clock, robot-events.csv, is read after the run); lockstep: every interval is h
    stamps = HostStampRows(COMPUTE_S["hil run"]) if online is not None and realtime else None

    def observer(k: int, sample: Sample) -> None:
        # sample k: q_k and the quantized torque of period k − 1, so row k − 1 is complete now
        started = time.perf_counter()
        if stamps is not None:
            row = stamps.push(sample.sent_at, sample.received_at, sample.tau_Nm, last["late_s"])
            if row is not None:
                assert online is not None
                online.push(last["q"], row.tau, t=row.t, uncertainty_s=row.uncertainty_s)
        elif online is not None and k > 0:
            online.push(last["q"], sample.tau_Nm)
        last["q"] = sample.q_rad
        # this cycle's command goes out after the update: it acts that much later
        last["late_s"] = time.perf_counter() - started

    say("identify", f"running {experiment} over {bench} -> {out}")
    run = run_experiment(
        bench,
        experiment,
        out,
        duration_s=args.duration,
        **drive_kwargs(args),
        progress=not args.json,
        observer=observer,
        robot=robot,
    )
    require_complete(f"{experiment} over {bench}", run)
    # as `hil identify --from OUT` reads it: a realtime run on its real times
    joints = 2 if robot is None else None  # an arm named by --robot: its own joint count
    rec = read_recording(args, out, command="identify", min_rows=2, joints=joints, allow_gaps=True)
    if online is not None:  # the last row's torque is only in the recording; its own command
        online.push(rec.q[-1], rec.tau[-1], t=None if stamps is None else stamps.newest_s)
    return rec


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
        fit = _record(args, bench, args.experiment, out / "fit", online)
        if args.validate:
            held_out = read_recording(
                args, args.validate, command="identify", min_rows=2, joints=2, allow_gaps=True
            )
        elif args.validation_experiment != "none":
            held_out = _record(args, bench, args.validation_experiment, out / "validation", None)
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


# ---- the model-object path: real recordings, any model terms ---------------------------------

SIMULATION_WINDOW_S = 0.1


def _robot_terms(args: argparse.Namespace) -> tuple[str, tuple[str, ...]]:
    from profiles.robot import load_robot

    robot = args.robot or "cicese"
    terms = load_robot(robot).terms
    if args.terms is not None:
        terms = tuple(split_list(args.terms))
        ArmModel(terms)  # raises on an unknown or repeated term
    return robot, terms


def model_path(args: argparse.Namespace) -> bool:
    """Identify with a model object when the arm has terms, --terms is given, or the recording
    is foreign (--format): the 9-parameter Table II path is the CICESE reproduction."""
    if args.terms is not None or getattr(args, "recording_format", None):
        return True
    return bool(_robot_terms(args)[1])


def bench_model_path(args: argparse.Namespace) -> bool:
    """Over a bench: whether its arm (or --robot) identifies with a model object (its profile
    has terms, or --terms is given), as :func:`model_path` says for a recording."""
    from profiles.bench import load_bench

    robot = args.robot or load_bench(args.bench or "virtual-slcan").robot
    return model_path(argparse.Namespace(**{**vars(args), "robot": robot}))


def record_then_identify_model(args: argparse.Namespace) -> Outcome:
    """`hil identify --bench B` for an arm with model terms (e.g. dfki-a0 on the MIT-mode
    bench): record the excitation (and the validation experiment unless --validate is given)
    over the bench, then identify from them as `--from`/`--validate` do."""
    from profiles.bench import load_bench

    bench = args.bench or "virtual-slcan"
    args.robot = args.robot or load_bench(bench).robot
    out = Path(args.out)
    excitation = args.experiment or arm_experiment(args.robot, "excitation", PAPER_EXCITATION)
    fit = _record(args, bench, excitation, out / "fit", None)
    validation = args.validation_experiment or arm_experiment(
        args.robot, "validation", PAPER_VALIDATION
    )
    if not args.validate and validation != "none":
        experiment = validation
        args.validate = str(_record(args, bench, experiment, out / "validation", None).path)
    args.from_recording = str(fit.path)
    return run_identify_model(args)


def run_identify_model(args: argparse.Namespace) -> Outcome:
    """`hil identify --from A [--validate B] --robot R [--terms ...]`: θ of the model object
    from A, side by side with the robot profile's θ, both validated on B (same rows, same
    filter): held-out torque prediction and restarted short-window simulation."""
    from hil.identify.schemes import torque_prediction_error
    from hil.model.openloop import simulate_windows
    from profiles.robot import load_robot

    if args.discretization != "exact":  # it was ignored: the rows below are the exact ones
        raise ValueError(
            "--discretization: a model with terms or a foreign recording (--format) is fitted "
            "on the exact rows only; the paper's are the 9-parameter reproduction's"
        )
    robot, terms = _robot_terms(args)
    profile = load_robot(robot)
    model = ArmModel(terms)
    out = Path(args.out)
    fit = read_recording(args, args.from_recording, command="identify", min_rows=8, joints=2)
    held_out = (
        read_recording(args, args.validate, command="identify", min_rows=8, joints=2)
        if args.validate
        else None
    )
    say(
        "identify",
        f"identifying {robot} model (terms: {', '.join(terms) or 'none'}) from {fit.path}",
    )
    ident = identify_arm(model, fit, "filtered_dynamic", lam=args.lam)
    res = ident.result
    # the profile's θ in the identified model's columns (terms it lacks are zero there; terms
    # the model lacks are dropped, which the report says)
    prof_model = ArmModel(profile.terms)
    prof_theta = profile.theta()
    reference = np.zeros(model.n_params)
    reference[:9] = prof_theta[:9]
    dropped = [t for t in prof_model.terms if t not in terms]
    for term in terms:
        if term in prof_model.terms:
            reference[model.term_columns(term)] = prof_theta[prof_model.term_columns(term)]
    window = args.window or SIMULATION_WINDOW_S
    candidates = {"identified": res.theta, f"profile {robot}": reference}
    validation: dict[str, Any] = {}
    for name, rec in (("fit", fit), ("held_out", held_out)):
        if rec is None:
            continue
        validation[name] = {
            label: {
                "torque_nrmse": torque_prediction_error(th, model, rec.t, rec.q, rec.tau, res.lam),
                "simulation": simulate_windows(model, th, rec.t, rec.q, rec.tau, window_s=window)
                if model.physical_consistency(th)["consistent"]
                else None,
            }
            for label, th in candidates.items()
        }
    report: dict[str, Any] = {
        "recording": str(fit.path),
        "validation_recording": str(held_out.path) if held_out is not None else None,
        "robot": robot,
        "profile_reference": profile.reference,
        "profile_terms": list(prof_model.terms),
        "profile_terms_not_in_model": dropped,
        "torque_source": getattr(fit, "torque_source", None),
        "loop_delay": getattr(fit, "loop_delay", None),
        "identification": res.to_json(),
        "profile_theta": reference.tolist(),
        "validation": validation,
        "simulation_window_s": window,
    }
    if profile.rotor is not None and "rotor_inertia" in terms:
        col = model.term_columns("rotor_inertia").start
        se = res.se_block[col]
        report["rotor_inertia"] = {
            "identified_kgm2": profile.rotor.inertia_from_theta(res.theta[col]),
            "se_kgm2": profile.rotor.inertia_from_theta(se),
            "identified": bool(res.identified[col]),
            "profile_kgm2": profile.rotor.inertia_kgm2,
            "datasheet_kgm2": profile.rotor.datasheet_inertia_kgm2,
            "gear_ratio": profile.rotor.gear_ratio,
        }
    # the bounded estimate is offered only when it is an arm, some parameter is determined and
    # it predicts every joint's torque better than the torque's own mean (NRMSE < 1, the
    # criterion of the URDF path's held-out verdict; on the held-out recording when given)
    judged = "held_out" if "held_out" in validation else "fit"
    nrmse_judged = validation[judged]["identified"]["torque_nrmse"]
    reason = ident.failed_reason
    if reason is None and not np.any(res.identified):
        reason = "no parameter is determined by these data (every SE > 50 % of its value)"
    if reason is None:
        worse = [j for j, x in enumerate(nrmse_judged) if not x < 1.0]
        if worse:
            reason = (
                f"torque prediction on the {judged.replace('_', '-')} recording no better than "
                "its mean on joint "
                + ", ".join(f"{j + 1} (NRMSE {nrmse_judged[j]:.3g})" for j in worse)
            )
    report["selection"] = {
        "scheme": "filtered_dynamic",
        "discretization": "exact",
        "usable": reason is None,
        "reason": reason,
        "schemes_usable": [] if reason else ["filtered_dynamic"],
    }
    report["identifications"] = [ident.failing(reason).to_json()]
    if reason is not None:
        report["params_files"] = []
        return Outcome(report, format_model_report(report, model))
    params = (
        out / "params.json",
        {
            "filtered_dynamic": {
                "theta": res.theta,
                "discretization": "exact",
                "lambda_rad_s": res.lam,
                "estimator": res.method,
                "physical_consistency": res.consistency,
                "identified": res.identified.tolist(),
                "se_blocked_bootstrap": res.se_block.tolist(),
            }
        },
        {
            "selected": "filtered_dynamic",
            "robot": robot,
            "recording": str(fit.path),
            "discretization": "exact",
            "model_terms": list(terms),
        },
    )
    report["params_files"] = [str(out / "params.json")]
    return Outcome(report, format_model_report(report, model), [params])


def format_model_report(report: dict[str, Any], model: ArmModel) -> str:
    """The side-by-side text of :func:`run_identify_model`."""
    ident = report["identification"]
    robot = report["robot"]
    lines = [
        f"Identification of the {robot} model (terms: {', '.join(model.terms) or 'none'}) from "
        f"{report['recording']}",
        f"  rows: filtered_dynamic, exact on the real time stamps, λ = {ident['lambda_rad_s']:.3g}"
        f" rad/s; {ident['rows']} rows ({ident['rows_excluded_stick']} excluded: stuck joint); "
        f"uncertainty: blocked bootstrap over {ident['blocks']} blocks of "
        f"{ident['block_s']:.3g} s",
        f"  estimate: {ident['method']}",
        "",
        f"{'parameter':14s}{'unit':>7s}{'identified':>16s}{'± SE (block)':>14s}"
        f"{'SE (white)':>12s}{'VIF':>8s}{'profile':>12s}",
    ]
    for row, ref in zip(ident["parameters"], report["profile_theta"], strict=True):
        value = f"{row['estimate']:.4g}" if row["identified"] else "not determined"
        lines.append(
            f"{row['parameter']:14s}{row['unit']:>7s}{value:>16s}"
            f"{row['se_blocked_bootstrap']:>14.2g}{row['se_white']:>12.2g}"
            f"{row['variance_inflation']:>8.0f}{ref:>12.4g}"
            + ("" if row["identified"] else f"   (estimate {row['estimate']:.3g})")
        )
    phys = ident["least_squares_physical"]
    lines.append(
        "  plain least squares: "
        + ("physical" if phys["consistent"] else "NOT physical: " + "; ".join(phys["violations"]))
    )
    if "rotor_inertia" in report:
        r = report["rotor_inertia"]
        lines.append(
            f"  rotor inertia Ir = θ_rotor / (gr² ∓ gr) = {r['identified_kgm2']:.3g} ± "
            f"{r['se_kgm2']:.2g} kg m² (profile {r['profile_kgm2']:.3g}, datasheet "
            + (f"{r['datasheet_kgm2']:.3g}" if r["datasheet_kgm2"] else "n/a")
            + f"; gear ratio {r['gear_ratio']:g})"
        )
    if report["profile_terms_not_in_model"]:
        lines.append(
            "  the profile's terms not in this model (left out of its column): "
            + ", ".join(report["profile_terms_not_in_model"])
        )
    for note in ident["notes"]:
        lines.append(f"  note: {note}")
    lines += [
        "",
        "Validation (NRMSE per joint, %): torque = filtered torque prediction (same rows, same "
        f"filter for both); simulation = open loop restarted every "
        f"{report['simulation_window_s']:g} s from the recorded state",
        f"{'':26s}{'torque j1':>10s}{'j2':>8s}{'simulation j1':>15s}{'j2':>8s}",
    ]
    for key, vals in report["validation"].items():
        where = {"fit": "fit", "held_out": "held-out"}.get(key, key)  # words, not JSON keys
        for label, v in vals.items():
            sim = v["simulation"]
            simtxt = (
                f"{100 * sim['position_nrmse'][0]:>15.2f}{100 * sim['position_nrmse'][1]:>8.2f}"
                if sim
                else f"{'not physical':>23s}"
            )
            lines.append(
                f"{where + ': ' + label:26s}{100 * v['torque_nrmse'][0]:>10.2f}"
                f"{100 * v['torque_nrmse'][1]:>8.2f}{simtxt}"
            )
    selection = report["selection"]
    lines.append(
        f"\nparameters: {report['params_files'][0]}"
        if selection["usable"]
        else f"\nidentified model FAILED: {selection['reason']}; parameters: none"
    )
    return "\n".join(lines)


# ---- arms described by a URDF (hil.model.urdf): any number of joints -------------------------


def urdf_robot(args: argparse.Namespace) -> bool:
    """The --robot profile describes its arm by a URDF only (no 2-DOF closed form)."""
    from profiles.robot import describes_urdf_only

    if not args.robot and args.from_recording:
        args.robot = recorded_urdf_robot(args.from_recording)
    return bool(args.robot) and describes_urdf_only(args.robot)


def run_identify_urdf(args: argparse.Namespace) -> Outcome:
    """`hil identify --from A [--validate B] --robot R [--schemes ...]` for a URDF arm: base
    parameters and friction by each scheme — ``filtered_dynamic``: weighted batch least squares
    on the torque regressor, parallel filtering (:func:`hil.identify.urdf.identify_torque`);
    ``supplied_energy``, ``filtered_power``: batch least squares on the energy rows
    (:func:`hil.identify.urdf.identify_energy`) — every scheme validated on the same torque rows
    of B, or of the last quarter of A's time when no B is given; beside the URDF's and profile's
    nominal parameters on those rows. The top-level ``parameters`` hold ``--params-scheme``'s."""
    from hil.identify.urdf import (
        energy_rows_cutoff,
        fit_split,
        held_out_verdict,
        regression_rows,
        smoothing_cutoff_hz,
        torque_nrmse,
    )
    from hil.model.urdf import UrdfArmModel

    if args.terms is not None:
        raise ValueError("--terms: a URDF arm takes its terms from the profile's [model] terms")
    if args.discretization != "exact":
        raise ValueError("--discretization: a URDF arm's rows are the exact ones only")
    schemes = split_list(args.schemes)
    model = UrdfArmModel.from_profile(args.robot)
    out = Path(args.out)
    bench = args.bench or "virtual-slcan"
    # files first: a bad --validate is refused before any run over the bench
    val = (
        read_recording(args, args.validate, command="identify", min_rows=8)
        if args.validate
        else None
    )
    if args.from_recording:
        fit = read_recording(args, args.from_recording, command="identify", min_rows=8)
    else:  # over a bench: the arm's own excitation, its drives on the bench's bus
        experiment = args.experiment or f"{Path(args.robot).stem}-excitation"
        fit = _record(args, bench, experiment, out / "fit", None, robot=args.robot)
        if val is None and args.validation_experiment not in (None, "none"):
            val = _record(
                args, bench, args.validation_experiment, out / "validation", None, robot=args.robot
            )
    for rec in (fit, val):
        if rec is not None and rec.n_joints != model.n_joints:
            raise ValueError(
                f"{rec.path}: {rec.joints_text}, robot {args.robot} has {model.n_joints}"
            )
    say(
        "identify",
        f"identifying {args.robot} ({model.n_joints} joints, {model.n_params} base parameters) "
        f"from {fit.path} ({', '.join(schemes)})",
    )
    held_out = 0.0 if val is not None else 0.25
    # this bench's own recordings (meta.json) hold each commanded torque over its period
    # (Recording.torque_held); a foreign file's torques are taken as sampled with the positions
    recording = fit
    cutoff = smoothing_cutoff_hz(recording)
    results: dict[str, dict[str, Any]] = {}
    idents: dict[str, Identification] = {}
    energy_cutoff: float | bool | None = False  # decided once, for both energy schemes
    torque_res = None
    for scheme in schemes:
        start = time.process_time()
        if scheme == "filtered_dynamic":
            ident = identify_arm(
                model, recording, scheme, held_out=held_out, consistent=args.consistent,
                cutoff_hz=cutoff,
            )  # fmt: skip
            torque_res = ident.result
            entry: dict[str, Any] = {
                "method": ident.method + " on the torque regressor (parallel filtering)",
                "smoothing_cutoff_hz": cutoff,
                "rows": ident.rows,
                # per joint: rows near its friction steps (sticks, reversals) left out, and
                # why (hil.identify.urdf.leave_out_friction_steps)
                "friction_steps_left_out": torque_res.left_out_joints.tolist(),
                "rows_left_out_fraction": (1.0 - torque_res.rows.weights).mean(axis=0).tolist(),
                "residual_ratio_near_friction_steps": [
                    None if not np.isfinite(x) else float(x) for x in torque_res.step_residual_ratio
                ],
            }
        else:
            # on the torque scheme's smoothed positions when the raw velocity is noisy: the
            # rows are quadratic in q̇, and its noise biases them (energy_rows_cutoff)
            if energy_cutoff is False:
                energy_cutoff = energy_rows_cutoff(recording, cutoff)
            ident = identify_arm(
                model, recording, scheme, lam=args.lam, held_out=held_out,
                cutoff_hz=energy_cutoff, consistent=args.consistent,
            )  # fmt: skip
            res = ident.result
            entry = {
                "method": ident.method
                + " on the exact "
                + (
                    "energy rows, eq. (28)"
                    if scheme == "supplied_energy"
                    else "power rows, eq. (30)"
                )
                + (" (smoothed positions)" if res.cutoff_hz is not None else ""),
                "lambda_rad_s": ident.lam,
                # None: the raw positions (their velocity noise below the rule's level)
                "smoothing_cutoff_hz": res.cutoff_hz,
                "rows": ident.rows,
            }
        entry["cpu_s"] = time.process_time() - start
        assert ident.uncertainty is not None  # every URDF scheme gives one
        entry["uncertainty"] = ident.uncertainty.as_json()
        if ident.theta_least_squares is not None:  # least squares not physical: θ is bounded
            entry["theta_least_squares"] = ident.theta_least_squares.tolist()
        idents[scheme] = ident
        results[scheme] = {"theta": ident.theta, **entry}
    if getattr(args, "instruments", "none") == "target" and torque_res is not None:
        ident, entry = _iv_identification(model, recording, torque_res, held_out, cutoff)
        idents[IV_SCHEME], results[IV_SCHEME] = ident, {"theta": ident.theta, **entry}
    nominal = model.base_theta()
    if val is not None:
        rows = regression_rows(model, val, cutoff_hz=cutoff)
        if torque_res is not None:  # the same equations left out as in the fit
            rows = rows.leaving_out(torque_res.left_out_joints)
        where = str(val.path)
    else:
        # the torque rows of the last quarter: the same rows judge every scheme
        split = fit_split(recording, 0.25)
        all_rows = (
            torque_res.rows
            if torque_res is not None
            else regression_rows(model, recording, cutoff_hz=cutoff)
        )
        rows = all_rows.select(all_rows.t >= split)
        where = f"last 25 % of {fit.path} (t >= {split:.3f} s)"
    for scheme, r in results.items():
        r["physical_consistency"] = idents[scheme].consistency
        # the held-out check decides what is reported: a scheme that does not predict every
        # joint's torque better than its mean is shown, marked failed, not offered as θ; nor
        # is one that is not an arm (the 2-DOF paths' rule)
        r["validation"] = held_out_verdict(r["theta"], rows, cutoff).as_json()
        held = None if r["validation"]["passed"] else r["validation"]["reason"]
        idents[scheme] = idents[scheme].failing(held and "failed held-out validation: " + held)
        r["usable"], r["failed_reason"] = idents[scheme].usable, idents[scheme].failed_reason
    chosen = results[args.params_scheme]
    chosen_passed = chosen["usable"]
    report: dict[str, Any] = {
        "recording": str(fit.path),
        "robot": args.robot,
        "model": "urdf",
        "urdf": model.urdf,
        "terms": list(model.terms),
        "params_scheme": args.params_scheme,
        "method": chosen["method"],
        "smoothing_cutoff_hz": cutoff,
        "torque": "held over each period (averaged onto the samples)"
        if recording.torque_held
        else "sampled with the positions",
        # --consistent: the selected scheme's physically consistent standard parameters
        "standard_parameters": None
        if idents[args.params_scheme].theta_standard is None
        else dict(
            zip(
                model.standard_names,
                idents[args.params_scheme].theta_standard.tolist(),
                strict=True,
            )
        ),
        "parameters": [
            {
                "name": n,
                "meaning": m,
                "unit": u,
                # None when the data do not determine it (issue 12's rule): its estimate and
                # uncertainty are beside it
                "identified": float(chosen["theta"][i])
                if chosen_passed and chosen["uncertainty"]["identified"][i]
                else None,
                "estimate": float(chosen["theta"][i]),
                "se_blocked_bootstrap": chosen["uncertainty"]["se_blocked_bootstrap"][i],
                "nominal": float(nominal[i]),
                "schemes": {s: float(r["theta"][i]) for s, r in results.items()},
                "not_identifiable_in": [
                    s for s, r in results.items() if not r["uncertainty"]["identified"][i]
                ],
            }
            for i, (n, m, u) in enumerate(
                zip(model.names, model.meanings, model.units, strict=True)
            )
        ],
        "physical_consistency": chosen["physical_consistency"],
        # as the 2-DOF paths': the --params-scheme, whether its θ is offered, and why not
        "selection": {
            "scheme": args.params_scheme,
            "discretization": "exact",
            "usable": chosen["usable"],
            "reason": chosen["failed_reason"],
            "schemes_usable": [s for s, r in results.items() if r["usable"]],
        },
        "validation": {
            "on": where,
            "torque_nrmse_identified": chosen["validation"]["torque_nrmse"],
            "torque_nrmse_nominal": torque_nrmse(nominal, rows).tolist(),
            # false: the top-level parameters failed it and are not the identified ones
            # (hil control --params refuses them; `hil identify` exits 1)
            "passed": chosen["validation"]["passed"],
            "reason": chosen["validation"]["reason"],
            "schemes_passed": [s for s, r in results.items() if r["validation"]["passed"]],
        },
        "schemes": {
            s: {**{k: v for k, v in r.items() if k != "theta"}, "theta": r["theta"].tolist()}
            for s, r in results.items()
        },
        # one layout for every arm (hil.identify.identification)
        "identifications": [i.to_json() for i in idents.values()],
    }
    out.mkdir(parents=True, exist_ok=True)
    return Outcome(report, format_urdf_report(report))


# --instruments target: the filtered dynamic rows fitted by IV, reported as this scheme
IV_SCHEME = "filtered_dynamic_iv"


def _iv_identification(
    model: Any, recording: Recording, torque_res: Any, held_out: float, cutoff: float
) -> tuple[Identification, dict[str, Any]]:
    """``--instruments target``: the filtered dynamic rows (the least-squares fit's cutoff and
    equations left out) fitted by instrumental variables on the recording's target positions
    (:func:`hil.identify.iv.identify_torque_iv`), as an :class:`Identification` (scheme
    filtered_dynamic, estimator ``iv``) and its report entry; not constrained by --consistent."""
    from hil.identify.iv import identify_torque_iv

    start = time.process_time()
    res = identify_torque_iv(
        model, recording, held_out=held_out, cutoff_hz=cutoff,
        left_out_joints=torque_res.left_out_joints,
    )  # fmt: skip
    uncertainty = Uncertainty(res.se_white, res.se_block, res.identified, res.block_s, res.blocks)
    method = (
        f"{res.method}, filtered dynamic rows; the motion follows the reference by "
        f"{res.tracking.delay_s:+.3f} s, within {res.tracking.relative_error.max():.1%} of its "
        "spread"
    )
    consistency = model.physical_consistency(res.theta)
    ident = Identification(
        model=model, scheme="filtered_dynamic", discretization="exact", estimator="iv",
        lam=None, theta=res.theta, method=method, rows=len(res.rows.t),
        consistency=consistency, uncertainty=uncertainty,
        failed_reason=unusable_reason(res.theta, consistency), result=res,
    )  # fmt: skip
    entry = {
        "method": method,
        "smoothing_cutoff_hz": cutoff,
        "rows": len(res.rows.t),
        "reference": res.tracking.as_json(),
        "cpu_s": time.process_time() - start,
        "uncertainty": uncertainty.as_json(),
    }
    return ident, entry


def format_urdf_report(report: dict[str, Any]) -> str:
    """The text of :func:`run_identify_urdf`: per base parameter the nominal value and each
    scheme's estimate, then each scheme's physical consistency and held-out torque NRMSE."""
    schemes = list(report["schemes"])
    failed = [s for s in schemes if not report["schemes"][s]["usable"]]

    def title(s: str) -> str:  # a scheme not offered (FAILED) is marked everywhere
        return SCHEME_TITLES[s] + (" (FAILED)" if s in failed else "")

    lines = [
        f"Identification of {report['robot']} from {report['recording']} "
        f"({len(report['validation']['torque_nrmse_nominal'])} joints, base parameters by "
        f"pivoted QR of the torque regressor; terms: {', '.join(report['terms']) or 'none'})",
        f"{'':8s} {'nominal':>11s}"
        + "".join(f" {title(s):>18s}" for s in schemes)
        + "  unit     meaning",
    ]
    for i, p in enumerate(report["parameters"]):
        cells = []
        for s in schemes:
            u = report["schemes"][s]["uncertainty"]
            se = u["se_blocked_bootstrap"][i]
            # issue 12's rule: a parameter the data do not determine is no number
            cells.append(
                f" {p['schemes'][s]:>9.4g} ±{se:<7.2g}"
                if u["identified"][i]
                else f" {'n/i ±' + format(se, '.2g'):>18s}"
            )
        lines.append(
            f"{p['name']:8s} {p['nominal']:11.5g}"
            + "".join(cells)
            + f"  {p['unit']:8s} {p['meaning']}"
        )
    not_identified = {
        s: [p["name"] for p in report["parameters"] if s in p["not_identifiable_in"]]
        for s in schemes
    }
    lines.append(
        "± blocked-bootstrap standard error; n/i: not identifiable from these data (standard "
        "error above half the estimate's size; the estimate is in identify.json)"
    )
    for s in schemes:
        if not_identified[s]:
            lines.append(
                f"  {SCHEME_TITLES[s]}: {len(not_identified[s])} not identifiable: "
                + ", ".join(not_identified[s])
            )
    for s in schemes:
        r = report["schemes"][s]
        pc = r["physical_consistency"]
        verdict = (
            "physically consistent (friction >= 0, M(q) > 0 at sampled q)"
            if pc["consistent"]
            else "NOT physically consistent: " + "; ".join(pc["violations"])
        )
        lines.append(f"{title(s)} ({r['method']}, {r['cpu_s']:.2f} s CPU): {verdict}")
    v = report["validation"]
    lines.append(f"held-out torque NRMSE per joint on {v['on']}:")
    for s in schemes:
        nrmse_s = report["schemes"][s]["validation"]["torque_nrmse"]
        lines.append(f"  {title(s):26s} " + " ".join(f"{x:7.4f}" for x in nrmse_s))
    lines.append(f"  {'nominal':26s} " + " ".join(f"{x:7.4f}" for x in v["torque_nrmse_nominal"]))
    for s in failed:
        r = report["schemes"][s]
        lines.append(
            f"{SCHEME_TITLES[s]} FAILED held-out validation: "
            f"{r['validation']['reason']}; its θ is not identified parameters"
            if not r["validation"]["passed"]
            else f"{SCHEME_TITLES[s]} FAILED: {r['failed_reason']}; its θ is not offered"
        )
    selection = report["selection"]
    lines.append(
        f"parameters: {report['params_scheme']} ('estimate' in identify.json; 'identified' is "
        "null where not identifiable)"
        if selection["usable"]
        else f"parameters: none ({report['params_scheme']} failed held-out validation; "
        f"schemes that passed: {', '.join(v['schemes_passed']) or 'none'})"
        if not v["passed"]
        else f"parameters: none ({report['params_scheme']} FAILED: {selection['reason']}; "
        f"usable schemes: {', '.join(selection['schemes_usable']) or 'none'})"
    )
    return "\n".join(lines)
