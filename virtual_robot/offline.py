"""What every offline simulation shares, whatever the arm (virtual_robot.simulate for the 2-DOF
closed-form plant, virtual_robot.urdf_plant for n joints): booting the drive models as a host
would, the open-loop rows (:func:`record_open_loop`: command, step, sample, record), booking the
drives' faults, describing them in meta.json, and the run's ending (:func:`run_open_loop`:
the recording, its meta.json totals, the result and the plot); for drives with their own loop
(virtual_robot.mit_simulate, virtual_robot.odrive_simulate, virtual_robot.moteus_simulate) their
rows and the recording of their offline run
(:func:`drive_loop_rows`, :func:`record_drive_loop`).

Imports drivers.recording, drivers.units, profiles.drive (profiles.experiment and
profiles.robot for type hints), virtual_robot (its version), virtual_robot.drive and
virtual_robot.stepping only.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.recording import RecordingWriter, read_signals
from drivers.units import (
    position_to_rad,
    torque_to_permille,
    torques_to_permille,
    unwrap_int32,
    wrap_int32,
)
from plots.positions import plot_positions
from profiles.drive import DriveProfile, load_drive
from virtual_robot import __version__
from virtual_robot.drive import CW_HALT, MODE_CST, DriveModel, State
from virtual_robot.stepping import Stepper

if TYPE_CHECKING:
    from profiles.effects import EffectsProfile
    from profiles.experiment import ExperimentProfile, TorqueRows
    from profiles.robot import RobotProfile, UrdfRobotProfile

ENABLE_SEQUENCE = (0x06, 0x07, 0x0F)  # shutdown, switch on, enable operation (CiA 402)
SW_ENABLED = 0x0637  # what a drive with its own loop that answers is recorded as (drivers.mit_arm)


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


def offline_rows(experiment: ExperimentProfile, duration_s: float | None) -> tuple[float, int]:
    """(h, rows) of an offline run: the experiment's period and ``duration_s`` (default the
    experiment's) in whole periods, at least one."""
    h = experiment.period_s
    duration = experiment.duration_s if duration_s is None else duration_s
    return h, max(1, round(duration / h))


