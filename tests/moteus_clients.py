"""The unmodified ``moteus`` client library driving the virtual moteus controllers, shared by
tests/test_moteus.py (fdcanusb pty, python-can's virtual bus) and tests/vcan/test_vcan_moteus.py
(python-can's socketcan on a kernel CAN-FD interface): the commands, and the library's run of them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from drivers.protocol.moteus import f32
from virtual_robot.moteus_drive import PositionCommand
from virtual_robot.moteus_simulate import torque_command

PERIOD_S = 0.002

# an open-loop experiment for the moteus benches: 0.3 s, 150 periods
MULTISINE = """
name = "moteus-multisine"
kind = "open_loop_torque"
period_s = 0.002
duration_s = 0.3
[[joints]]
sines = [{ amplitude_Nm = 2.0, omega_rad_s = 9.0, phase_rad = 0.3 }]
[[joints]]
sines = [{ amplitude_Nm = 0.7, omega_rad_s = 14.0, phase_rad = 1.0 }]
"""


def commands(n: int) -> list[list[PositionCommand]]:
    """Torque first (kp_scale = kd_scale = 0), then the drive's own PD to a moving target."""
    t = np.arange(n) * PERIOD_S
    rows = []
    for k in range(n):
        if k < n // 2:
            rows.append(
                [
                    torque_command(1.5 * math.sin(2 * math.pi * 2.0 * t[k])),
                    torque_command(-0.8 * math.cos(2 * math.pi * 3.0 * t[k])),
                ]
            )
        else:
            target = f32(0.05 * math.sin(2 * math.pi * 1.0 * t[k]))
            rows.append(
                [
                    PositionCommand(
                        position_rev=target, velocity_rev_s=0.0, kp_scale=1.0, kd_scale=1.0
                    ),
                    PositionCommand(
                        position_rev=math.nan,
                        feedforward_Nm=f32(0.3),
                        kp_scale=0.0,
                        kd_scale=f32(0.5),
                    ),
                ]
            )
    return rows


async def library_run(
    make_transport: Callable[[], Any], rows: list[list[PositionCommand]]
) -> dict[str, np.ndarray]:
    """moteus.Controller ids 1 and 2 on ``make_transport()`` (a moteus transport, made inside
    the event loop): stop and bring up both, then each period set_position with query=True to
    controller 1 then 2; the replies' mode, position, velocity and torque recorded."""
    import moteus

    transport = make_transport()
    ctl = [moteus.Controller(id=i, transport=transport) for i in (1, 2)]
    keys = (
        moteus.Register.MODE,
        moteus.Register.POSITION,
        moteus.Register.VELOCITY,
        moteus.Register.TORQUE,
    )
    out = {
        k: np.zeros((len(rows), 2)) for k in ("mode", "position_rev", "velocity_rev_s", "torque_Nm")
    }
    try:
        for c in ctl:  # stop, then bring up: position mode without torque (takes no time)
            await c.set_stop()
            await c.set_position(position=math.nan, kp_scale=0, kd_scale=0, feedforward_torque=0)
        for k, row in enumerate(rows):
            for j, (c, cmd) in enumerate(zip(ctl, row, strict=True)):
                r = await c.set_position(
                    position=cmd.position_rev,
                    velocity=cmd.velocity_rev_s,
                    feedforward_torque=cmd.feedforward_Nm,
                    kp_scale=cmd.kp_scale,
                    kd_scale=cmd.kd_scale,
                    query=True,
                )
                for name, key in zip(out, keys, strict=True):
                    out[name][k, j] = r.values[key]
        for c in ctl:
            await c.set_stop()
        return out
    finally:
        transport.close()
