"""Benchmark: offline simulation of the 10 s Reyes & Kelly experiment (`make bench`).

Target (issue 2): at least 50x faster than real time on the 2-core reference machine.
Reports the integrator step, the cost per plant step and the real-time factor, as the median of
several repeats. ``--json`` prints one JSON document; exit status 1 if the target is missed.
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
    """Wall time and step count of the plant alone under the held experiment torques."""
    h = experiment.period_s
    n = round(experiment.duration_s / h)
    torques = experiment.torque_table(np.arange(n) * h).tolist()
    plant = Plant(PlantParams.from_profiles(robot), max_step_s=step_s)
    start = time.perf_counter()
    for k in range(n):
        plant.command(torques[k])
        plant.advance_to((k + 1) * h)
    return time.perf_counter() - start, plant.steps


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    robot, experiment = load_robot("cicese"), load_experiment("reyes-kelly")
    plant_runs = [plant_only(robot, experiment, DEFAULT_STEP_S) for _ in range(args.repeats)]
    plant_wall = statistics.median(w for w, _ in plant_runs)
    steps = plant_runs[0][1]
    sim_walls = []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeats):
            sim_walls.append(simulate(robot, experiment, tmp, plot=False).wall_time_s)
    sim_wall = statistics.median(sim_walls)
    factor = experiment.duration_s / sim_wall
    result = {
        "benchmark": "offline simulation, reyes-kelly 10 s, h = 2.5 ms",
        "integrator_step_s": DEFAULT_STEP_S,
        "plant_steps": steps,
        "plant_us_per_step": round(plant_wall / steps * 1e6, 2),
        "plant_wall_s": round(plant_wall, 4),
        "simulate_wall_s_median": round(sim_wall, 4),
        "simulate_wall_s_min": round(min(sim_walls), 4),
        "realtime_factor": round(factor, 1),
        "target_realtime_factor": TARGET_REALTIME_FACTOR,
        "met": factor >= TARGET_REALTIME_FACTOR,
        "repeats": args.repeats,
    }
    if args.json:
        print(json.dumps(result))
    else:
        print(f"offline simulation, 10 s of eqs. (31)-(32), h = 2.5 ms, median of {args.repeats}")
        print(f"  integrator step      {DEFAULT_STEP_S * 1e3:.2f} ms (RK4), {steps} steps")
        print(f"  plant cost per step  {result['plant_us_per_step']:.2f} us")
        print(
            f"  simulate (drives, plant, recording)  {sim_wall:.3f} s  ->  {factor:.1f}x real time "
            f"(target >= {TARGET_REALTIME_FACTOR:.0f}x: {'met' if result['met'] else 'MISSED'})"
        )
    return 0 if result["met"] else 1


if __name__ == "__main__":
    sys.exit(main())
