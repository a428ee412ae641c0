"""The URDF path of `hil identify` (:func:`run_identify_urdf`): the base parameters of an
n-joint arm (:mod:`hil.model.urdf`) by each scheme, each validated on the same held-out torque
rows, with the instrumental-variable scheme on the targets when asked.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

from hil.cli_options import (
    read_recording,
    recorded_urdf_robot,
    say,
    split_list,
)
from hil.identify.identification import Identification
from hil.identify.identification import identify as identify_arm
from hil.identify.outcome import Outcome, record_run
from hil.identify.schemes import (
    SCHEME_TITLES,
)


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
        fit = record_run(args, bench, experiment, out / "fit", None, robot=args.robot)
        if val is None and args.validation_experiment not in (None, "none"):
            val = record_run(
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
        from hil.identify.iv import IV_SCHEME, iv_identification

        ident, entry = iv_identification(
            model, recording, held_out=held_out, cutoff_hz=cutoff,
            left_out_joints=torque_res.left_out_joints,
        )  # fmt: skip
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
