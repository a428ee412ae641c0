"""The loop runner: one command per period over any :class:`~drivers.arm.Arm`.

It does not know the transport. Lockstep runs as fast as the link answers; realtime runs on
absolute wall-clock deadlines (t_open + k·h, so it does not drift) and records, for every cycle,
its deadline, when the SYNC/request went out and when the feedback came back.

Row k of the recording (DESIGN.md): t = k·h, q = the sample taken at the start of period k,
tau = the torque commanded for period k (as the driver quantized it), held until the next row.
"""

from __future__ import annotations

import gc
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers.arm import Arm, LinkError, SafetyStop, Sample
from drivers.protocol.cia402 import State, state_from_statusword
from drivers.recording import RecordingWriter

Command = Callable[[int, Sample], Sequence[float]]
TIMING_COLUMNS = ("deadline_s", "sync_sent_s", "feedback_s")
LATE_FRACTION = 0.1  # a SYNC sent later than 10 % of a period after its deadline: late release


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
) -> LoopResult:
    """Run ``n_periods`` cycles, writing one row per period as it completes.

    A dead link, a safety stop or Ctrl-C ends the run; every completed row is already on disk
    and the result says why it ended. The caller's ``with arm:`` block makes the drives safe.
    """
    # The cyclic garbage collector can pause for milliseconds at any allocation; in realtime it
    # runs between runs, not between deadlines (reference counting still frees as usual). No
    # gc.collect() here either: the drives are already enabled and their watchdog is counting.
    gc_was_enabled = gc.isenabled()
    if realtime:
        gc.disable()
    try:
        return _run(arm, command, n_periods, writer, realtime=realtime, progress=progress)
    finally:
        if realtime and gc_was_enabled:
            gc.enable()


def _run(
    arm: Arm,
    command: Command,
    n_periods: int,
    writer: RecordingWriter,
    *,
    realtime: bool,
    progress: Callable[[int, int], None] | None,
) -> LoopResult:
    h = arm.period_s
    started = time.perf_counter()
    last_report = started
    lateness: list[float] = []
    latency: list[float] = []
    rows = 0
    status, reason = "complete", None
    try:
        sample = arm.start()
        _check_enabled(arm, sample)
        t_start = arm.now()
        for k in range(n_periods):
            tau = command(k, sample)
            deadline = t_start + (k + 1) * h if realtime else None
            nxt = arm.cycle(tau, deadline=deadline)
            row: list[float | int] = [k * h, *sample.q_rad, *nxt.tau_Nm, *sample.status]
            if realtime:
                row += [sample.deadline, sample.sent_at, sample.received_at]
                if k > 0:
                    lateness.append(sample.sent_at - sample.deadline)
                latency.append(sample.received_at - sample.sent_at)
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
    except KeyboardInterrupt:
        status, reason = "interrupted", "interrupted by the user (Ctrl-C)"
    wall = time.perf_counter() - started
    timing = timing_statistics(h, lateness, latency) if realtime else {}
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
            codes = [f"0x{f.error_code:04X}" for f in arm.faults() if f.joint == joint]
            detail = f", error {', '.join(codes)}" if codes else ""
        except Exception as exc:
            detail = f" (error code unreadable: {exc})"
        name = state.name if state is not None else f"statusword 0x{sw:04X}"
        raise DriveFaultError(
            f"drive {joint + 1} left OPERATION ENABLED at t = {sample.t:.4f} s: "
            f"{name}{detail}; torque zero"
        )


def timing_statistics(
    period_s: float, lateness: Sequence[float], latency: Sequence[float]
) -> dict[str, Any]:
    """Deadline misses and latency percentiles (seconds) of a realtime run."""

    def pct(values: Sequence[float]) -> dict[str, float]:
        if not values:
            return {}
        a = np.asarray(values)
        return {
            "p50_ms": float(np.percentile(a, 50) * 1e3),
            "p99_ms": float(np.percentile(a, 99) * 1e3),
            "max_ms": float(a.max() * 1e3),
            "mean_ms": float(a.mean() * 1e3),
        }

    late = [x for x in lateness if x > LATE_FRACTION * period_s]
    # lateness[i] and latency[i + 1] belong to the same cycle (lateness starts at k = 1)
    overruns = [a + b for a, b in zip(lateness, latency[1:], strict=False) if a + b > period_s]
    return {
        "period_s": period_s,
        "cycles": len(latency),
        # deadline miss (overrun): the feedback, hence the period's command, came after the period
        # ended, so the torque for period k was not in place for it
        "deadline_misses": len(overruns),
        "deadline_miss_fraction": len(overruns) / len(lateness) if lateness else math.nan,
        # late release: the SYNC/request left more than 10 % of a period after its deadline
        "late_releases": len(late),
        "late_release_fraction": len(late) / len(lateness) if lateness else math.nan,
        "late_release_threshold_ms": LATE_FRACTION * period_s * 1e3,
        "sync_lateness": pct(lateness),
        "command_to_feedback_latency": pct(latency),
    }
