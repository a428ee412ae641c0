"""Offline runs of arms on drives with their own loop (MIT mode: virtual_robot.mit_simulate,
ODrive: virtual_robot.odrive_simulate, moteus: virtual_robot.moteus_simulate): what their
``run_*`` and ``simulate_*`` share.

:func:`lockstep_core` is the virtual robot their lockstep stepping runs (checked to have the
protocol's drives, sampled at t = 0); :func:`simulate_drive_loop` is the ``virtual-robot
simulate`` of such an arm: the experiment's rows (virtual_robot.offline.drive_loop_rows), the
protocol's own run of them, timed, and its recording (virtual_robot.offline.record_drive_loop).

Imports profiles (types), virtual_robot.offline and virtual_robot.robot only.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

from profiles.drive import DriveProfile
from profiles.effects import EffectsProfile
from profiles.experiment import ExperimentProfile, TorqueRows
from profiles.robot import RobotProfile, UrdfRobotProfile
from virtual_robot.offline import SimulationResult, drive_loop_rows, record_drive_loop
from virtual_robot.robot import LOCKSTEP, VirtualRobot

Rows = Iterable[tuple[Sequence[float], Sequence[float]]]
# (drive profiles, period h, rows, the experiment's torque rows) → the (q, τ) rows, plant steps
DriveLoopRun = Callable[[list[DriveProfile], float, int, TorqueRows], tuple[Rows, int]]


def lockstep_core(
    robot: RobotProfile | UrdfRobotProfile,
    period_s: float,
    protocol: str,
    not_them: str,
    *,
    effects: EffectsProfile | None = None,
    q0: Sequence[float] | None = None,
) -> VirtualRobot:
    """The lockstep virtual robot of ``robot`` at ``period_s``, sample 0 taken at t = 0; a
    ValueError ``robot <name>: its drives <not_them>`` if they do not speak ``protocol``."""
    core = VirtualRobot(robot, effects, mode=LOCKSTEP, period_s=period_s, q0=q0)
    if core.protocol != protocol:
        raise ValueError(f"robot {robot.name}: its drives {not_them}")
    core.stepper.sync()
    return core


def simulate_drive_loop(
    robot: RobotProfile | UrdfRobotProfile,
    experiment: ExperimentProfile,
    out_dir: str | Path,
    *,
    protocol: str,
    run: DriveLoopRun,
    effects: EffectsProfile | None = None,
    duration_s: float | None = None,
    drive_extra: Callable[[DriveProfile], dict[str, Any]] | None = None,
) -> SimulationResult:
    """The experiment's torques through the robot's ``protocol`` drives: ``run`` (timed: the
    recording's wall time) steps them and gives the (q, τ) rows; written to ``out_dir``, each
    drive described in meta.json by its model, the protocol and ``drive_extra`` of its profile."""
    drives, h, n_rows, torque = drive_loop_rows(robot, experiment, duration_s)
    started = time.perf_counter()
    rows, plant_steps = run(drives, h, n_rows, torque)
    wall = time.perf_counter() - started
    return record_drive_loop(
        out_dir,
        robot=robot,
        experiment=experiment,
        effects_name=(effects or EffectsProfile()).name,
        protocol=protocol,
        drives=[
            {"model": p.model, "protocol": protocol, **(drive_extra(p) if drive_extra else {})}
            for p in drives
        ],
        period_s=h,
        n_rows=n_rows,
        rows=rows,
        wall_s=wall,
        plant_steps=plant_steps,
    )


__all__ = ["DriveLoopRun", "lockstep_core", "simulate_drive_loop"]
