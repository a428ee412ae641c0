"""Offline stepping of an arm on ODrive axes: torques through the axes' control loop into the
plant, no transport and no clock.

:func:`run_torques` is the lockstep sequence of
:class:`~virtual_robot.odrive_server.OdriveServer` written against the axes and the stepper
directly; a client driving the served robot in lockstep with the same torques reads the same
estimates (tests/test_odrive.py). :func:`simulate_odrive` is ``virtual-robot simulate`` for such
an arm: each period's torque as the float32 Set_Input_Torque carries, and the recording's q the
joint position of each Pos_Estimate at t_k (its encoder count).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from drivers.protocol import odrive as od
from profiles.drive import DriveProfile
from profiles.effects import EffectsProfile
from profiles.experiment import ExperimentProfile, TorqueRows
from profiles.robot import RobotProfile, UrdfRobotProfile
from virtual_robot.loop_offline import lockstep_core, simulate_drive_loop
from virtual_robot.odrive_drive import OdriveAxis
from virtual_robot.offline import SimulationResult


def run_torques(
    robot: RobotProfile | UrdfRobotProfile,
    period_s: float,
    torques: Sequence[Sequence[float]],
    *,
    effects: EffectsProfile | None = None,
    q0: Sequence[float] | None = None,
) -> dict[str, np.ndarray]:
    """Offline stepping of :class:`OdriveServer`'s lockstep: every axis in closed loop, torque
    control, from t = 0; in period k each axis gets ``torques[k][j]`` (as the float32 the frame
    carries), the plant runs one period, and ``pos_rev``, ``vel_rev_s`` (rows × axes: the encoder
    estimates sent after the period, float32) and ``counts`` are recorded; ``pos0_rev`` is the
    estimate at t = 0."""
    core = lockstep_core(robot, period_s, "odrive", "are no ODrive axes", effects=effects, q0=q0)
    axes: list[OdriveAxis] = list(core.drives)  # type: ignore[arg-type]
    for d in axes:
        d.set_controller_mode(od.TORQUE_CONTROL, od.PASSTHROUGH)
        d.request_state(od.CLOSED_LOOP_CONTROL, 0.0)
    n, m = len(torques), len(axes)
    out = {k: np.zeros((n, m)) for k in ("pos_rev", "vel_rev_s", "counts")}
    out["pos0_rev"] = np.array([od.f32(d.pos_estimate_rev) for d in axes])  # at t = 0
    for k, row in enumerate(torques):
        if len(row) != m:
            raise ValueError(f"torques row {k}: {len(row)} torques for {m} axes")
        for d, tau in zip(axes, row, strict=True):
            d.set_input_torque(od.f32(tau))
        core.step_host_period()
        for j, d in enumerate(axes):
            out["pos_rev"][k, j] = od.f32(d.pos_estimate_rev)
            out["vel_rev_s"][k, j] = od.f32(d.vel_estimate_rev_s)
            out["counts"][k, j] = d.counts
    out["plant_steps"] = np.array([getattr(core.plant, "steps", 0)])
    return out


def simulate_odrive(
    robot: RobotProfile | UrdfRobotProfile,
    experiment: ExperimentProfile,
    out_dir: str | Path,
    *,
    effects: EffectsProfile | None = None,
    duration_s: float | None = None,
) -> SimulationResult:
    """The experiment's torques through the robot's ODrive axes (module docstring), written to
    ``out_dir`` as a recording (t, q, tau: the torque each axis applied, status)."""

    def run(drives: list[DriveProfile], h: float, n_rows: int, torque: TorqueRows) -> tuple:
        out = run_torques(robot, h, torque, effects=effects, q0=experiment.initial_q_rad)
        limit = [p.rated_torque_Nm * p.max_torque_permille / 1000.0 for p in drives]
        pos = np.vstack([out["pos0_rev"], out["pos_rev"][:-1]])  # the estimate at t_k
        rows = (
            (
                [2.0 * math.pi * p for p in pos[k]],
                [max(-lim, min(lim, od.f32(t))) for t, lim in zip(torque[k], limit, strict=True)],
            )
            for k in range(n_rows)
        )
        return rows, int(out["plant_steps"][0])

    return simulate_drive_loop(
        robot,
        experiment,
        out_dir,
        protocol="odrive",
        run=run,
        effects=effects,
        duration_s=duration_s,
    )


__all__ = ["run_torques", "simulate_odrive"]
