"""Timing faults on the virtual robot's side: when a command takes effect, when a sample is taken.

The virtual robot applies a late command late: its physics runs on the command's arrival time
(:meth:`Plant.command` with ``deliver_at``). :class:`RobotTiming` says what that time is.

* **realtime** (robot time = its clock): a command from the host takes effect ``latency + J``
  after it arrives (J the jitter of that frame, see profiles/timing_faults.py); command frames
  are dropped with ``drop_probability`` (the drive holds its previous torque and its command
  watchdog counts the missed period); feedback frames leave ``feedback_delay_s`` late.
* **lockstep** (robot time = simulated time): every fault is imposed in simulated time, so a
  faulted lockstep run is still deterministic. The command of cycle k (sent after sample k at
  t_k) takes effect at a_k = t_k + d_k with d_k the sum of the latencies, feedback delays and
  jitters of both sides (a host-side delay in lockstep can only be imposed here: the host does
  not own simulated time); a late feedback only delays the command computed from it, so it
  adds to d_k too. Command frames do not overtake each other: a_k >= a_{k-1}. Host-side drops
  and stalls are the host's own (drivers/fault_injection.py).
* **trace** (lockstep): sample n is taken at ``sample_s[n]`` and the command of cycle k takes
  effect at ``command_s[k]``, both from a timing trace (hil/timing/replay.py writes one from a
  recorded realtime run), instead of n·h and t_k.

Seeded: the jitter and drop draws of each side come from their own numpy streams of the seed,
so changing a drop rate does not change the jitter sequence.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from profiles.timing_faults import (
    STREAM_HOST_JITTER,
    STREAM_ROBOT_DROP,
    STREAM_ROBOT_JITTER,
    TimingFaults,
    draw_jitter,
    read_trace,
    stream,
)


@dataclass
class RobotTimingStats:
    commands: int = 0
    dropped_commands: int = 0
    delayed_feedback: int = 0
    max_delay_s: float = 0.0
    delays_s: list[float] = field(default_factory=list)  # lockstep: d_k of every cycle


class RobotTiming:
    """When commands take effect and samples are taken, under ``faults`` (module docstring)."""

    def __init__(
        self, faults: TimingFaults, *, lockstep: bool, period_s: float, seed: int | None = None
    ) -> None:
        self.faults = faults
        self.lockstep = lockstep
        self.period_s = period_s
        seed = faults.seed if seed is None else seed
        self.seed = seed
        self.trace = (
            read_trace(faults.trace, faults.trace_steps) if faults.trace and lockstep else None
        )
        self._robot_jitter = stream(seed, STREAM_ROBOT_JITTER)
        self._host_jitter = stream(seed, STREAM_HOST_JITTER)
        self._drop = stream(seed, STREAM_ROBOT_DROP)
        self._last_delivery = -np.inf
        self._cycle = -1
        self._cycle_delivery = (0.0, 0.0)
        self._step = 0  # next unused index into the trace's steps
        self.stats = RobotTimingStats()

    # ---- lockstep ---------------------------------------------------------------------------
    def sample_time(self, n: int) -> float:
        """Robot time of the n-th sample: n·h, or the trace's (on the recorded robot's clock:
        sample 0 is at its first time, not at 0)."""
        tr = self.trace
        if tr is None:
            return n * self.period_s
        if n < len(tr):
            return float(tr.sample_s[n])
        return float(tr.sample_s[-1]) + (n - len(tr) + 1) * self.period_s

    def deliveries(self, k: int, issued_at: float) -> tuple[float, float]:
        """Lockstep: when the command of cycle k (issued at t_k = ``issued_at``) takes effect,
        as (joint 1's, every joint's): equal, except in a trace where the drives' frames
        arrived apart. The same for every write of cycle k (the draws are made once)."""
        if k == self._cycle:
            return self._cycle_delivery
        self._cycle = k
        tr = self.trace
        if tr is not None:
            inside = k < len(tr)
            at = float(tr.command_s[k]) if inside else issued_at
            first = float(tr.first_command_s[k]) if inside else at  # type: ignore[index]
        else:
            r, h = self.faults.robot, self.faults.host
            delay = r.latency_s + r.feedback_delay_s + draw_jitter(self._robot_jitter, r.jitter)
            if h.delays:
                delay += h.latency_s + h.feedback_delay_s + draw_jitter(self._host_jitter, h.jitter)
            at = issued_at + delay if delay > 0 else issued_at
            first = at
        at = max(at, self._last_delivery)  # frames on one link do not overtake
        first = min(max(first, self._last_delivery), at)
        self._last_delivery = at
        self._cycle_delivery = (first, at)
        self.stats.commands += 1
        self.stats.delays_s.append(at - issued_at)
        self.stats.max_delay_s = max(self.stats.max_delay_s, at - issued_at)
        return first, at

    def advance(self, plant: Any, t_end: float) -> None:
        """Lockstep: integrate ``plant`` to ``t_end`` through the trace's steps before it (the
        times the recorded robot integrated to), so both integrate on the same grid."""
        steps = self.trace.steps if self.trace is not None else None
        if steps is not None:
            i, n = self._step, len(steps)
            while i < n and steps[i] < t_end:
                if steps[i] > plant.t:
                    plant.advance_to(float(steps[i]))
                i += 1
            self._step = i
        plant.advance_to(t_end)

    # ---- realtime -----------------------------------------------------------------------------
    def realtime_delivery(self, arrival: float) -> float:
        """Realtime: a command arriving now takes effect at the returned robot time."""
        r = self.faults.robot
        delay = r.latency_s + draw_jitter(self._robot_jitter, r.jitter)
        at = max(arrival + delay, self._last_delivery)
        self._last_delivery = at
        self.stats.commands += 1
        self.stats.max_delay_s = max(self.stats.max_delay_s, at - arrival)
        return at

    def feedback_delay_s(self) -> float:
        """Realtime: how long the feedback of this sample is held back."""
        d = self.faults.robot.feedback_delay_s
        if d > 0:
            self.stats.delayed_feedback += 1
        return d

    # ---- both ---------------------------------------------------------------------------------
    def drop_command(self) -> bool:
        """Whether this command frame is lost (robot side, ``drop_probability``)."""
        p = self.faults.robot.drop_probability
        if p <= 0:
            return False
        dropped = bool(self._drop.random() < p)
        self.stats.dropped_commands += dropped
        return dropped

    def describe(self) -> dict[str, object]:
        s = self.stats
        out: dict[str, object] = {
            "faults": self.faults.describe(),
            "seed": self.seed,
            "commands": s.commands,
            "dropped_commands": s.dropped_commands,
            "delayed_feedback": s.delayed_feedback,
            "max_delay_s": s.max_delay_s,
        }
        if s.delays_s:
            out["mean_delay_s"] = float(np.mean(s.delays_s))
        return out


class EventLog:
    """The robot's own times of its samples and of the host's commands (realtime runs), one CSV
    line per event: ``event,n,t`` with ``n`` the number of SYNCs before it and ``t`` robot time.
    ``hil replay`` reads it to impose the run's timing exactly (hil/timing/replay.py)."""

    COLUMNS = ("event", "n", "t")

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file = open(self.path, "w", buffering=1 << 16)  # noqa: SIM115 (closed in close())
        self._file.write(",".join(self.COLUMNS) + "\n")

    def __call__(self, event: str, n: int, t: float) -> None:
        self._file.write(f"{event},{n},{t!r}\n")

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()
