"""What limits the identification of the 6-DOF ur5e arm (docs/urdf.md, "A 6-DOF arm: ur5e"):
simulate an excitation (`virtual-robot simulate --robot ur5e`), identify it (`hil identify
--from`, all three schemes, last quarter held out) and print

- per joint: the share of intervals it sticks in (hil.model.regressors.quantized_stick), the
  number and length of its sticks, its peak speed against the drive's limit and its range;
- the condition number of the torque scheme's rows as fitted (stuck rows left out, each joint's
  equation divided by its RMS torque, columns scaled to unit norm: Gautier's measure);
- per scheme, every base parameter that misses the CICESE targets (tests/ur5e_targets.py),
  with its error in blocked-bootstrap standard errors and its relative standard error, and the
  parameters the report calls not identifiable.

    python tests/benchmarks/ur5e_identifiability.py                        # the shipped run
    python tests/benchmarks/ur5e_identifiability.py --experiment OLD.toml  # another excitation

About 40 s CPU. Writes the run and identify.json under --out.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/ (ur5e_targets)
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the tree

from ur5e_targets import check_targets, torque_recording, torque_shares

from drivers.recording import read_signals
from hil.cli import main as hil_main
from hil.identify.schemes import bootstrap_block_s
from hil.identify.urdf import parameter_uncertainty, regression_rows
from hil.model.estimators import BlockNormalEquations, weighted_least_squares
from hil.model.regressors import quantized_stick
from hil.model.urdf import UrdfArmModel
from profiles.experiment import load_experiment
from profiles.robot import load_urdf_robot
from virtual_robot.urdf_plant import simulate_urdf


def stick_table(rec, velocity_limit: list[float]) -> list[str]:
    stuck = quantized_stick(rec.q, rec.t)
    h = float(np.median(np.diff(rec.t)))
    speed = np.abs(np.diff(rec.q, axis=0) / np.diff(rec.t)[:, None]).max(axis=0)
    lines = ["joint  stuck %  sticks  median ms  max ms  peak |q'| / limit rad/s  q range rad"]
    for j in range(rec.n_joints):
        edges = np.diff(np.r_[0, stuck[:, j].astype(int), 0])
        lengths = (np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)) * h * 1e3
        lines.append(
            f"{j + 1:5d}  {100 * stuck[:, j].mean():7.1f}  {len(lengths):6d}  "
            f"{np.median(lengths) if len(lengths) else 0:9.1f}  "
            f"{lengths.max() if len(lengths) else 0:6.1f}  "
            f"{speed[j]:10.1f} / {velocity_limit[j]:<12.0f}  "
            f"[{rec.q[:, j].min():.2f}, {rec.q[:, j].max():.2f}]"
        )
    return lines


def condition_number(model: UrdfArmModel, rec, report: dict) -> float:
    """κ of the fitted torque rows: weights as fitted, joints by RMS torque, unit columns."""
    rows = regression_rows(model, rec, cutoff_hz=report["smoothing_cutoff_hz"])
    rows = rows.leaving_out(report["schemes"]["filtered_dynamic"]["friction_steps_left_out"])
    fit = rows.t < float(report["validation"]["on"].split("t >= ")[1].split(" s")[0])
    w = rows.weights[fit]
    rms = np.sqrt(np.sum(w * rows.tau[fit] ** 2, axis=0) / w.sum(axis=0))
    A = (rows.Y[fit] * (np.sqrt(w) / rms)[:, :, None]).reshape(-1, model.n_params)
    sv = np.linalg.svd(A / np.linalg.norm(A, axis=0), compute_uv=False)
    return float(sv[0] / sv[-1])


def all_rows_fit(model: UrdfArmModel, rec, report: dict, nominal: np.ndarray, shares) -> list[str]:
    """The torque scheme as it was before rows near friction steps were left out: weighted
    least squares on every fitted row; its misses with their errors in white-residual and
    blocked-bootstrap standard errors, and the parameters whose SE exceeds their value."""
    rows = regression_rows(model, rec, cutoff_hz=report["smoothing_cutoff_hz"])
    fit = rows.t < float(report["validation"]["on"].split("t >= ")[1].split(" s")[0])
    theta = weighted_least_squares(rows.Y[fit], rows.tau[fit])
    block_s = bootstrap_block_s(
        2 * np.pi * report["smoothing_cutoff_hz"], float(rec.t[-1] - rec.t[0])
    )
    blocks = BlockNormalEquations(model.n_params, model.n_joints, block_s)
    blocks.add(rows.t[fit], rows.tau[fit], rows.Y[fit], np.ones(rows.tau[fit].shape))
    u = parameter_uncertainty(blocks, theta)
    meanings = list(model.meanings)
    lines = ["torque scheme on every row (nothing left out):"]
    for line in check_targets(report, list(theta), shares, model, rec):
        k = meanings.index(line.split(":")[0])
        err = theta[k] - nominal[k]
        lines.append(
            f"  {line}  (error {err / u.se_white[k]:+.1f} white SE, {err / u.se_block[k]:+.1f} "
            "bootstrap SE)"
        )
    significant = shares.max(axis=1) >= 0.05  # the parameters judged by a relative target
    relative = np.where(significant, u.se_white / np.maximum(np.abs(nominal), 1e-300), 0.0)
    for k in np.argsort(-relative):
        if relative[k] > 0.02:
            lines.append(
                f"  {meanings[k]}: white SE {relative[k]:.0%}, bootstrap SE "
                f"{u.se_block[k] / abs(nominal[k]):.0%} of its nominal value"
            )
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--experiment", default="ur5e-excitation", help="name or TOML file")
    ap.add_argument("--out", default="runs/ur5e-identifiability", help="run directory")
    args = ap.parse_args()
    out = Path(args.out)
    robot = load_urdf_robot("ur5e")
    simulate_urdf(robot, load_experiment(args.experiment), out / "sim", plot=False)
    ident = out / "identify"
    argv = ["identify", "--from", str(out / "sim"), "--out", str(ident), "--no-plot", "--overwrite"]
    with (out / "identify.txt").open("w") as text, contextlib.redirect_stdout(text):
        assert hil_main(argv) == 0  # its text report: OUT/identify.txt
    report = json.loads((ident / "identify.json").read_text())
    model = UrdfArmModel.from_profile("ur5e")
    rec = read_signals(out / "sim")
    print(f"experiment {args.experiment}, {len(rec.t)} rows")
    print("\n".join(stick_table(rec, list(robot.limits.velocity_rad_s))))
    torque = report["schemes"]["filtered_dynamic"]
    print(
        "torque scheme: rows near friction steps left out on joints "
        + str([j + 1 for j, x in enumerate(torque["friction_steps_left_out"]) if x])
        + " (share of rows: "
        + ", ".join(f"{x:.2f}" for x in torque["rows_left_out_fraction"])
        + "; first-fit residual near steps / elsewhere: "
        + ", ".join(
            "-" if x is None else f"{x:.1f}" for x in torque["residual_ratio_near_friction_steps"]
        )
        + ")"
    )
    print(f"condition number of the fitted torque rows: {condition_number(model, rec, report):.0f}")
    nominal = np.array([x["nominal"] for x in report["parameters"]])
    shares = torque_shares(model, torque_recording(out / "sim"), nominal)
    meanings = [x["meaning"] for x in report["parameters"]]
    print("held-out torque NRMSE per joint:")
    print(
        f"  {'nominal':17s}"
        + "".join(f"{x:8.4f}" for x in report["validation"]["torque_nrmse_nominal"])
    )
    for scheme, entry in report["schemes"].items():
        print(f"  {scheme:17s}" + "".join(f"{x:8.4f}" for x in entry["validation"]["torque_nrmse"]))
    print("\n".join(all_rows_fit(model, rec, report, nominal, shares)))
    for scheme, entry in report["schemes"].items():
        theta = np.array(entry["theta"])
        se = np.array(entry["uncertainty"]["se_blocked_bootstrap"])
        misses = check_targets(report, entry["theta"], shares, model, rec)
        print(f"{scheme}: {len(misses)} missed")
        for line in misses:
            k = meanings.index(line.split(":")[0])
            relative = f"{se[k] / abs(nominal[k]):.1%}" if nominal[k] else "-"
            print(
                f"  {line}  (error {(theta[k] - nominal[k]) / se[k]:+.1f} SE; SE {relative} of "
                f"nominal; {'identified' if entry['uncertainty']['identified'][k] else 'n/i'})"
            )
        not_identified = [
            x["name"] for x in report["parameters"] if scheme in x["not_identifiable_in"]
        ]
        print(f"  not identifiable ({len(not_identified)}): {', '.join(not_identified)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
