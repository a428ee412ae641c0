"""What every offline simulation shares, whatever the arm (virtual_robot.simulate for the 2-DOF
closed-form plant, virtual_robot.urdf_plant for n joints): booting the drive models as a host
would, the open-loop rows (:func:`record_open_loop`: command, step, sample, record), booking the
drives' faults, describing them in meta.json, and the run's ending (:func:`run_open_loop`:
the recording, its meta.json totals, the result and the plot).

Imports drivers.recording, drivers.units, profiles.drive, virtual_robot.drive and
virtual_robot.stepping only.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from drivers.recording import RecordingWriter, plot_positions, read_signals
from drivers.units import position_to_rad, torque_to_permille, unwrap_int32
from profiles.drive import DriveProfile
from virtual_robot.drive import MODE_CST, DriveModel, State
from virtual_robot.stepping import Stepper

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
    # n-joint plant only: which RK4 step ran, "compiled" or "python", and why not compiled
    plant_kernel: dict[str, Any] | None = None

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
        } | ({"plant_kernel": self.plant_kernel} if self.plant_kernel else {})


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


def record_open_loop(
    rec: RecordingWriter,
    stepper: Stepper,
    drives: Sequence[DriveModel],
    profiles: Sequence[DriveProfile],
    commanded_Nm: Any,
    n_rows: int,
    progress: Callable[[float, float], None] | None = None,
) -> list[dict[str, Any]]:
    """Row k of ``commanded_Nm`` (torques, Nm) through the drives, open loop, one lockstep SYNC
    a row: the torques written at t_{k-1} are held over [t_{k-1}, t_k), the encoders sampled at
    t_k; each row ``t, q1..qn, tau1..taun, status1..statusn`` is written to ``rec``. Returns the
    drives' faults (each also said on stderr)."""
    h = stepper.period_s
    joints = tuple(
        (d, p.counts_per_rev, p.rated_torque_Nm, p.model)
        for d, p in zip(drives, profiles, strict=True)
    )
    counts = [d.position_counts for d in drives]
    enabled = State.OPERATION_ENABLED
    faults: list[dict[str, Any]] = []
    last_report = time.perf_counter()
    for k in range(n_rows):
        t = stepper.sync()
        commanded = commanded_Nm[k]
        q: list[float | int] = [t]  # the row: t, q1..qn, then tau1..taun, status1..statusn
        tau, status = [], []
        for i, (d, cpr, rated, model) in enumerate(joints):
            counts[i] = unwrap_int32(counts[i], d.position_counts)
            q.append(position_to_rad(counts[i], cpr))
            d.write_target_torque(torque_to_permille(commanded[i], rated), t)
            tau.append(d.torque_Nm)  # quantized, clamped, zero unless enabled: held over [t, t+h)
            if d.state is not enabled:
                collect_faults(d, model, t, faults)
            status.append(d.statusword)
        rec.write(q + tau + status)
        if progress is not None and time.perf_counter() - last_report > 1.0:
            last_report = time.perf_counter()
            progress(t + h, n_rows * h)
    stepper.advance()  # the last row's torque held over its period too
    return faults


def run_open_loop(
    out_dir: str | Path,
    meta: dict[str, Any],
    plant: Any,
    drives: Sequence[DriveModel],
    profiles: Sequence[DriveProfile],
    commanded_Nm: Any,
    n_rows: int,
    *,
    plot: bool = True,
    progress: Callable[[float, float], None] | None = None,
) -> SimulationResult:
    """The recording of an offline simulation, whatever the arm: ``n_rows`` rows of
    ``commanded_Nm`` through the enabled ``drives`` into ``plant`` (a 2-DOF ``Plant`` or an
    n-joint ``UrdfPlant``: ``steps``, ``stick_events``) in the one lockstep sequence
    (:class:`virtual_robot.stepping.Stepper`, :func:`record_open_loop`), written to ``out_dir``
    with ``meta`` (its ``period_s``) and the run's totals; positions.png when ``plot``."""
    h = meta["period_s"]
    n = len(drives)
    status = tuple(f"status{j}" for j in range(1, n + 1))
    started = time.perf_counter()
    cpu_started = time.process_time()
    with RecordingWriter(out_dir, meta, extra_columns=status, n_joints=n) as rec:
        stepper = Stepper(plant, drives, h)
        faults = record_open_loop(rec, stepper, drives, profiles, commanded_Nm, n_rows, progress)
        wall = time.perf_counter() - started
        cpu = time.process_time() - cpu_started
        rec.meta.update(
            wall_time_s=wall,
            cpu_time_s=cpu,
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
            title=f"virtual-robot simulate: {meta['robot']}, {meta['experiment']}, "
            f"effects {meta['effects']}",
        )
    return result
