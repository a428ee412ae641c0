"""The loop runner: one command per period over any :class:`~drivers.arm.Arm`.

It does not know the transport. Lockstep runs as fast as the link answers; realtime runs on
absolute wall-clock deadlines (t_open + k·h, so it does not drift) and records, for every cycle,
its deadline, when the SYNC/request went out and when the feedback came back. The waiting is
:class:`hil.bench.scheduler.DeadlineScheduler`'s (sleep, then spin), installed in the arm for the
run;
the OS policy (SCHED_FIFO, memory lock) is acquired by the caller before the link opens
(:func:`hil.bench.scheduler.realtime_scheduling`) and reported with the timing statistics
(:mod:`hil.bench.timing_stats`).

Row k of the recording (docs/design.md): t = k·h, q = the sample taken at the start of period k,
tau = the torque commanded for period k (as the driver quantized it), held until the next row.
"""

from __future__ import annotations

import gc
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from drivers.arm import Arm, LinkError, SafetyStop, Sample
from drivers.process import interrupt_reason
from drivers.protocol.cia402 import State, state_from_statusword
from drivers.recording import RecordingWriter
from hil.bench.scheduler import DeadlineScheduler, Scheduling

# LATE_FRACTION, timing_statistics: moved there, importable here
from hil.bench.timing_stats import (
    LATE_FRACTION,  # noqa: F401
    loop_timing,
    timing_statistics,  # noqa: F401
)

Command = Callable[[int, Sample], Sequence[float]]
TIMING_COLUMNS = ("deadline_s", "sync_sent_s", "feedback_s")


@dataclass
class LoopResult:
    rows: int
    status: str  # complete | failed | interrupted | safety_stop
    reason: str | None = None
    timing: dict[str, Any] = field(default_factory=dict)
    wall_time_s: float = 0.0


def extra_columns(n_joints: int, realtime: bool) -> tuple[str, ...]:
    cols = tuple(f"status{j + 1}" for j in range(n_joints))
    return cols + TIMING_COLUMNS if realtime else cols


def run_loop(
    arm: Arm,
    command: Command,
    n_periods: int,
    writer: RecordingWriter,
    *,
    realtime: bool,
    progress: Callable[[int, int], None] | None = None,
    scheduling: Scheduling | None = None,
    scheduler: DeadlineScheduler | None = None,
    spin: bool = True,
) -> LoopResult:
    """Run ``n_periods`` cycles, writing one row per period as it completes.

    A dead link, a safety stop or Ctrl-C ends the run; every completed row is already on disk
    and the result says why it ended. The caller's ``with arm:`` block makes the drives safe.
    Realtime: ``scheduler`` (default a :class:`DeadlineScheduler` on ``arm.now``) waits for the
    deadlines; ``scheduling`` (what the caller got from the OS) goes into the timing report.
    ``spin``: whether the default scheduler spins before a deadline (False: sleeps to it).
    """
    # The cyclic garbage collector can pause for milliseconds at any allocation; in realtime it
    # runs between runs, not between deadlines (reference counting still frees as usual). No
    # gc.collect() here either: the drives are already enabled and their watchdog is counting.
    gc_was_enabled = gc.isenabled()
    if not realtime:
        return _run(arm, command, n_periods, writer, realtime=False, progress=progress)
    gc.disable()
    if scheduler is None:
        scheduler = DeadlineScheduler(arm.period_s, clock=arm.now, spin=spin)
    arm.deadline_waiter = scheduler.wait_until
    try:
        result = _run(
            arm, command, n_periods, writer, realtime=True, progress=progress, scheduler=scheduler
        )
    finally:
        arm.deadline_waiter = None
        if gc_was_enabled:
            gc.enable()
    result.timing["scheduler"] = {
        **(scheduling.as_dict() if scheduling is not None else {"requested": "not set"}),
        **scheduler.report(),
    }
    return result


def _run(
    arm: Arm,
    command: Command,
    n_periods: int,
    writer: RecordingWriter,
    *,
    realtime: bool,
    progress: Callable[[int, int], None] | None,
    scheduler: DeadlineScheduler | None = None,
) -> LoopResult:
    h = arm.period_s
    started = time.perf_counter()
    last_report = started
    deadlines: list[float] = []
    releases: list[float] = []
    feedbacks: list[float] = []
    rows = 0
    status, reason = "complete", None
    try:
        sample = arm.start()
        _check_enabled(arm, sample)
        if scheduler is not None:
            scheduler.start(arm.now())  # deadlines t_0 + k·h from here
        for k in range(n_periods):
            tau = command(k, sample)
            deadline = scheduler.deadline(k + 1) if scheduler is not None else None
            nxt = arm.cycle(tau, deadline=deadline)
            row: list[float | int] = [k * h, *sample.q_rad, *nxt.tau_Nm, *sample.status]
            if realtime:
                row += [sample.deadline, sample.sent_at, sample.received_at]
                deadlines.append(sample.deadline)
                releases.append(sample.sent_at)
                feedbacks.append(sample.received_at)
            writer.write(row)
            rows += 1
            sample = nxt
            _check_enabled(arm, sample)
            if progress is not None and time.perf_counter() - last_report > 1.0:
                last_report = time.perf_counter()
                progress(k + 1, n_periods)
    except SafetyStop as exc:
        status, reason = "safety_stop", str(exc)
    except (DriveFaultError, LinkError) as exc:
        status, reason = "failed", str(exc)
    except KeyboardInterrupt:  # Ctrl-C, SIGTERM or SIGHUP (drivers.process)
        status, reason = "interrupted", interrupt_reason()
    wall = time.perf_counter() - started
    timing: dict[str, Any] = {}
    if realtime:
        timing = loop_timing(h, deadlines, releases, feedbacks, lost_feedback=arm.stats.timeouts)
        # feedback later than one period but within the bench's feedback budget: timing events
        timing["late_feedback"] = arm.stats.late_feedback
        timing["max_feedback_wait_s"] = arm.stats.max_feedback_wait_s
        timing["feedback_budget_s"] = arm.feedback_budget_s
    return LoopResult(rows, status, reason, timing, wall)


class DriveFaultError(RuntimeError):
    """A drive left OPERATION ENABLED during a run (fault, quick stop, disabled)."""


def _check_enabled(arm: Arm, sample: Sample) -> None:
    """Stop the run the period a drive is no longer enabled, naming the drive and its fault."""
    for joint, sw in enumerate(sample.status):
        state = state_from_statusword(sw)
        if state is State.OPERATION_ENABLED:
            continue
        detail = ""
        try:
            codes = [
                f"0x{f.error_code:04X}" + (f" ({f.text})" if f.text else "")
                for f in arm.faults()
                if f.joint == joint
            ]
            detail = f", error {', '.join(codes)}" if codes else ""
        except Exception as exc:
            detail = f" (error code unreadable: {exc})"
        name = state.name if state is not None else f"statusword 0x{sw:04X}"
        raise DriveFaultError(
            f"drive {joint + 1} left OPERATION ENABLED at t = {sample.t:.4f} s: "
            f"{name}{detail}; torque zero"
        )


__all__ = [
    "TIMING_COLUMNS",
    "DriveFaultError",
    "LoopResult",
    "run_loop",
]
