"""Offline stepping of an arm on moteus controllers: position-mode commands through the
controllers' loop into the plant, no transport and no clock.

:func:`run_commands` is the lockstep sequence of
:class:`~virtual_robot.moteus_server.MoteusServer` written against the controllers and the
stepper directly: every controller brought up at t = 0 (:data:`BRING_UP`: position mode, no
torque; it takes no time); in period k each is commanded
``commands[k][j]`` and reports its state sampled at t_k (mode, position, velocity, torque: the
float32 a default query reply carries), then the plant runs one period. A client driving the
served robot in lockstep with the same commands (``query=True``) reads the same replies
(tests/test_moteus.py). :func:`simulate_moteus` is ``virtual-robot simulate`` for such an arm:
each period's torque sent as feedforward_torque (float32, kp_scale = kd_scale = 0, position
NaN), the recording's q 2π × the reply's position at t_k.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from drivers.protocol.moteus import f32
from profiles.drive import DriveProfile
from profiles.effects import EffectsProfile
from profiles.experiment import ExperimentProfile, TorqueRows
from profiles.robot import RobotProfile, UrdfRobotProfile
from virtual_robot.loop_offline import lockstep_core, simulate_drive_loop
from virtual_robot.moteus_drive import MoteusDrive, PositionCommand
from virtual_robot.offline import SimulationResult

TWO_PI = 2.0 * math.pi


def torque_command(tau_Nm: float) -> PositionCommand:
    """A pure torque command as the moteus library sends it (default F32 resolution)."""
    return PositionCommand(
        position_rev=math.nan, feedforward_Nm=f32(tau_Nm), kp_scale=0.0, kd_scale=0.0
    )


# how a client brings a controller up: position mode, the present position, no gain, no torque
BRING_UP = PositionCommand(position_rev=math.nan, feedforward_Nm=0.0, kp_scale=0.0, kd_scale=0.0)


def run_commands(
    robot: RobotProfile | UrdfRobotProfile,
    period_s: float,
    commands: Sequence[Sequence[PositionCommand]],
    *,
    effects: EffectsProfile | None = None,
    q0: Sequence[float] | None = None,
) -> dict[str, np.ndarray]:
    """Each period's commands (one per controller) stepped through the controllers and the
    plant; returns ``mode``, ``position_rev``, ``velocity_rev_s``, ``torque_Nm`` (rows ×
    controllers: the float32 replies, sampled at t_k after the command) and ``plant_steps``."""
    not_them = "are no moteus controllers"
    core = lockstep_core(robot, period_s, "moteus", not_them, effects=effects, q0=q0)
    drives: list[MoteusDrive] = list(core.drives)  # type: ignore[arg-type]
    for d in drives:
        d.position(BRING_UP)
    n, m = len(commands), len(drives)
    out = {k: np.zeros((n, m)) for k in ("mode", "position_rev", "velocity_rev_s", "torque_Nm")}
    for k, row in enumerate(commands):
        if len(row) != m:
            raise ValueError(f"commands row {k}: {len(row)} commands for {m} controllers")
        for j, (d, cmd) in enumerate(zip(drives, row, strict=True)):
            why = d.position(cmd)
            if why:
                raise ValueError(f"commands row {k}, controller {j + 1}: {why}")
            out["mode"][k, j] = d.mode
            out["position_rev"][k, j] = f32(d.position_rev)
            out["velocity_rev_s"][k, j] = f32(d.velocity_rev_s)
            out["torque_Nm"][k, j] = f32(d.drive_torque_Nm)
        core.step_host_period()
    out["plant_steps"] = np.array([getattr(core.plant, "steps", 0)])
    return out


def simulate_moteus(
    robot: RobotProfile | UrdfRobotProfile,
    experiment: ExperimentProfile,
    out_dir: str | Path,
    *,
    effects: EffectsProfile | None = None,
    duration_s: float | None = None,
) -> SimulationResult:
    """The experiment's torques through the robot's moteus controllers (module docstring),
    written to ``out_dir`` as a recording (t, q, tau: the torque each controller applied)."""

    def run(drives: list[DriveProfile], h: float, n_rows: int, torque: TorqueRows) -> tuple:
        commands = [[torque_command(t) for t in torque[k]] for k in range(n_rows)]
        out = run_commands(robot, h, commands, effects=effects, q0=experiment.initial_q_rad)
        rows = (
            ([TWO_PI * p for p in out["position_rev"][k]], out["torque_Nm"][k])
            for k in range(n_rows)
        )
        return rows, int(out["plant_steps"][0])

    return simulate_drive_loop(
        robot,
        experiment,
        out_dir,
        protocol="moteus",
        run=run,
        effects=effects,
        duration_s=duration_s,
    )


__all__ = ["BRING_UP", "run_commands", "simulate_moteus", "torque_command"]
