"""Offline simulation: an experiment's torques through the two drive models into the plant.

No transport and no wall clock: each period k the drives sample the encoders at t = k·h, the
experiment's torque is quantized by the drive (0x6071 per-mille, clamped to 0x6072) and held over
[t, t + h) while the plant integrates. The stepping is the served robot's lockstep sequence
(virtual_robot.stepping.Stepper), without its lock. The recording follows DESIGN.md
(drivers.recording).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from drivers.recording import RecordingWriter, plot_positions, read_signals
from drivers.units import counts_to_rad, torque_to_permille, unwrap_int32
from profiles.drive import DriveProfile, load_drive
from profiles.effects import EffectsProfile
from profiles.experiment import ExperimentProfile
from profiles.robot import RobotProfile, UrdfRobotProfile
from virtual_robot import __version__
from virtual_robot.drive import State
from virtual_robot.offline import SimulationResult, collect_faults, drive_meta, enable_drives
from virtual_robot.plant import DEFAULT_STEP_S, Plant, PlantParams
from virtual_robot.stepping import Stepper


def drive_profiles(robot: RobotProfile) -> tuple[DriveProfile, DriveProfile]:
    """The robot profile's joint → drive map, loaded."""
    return load_drive(robot.drives[0]), load_drive(robot.drives[1])


def simulate(
    robot: RobotProfile | UrdfRobotProfile,
    experiment: ExperimentProfile,
    out_dir: str | Path,
    *,
    effects: EffectsProfile | None = None,
    duration_s: float | None = None,
    step_s: float = DEFAULT_STEP_S,
    plot: bool = True,
    progress: Callable[[float, float], None] | None = None,
) -> SimulationResult:
    """Run ``experiment`` open loop on the virtual arm and write a recording to ``out_dir``.
    An arm described by its URDF only runs on the n-joint plant (virtual_robot.urdf_plant)."""
    if isinstance(robot, UrdfRobotProfile):
        from virtual_robot.urdf_plant import simulate_urdf

        if effects is not None and effects.enabled:
            raise ValueError(
                f"effects {effects.name}: the n-joint plant ({robot.name}) has no concealed "
                "effects yet; simulate it without --effects"
            )
        return simulate_urdf(
            robot,
            experiment,
            out_dir,
            duration_s=duration_s,
            step_s=step_s,
            plot=plot,
            progress=progress,
        )
    experiment.check_joints(2, robot.name)
    effects = effects or EffectsProfile()
    drives_p = drive_profiles(robot)
    h = experiment.period_s
    duration = experiment.duration_s if duration_s is None else duration_s
    n_rows = max(1, round(duration / h))
    plant = Plant(
        PlantParams.from_profiles(robot, effects),
        q0=experiment.initial_q_rad,
        max_step_s=min(step_s, h),
    )
    drives = enable_drives(drives_p, h, plant.measured_q, plant.dq)
    stepper = Stepper(plant, drives, h)
    counts = [drives[i].position_counts for i in range(2)]
    meta = {
        "kind": "simulate",
        "version": __version__,
        "robot": robot.name,
        "robot_profile": robot.source,
        "effects": effects.name,
        "effects_profile": effects.source,
        "effects_enabled": list(effects.enabled),
        "experiment": experiment.name,
        "experiment_profile": experiment.source,
        "mode": "offline",
        "period_s": h,
        "duration_s": n_rows * h,
        "seed": None,
        "drives": drive_meta(drives_p),
        "integrator": {
            "method": "RK4, fixed step, stick-slip events located",
            "step_s": plant.max_step_s,
        },
    }
    faults: list[dict[str, Any]] = []
    commanded_Nm = experiment.torque_rows(h, n_rows)  # a block at a time: bounded memory
    started = time.perf_counter()
    last_report = started
    with RecordingWriter(out_dir, meta, extra_columns=("status1", "status2")) as rec:
        cpr = [p.counts_per_rev for p in drives_p]
        rated = [p.rated_torque_Nm for p in drives_p]
        q = [0.0, 0.0]
        tau = [0.0, 0.0]
        for k in range(n_rows):
            # the torques written at t_{k-1} held over [t_{k-1}, t_k), encoders sampled at t_k
            t = stepper.sync()
            commanded = commanded_Nm[k]
            for i, d in enumerate(drives):
                counts[i] = unwrap_int32(counts[i], d.position_counts)
                q[i] = counts_to_rad(counts[i], cpr[i])
                d.write_target_torque(torque_to_permille(commanded[i], rated[i]), t)
                tau[i] = d.torque_Nm  # quantized, clamped, zero unless enabled: held over [t, t+h)
                if d.state is not State.OPERATION_ENABLED:
                    collect_faults(d, drives_p[i].model, t, faults)
            rec.write((t, q[0], q[1], tau[0], tau[1], drives[0].statusword, drives[1].statusword))
            if progress is not None and time.perf_counter() - last_report > 1.0:
                last_report = time.perf_counter()
                progress(t + h, n_rows * h)
        stepper.advance()  # the last row's torque held over its period too
        wall = time.perf_counter() - started
        rec.meta.update(
            wall_time_s=wall,
            realtime_factor=n_rows * h / wall if wall else None,
            plant_steps=plant.steps,
            stick_events=plant.stick_events,
            faults=faults,
        )
    result = SimulationResult(Path(out_dir), n_rows, wall, n_rows * h, plant.steps, faults)
    if plot:
        result.plot = plot_positions(
            read_signals(out_dir),
            Path(out_dir) / "positions.png",
            title=f"virtual-robot simulate: {robot.name}, "
            f"{experiment.name}, effects {effects.name}",
        )
    return result
