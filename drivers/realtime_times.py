"""When a realtime run's samples were taken and its commands took effect, and the run on them.

A realtime run's ``t`` column is the deadline grid k·h, not when anything happened: the plant
moves in wall-clock time, sample k is taken when the SYNC reaches the robot (s_k) and the command
computed from it acts from when it arrives (a_k), so an interval is anything from 0.3 ms (the
catch-up burst after a stall) to the stall itself, and the torque of row k acts over
[a_k, a_{k+1}), not [t_k, t_{k+1}). Read on k·h, a 400 Hz run with stalls diagnosed as a
−38 % torque gain, a 30 ms lag and cogging (issue 12). Where the times come from:

* ``robot-events.csv`` (every realtime run of the virtual robot over a CAN bench): the robot's
  own clock, when it sampled and when each drive's command took effect
  (:func:`robot_event_trace`);
* otherwise the host's stamps in ``signals.csv`` (``sync_sent_s``, ``feedback_s``):
  s_k = sync_sent_k and a_k = feedback_k + the host's compute time (:func:`host_stamp_trace`).
  On the virtual bench these miss the robot's wake-up by 0.14 ms (90th percentile) to 0.6 ms
  (99th), too much for a diagnosis; on drives that sample on SYNC reception they are close.

:func:`on_real_times` rewrites a recording onto those times: t_k = s_k − s_0, and each
interval's torque is the mean of what acted in it, τ̄_k = (1/(s_{k+1} − s_k))∫_{s_k}^{s_{k+1}} τ_a,
with τ_a the command of row i from a_i on (per drive: joint 1's write lands first). The momentum
balance over an interval needs only that integral (docs/diagnosis.md, eq. (24) over intervals),
so the rows are exact for any loop order, and the ±1-row loop delay question does not arise.

Pure computation plus reading the event log; imports profiles and drivers.recording only.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from drivers.recording import Recording, RecordingError, reassemble
from profiles.timing_faults import MAX_FEEDBACK_BUDGET_S, TimingTrace, check_trace

ROBOT_EVENTS = "robot-events.csv"  # realtime: the virtual robot's own sample and command times
# Host time from a cycle's feedback to its command taking effect on the robot, used when only
# the host's stamps are known: the median of (robot sample→command) − (host SYNC→feedback),
# measured from robot-events.csv over virtual-slcan on the 2-core machine, per kind of run
# (`hil control` also computes the control law and writes control.csv before it sends).
COMPUTE_S = {"hil run": 2.1e-4, "hil control": 4.4e-4}
DEFAULT_COMPUTE_S = 2.1e-4


def robot_event_trace(path: Path, rows: int, *, bounded: bool = True) -> TimingTrace:
    """The trace of a run from the robot's event log (virtual_robot EventLog), on the robot's
    clock: sample times, the first and the last command write of each cycle, and every other
    time it integrated its plant to (period ticks, frames). ``bounded`` False: an interval
    past the longest feedback budget is taken (a gap, for analysis), not refused."""
    samples: dict[int, float] = {}
    first: dict[int, float] = {}
    last: dict[int, float] = {}
    steps: list[float] = []
    with open(path, newline="", errors="replace") as f:  # a stray byte: a row not parsed
        reader = csv.reader(f)
        try:
            if next(reader, None) != ["event", "n", "t"]:
                raise RecordingError(f"{path}: not a robot event log (header event,n,t)")
            for line, row in enumerate(reader, start=2):
                if len(row) != 3:
                    continue  # a torn last line
                try:
                    event, n, t = row[0], int(row[1]), float(row[2])
                except ValueError:
                    raise RecordingError(f"{path}:{line}: not an event,n,t row: {row}") from None
                if event == "advance":
                    steps.append(t)
                elif event == "sample":
                    samples.setdefault(n, t)
                elif event == "command" and n > 0:
                    # the command of cycle k arrives after sample k (n = k + 1 SYNCs so far):
                    # joint 1's write first, then joint 2's, when every drive has its new torque
                    first.setdefault(n - 1, t)
                    last[n - 1] = t
        except csv.Error as exc:
            raise RecordingError(f"{path}: not a robot event log ({exc})") from None
    missing = [k for k in range(rows) if k not in samples]
    if missing:
        raise RecordingError(f"{path}: no sample event for row {missing[0]} (of {rows})")
    sample = np.array([samples[k] for k in range(rows)])
    command = np.array([last.get(k, samples[k]) for k in range(rows)])
    first_command = np.array([first.get(k, samples[k]) for k in range(rows)])
    _checked(sample, first_command, command, str(path), bounded)
    grid = np.array(sorted(t for t in steps if t > sample[0]))
    return TimingTrace(
        sample, np.maximum.accumulate(command), first_command, grid if len(grid) else None
    )


def _checked(
    sample: np.ndarray, first: np.ndarray, command: np.ndarray, where: str, bounded: bool
) -> None:
    """:func:`profiles.timing_faults.check_trace` as a :class:`RecordingError` (a run's file);
    ``bounded`` False: no bound on an interval (module docstring of :func:`run_trace`)."""
    try:
        check_trace(sample, first, command, where, None if not bounded else MAX_FEEDBACK_BUDGET_S)
    except ValueError as exc:
        raise RecordingError(str(exc)) from None


def host_stamp_trace(rec: Recording, compute_s: float, *, bounded: bool = True) -> TimingTrace:
    """The trace from the host's stamps of every cycle (module docstring); ``bounded`` as for
    :func:`robot_event_trace`."""
    cols = rec.columns
    for name in ("sync_sent_s", "feedback_s"):
        if name not in cols:
            raise RecordingError(f"{rec.path}: no {name} column: not a realtime recording")
    sent, received = cols["sync_sent_s"], cols["feedback_s"]
    if not (np.all(np.isfinite(sent)) and np.all(np.isfinite(received))):
        raise RecordingError(f"{rec.path}: a sync_sent_s or feedback_s value is missing")
    sample = sent - sent[0]
    command = np.maximum(received - sent[0] + compute_s, sample)
    _checked(sample, command, command, f"{rec.path}: sync_sent_s, feedback_s", bounded)
    return TimingTrace(sample, np.maximum.accumulate(command))


class StampedRow(NamedTuple):
    """One row on the host's stamps: ``t`` its sample time s_k − s_0 (the SYNC sent), ``tau``
    the mean torque over [s_k, s_{k+1}), ``uncertainty_s`` how much longer its SYNC→feedback
    round trip took than the shortest so far. The robot sampled somewhere in the round trip;
    the shortest one is the bus and the device with nobody waiting, which shifts every stamp
    alike and so no interval: only the waiting beyond it (the robot woke late, or the host
    read late) leaves the sample time unknown."""

    t: float
    tau: np.ndarray
    uncertainty_s: float


class HostStampRows:
    """:func:`host_stamp_trace` then :func:`on_real_times` as a realtime run goes, for what
    updates during it (the online RLS, hil.identify.online): each cycle's host stamps and the
    torque of the cycle before give that row's real time, interval torque and how well its
    sample time is known (:class:`StampedRow`).

    Cycle k's feedback brings s_k (its SYNC sent, ``sent_at``) and its receive time; row k − 1's
    interval [s_{k−1}, s_k) is then closed and every command acting in it known (a_i ≥ s_i: none
    after row k − 1's), so its torque is the batch's τ̄_{k−1} (:func:`interval_torque` over the
    rows from the one acting at s_{k−1} on). a_i = received_i + ``compute_s`` + ``late_s``
    (what the host did in that cycle before its command went out beyond the loop's own, the
    online update itself: known online, not in signals.csv), never before s_i, nor before
    a_{i−1} (as :func:`host_stamp_trace`)."""

    def __init__(self, compute_s: float) -> None:
        self.compute_s = compute_s
        self.origin: float | None = None
        self.pending: tuple[float, float] | None = None  # (s, received) of the newest cycle
        self.shortest = np.inf  # the shortest SYNC→feedback round trip so far
        self.sample: list[float] = []  # rows from the one acting at the newest s on
        self.command: list[float] = []
        self.tau: list[np.ndarray] = []

    def push(
        self, sent_at: float, received_at: float, tau_before: Sequence[float], late_s: float = 0.0
    ) -> StampedRow | None:
        """Cycle k's stamps, row k − 1's torque and cycle k − 1's ``late_s``: row k − 1 on its
        real time (None at k = 0)."""
        if not (np.isfinite(sent_at) and np.isfinite(received_at)):
            raise ValueError("a cycle without host stamps (sent_at, received_at): not realtime")
        if self.origin is None:
            self.origin = sent_at
        s = sent_at - self.origin
        out = None
        if self.pending is not None:
            s_prev, received_prev = self.pending
            uncertainty = received_prev - s_prev - self.shortest
            a = max(received_prev + self.compute_s + late_s, s_prev, *self.command[-1:])
            self.sample.append(s_prev)
            self.command.append(a)
            self.tau.append(np.asarray(tau_before, dtype=float))
            taus = np.array([*self.tau, self.tau[-1]])  # row k (not known yet) acts from s_k on
            at_s = np.array([*self.sample, s])
            at_a = np.array([*self.command, s])
            mean = [interval_torque(taus[:, j], at_s, at_a)[-2] for j in range(taus.shape[1])]
            out = StampedRow(s_prev, np.array(mean), uncertainty)
            # rows before the one acting at s_k are no longer needed
            drop = int(np.searchsorted(self.command, s, side="right")) - 1
            if drop > 0:
                del self.sample[:drop], self.command[:drop], self.tau[:drop]
        self.pending = (s, received_at - self.origin)
        self.shortest = min(self.shortest, received_at - sent_at)
        return out

    @property
    def newest_s(self) -> float:
        """The newest cycle's sample time (the last row's t: its torque is its own command)."""
        if self.pending is None:
            raise ValueError("no cycle yet")
        return self.pending[0]


def run_trace(rec: Recording) -> tuple[TimingTrace, str] | None:
    """The trace of a realtime run directory (robot events if there, else the host's stamps)
    and where it came from; None for a recording that is not a realtime run of this bench.
    Read for analysis: a stall past the longest feedback budget (a host suspended, say) is kept
    as a long interval, which the reader then splits the run at as a gap; a replay, which would
    integrate over it, reads the trace bounded (hil.timing.replay)."""
    if rec.meta.get("mode") != "realtime" or rec.loop_delay != 0:
        return None
    events = Path(rec.path) / ROBOT_EVENTS
    if events.is_file() and rec.meta.get("protocol") != "serial":
        trace = robot_event_trace(events, len(rec), bounded=False)
        return trace, f"the robot's clock ({ROBOT_EVENTS})"
    if {"sync_sent_s", "feedback_s"} <= set(rec.columns):
        compute = COMPUTE_S.get(str(rec.meta.get("kind", "")), DEFAULT_COMPUTE_S)
        trace = host_stamp_trace(rec, compute, bounded=False)
        return trace, "the host's stamps (sync_sent_s, feedback_s)"
    return None


def interval_torque(tau: np.ndarray, sample_s: np.ndarray, command_s: np.ndarray) -> np.ndarray:
    """Mean applied torque over each [s_k, s_{k+1}) when row i's command acts from a_i on
    (one joint): τ̄_k = (F(s_{k+1}) − F(s_k)) / (s_{k+1} − s_k), F the integral of the
    piecewise-constant applied torque (linear between the a_i). Before a_0 the first command is
    taken as already acting; the last row keeps its own command (no interval follows it)."""
    a = np.maximum.accumulate(np.asarray(command_s, float))
    s = np.asarray(sample_s, float)
    tau = np.asarray(tau, float)
    knots = np.concatenate([[min(a[0], s[0]) - 1.0], a, [max(a[-1], s[-1]) + 1.0]])
    held = np.concatenate([[tau[0]], tau])  # the torque acting from each knot to the next
    F = np.concatenate([[0.0], np.cumsum(held * np.diff(knots))])
    at = np.interp(s, knots, F)
    out = tau.copy()
    out[:-1] = np.diff(at) / np.diff(s)
    return out


def on_real_times(rec: Recording, trace: TimingTrace, source: str) -> Recording:
    """``rec`` on the real sample times of ``trace``, each interval's torque the mean of the
    commands that acted in it (module docstring); the reader's checks (gaps, irregular
    intervals) redone on the new stamps, and a note saying what was done."""
    s = np.asarray(trace.sample_s, float)
    first = trace.first_command_s if trace.first_command_s is not None else trace.command_s
    switch = [np.asarray(first, float)] + [np.asarray(trace.command_s, float)] * (rec.n_joints - 1)
    columns = dict(rec.columns)
    columns["t"] = s - s[0]
    for j in range(rec.n_joints):
        columns[f"tau{j + 1}"] = interval_torque(rec.columns[f"tau{j + 1}"], s, switch[j])
    lag = np.asarray(trace.command_s, float) - s
    note = (
        f"realtime run read on {source}: sample intervals "
        f"{np.min(np.diff(s)) * 1e3:.3g} to {np.max(np.diff(s)) * 1e3:.3g} ms; each "
        f"interval's torque is the mean of the commands acting in it (a command took effect "
        f"{np.median(lag) * 1e3:.3g} ms after its sample, median; max {np.max(lag) * 1e3:.3g} ms)"
    )
    return reassemble(rec, columns, note)


__all__ = [
    "COMPUTE_S",
    "DEFAULT_COMPUTE_S",
    "ROBOT_EVENTS",
    "HostStampRows",
    "StampedRow",
    "host_stamp_trace",
    "interval_torque",
    "on_real_times",
    "robot_event_trace",
    "run_trace",
]
