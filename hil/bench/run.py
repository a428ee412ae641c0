"""`hil run`: record one experiment over a bench (virtual or real), as the recording format says."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drivers.arm import Arm, Sample
from drivers.fault_injection import TimingFaultArm, with_host_faults
from drivers.links import open_arm
from drivers.protocol.cia402 import ERR_RPDO_TIMEOUT
from drivers.realtime_times import ROBOT_EVENTS
from drivers.recording import RecordingWriter, read_signals, write_run_mcap
from hil import __version__
from hil.bench.launch import VirtualRobotProcess
from hil.bench.loop import Command, LoopResult, extra_columns, run_loop
from hil.bench.scheduler import realtime_scheduling
from plots.positions import plot_positions
from profiles.bench import BenchProfile, bench_for_robot, load_bench
from profiles.experiment import check_duration, load_experiment


def timing_fault_meta(
    arm: Arm, bench: BenchProfile, effects: str | None, seed: int | None
) -> dict[str, Any]:
    """meta.json's ``timing_faults``: the profiles' faults and what the host injected (the
    virtual robot's counts are in virtual-robot.log); nothing if no fault is configured."""
    from profiles.effects import load_effects
    from profiles.timing_faults import combine

    effects_faults = None
    if bench.virtual and (effects or bench.effects):
        effects_faults = load_effects(effects or bench.effects).timing_faults
    faults = combine(bench.timing_faults, effects_faults)
    if faults is None:
        return {}
    doc: dict[str, Any] = {**faults.with_seed(seed).describe()}
    if isinstance(arm, TimingFaultArm):
        doc["host_injected"] = arm.describe()
    return {"timing_faults": doc}


class UsageError(ValueError):
    """A request the bench refuses (e.g. a real bench without --confirm-real)."""


def _progress(done: int, total: int) -> None:
    print(f"hil: {done}/{total} periods ({100 * done / total:.0f} %)", file=sys.stderr)


@dataclass
class BenchRun:
    """How a recording over a bench ended (meta.json holds the same)."""

    result: LoopResult
    reason: str | None
    realtime_factor: float | None
    traffic_log: str | None


def check_bench(
    bench_name: str, *, confirm_real: bool, effects: str | None, robot: str | None = None
) -> BenchProfile:
    """Load a bench profile, with ``robot`` in place of its own if given (and host limits for
    that arm, :func:`profiles.bench.bench_for_robot`), and refuse what it must not do (a real
    arm without confirmation)."""
    bench: BenchProfile = bench_for_robot(load_bench(bench_name), robot)
    if not bench.virtual and not confirm_real:
        raise UsageError(
            f"bench {bench.name} drives a real arm on {bench.channel}: pass "
            "--confirm-real once you have checked the limits in " + bench.source
        )
    if effects is not None and not bench.virtual:
        raise UsageError("--effects only applies to a virtual bench")
    if bench.virtual:
        check_virtual_robot_profiles(bench, effects)
    return bench


def check_virtual_robot_profiles(bench: BenchProfile, effects: str | None) -> None:
    """Load what the bench's virtual robot will load (its robot profile, its drives, the
    effects profile for that robot's joints) here, before anything is written or started: a
    bad profile is a one-line :class:`profiles.ProfileError` (exit 2) naming the file and the
    field, not a robot that fails to start (exit 3) with the cause only in its log, nor a file
    left in ``--out``. The robot checks them again when it loads them."""
    from profiles.drive import load_drive
    from profiles.effects import load_effects
    from profiles.robot import load_any_robot

    arm = load_any_robot(bench.robot)
    for drive in getattr(arm, "drives", None) or ():
        load_drive(drive)
    load_effects(effects or bench.effects).for_joints(arm.n_joints, arm.name)


def bench_meta(
    kind: str, bench: BenchProfile, channel: dict[str, Any], mode: str
) -> dict[str, Any]:
    """The first fields of meta.json: what ran, over which bench and link."""
    return {
        "kind": kind,
        "version": __version__,
        "bench": bench.name,
        "bench_profile": bench.source,
        "protocol": bench.protocol,
        "transport": bench.transport,
        "channel": channel or bench.channel,
        "virtual": bench.virtual,
        "mode": mode,
        "period_s": bench.period_s,
    }


def record_over_bench(
    bench: BenchProfile,
    out: Path,
    command: Command,
    n_periods: int,
    meta: Callable[[dict[str, Any]], dict[str, Any]],
    *,
    mode: str,
    effects: str | None = None,
    seed: int | None = None,
    progress: bool = True,
    realtime_policy: str = "auto",
    spin: bool = True,
    initial_q: Sequence[float] | None = None,
    clear_faults: bool = False,
) -> BenchRun:
    """Start the bench's virtual robot (if virtual), open the arm, run ``command`` for
    ``n_periods`` through the loop runner and record it in ``out``.

    ``meta(channel)`` gives meta.json's fields once the link's channel is known. The drives end
    at zero torque and disabled on every path; meta.json says how the run ended. Realtime:
    ``realtime_policy`` "auto" tries SCHED_FIFO and a memory lock (hil.bench.scheduler) before the
    link opens, "off" does not; ``spin=False``: the deadline wait sleeps, never spins.
    ``initial_q``: where a virtual robot's arm starts at rest (default 0 on every joint).
    ``clear_faults``: fault-reset drives that hold a fault before enabling them, each logged
    (a fault is otherwise refused: the run ends before any torque is commanded).
    """
    realtime = mode == "realtime"
    h = bench.period_s
    launcher = (
        VirtualRobotProcess(
            bench,
            mode=mode,
            effects=effects,
            seed=seed,
            log_path=out / "virtual-robot.log",
            event_log=out / ROBOT_EVENTS if realtime else None,  # for `hil replay`
            initial_q=initial_q,
        )
        if bench.virtual
        else contextlib.nullcontext()
    )
    with launcher as robot:
        channel = robot.channel if bench.virtual else {}
        # host-side timing faults of the bench profile, if any (drivers/fault_injection.py)
        arm = with_host_faults(
            open_arm(bench, channel, mode=mode, log_dir=out), bench.timing_faults, seed=seed
        )
        if bench.virtual:  # a dead robot process ends a wait for feedback at once
            arm.peer_alive = robot.alive
        policy = (
            realtime_scheduling(realtime_policy, peer_pid=robot.pid if bench.virtual else None)
            if realtime
            else contextlib.nullcontext()
        )
        with (
            policy as scheduling,
            RecordingWriter(
                out,
                meta(channel),
                extra_columns=extra_columns(arm.n_joints, realtime),
                flush_every=1 if realtime else 50,
                n_joints=arm.n_joints,
            ) as writer,
        ):
            with arm:
                if clear_faults:
                    clear_drive_faults(arm)
                arm.enable()
                result = run_loop(
                    arm,
                    command,
                    n_periods,
                    writer,
                    realtime=realtime,
                    progress=_progress if progress else None,
                    scheduling=scheduling,
                    spin=spin,
                )
            reason = result.reason
            factor = n_periods * h / result.wall_time_s if result.wall_time_s else None
            if bench.virtual and result.status == "failed" and not robot.alive():
                reason = f"virtual robot (pid {robot.pid}) is gone; {reason}"
            elif realtime and result.status == "failed":
                reason = _with_stall_advice(reason, bench, arm, scheduling)
            writer.close(
                result.status,
                reason=reason,
                timing=result.timing,
                wall_time_s=result.wall_time_s,
                realtime_factor=factor,
                link=vars(arm.stats),
                traffic_log=arm.traffic_log(),
                **timing_fault_meta(arm, bench, effects, seed),
            )
    return BenchRun(result, reason, factor, arm.traffic_log())


def clear_drive_faults(arm: Arm) -> None:
    """Fault reset of every drive in FAULT, each fault said on stderr first (``--clear-faults``)."""
    faults = arm.faults()
    for f in faults:
        print(
            f"hil run: clearing joint {f.joint + 1}'s fault 0x{f.error_code:04X} ({f.text}) "
            "(--clear-faults)",
            file=sys.stderr,
            flush=True,
        )
    if faults:
        arm.clear_faults()


# the pty transports: every write crosses a kernel worker (tty flip buffer) at normal priority
PTY_TRANSPORTS = ("slcan", "serial", "fdcanusb")


def stalled(reason: str | None, arm: Arm) -> bool:
    """Did a realtime run end because the link was *late* (feedback budget, drive watchdog),
    not because something is gone or refused?"""
    if not reason:
        return False
    watchdog = f"0x{ERR_RPDO_TIMEOUT:04X}" in reason  # the drives' command watchdog (EMCY)
    return watchdog or (arm.stats.timeouts > 0 and "gone" not in reason.split(":")[0])


def _with_stall_advice(reason: str | None, bench: BenchProfile, arm: Arm, scheduling: Any) -> str:
    """``reason`` and, for a run the link's lateness ended, what was seen and what to do."""
    text = reason or "failed"
    if not stalled(reason, arm):
        return text
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    seen = (
        f"{arm.stats.late_feedback} late feedbacks before it, the longest "
        f"{arm.stats.max_feedback_wait_s * 1e3:.0f} ms; load average {load:.1f} on "
        f"{os.cpu_count()} CPUs"
    )
    pty = bench.virtual and bench.transport in PTY_TRANSPORTS
    why = (
        "a pty's data crosses a kernel worker at normal priority, which SCHED_FIFO does not "
        "cover and CPU-bound jobs delay (docs/jitter.md, under load)"
        if pty
        else "the host or the link stalled"
    )
    todo = [
        f"a lower --rate (now {1 / bench.period_s:g} Hz)",
        "--mode lockstep",
        "fewer CPU-bound jobs beside it, or those at nice 19",
    ]
    if pty:  # a socket wakes its reader directly (docs/jitter.md: pty vs socket round trips)
        todo.append("a socket transport (--bench virtual-socketcand)")
    if getattr(scheduling, "realtime_refused", None):
        todo.append("realtime priority (docs/jitter.md, Privileges)")
    todo.append("a longer feedback_budget_s and drive watchdog_s (docs/faults.md)")
    return f"{text} [late, not gone: {seen}; {why}. Try {', '.join(todo[:-1])} or {todo[-1]}]"


def _joints_of(bench: BenchProfile) -> int:
    """Joints of the bench's robot: one host limit per joint (bench_for_robot checked it)."""
    return len(bench.torque_limit_Nm)


def run_experiment(
    bench_name: str,
    experiment_name: str,
    out_dir: str | Path,
    *,
    duration_s: float | None = None,
    mode: str | None = None,
    effects: str | None = None,
    seed: int | None = None,
    confirm_real: bool = False,
    plot: bool = True,
    progress: bool = True,
    observer: Callable[[int, Sample], None] | None = None,
    robot: str | None = None,
    clear_faults: bool = False,
    mcap: bool = False,
) -> dict[str, Any]:
    """Run an open-loop experiment over a bench; returns the summary that `--json` prints.
    ``mcap``: also write the recording as ``run.mcap`` beside signals.csv (ROS 2 JointState
    messages, JSON; :func:`drivers.recording.write_run_mcap`).

    ``robot``: a robot profile in place of the bench's (its drives on the bus, the virtual
    robot launched with it). ``clear_faults``: as :func:`record_over_bench`.
    ``observer(k, sample)``, if given, sees every period's feedback as it arrives (e.g. online
    identification); sample k carries q_k and the quantized torque of period k − 1."""
    bench = check_bench(bench_name, confirm_real=confirm_real, effects=effects, robot=robot)
    experiment = load_experiment(experiment_name)
    experiment.check_joints(_joints_of(bench), bench.robot)
    mode = mode or bench.mode
    h = bench.period_s
    duration = experiment.duration_s if duration_s is None else duration_s
    n = check_duration(duration, h)
    torques = experiment.torque_rows(h, n)  # computed a block at a time
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)

    def command(k: int, sample: Sample) -> list[float]:
        if observer is not None:
            observer(k, sample)
        return torques[k]

    def meta(channel: dict[str, Any]) -> dict[str, Any]:
        fields = {
            **bench_meta("hil run", bench, channel, mode),
            "duration_s": n * h,
            "experiment": experiment.name,
            "experiment_profile": experiment.source,
            "effects": effects,
            "seed": seed,
            "robot": bench.robot,
        }
        if abs(experiment.period_s - h) > 1e-12:
            fields["note"] = f"experiment period {experiment.period_s} s; the bench's {h} s is used"
        return fields

    run = record_over_bench(
        bench,
        out,
        command,
        n,
        meta,
        mode=mode,
        effects=effects,
        seed=seed,
        progress=progress,
        # the arm starts where `virtual-robot simulate` starts it; a robot at rest at 0 is
        # the default, so the flag is left out for it (the 2-DOF benches' launch unchanged)
        initial_q=experiment.initial_q_rad if any(experiment.initial_q_rad) else None,
        clear_faults=clear_faults,
    )
    result, reason, factor = run.result, run.reason, run.realtime_factor
    summary = {
        "out_dir": str(out),
        "signals": str(out / "signals.csv"),
        "rows": result.rows,
        "status": result.status,
        "reason": reason,
        "bench": bench.name,
        "mode": mode,
        "wall_time_s": round(result.wall_time_s, 4),
        "realtime_factor": round(factor, 2) if factor else None,
        "timing": result.timing,
        "traffic_log": run.traffic_log,
        "plot": None,
    }
    if mcap:
        summary["mcap"] = str(write_run_mcap(out)) if result.rows > 0 else None
    if plot and result.rows > 1:
        summary["plot"] = str(
            plot_positions(
                read_signals(out),
                out / "positions.png",
                title=f"hil run: {bench.name} ({mode}), {experiment.name}",
            )
        )
    return summary


__all__ = [
    "BenchRun",
    "UsageError",
    "check_bench",
    "record_over_bench",
    "run_experiment",
]
