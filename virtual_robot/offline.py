"""What every offline simulation shares, whatever the arm (virtual_robot.simulate for the 2-DOF
closed-form plant, virtual_robot.urdf_plant for n joints): booting the drive models as a host
would, booking their faults, describing them in meta.json, and the result.

Imports profiles.drive and virtual_robot.drive only.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from profiles.drive import DriveProfile
from virtual_robot.drive import MODE_CST, DriveModel, State

ENABLE_SEQUENCE = (0x06, 0x07, 0x0F)  # shutdown, switch on, enable operation (CiA 402)


@dataclass
class SimulationResult:
    out_dir: Path
    rows: int
    wall_time_s: float
    simulated_s: float
    plant_steps: int
    faults: list[dict[str, Any]] = field(default_factory=list)
    plot: Path | None = None

    @property
    def realtime_factor(self) -> float:
        return self.simulated_s / self.wall_time_s if self.wall_time_s > 0 else math.inf

    def summary(self) -> dict[str, Any]:
        return {
            "out_dir": str(self.out_dir),
            "signals": str(self.out_dir / "signals.csv"),
            "plot": str(self.plot) if self.plot else None,
            "rows": self.rows,
            "simulated_s": self.simulated_s,
            "wall_time_s": round(self.wall_time_s, 4),
            "realtime_factor": round(self.realtime_factor, 1),
            "plant_steps": self.plant_steps,
            "faults": self.faults,
        }


def enable_drives(
    profiles: Sequence[DriveProfile], period_s: float, q: Sequence[float], dq: Sequence[float]
) -> list[DriveModel]:
    """One drive model per joint, booted and enabled exactly as a host would over the bus."""
    drives = [DriveModel(p, period_s=period_s) for p in profiles]
    for i, d in enumerate(drives):
        d.update(0.0, q[i], dq[i])
        d.write_mode(MODE_CST)
        for cw in ENABLE_SEQUENCE:
            d.write_controlword(cw, 0.0)
        if d.state is not State.OPERATION_ENABLED:
            raise RuntimeError(f"drive {profiles[i].model} did not enable (state {d.state.name})")
    return drives


def collect_faults(drive: DriveModel, model: str, t: float, faults: list[dict[str, Any]]) -> None:
    """Book a faulted drive's emergency messages (its torque is zeroed) and say so on stderr."""
    for e in drive.pop_emcy():
        faults.append({"t": t, "drive": model, "error_code": f"0x{e.error_code:04X}"})
        print(
            f"virtual-robot: drive {model} fault 0x{e.error_code:04X} "
            f"at t = {t:.4f} s; torque zeroed",
            file=sys.stderr,
        )


def drive_meta(profiles: Sequence[DriveProfile]) -> list[dict[str, Any]]:
    """The drives as meta.json lists them."""
    return [
        {
            "model": p.model,
            "counts_per_rev": p.counts_per_rev,
            "rated_torque_Nm": p.rated_torque_Nm,
            "max_torque_Nm": p.max_torque_Nm,
        }
        for p in profiles
    ]
