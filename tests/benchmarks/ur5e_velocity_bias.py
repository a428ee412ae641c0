"""Where the effect-free ur5e's false `unexplained` structure on joint 6 came from
(docs/diagnosis.md, "The effect-free ur5e"): simulate the shipped 20 s `ur5e-excitation`
without effects, keeping the plant's own q and q̇ at every sample, then build the diagnosis's
nominal regression three ways and print per joint the residual RMS and the `unexplained`
tests (held-out error reduction of the velocity and position bins, blocks improved, sign-test
p; a finding needs ≥ 2 % and p ≤ 1e-3 / 12):

- ``plain``: the host's velocities (three-point derivative of the encoder), rows y = F[τ]
  (the diagnosis before the held torque's corners were allowed for);
- ``corrected``: the same velocities, y = F[τ_k + (b_{k+1} − b_k)/h]
  (hil.model.regressors.held_torque_momentum_bias, what `hil diagnose` does);
- ``plant``: the plant's own q̇ at the samples in place of the estimate (no bias to correct).

    python tests/benchmarks/ur5e_velocity_bias.py [--out DIR]

About 30 s CPU. The velocity is swapped by patching the estimator inside this script only.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the tree

import hil.diagnose.columns as columns
import hil.model.regressors as regressors
from drivers.recording import read_signals
from hil.diagnose.interpret import _bin_columns
from hil.diagnose.problem import build_problem
from hil.diagnose.stats import block_stats, cross_validate, evidence, extend_stats_many
from hil.model.urdf import UrdfArmModel
from profiles.experiment import load_experiment
from profiles.robot import load_urdf_robot
from virtual_robot import stepping
from virtual_robot.urdf_plant import simulate_urdf


def simulate_with_plant_state(out: Path) -> tuple[np.ndarray, np.ndarray]:
    """The null run into ``out``; the plant's q, q̇ at every sample (row 0: the start, at rest)."""
    kept_q, kept_dq = [], []
    advance_held = stepping.Stepper.advance_held

    def keeping(self, torques, bounds, q_out, dq_out):  # type: ignore[no-untyped-def]
        done, inside = advance_held(self, torques, bounds, q_out, dq_out)
        kept_q.append(q_out[:done].copy())
        kept_dq.append(dq_out[:done].copy())
        return done, inside

    stepping.Stepper.advance_held = keeping  # type: ignore[method-assign]
    try:
        robot, experiment = load_urdf_robot("ur5e"), load_experiment("ur5e-excitation")
        simulate_urdf(robot, experiment, out, plot=False)
    finally:
        stepping.Stepper.advance_held = advance_held  # type: ignore[method-assign]
    q0 = np.asarray(experiment.initial_q_rad, float)[None]
    return np.vstack([q0, *kept_q]), np.vstack([np.zeros_like(q0), *kept_dq])


def report(name: str, q: np.ndarray, tau: np.ndarray, h: float, t: np.ndarray) -> None:
    prob, theta = build_problem([(q, tau, h, t)], UrdfArmModel.from_profile("ur5e"))
    stats = block_stats(prob.design_groups([]), prob.y, prob.w, prob.blocks)
    design, base = prob.joint_columns([]), cross_validate(stats)
    residual = prob.y_raw - prob.Psi_raw @ theta
    for j in range(prob.n_joints):
        tests = []
        for variable in ("velocity", "position"):
            X = _bin_columns(prob, j, variable)[:, :, None]
            cv = cross_validate(extend_stats_many(stats, design, X, prob.y, prob.w, prob.blocks))
            ev = evidence(base, cv, [j])
            tests.append(
                f"{variable} {100 * ev.reduction:+.2f} % {ev.blocks_improved}/{ev.blocks} "
                f"p {ev.sign_p:.1g}"
            )
        used = prob.w[:, j] > 0
        rms = 1e3 * np.sqrt(np.mean(residual[used, j] ** 2))
        print(f"{name:9s} joint {j + 1}: residual {rms:8.4f} mN m RMS | " + " | ".join(tests))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="ur5e-null-"))
    plant_q, plant_dq = simulate_with_plant_state(out)
    rec = read_signals(out)
    assert np.max(np.abs(plant_q - rec.q)) < 1e-4  # the encoder's floor of the plant's angle
    plain_bias = regressors.held_torque_momentum_bias
    columns.held_torque_momentum_bias = lambda tau, *a: np.zeros(np.shape(tau))  # type: ignore
    report("plain", rec.q, rec.tau, rec.period_s, rec.t)
    columns.held_torque_momentum_bias = plain_bias
    report("corrected", rec.q, rec.tau, rec.period_s, rec.t)
    estimate = regressors.central_difference

    def plant_velocity(q: np.ndarray, h: float) -> np.ndarray:
        return plant_dq.copy() if q.shape == plant_dq.shape else estimate(q, h)

    regressors.central_difference = columns.central_difference = plant_velocity  # type: ignore
    columns.held_torque_momentum_bias = lambda tau, *a: np.zeros(np.shape(tau))  # type: ignore
    report("plant", rec.q, rec.tau, rec.period_s, rec.t)


if __name__ == "__main__":
    main()
