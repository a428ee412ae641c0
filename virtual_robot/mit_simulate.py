"""Offline stepping of an MIT-mode arm: a table of p/v/kp/kd/τ commands through the drives'
PD loop into the plant, no transport and no clock.

The lockstep sequence of :class:`~virtual_robot.mit_server.MitDriveServer`, written against the
drives and the stepper directly: every drive in motor mode from t = 0, its zero at the rest
position; in period k each drive is commanded ``commands[k][j]`` and reports its state sampled
at t_k (p, v, τ, the drive's frame), then the plant runs one period h in ``mit_substeps`` PD
updates (virtual_robot.stepping.Stepper). A client library driving the served robot in
lockstep with the same commands reads the same replies (tests/test_mit.py).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from drivers.protocol.mit import MitCommand
from profiles.effects import EffectsProfile
from profiles.robot import RobotProfile, UrdfRobotProfile
from virtual_robot.mit_drive import MitDrive
from virtual_robot.robot import LOCKSTEP, VirtualRobot


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
    sampled at t_k before the period's step) and ``t`` (t_k)."""
    core = VirtualRobot(robot, effects, mode=LOCKSTEP, period_s=period_s, q0=q0)
    if core.protocol != "mit":
        raise ValueError(f"robot {robot.name}: its drives do not speak MIT mode")
    drives: list[MitDrive] = list(core.drives)  # type: ignore[arg-type]
    stepper = core.stepper
    stepper.sync()  # sample 0 at t = 0
    for d in drives:
        d.set_zero(0.0)
        d.enter_motor_mode(0.0)
    n, m = len(commands), len(drives)
    out = {k: np.zeros((n, m)) for k in ("p", "v", "tau")}
    out["t"] = np.zeros(n)
    for k, row in enumerate(commands):
        if len(row) != m:
            raise ValueError(f"commands row {k}: {len(row)} commands for {m} joints")
        out["t"][k] = stepper.t
        for j, (d, cmd) in enumerate(zip(drives, row, strict=True)):
            d.write_command(cmd, stepper.t)
            out["p"][k, j] = d.position_rad
            out["v"][k, j] = d.velocity_rad_s
            out["tau"][k, j] = d.drive_torque_Nm
        stepper.unapplied = True
        for _ in range(core.mit_substeps):
            stepper.sync()
    return out


__all__ = ["run_commands"]
