"""Offline stepping of an MIT-mode arm: a table of p/v/kp/kd/τ commands through the drives'
PD loop into the plant, no transport and no clock.

The lockstep sequence of :class:`~virtual_robot.mit_server.MitDriveServer`, written against the
drives and the stepper directly: every drive in motor mode from t = 0, its zero at the rest
position; in period k each drive is commanded ``commands[k][j]`` and reports its state sampled
at t_k (p, v, τ, the drive's frame), then the plant runs one period h in ``mit_substeps`` PD
updates (virtual_robot.stepping.Stepper). A client library driving the served robot in
lockstep with the same commands reads the same replies (tests/test_mit.py).

:func:`simulate_mit` is ``virtual-robot simulate`` for an arm on MIT-mode drives: an
experiment's torque of each period sent as τ_ff (kp = kd = 0) in each drive's frame, packed as
the firmware and the client libraries pack it, and the recording's q the joint-frame position
of each reply (its 16-bit field).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from drivers.protocol import mit
from drivers.protocol.mit import MitCommand
from profiles.drive import DriveProfile
from profiles.effects import EffectsProfile
from profiles.experiment import ExperimentProfile, TorqueRows
from profiles.robot import RobotProfile, UrdfRobotProfile
from virtual_robot.loop_offline import lockstep_core, simulate_drive_loop
from virtual_robot.mit_drive import MitDrive
from virtual_robot.offline import SW_ENABLED, SimulationResult


def run_commands(
    robot: RobotProfile | UrdfRobotProfile,
    period_s: float,
    commands: Sequence[Sequence[MitCommand]],
    *,
    effects: EffectsProfile | None = None,
    q0: Sequence[float] | None = None,
) -> dict[str, np.ndarray]:
    """Each period's commands (one per joint) stepped through the MIT-mode drives and the plant;
    returns ``p``, ``v``, ``tau`` (rows × joints, the drives' frame: what their replies carry,
    sampled at t_k before the period's step), ``t`` (t_k) and ``plant_steps`` (one value)."""
    core = lockstep_core(robot, period_s, "mit", "do not speak MIT mode", effects=effects, q0=q0)
    drives: list[MitDrive] = list(core.drives)  # type: ignore[arg-type]
    stepper = core.stepper
    for d in drives:
        d.set_zero(0.0)
        d.enter_motor_mode(0.0)
    n, m = len(commands), len(drives)
    out = {k: np.zeros((n, m)) for k in ("p", "v", "tau")}
    out["t"] = np.zeros(n)
    out["plant_steps"] = np.zeros(1)
    for k, row in enumerate(commands):
        if len(row) != m:
            raise ValueError(f"commands row {k}: {len(row)} commands for {m} joints")
        out["t"][k] = stepper.t
        for j, (d, cmd) in enumerate(zip(drives, row, strict=True)):
            d.write_command(cmd, stepper.t)
            out["p"][k, j] = d.position_rad
            out["v"][k, j] = d.velocity_rad_s
            out["tau"][k, j] = d.drive_torque_Nm
        core.step_host_period()
    out["plant_steps"][0] = getattr(core.plant, "steps", 0)
    return out


def simulate_mit(
    robot: RobotProfile | UrdfRobotProfile,
    experiment: ExperimentProfile,
    out_dir: str | Path,
    *,
    effects: EffectsProfile | None = None,
    duration_s: float | None = None,
) -> SimulationResult:
    """The experiment's torques through the robot's MIT-mode drives (module docstring), written
    to ``out_dir`` as a recording (t, q, tau, status: the torque each drive applied, in the
    joint's frame)."""

    def run(drives: list[DriveProfile], h: float, n_rows: int, torque: TorqueRows) -> tuple:
        ranges = [mit.MitRanges.of(p.mit) for p in drives]  # type: ignore[arg-type]
        sign = [p.mit.axis_direction for p in drives]  # type: ignore[union-attr]
        commands = [
            [
                mit.unpack_command(mit.pack_command(MitCommand(0.0, 0.0, 0.0, 0.0, d * t), r), r)
                for t, d, r in zip(torque[k], sign, ranges, strict=True)
            ]
            for k in range(n_rows)
        ]
        out = run_commands(robot, h, commands, effects=effects, q0=experiment.initial_q_rad)
        rows = (
            (
                [d * _reply_p(p, r) for p, d, r in zip(out["p"][k], sign, ranges, strict=True)],
                [d * c.t_ff for c, d in zip(commands[k], sign, strict=True)],
            )
            for k in range(n_rows)
        )
        return rows, int(out["plant_steps"][0])

    return simulate_drive_loop(
        robot,
        experiment,
        out_dir,
        protocol="mit",
        run=run,
        effects=effects,
        duration_s=duration_s,
        drive_extra=lambda p: {"t_max_Nm": mit.MitRanges.of(p.mit).t_max},  # type: ignore[arg-type]
    )


def _reply_p(p: float, r: mit.MitRanges) -> float:
    """p as a reply's 16-bit field carries it."""
    return mit.uint_to_float(mit.float_to_uint(p, -r.p_max, r.p_max, 16), -r.p_max, r.p_max, 16)


__all__ = ["SW_ENABLED", "run_commands", "simulate_mit"]