def simulation_meta(
    robot: RobotProfile | UrdfRobotProfile,
    experiment: ExperimentProfile,
    effects: EffectsProfile | str,
    *,
    period_s: float,
    n_rows: int,
    drives: list[dict[str, Any]],
    about_robot: dict[str, Any] | None = None,
    about_mode: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """meta.json of an offline simulation (``virtual-robot simulate``), in one order for every
    kind of arm: ``effects`` the profile run (name, source, the effects it enables) or only its
    name (drives with their own loop); ``about_robot`` keys after the robot's (URDF, joints),
    ``about_mode`` after the mode (the drives' protocol)."""
    if isinstance(effects, str):
        effects_keys: dict[str, Any] = {"effects": effects}
    else:
        effects_keys = {
            "effects": effects.name,
            "effects_profile": effects.source,
            "effects_enabled": list(effects.enabled),
        }
    return {
        "kind": "simulate",
        "version": __version__,
        "robot": robot.name,
        "robot_profile": robot.source,
        **(about_robot or {}),
        **effects_keys,
        "experiment": experiment.name,
        "experiment_profile": experiment.source,
        "mode": "offline",
        **(about_mode or {}),
        "period_s": period_s,
        "duration_s": n_rows * period_s,
        "seed": None,
        "drives": drives,
    }


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
    drives' faults (each also said on stderr).

    While every drive applies torque and none can fault, the rows go by :func:`_held_rows`
    (the drives' arithmetic on a block of rows at once); from the first row where one might
    (overspeed, a non-finite value) on, row by row through the drive models."""
    h = stepper.period_s
    joints = tuple(
        (d, p.counts_per_rev, p.rated_torque_Nm, p.model)
        for d, p in zip(drives, profiles, strict=True)
    )
    counts = [d.position_counts for d in drives]
    enabled = State.OPERATION_ENABLED
    faults: list[dict[str, Any]] = []
    last_report = [time.perf_counter()]

    def report(t: float) -> None:
        if progress is not None and time.perf_counter() - last_report[0] > 1.0:
            last_report[0] = time.perf_counter()
            progress(t + h, n_rows * h)

    start, t = 0, None
    if _rows_can_be_held(stepper, drives):
        start, t, counts = _held_rows(rec, stepper, drives, profiles, commanded_Nm, n_rows, report)
    for k in range(start, n_rows):
        if t is None:
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
        report(t)
        t = None
    stepper.advance()  # the last row's torque held over its period too
    return faults


# Rows integrated between two writes of :func:`_held_rows` (1 s at 400 Hz)
HELD_BLOCK = 400
# |position| below this many encoder counts: the counts are exact in int64 and float64
_COUNTS_EXACT = 2.0**52


def _rows_can_be_held(stepper: Stepper, drives: Sequence[DriveModel]) -> bool:
    """Whether :func:`_held_rows` gives the row-by-row result: lockstep without timing faults,
    every drive applying torque, and its watchdog not tripping between a sample and the write
    that follows it (more than one period); and whether it pays: only for a plant that takes
    many periods in one call (``advance_periods``, the n-joint plant). The 2-DOF plant's rows
    stay row by row: with two drives the drive models cost less than the block's array work
    (measured: 65-70x against 50-62x real time per CPU second on the loaded VM)."""
    return (
        hasattr(stepper.plant, "advance_periods")
        and stepper.timing is None
        and stepper.lockstep
        and all(
            d.state is State.OPERATION_ENABLED
            and not d.controlword & CW_HALT
            and d.watchdog_periods > 1
            for d in drives
        )
    )


def _held_rows(
    rec: RecordingWriter,
    stepper: Stepper,
    drives: Sequence[DriveModel],
    profiles: Sequence[DriveProfile],
    commanded_Nm: Any,
    n_rows: int,
    report: Callable[[float], None],
) -> tuple[int, float | None, list[int]]:
    """The rows of :func:`record_open_loop` while every drive applies torque and none faults,
    a block at a time: the plant integrated under the torques the drives would hold
    (:meth:`DriveModel.enabled_outputs` of the commanded per-mille) by
    :meth:`Stepper.advance_held` (the n-joint plant's kernel takes the periods between stick
    events in one call), its measured q and q̇ kept at each sample; the encoder counts,
    positions and status words of the block after, by the drives' own arithmetic on arrays
    (:meth:`DriveModel.encoder_counts`); the rows written as the drive models would have
    produced them, byte for byte. It stops at the first
    sample where a drive might leave that state (|q̇| above its overspeed threshold, a
    non-finite or huge q or q̇, a non-finite command): the drives are brought to the state the
    rows before left them in (their last two samples and writes, replayed), and that row is
    the row-by-row path's. Returns (that row or ``n_rows``, its sample time t_k if the plant is
    already there, else None; the unbounded counts of the last row written)."""
    n = len(drives)
    rated = np.array([p.rated_torque_Nm for p in profiles])
    max_speed = np.array([p.max_velocity_rad_s for p in profiles])
    max_position = np.array([_COUNTS_EXACT * d.profile.rad_per_count for d in drives])
    per_rev = np.array([2.0 * math.pi / p.counts_per_rev for p in profiles])  # position_to_rad
    counts = np.array([d.position_counts for d in drives], dtype=np.int64)  # unwrapped so far
    raw = counts.copy()  # the last INT32 readings
    held_last: np.ndarray | None = None  # the torques the drives hold since the last row
    bounds = (max_speed, max_position)
    h = stepper.period_s
    replay: list[tuple[float, list[float], list[float], list[int]]] = []  # the last two rows
    k, t_stop = 0, None
    while k < n_rows and t_stop is None:
        stop = min(n_rows, k + HELD_BLOCK)
        commanded = np.array([commanded_Nm[j] for j in range(k, stop)], dtype=float)
        finite = np.isfinite(commanded).all(axis=1)
        if not finite.all():  # the row-by-row path says which torque, in one line
            stop = k + int(np.argmin(finite))
            commanded = commanded[: stop - k]
            if stop == k:
                break
        permille = np.column_stack(
            [torques_to_permille(commanded[:, i], rated[i]) for i in range(n)]
        )
        outputs = [drives[i].enabled_outputs(permille[:, i]) for i in range(n)]
        tau = np.column_stack([o[0] for o in outputs])
        status = np.column_stack([o[1] for o in outputs])
        q_rows = np.empty((stop - k, n))
        dq_rows = np.empty((stop - k, n))
        first = 0  # rows of the block without a period before them (SYNC 0)
        try:
            if stepper.syncs == 0:  # SYNC 0 samples the plant as it starts
                t = stepper.advance()
                q_rows[0], dq_rows[0] = stepper.plant.measured_q, stepper.plant.dq
                if not _inside(q_rows[0], dq_rows[0], bounds):
                    t_stop = t
                    break
                stepper.sampled(t, drives=False)
                first = 1
            # the period before row r holds row r − 1's torques
            held = tau[:-1] if held_last is None else np.vstack([held_last, tau[:-1]])
            _, inside = stepper.advance_held(
                np.ascontiguousarray(held), bounds, q_rows[first:], dq_rows[first:]
            )
            if not inside:
                t_stop = stepper.t
        finally:  # the rows integrated so far are written, whatever happened after
            m = stepper.syncs - k
            times = [r * h for r in range(k, k + m)]  # t_r = r·h, as Stepper.advance takes it
            if m:
                raw_block = wrap_int32(
                    np.column_stack([d.encoder_counts(q_rows[:m, i]) for i, d in enumerate(drives)])
                )
                steps = wrap_int32(np.diff(raw_block, axis=0, prepend=raw[None, :]))
                unwrapped = counts + np.cumsum(steps, axis=0)  # unwrap_int32, row after row
                positions = (unwrapped + 0.5) * per_rev  # the count's centre
                for row in zip(
                    times, positions.tolist(), tau[:m].tolist(), status[:m].tolist(), strict=True
                ):
                    rec.write([row[0], *row[1], *row[2], *row[3]])
                counts, raw = unwrapped[-1], raw_block[-1]
                replay = (replay + [
                    (times[j], q_rows[j].tolist(), dq_rows[j].tolist(), permille[j].tolist())
                    for j in range(max(0, m - 2), m)
                ])[-2:]  # fmt: skip
                report(times[-1])
                held_last = tau[m - 1]
        k += m
    # the drives as the rows before left them: the last two samples and target writes
    for t_j, q_j, dq_j, permille_j in replay:
        for i, d in enumerate(drives):
            d.update(t_j, q_j[i], dq_j[i], True)
            d.write_target_torque(permille_j[i], t_j)
    if t_stop is not None:
        stepper.sampled(t_stop)
    return k, t_stop, counts.tolist()


def _inside(q: np.ndarray, dq: np.ndarray, bounds: tuple[np.ndarray, np.ndarray]) -> bool:
    """|q̇| within the overspeed thresholds and |q| within exact counts, joint by joint."""
    return bool((np.abs(dq) <= bounds[0]).all() and (np.abs(q) <= bounds[1]).all())


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


def drive_loop_rows(
    robot: RobotProfile | UrdfRobotProfile, experiment: ExperimentProfile, duration_s: float | None
) -> tuple[list[DriveProfile], float, int, TorqueRows]:
    """What an offline run of drives with their own loop steps: the robot's drive profiles (the
    experiment checked to drive as many joints), the period h, the number of rows (``duration_s``
    or the experiment's, at least one) and the experiment's torque of each row, read in order."""
    drives = [load_drive(name) for name in robot.drives]
    experiment.check_joints(len(drives), robot.name)
    h, n_rows = offline_rows(experiment, duration_s)
    return drives, h, n_rows, experiment.torque_rows(h, n_rows)


def record_drive_loop(
    out_dir: str | Path,
    *,
    robot: RobotProfile | UrdfRobotProfile,
    experiment: ExperimentProfile,
    effects_name: str,
    protocol: str,
    drives: list[dict[str, Any]],
    period_s: float,
    n_rows: int,
    rows: Iterable[tuple[Sequence[float], Sequence[float]]],
    wall_s: float,
    plant_steps: int,
) -> SimulationResult:
    """The recording of an offline run of drives with their own loop (``protocol`` "mit",
    "odrive" or "moteus"): ``robot`` and ``experiment`` the profiles run, ``drives``
    meta.json's drive list, ``rows`` the ``n_rows`` pairs (q, tau) at t = k ``period_s``, each
    drive recorded as enabled (SW_ENABLED); ``wall_s`` the run's wall time."""
    h = period_s
    meta = simulation_meta(
        robot,
        experiment,
        effects_name,
        period_s=h,
        n_rows=n_rows,
        drives=drives,
        about_mode={"protocol": protocol},
    )
    n = len(drives)
    status = tuple(f"status{j}" for j in range(1, n + 1))
    with RecordingWriter(out_dir, meta, extra_columns=status, n_joints=n) as rec:
        for k, (q, tau) in enumerate(rows):
            rec.write([k * h, *q, *tau, *([SW_ENABLED] * n)])
        rec.meta.update(wall_time_s=wall_s, realtime_factor=n_rows * h / wall_s if wall_s else None)
    return SimulationResult(Path(out_dir), n_rows, wall_s, n_rows * h, plant_steps)
