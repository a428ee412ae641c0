"""The model-object path of `hil identify` (:func:`run_identify_model`): a 2-DOF arm with model
terms or a foreign recording; bounded estimate, uncertainty, the profile's θ side by side.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from hil.cli_options import (
    read_recording,
    say,
    split_list,
)
from hil.identify.identification import identify as identify_arm
from hil.identify.outcome import (
    PAPER_EXCITATION,
    PAPER_VALIDATION,
    Outcome,
    arm_experiment,
    record_run,
)
from hil.model.closed_form import ArmModel

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
    fit = record_run(args, bench, excitation, out / "fit", None)
    validation = args.validation_experiment or arm_experiment(
        args.robot, "validation", PAPER_VALIDATION
    )
    if not args.validate and validation != "none":
        experiment = validation
        args.validate = str(record_run(args, bench, experiment, out / "validation", None).path)
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
