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
from hil.identify.identification import Identification
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
    """`hil identify --from A [--validate B] --robot R [--terms ...] [--instruments target]`:
    θ of the model object from A, side by side with the robot profile's θ, both validated on B
    (same rows, same filter): held-out torque prediction and restarted short-window simulation.
    ``--instruments target``: the same rows fitted by instrumental variables on A's target
    positions as well (:func:`hil.identify.iv.iv_identification`), validated alike, both
    reported under ``schemes`` as the URDF path reports them; ``--params-scheme
    filtered_dynamic_iv`` selects its θ."""
    from hil.identify.iv import IV_SCHEME, iv_identification
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
    iv = getattr(args, "instruments", "none") == "target"
    if iv:  # the least-squares rows (its λ) on the whole of A, as least squares fits them
        iv_ident, iv_entry = iv_identification(model, fit, held_out=0.0, lam=res.lam)
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
    if iv:
        candidates = {"identified": res.theta, IV_SCHEME: iv_ident.theta, **candidates}
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
    reason = _failed_reason(ident, validation[judged]["identified"]["torque_nrmse"], judged)
    idents = {"filtered_dynamic": ident.failing(reason)}
    if iv:
        iv_reason = _failed_reason(iv_ident, validation[judged][IV_SCHEME]["torque_nrmse"], judged)
        idents[IV_SCHEME] = iv_ident.failing(iv_reason)
        # both fits in the URDF path's layout (hil.identify.urdf_path): what IV changes
        ls_entry = {
            "method": res.method,
            "lambda_rad_s": res.lam,
            "rows": res.rows,
            "uncertainty": res.uncertainty.as_json(),
        }
        report["schemes"] = {
            s: {
                **entry,
                "theta": idents[s].theta.tolist(),
                "physical_consistency": idents[s].consistency,
                "validation": _validation_entry(
                    validation[judged][label]["torque_nrmse"], judged, report
                ),
                "usable": idents[s].usable,
                "failed_reason": idents[s].failed_reason,
            }
            for s, label, entry in (
                ("filtered_dynamic", "identified", ls_entry),
                (IV_SCHEME, IV_SCHEME, iv_entry),
            )
        }
    scheme = IV_SCHEME if iv and args.params_scheme == IV_SCHEME else "filtered_dynamic"
    reason = idents[scheme].failed_reason
    report["selection"] = {
        "scheme": scheme,
        "discretization": "exact",
        "usable": reason is None,
        "reason": reason,
        "schemes_usable": [s for s, i in idents.items() if i.usable],
    }
    report["identifications"] = [i.to_json() for i in idents.values()]
    if reason is not None:
        report["params_files"] = []
        return Outcome(report, format_model_report(report, model))
    entries = {
        s: {
            "theta": i.theta,
            "discretization": "exact",
            "lambda_rad_s": i.lam,
            "estimator": i.method,
            "physical_consistency": i.consistency,
            "identified": i.uncertainty.identified.tolist(),
            "se_blocked_bootstrap": i.uncertainty.se_block.tolist(),
        }
        for s, i in idents.items()
        if i.usable and i.uncertainty is not None
    }
    params = (
        out / "params.json",
        entries,
        {
            "selected": scheme,
            "robot": robot,
            "recording": str(fit.path),
            "discretization": "exact",
            "model_terms": list(terms),
        },
    )
    report["params_files"] = [str(out / "params.json")]
    return Outcome(report, format_model_report(report, model), [params])


def _failed_reason(ident: Identification, nrmse: list[float], judged: str) -> str | None:
    """Why the model path does not offer ``ident``'s θ (None: it does): not an arm
    (:func:`hil.identify.identification.unusable_reason`), no parameter determined, or a joint's
    torque NRMSE ``nrmse`` on the ``judged`` recording ("fit" or "held_out") not below 1."""
    reason = ident.failed_reason
    determined = ident.uncertainty is None or np.any(ident.uncertainty.identified)
    if reason is None and not determined:
        reason = "no parameter is determined by these data (every SE > 50 % of its value)"
    if reason is None:
        worse = _worse_than_mean(nrmse)
        if worse:
            reason = (
                f"torque prediction on the {judged.replace('_', '-')} recording no better than "
                "its mean on joint " + ", ".join(f"{j + 1} (NRMSE {nrmse[j]:.3g})" for j in worse)
            )
    return reason


