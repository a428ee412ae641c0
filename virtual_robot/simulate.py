"""Offline simulation: an experiment's torques through the two drive models into the plant.

No transport and no wall clock: each period k the drives sample the encoders at t = k·h, the
experiment's torque is quantized by the drive (0x6071 per-mille, clamped to 0x6072) and held over
[t, t + h) while the plant integrates. The stepping is the served robot's lockstep sequence
(virtual_robot.stepping.Stepper), without its lock. The recording follows docs/design.md
(drivers.recording); it and the run's ending are the n-joint arm's too
(:func:`virtual_robot.offline.run_open_loop`).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from profiles.drive import DriveProfile, load_drive
from profiles.effects import EffectsProfile
from profiles.experiment import ExperimentProfile
from profiles.robot import RobotProfile, UrdfRobotProfile
from virtual_robot.offline import (
    SimulationResult,
    drive_meta,
    enable_drives,
    offline_rows,
    run_open_loop,
    simulation_meta,
)
from virtual_robot.plant import DEFAULT_STEP_S, Plant, PlantParams


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

        return simulate_urdf(
            robot,
            experiment,
            out_dir,
            effects=effects,
            duration_s=duration_s,
            step_s=step_s,
            plot=plot,
            progress=progress,
        )
    experiment.check_joints(2, robot.name)
    effects = effects or EffectsProfile()
    drives_p = drive_profiles(robot)
    if drives_p[0].protocol == "mit":  # MIT-mode drives: their commands, their replies
        from virtual_robot.mit_simulate import simulate_mit

        return simulate_mit(robot, experiment, out_dir, effects=effects, duration_s=duration_s)
    if drives_p[0].protocol == "odrive":  # ODrive axes: their torque setpoints, their estimates
        from virtual_robot.odrive_simulate import simulate_odrive

        return simulate_odrive(robot, experiment, out_dir, effects=effects, duration_s=duration_s)
    if drives_p[0].protocol == "moteus":  # moteus controllers: position-mode torque commands
        from virtual_robot.moteus_simulate import simulate_moteus

        return simulate_moteus(robot, experiment, out_dir, effects=effects, duration_s=duration_s)
    h, n_rows = offline_rows(experiment, duration_s)
    plant = Plant(
        PlantParams.from_profiles(robot, effects),
        q0=experiment.initial_q_rad,
        max_step_s=min(step_s, h),
    )
    drives = enable_drives(drives_p, h, plant.measured_q, plant.dq)
    meta = simulation_meta(
        robot, experiment, effects, period_s=h, n_rows=n_rows, drives=drive_meta(drives_p)
    )
    meta["integrator"] = {
        "method": "RK4, fixed step, stick-slip events located",
        "step_s": plant.max_step_s,
    }
    commanded_Nm = experiment.torque_rows(h, n_rows)  # a block at a time: bounded memory
    return run_open_loop(
        out_dir, meta, plant, drives, drives_p, commanded_Nm, n_rows, plot=plot, progress=progress
    )
