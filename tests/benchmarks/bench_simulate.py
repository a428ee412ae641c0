"""Benchmark: offline simulation of the 10 s Reyes & Kelly experiment (`make bench`).

Target (issue 2): at least 50x faster than real time on the 2-core reference machine.
Reports the integrator step, the cost per plant step and the real-time factor, as the median of
several repeats, on CPU time (the work is single-threaded; on a shared machine the wall clock
mostly measures the other processes), every run's factor listed in order, the first included.
``--json`` prints one JSON document; exit status 1 if the target is missed.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time

import numpy as np

from profiles.experiment import load_experiment
from profiles.robot import load_robot
from virtual_robot.plant import DEFAULT_STEP_S, Plant, PlantParams
from virtual_robot.simulate import simulate

TARGET_REALTIME_FACTOR = 50.0


def plant_only(robot, experiment, step_s: float) -> tuple[float, int]:
    """CPU time and step count of the plant alone under the held experiment torques."""
    h = experiment.period_s
    n = round(experiment.duration_s / h)
    torques = experiment.torque_table(np.arange(n) * h).tolist()
    plant = Plant(PlantParams.from_profiles(robot), max_step_s=step_s)
    start = time.process_time()
    for k in range(n):
        plant.command(torques[k])
        plant.advance_to((k + 1) * h)
    return time.process_time() - start, plant.steps


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    robot, experiment = load_robot("cicese"), load_experiment("reyes-kelly")
    plant_runs = [plant_only(robot, experiment, DEFAULT_STEP_S) for _ in range(args.repeats)]
    plant_cpu = statistics.median(c for c, _ in plant_runs)
    steps = plant_runs[0][1]
    sim_cpus = []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeats):
            start = time.process_time()
            simulate(robot, experiment, tmp, plot=False)
            sim_cpus.append(time.process_time() - start)
    sim_cpu = statistics.median(sim_cpus)
    factor = experiment.duration_s / sim_cpu
    result = {
        "benchmark": "offline simulation, reyes-kelly 10 s, h = 2.5 ms",
        "integrator_step_s": DEFAULT_STEP_S,
        "plant_steps": steps,
        "plant_us_per_step_cpu": round(plant_cpu / steps * 1e6, 2),
        "plant_cpu_s": round(plant_cpu, 4),
        "simulate_cpu_s_median": round(sim_cpu, 4),
        "simulate_cpu_s_min": round(min(sim_cpus), 4),
        "realtime_factor_cpu": round(factor, 1),
        "runs_realtime_factor_cpu": [round(experiment.duration_s / c, 1) for c in sim_cpus],
        "target_realtime_factor": TARGET_REALTIME_FACTOR,
        "met": factor >= TARGET_REALTIME_FACTOR,
        "repeats": args.repeats,
    }
    if args.json:
        print(json.dumps(result))
    else:
        print(f"offline simulation, 10 s of eqs. (31)-(32), h = 2.5 ms, median of {args.repeats}")
        print(f"  integrator step      {DEFAULT_STEP_S * 1e3:.2f} ms (RK4), {steps} steps")
        print(f"  plant cost per step  {result['plant_us_per_step_cpu']:.2f} us CPU")
        print(
            f"  simulate (drives, plant, recording)  {sim_cpu:.3f} s CPU  ->  {factor:.1f}x "
            f"real time (target >= {TARGET_REALTIME_FACTOR:.0f}x: "
            f"{'met' if result['met'] else 'MISSED'})"
        )
        runs = ", ".join(f"{r:.1f}" for r in result["runs_realtime_factor_cpu"])
        print(f"  every run, in order: {runs}")
    return 0 if result["met"] else 1


if __name__ == "__main__":
    sys.exit(main())
