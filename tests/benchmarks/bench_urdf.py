"""Benchmark: arms from a URDF through Pinocchio (hil/model/urdf.py, hil/identify/urdf.py).

1. µs per sample of M(q), of one θ's M(q) q̇ and g − Cᵀq̇ (``momentum``, ``static_torque``)
   and of the regressors, 2 joints (cicese.urdf; the closed form beside it) and 7 joints
   (panda.urdf).
2. Identification of 60 s of 7-joint data at 1 kHz (jittered stamps), all three schemes, batch:
   filtered dynamic (torque regressor, parallel filtering, weighted least squares), supplied
   energy and filtered power (exact energy rows, least squares): target under 10 s for the
   three together (issue 14). The data are the Panda URDF's own torques along a multisine plus
   1 % noise, so each scheme's fit is also checked.
3. With the Panda excitation of Gaz et al. (2019) present in ../shared/realdata (GPL-3, read
   only from there): the held-out torque NRMSE per joint of our identification and of their
   published model on the same rows — the table of docs/urdf.md.
4. `virtual-robot simulate` of n-joint arms (virtual_robot/urdf_plant.py) at 2.5 ms with a
   0.5 ms RK4 step, drives included: simulated seconds per CPU second for the 3-DOF cicese3,
   the 7-joint Panda and every shipped 6-joint arm (issue 14's target for a 6-DOF arm: ≥ 20×
   real time), and the 2-DOF closed-form plant beside them; best of ``--repeats`` runs (the
   load of a shared machine only ever adds). Beside each URDF arm, the floor: one ABA call's
   CPU cost now, the share of the run that the four ABA calls per RK4 step take, and the
   factor ABA alone would give. Every run's factor is listed in order, the first included.

``--json`` prints one JSON document; exit 1 if the identification target is missed (on CPU
time: the work is single-threaded; wall time is printed beside it).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

import hil.model.closed_form as closed_form
from drivers.one_per_line import read_one_per_line_log
from drivers.process import limit_blas_threads
from drivers.recording import Recording
from hil.identify.urdf import (
    DEFAULT_CUTOFF_HZ,
    ENERGY_SCHEMES,
    energy_rows_cutoff,
    filtered_rows,
    held_out_verdict,
    identify_energy,
    identify_torque,
    smoothed_motion,
    smoothing_cutoff_hz,
)
from hil.model.metrics import nrmse
from hil.model.urdf import UrdfArmModel

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import gaz_reference  # tests/gaz_reference.py

TARGET_IDENTIFY_S = 10.0
TARGET_SIMULATE_6DOF = 20.0  # × real time, issue 14
SAMPLES = 2000
SIMULATE_S = 5.0


def per_sample_us(fn, n: int, repeats: int = 3) -> float:
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        runs.append(time.perf_counter() - start)
    return statistics.median(runs) / n * 1e6


def model_timings(model: UrdfArmModel, rng: np.random.Generator) -> dict[str, float]:
    n = model.n_joints
    q, dq, ddq = rng.uniform(-2, 2, (3, SAMPLES, n))
    b = model.base_theta()
    return {
        "mass_matrix": per_sample_us(lambda: model.mass_matrix(b, q), SAMPLES),
        # one θ's torques (the diagnosis's torque rows) beside the regressors they replace
        "momentum": per_sample_us(lambda: model.momentum(b, q, dq), SAMPLES),
        "static_torque": per_sample_us(lambda: model.static_torque(b, q, dq), SAMPLES),
        "torque_regressor": per_sample_us(lambda: model.torque_regressor(q, dq, ddq), SAMPLES),
        "momentum_regressor": per_sample_us(lambda: model.momentum_regressor(q, dq), SAMPLES),
        "static_regressor": per_sample_us(lambda: model.static_regressor(q, dq), SAMPLES),
        "energy_regressor": per_sample_us(lambda: model.energy_regressor(q, dq), SAMPLES),
    }


def closed_form_timings(rng: np.random.Generator) -> dict[str, float]:
    q, dq, ddq = rng.uniform(-2, 2, (3, SAMPLES, 2))
    theta = np.ones(9)
    return {
        "mass_matrix": per_sample_us(lambda: closed_form.mass_matrix(theta, q), SAMPLES),
        "torque_regressor": per_sample_us(
            lambda: closed_form.dynamic_regressor(q, dq, ddq), SAMPLES
        ),
    }


def synthetic_panda(
    model: UrdfArmModel, rng: np.random.Generator, seconds: float = 60.0, noise: float = 0.01
):
    """A multisine around a mid configuration at 1 kHz with ±20 % jitter; torque with ``noise``
    (a fraction of each joint's torque spread, 1 %)."""
    t = np.cumsum(rng.uniform(0.8e-3, 1.2e-3, int(seconds * 1000)))
    w = rng.uniform(0.5, 4.0, (7, 4))
    a = rng.uniform(0.05, 0.25, (7, 4))
    phase = rng.uniform(0, 2 * np.pi, (7, 4))
    mid = np.array([0.0, 0.0, 0.0, -1.6, 0.0, 1.8, 0.0])
    arg = t[:, None, None] * w + phase
    q = mid + (a * np.sin(arg)).sum(-1)
    dq = (a * w * np.cos(arg)).sum(-1)
    ddq = (-a * w**2 * np.sin(arg)).sum(-1)
    truth = model.base_theta()
    tau = model.torque(truth, q, dq, ddq)
    tau = tau + noise * tau.std(0) * rng.normal(size=tau.shape)
    return Recording.from_arrays(t, q, tau, source="synthetic"), truth


def panda_table(model: UrdfArmModel) -> dict | None:
    if not gaz_reference.available():
        return None
    rec = read_one_per_line_log(gaz_reference.LOG_DIR)
    result = identify_torque(model, rec)  # the 4 Hz default cutoff
    cutoff = DEFAULT_CUTOFF_HZ
    held = result.rows.t >= result.fit_until_s
    motion = smoothed_motion(rec)
    theirs = filtered_rows(
        motion, gaz_reference.GazModel().torque(motion.q, motion.dq, motion.ddq)[..., None]
    )
    nominal = np.einsum("knp,p->kn", result.rows.Y[held], model.base_theta())
    start = time.process_time()
    feasible = identify_torque(model, rec, consistent=True)
    feasible_cpu = time.process_time() - start
    energy = {}
    # as `hil identify` decides (its cutoff from the data, 4.28 Hz here)
    energy_cutoff = energy_rows_cutoff(rec, smoothing_cutoff_hz(rec))
    for scheme in ENERGY_SCHEMES:  # on the same held-out rows
        for consistent in (False, True):
            res = identify_energy(
                model, rec, scheme, cutoff_hz=energy_cutoff, consistent=consistent
            )
            key = scheme + ("_consistent" if consistent else "")
            energy[key] = nrmse(
                result.rows.tau[held], np.einsum("knp,p->kn", result.rows.Y[held], res.theta)
            ).tolist()
            # `hil identify`'s verdict: on the rows as fitted (joint 7's near steps left out)
            energy[key + "_passed"] = held_out_verdict(
                res.theta, result.rows.select(held), cutoff
            ).passed
    return {
        **energy,
        # every model on the same held-out rows, all of them (nrmse_held_out leaves out the
        # rows near friction steps of the joints whose fit left them out: joint 7 here)
        "ours_consistent": nrmse(feasible.rows.tau[held], feasible.predicted[held]).tolist(),
        "consistent_fit_cpu_s": feasible_cpu,
        "ls_physically_consistent": model.physical_consistency(result.theta)["consistent"],
        "source": str(gaz_reference.LOG_DIR),
        "samples": len(rec.t),
        "fit_until_s": result.fit_until_s - rec.t[0],
        "ours": nrmse(result.rows.tau[held], result.predicted[held]).tolist(),
        "ours_rows_as_fitted": result.nrmse_held_out.tolist(),
        "friction_steps_left_out": result.left_out_joints.tolist(),
        "gaz_2019": nrmse(theirs.tau[held], theirs.Y[held, :, 0]).tolist(),
        "urdf_nominal": nrmse(result.rows.tau[held], nominal).tolist(),
    }


def simulate_speed(tmp: Path, repeats: int = 3) -> dict[str, dict[str, float]]:
    """Simulated seconds per CPU second (and per wall second) of `virtual-robot simulate`, the
    best of ``repeats`` runs."""
    from dataclasses import replace

    from profiles.experiment import ExperimentProfile, JointExcitation, Sine, load_experiment
    from profiles.robot import load_robot, load_urdf_robot
    from virtual_robot.simulate import simulate

    # The Panda has no drives in its profile: seven DM1200-A models stand in (12 rad/s
    # overspeed). Open loop from rest at the minimum of its potential energy (found by BFGS
    # from hanging down), one sine per joint sized to its inertia: it swings with stick-slip
    # (about 190 stick events in 5 s), every joint below 8 rad/s, no drive faults (checked:
    # "faults" below). From upright q = 0 with 10-28 Nm sines the drives faulted on overspeed
    # at 0.13 s and most of the run was a falling, unpowered arm.
    panda = replace(load_urdf_robot("panda"), drives=("dm1200a",) * 7)
    amplitudes = (1.5, 6.0, 1.5, 4.0, 0.8, 0.8, 0.6)
    sines = [
        JointExcitation(0.0, 1.0, (Sine(a, 10.0 + 3 * j, 0.1 * j),))
        for j, a in enumerate(amplitudes)
    ]
    panda_exp = ExperimentProfile("bench", "bench", "open_loop_torque", 0.0025, SIMULATE_S,
                                  panda_rest(panda), tuple(sines))  # fmt: skip
    cases = {
        "closed_form_2 (cicese)": (load_robot("cicese"), load_experiment("reyes-kelly")),
        "urdf_3 (cicese3)": (load_urdf_robot("cicese3"), load_experiment("cicese3-excitation")),
        "urdf_7 (panda)": (panda, panda_exp),
        **six_dof_arms(),
    }
    out = {}
    for name, (robot, experiment) in cases.items():
        urdf = name.startswith("urdf")
        # each URDF arm with the plant's default step (compiled when it builds) and with the
        # Python step forced (compiled_step.py): after and before on the same machine, now
        for kernel in ("auto", "python") if urdf else ("auto",):
            runs = []  # (CPU, wall) of each repeat; the machine's load only ever adds to them
            for _ in range(repeats):
                start, cpu = time.perf_counter(), time.process_time()
                result = _simulate_with_kernel(kernel, simulate, robot, experiment,
                                               tmp / name.split()[0])  # fmt: skip
                runs.append((time.process_time() - cpu, time.perf_counter() - start))
            cpu, wall = min(c for c, _ in runs), min(w for _, w in runs)
            if kernel == "python":
                out[name]["python_step_realtime_factor_cpu"] = SIMULATE_S / cpu
                continue
            steps, default_cpu = result.plant_steps, cpu
            out[name] = {
                "realtime_factor_cpu": SIMULATE_S / cpu,
                "realtime_factor_wall": SIMULATE_S / wall,
                # every run, the first included (it also loads the arm's kernel and URDF once)
                "runs_realtime_factor_cpu": [SIMULATE_S / c for c, _ in runs],
                "plant_steps": result.plant_steps,
                "faults": len(result.faults),
                "repeats": repeats,
            }
            if result.plant_kernel:
                out[name]["plant_kernel"] = result.plant_kernel
            if urdf:  # the plant alone, with the torques the drives gave it in that run
                out[name]["plant_alone_realtime_factor_cpu"] = SIMULATE_S / min(
                    plant_alone_cpu(robot, experiment, tmp / name.split()[0])
                    for _ in range(repeats)
                )
        if urdf:
            # the floor: four ABA calls per RK4 step and nothing else, at this moment's cost
            aba_us = aba_call_us(robot)
            out[name].update(
                aba_call_us=aba_us,
                aba_share_of_cpu=4 * aba_us * 1e-6 * steps / default_cpu,
                realtime_factor_aba_only=SIMULATE_S / (4 * aba_us * 1e-6 * steps),
            )
    return out


def panda_rest(robot) -> tuple[float, ...]:
    """The Panda's configuration of least potential energy (BFGS from hanging down, q2 = 3):
    the arm at rest there, so that small torques swing it instead of letting it fall."""
    import pinocchio as pin
    from scipy.optimize import minimize

    model = pin.buildModelFromUrdf(robot.urdf)
    model.gravity.linear = np.array([0.0, 0.0, -robot.gravity_m_s2])
    data = model.createData()
    start = np.array([0.0, 3.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    best = minimize(lambda q: pin.computePotentialEnergy(model, data, q), start, method="BFGS",
                    options={"gtol": 1e-10})  # fmt: skip
    return tuple(best.x.tolist())


def six_dof_arms() -> dict:
    """Every shipped 6-joint URDF arm with drives and an experiment ``<name>-excitation``,
    for issue 14's target itself (the shipped ur5e)."""
    from profiles import available
    from profiles.experiment import load_experiment
    from profiles.robot import describes_urdf_only, load_urdf_robot

    arms = {}
    for name in available("robots"):
        if not describes_urdf_only(name) or f"{name}-excitation" not in available("experiments"):
            continue
        robot = load_urdf_robot(name)
        if robot.n_joints == 6 and robot.drives:
            arms[f"urdf_6 ({name})"] = (robot, load_experiment(f"{name}-excitation"))
    return arms


def plant_alone_cpu(robot, experiment, recording: Path) -> float:
    """CPU seconds of the n-joint plant alone (the default step) over a recording's torque
    rows, held over each period as in the simulation: no drive models, no CSV rows."""
    from drivers.recording import read_signals
    from virtual_robot.urdf_plant import UrdfPlant, UrdfPlantParams

    tau = read_signals(recording).tau
    h = experiment.period_s
    plant = UrdfPlant(UrdfPlantParams.from_profile(robot), q0=experiment.initial_q_rad)
    cpu = time.process_time()
    for k, row in enumerate(tau):
        plant.command(row)
        plant.advance_to((k + 1) * h)
    return time.process_time() - cpu


def _simulate_with_kernel(kernel: str, simulate, robot, experiment, out: Path):
    """One `virtual-robot simulate` run with DDBENCH_PLANT_KERNEL set to ``kernel``."""
    import os

    from virtual_robot.compiled_step import KERNEL_ENV

    before = os.environ.get(KERNEL_ENV)
    os.environ[KERNEL_ENV] = kernel
    try:
        return simulate(robot, experiment, out, duration_s=SIMULATE_S, plot=False)
    finally:
        if before is None:
            del os.environ[KERNEL_ENV]
        else:
            os.environ[KERNEL_ENV] = before


def aba_call_us(robot, calls: int = 20000) -> float:
    """CPU µs of one Pinocchio ABA call from Python on the arm's plant model (median of 5)."""
    import pinocchio as pin

    from virtual_robot.urdf_plant import UrdfPlant, UrdfPlantParams

    plant = UrdfPlant(UrdfPlantParams.from_profile(robot))
    m, d, n = plant.model, plant.data, plant.n_joints
    q, v, tau = np.random.default_rng(0).uniform(-1, 1, (3, n))
    runs = []
    for _ in range(5):
        start = time.process_time()
        for _ in range(calls):
            pin.aba(m, d, q, v, tau)
        runs.append((time.process_time() - start) / calls * 1e6)
    return statistics.median(runs)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--no-panda", action="store_true", help="skip the real-data table")
    parser.add_argument("--only-simulate", action="store_true", help="part 4 only")
    parser.add_argument("--only-identify", action="store_true", help="parts 1 and 2 only")
    parser.add_argument("--only-timings", action="store_true", help="part 1 only")
    parser.add_argument("--no-simulate", action="store_true", help="skip part 4")
    parser.add_argument(
        "--noise", type=float, default=0.01, help="part 2: torque noise per joint (of its spread)"
    )
    parser.add_argument("--repeats", type=int, default=3, help="simulation runs per arm (best)")
    args = parser.parse_args()
    limit_blas_threads()  # as `hil identify` and `virtual-robot simulate` run: one BLAS thread
    if args.only_simulate:
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            speed = simulate_speed(Path(tmp), args.repeats)
        print(json.dumps(speed, indent=2) if args.json else _speed_lines(speed))
        return 0
    rng = np.random.default_rng(0)
    cicese, panda = UrdfArmModel.from_profile("cicese"), UrdfArmModel.from_profile("panda")
    doc: dict = {
        "us_per_sample": {
            "closed_form_2": closed_form_timings(rng),
            "urdf_2 (cicese)": model_timings(cicese, rng),
            "urdf_7 (panda)": model_timings(panda, rng),
        }
    }
    if args.only_timings:
        print(json.dumps(doc, indent=2) if args.json else _timing_lines(doc["us_per_sample"]))
        return 0
    rec, truth = synthetic_panda(panda, rng, noise=args.noise)
    doc["identify_60s_7joints_1kHz"] = ident = identify_speed(panda, rec, truth)
    cpu = ident["cpu_seconds"]
    if args.only_identify:
        print(json.dumps(ident, indent=2) if args.json else _identify_lines(ident))
        return 0 if cpu < TARGET_IDENTIFY_S else 1
    if not args.no_panda:
        doc["panda_gaz2019"] = panda_table(panda) or "data not found: skipped"
    import tempfile

    if not args.no_simulate:
        with tempfile.TemporaryDirectory() as tmp:
            doc["simulate"] = simulate_speed(Path(tmp), args.repeats)
    if args.json:
        print(json.dumps(doc, indent=2))
    else:
        print(_timing_lines(doc["us_per_sample"]))
        print(_identify_lines(doc["identify_60s_7joints_1kHz"]))
        table = doc.get("panda_gaz2019")
        if isinstance(table, dict):
            print(f"Panda (Gaz et al. 2019), held-out NRMSE after {table['fit_until_s']:.2f} s:")
            print(
                "| joint | ours (LS) | ours (consistent) | Gaz et al. (2019) model | URDF nominal "
                "| supplied energy (LS, consistent) | filtered power (LS, consistent) |"
            )
            print("|---|---|---|---|---|---|---|")
            for j in range(7):
                print(
                    f"| {j + 1} | {table['ours'][j]:.3f} | {table['ours_consistent'][j]:.3f} | "
                    f"{table['gaz_2019'][j]:.3f} | {table['urdf_nominal'][j]:.3f} | "
                    + " | ".join(
                        f"{table[s][j]:.3f}, {table[s + '_consistent'][j]:.3f}"
                        for s in ENERGY_SCHEMES
                    )
                    + " |"
                )
            print(
                "held-out validation passed (LS, consistent): "
                + "; ".join(
                    f"{s} {table[s + '_passed']}, {table[s + '_consistent_passed']}"
                    for s in ENERGY_SCHEMES
                )
            )
            print(
                f"LS parameters physically consistent: {table['ls_physically_consistent']}; "
                f"consistent fit {table['consistent_fit_cpu_s']:.1f} s CPU"
            )
        elif table:
            print(f"Panda table: {table}")
        if "simulate" in doc:
            print(_speed_lines(doc["simulate"]))
    # judged on CPU time: the work is single-threaded, and on this shared 2-core VM the wall
    # clock mostly measures the other agents' load (both are printed)
    return 0 if cpu < TARGET_IDENTIFY_S else 1


def identify_speed(model: UrdfArmModel, rec: Recording, truth: np.ndarray) -> dict:
    """CPU and wall seconds of each scheme on ``rec`` (fit on the first 75 %), its held-out
    torque NRMSE (the torque scheme's rows, as `hil identify` reports) and its largest base
    parameter error (relative, against max(|θ|, 0.01))."""
    schemes: dict[str, dict] = {}
    torque_rows = None
    for scheme in ("filtered_dynamic", *ENERGY_SCHEMES):
        start, cpu = time.perf_counter(), time.process_time()
        if scheme == "filtered_dynamic":
            res = identify_torque(model, rec)
            torque_rows, split = res.rows, res.fit_until_s
        else:
            # as `hil identify` runs it (smoothed positions only for noisy velocities)
            cutoff = energy_rows_cutoff(rec, smoothing_cutoff_hz(rec))
            res = identify_energy(model, rec, scheme, cutoff_hz=cutoff)
        elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu
        assert torque_rows is not None
        held = torque_rows.t >= split
        predicted = np.einsum("knp,p->kn", torque_rows.Y[held], res.theta)
        schemes[scheme] = {
            "seconds": elapsed,
            "cpu_seconds": cpu,
            "held_out_nrmse_max": float(nrmse(torque_rows.tau[held], predicted).max()),
            "max_relative_error_of_base_parameters": float(
                np.max(np.abs(res.theta - truth) / np.maximum(np.abs(truth), 1e-2))
            ),
        }
    return {
        "seconds": sum(x["seconds"] for x in schemes.values()),
        "cpu_seconds": sum(x["cpu_seconds"] for x in schemes.values()),
        "target_s": TARGET_IDENTIFY_S,
        "schemes": schemes,
    }


def _timing_lines(us_per_sample: dict[str, dict[str, float]]) -> str:
    return "\n".join(
        f"{name:18s} " + "  ".join(f"{k} {v:7.1f} µs" for k, v in timings.items())
        for name, timings in us_per_sample.items()
    )


def _identify_lines(ident: dict) -> str:
    lines = [
        f"identify 60 s, 7 joints, 1 kHz, all three schemes: {ident['seconds']:.2f} s wall, "
        f"{ident['cpu_seconds']:.2f} s CPU (target < {TARGET_IDENTIFY_S:.0f} s)"
    ]
    for scheme, x in ident["schemes"].items():
        lines.append(
            f"  {scheme:17s} {x['cpu_seconds']:5.2f} s CPU ({x['seconds']:.2f} s wall); "
            f"held-out NRMSE max {x['held_out_nrmse_max']:.4f}; "
            f"base parameters within {x['max_relative_error_of_base_parameters']:.2%}"
        )
    return "\n".join(lines)


def _speed_lines(speed: dict[str, dict[str, float]]) -> str:
    repeats = next(iter(speed.values()))["repeats"]
    lines = [
        f"virtual-robot simulate, {SIMULATE_S:g} s at 2.5 ms, 0.5 ms RK4 step (best of {repeats}):"
    ]
    for name, x in speed.items():
        runs = ", ".join(f"{r:.1f}" for r in x["runs_realtime_factor_cpu"])
        lines.append(
            f"  {name:24s} {x['realtime_factor_cpu']:6.1f}x real time per CPU second "
            f"({x['realtime_factor_wall']:.1f}x wall), {x['plant_steps']} plant steps, "
            f"{x['faults']} drive faults; runs in order: {runs}"
        )
        if "plant_kernel" in x:
            kernel = x["plant_kernel"]
            why = f" ({kernel['reason']})" if "reason" in kernel else ""
            lines.append(f"  {'':24s} plant step: {kernel['kernel']}{why}")
        if "plant_alone_realtime_factor_cpu" in x:
            lines.append(
                f"  {'':24s} the plant alone (the recorded torques, no drives, no rows): "
                f"{x['plant_alone_realtime_factor_cpu']:.1f}x"
            )
        if "python_step_realtime_factor_cpu" in x:
            lines.append(
                f"  {'':24s} with the Python step forced: "
                f"{x['python_step_realtime_factor_cpu']:.1f}x real time per CPU second"
            )
        if "aba_call_us" in x:
            lines.append(
                f"  {'':24s} one ABA call {x['aba_call_us']:.2f} µs CPU: the 4 per step are "
                f"{x['aba_share_of_cpu']:.0%} of it; ABA alone would run "
                f"{x['realtime_factor_aba_only']:.0f}x"
            )
    lines.append(f"  (issue 14 target for a 6-DOF arm: >= {TARGET_SIMULATE_6DOF:g}x)")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