def _worse_than_mean(nrmse: list[float]) -> list[int]:
    """The joints whose torque NRMSE is not below 1 (no better than predicting the mean). A
    joint whose recorded torque has no spread (a passive joint of DFKI C.0, τ ≡ 0: NRMSE nan)
    has nothing to predict and is not held against θ; when no joint has, every joint fails."""
    scored = [x is not None and bool(np.isfinite(x)) for x in nrmse]
    if not any(scored):
        return list(range(len(nrmse)))
    return [j for j, x in enumerate(nrmse) if scored[j] and x >= 1.0]


def _validation_entry(nrmse: list[float], judged: str, report: dict[str, Any]) -> dict[str, Any]:
    """A scheme's ``validation`` in identify.json's ``schemes`` (the URDF path's keys): its
    torque NRMSE on the judged recording and whether every joint is below 1."""
    worse = _worse_than_mean(nrmse)
    return {
        "on": report["validation_recording"] if judged == "held_out" else report["recording"],
        "torque_nrmse": nrmse,
        "passed": not worse,
        "reason": None
        if not worse
        else "no better than the mean on joint " + ", ".join(str(j + 1) for j in worse),
        "criterion": "every joint's filtered torque NRMSE below 1 (better than predicting its "
        "mean; a joint whose torque has no spread is not scored), on the held-out recording "
        "when given, else on the fit",
    }


LABEL = 30  # width of the validation table's row labels ("held-out: filtered_dynamic_iv")


def _iv_lines(report: dict[str, Any], model: ArmModel) -> list[str]:
    """The text of ``--instruments target``: least squares and IV side by side per parameter
    (± blocked-bootstrap SE, n/d where not determined), the reference's delay and tracking."""
    from hil.identify.iv import IV_SCHEME

    schemes = report.get("schemes", {})
    if IV_SCHEME not in schemes:
        return []
    ls, iv = schemes["filtered_dynamic"], schemes[IV_SCHEME]
    lines = [
        "",
        f"Filtered Dynamic IV (filtered_dynamic_iv): {iv['method']}; "
        f"{iv['rows']} rows, λ = {iv['lambda_rad_s']:.3g} rad/s",
        f"{'parameter':14s}{'unit':>7s}{'least squares':>16s}{'± SE':>10s}{'IV':>12s}{'± SE':>10s}",
    ]

    def cell(entry: dict[str, Any], i: int) -> str:
        u = entry["uncertainty"]
        value = f"{entry['theta'][i]:.4g}" if u["identified"][i] else "n/d"
        return f"{value:>16s}{u['se_blocked_bootstrap'][i]:>10.2g}"

    for i, (name, unit) in enumerate(zip(model.names, model.units, strict=True)):
        lines.append(f"{name:14s}{unit:>7s}{cell(ls, i)}{cell(iv, i)[4:]}")
    lines.append(
        "  n/d: not determined (blocked-bootstrap SE > 50 % of the value); least squares as "
        "fitted (bounded when not physical)"
    )
    for s in (IV_SCHEME,):
        if schemes[s]["failed_reason"]:
            lines.append(f"  {s} FAILED: {schemes[s]['failed_reason']}")
    return lines


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
    lines += _iv_lines(report, model)
    lines += [
        "",
        "Validation (NRMSE per joint, %): torque = filtered torque prediction (same rows, same "
        f"filter for both); simulation = open loop restarted every "
        f"{report['simulation_window_s']:g} s from the recorded state",
        f"{'':{LABEL}s}{'torque j1':>10s}{'j2':>8s}{'simulation j1':>15s}{'j2':>8s}",
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
                f"{where + ': ' + label:{LABEL}s}{100 * v['torque_nrmse'][0]:>10.2f}"
                f"{100 * v['torque_nrmse'][1]:>8.2f}{simtxt}"
            )
    selection = report["selection"]
    lines.append(
        f"\nparameters: {report['params_files'][0]}"
        if selection["usable"]
        else f"\nidentified model FAILED: {selection['reason']}; parameters: none"
    )
    return "\n".join(lines)
