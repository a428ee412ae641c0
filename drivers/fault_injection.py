"""Host-side timing faults: an :class:`~drivers.arm.Arm` that wraps another and injects them.

The loop runner does not know: it sees an Arm. The faults are the ``[timing_faults.host]`` table
of the bench profile (profiles/timing_faults.py); what each does, per cycle k (the command τ_k
the loop hands over after sample k at t_k = k·h):

* ``drop_probability``: the command frame is lost, so the drives hold the previous torque
  (emulated by sending that torque again: the drives' watchdog is still fed).
* ``feedback_drop_probability``: the feedback frame is lost and the host reuses the previous
  sample's positions and statuses.
* ``stall`` (at T for D): realtime, the host stops for D before the first cycle with t_k >= T
  (the loop then catches up on its absolute deadlines); lockstep, the drives hold the last
  command before T for every cycle with T <= t_k < T + D.
* ``latency_s`` + jitter J_k: realtime, every frame the host sends leaves late: the command
  after a sleep of latency + J_k, the SYNC at deadline + latency + J_k (visible in the recording
  as ``sync_sent_s - deadline_s``). ``feedback_delay_s``: realtime, the host reads the feedback
  that much later (visible as ``feedback_s - sync_sent_s``).
  In lockstep the host does not own simulated time: these delays are imposed by the virtual
  robot, which reads the same bench profile (virtual_robot/timing_faults.py).

Draws come from numpy streams of the seed (``--seed``, else the profile's, else 0).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

from drivers.arm import Arm, Fault, Sample
from profiles.timing_faults import (
    STREAM_HOST_DROP,
    STREAM_HOST_FEEDBACK_DROP,
    STREAM_HOST_JITTER,
    SideFaults,
    TimingFaults,
    draw_jitter,
    stream,
)

SPIN_S = 2e-4  # sleep until this close to a target time, then spin


def sleep_until(target: float, clock: Any = time.monotonic) -> None:
    """Sleep until ``clock() >= target``, spinning the last 0.2 ms (sleep alone overshoots)."""
    while (left := target - clock()) > 0:
        time.sleep(left - SPIN_S if left > 2 * SPIN_S else 0)


@dataclass
class HostFaultStats:
    cycles: int = 0
    dropped_commands: int = 0
    dropped_feedback: int = 0
    stalled_cycles: int = 0
    stalls: int = 0
    delay_sum_s: float = 0.0
    max_delay_s: float = 0.0


class TimingFaultArm(Arm):
    """``inner`` with the host-side faults of ``faults`` injected (module docstring)."""

    def __init__(self, inner: Arm, faults: SideFaults, *, seed: int | None = None) -> None:
        self.inner = inner
        self.faults = faults
        self.seed = seed
        self._jitter = stream(seed, STREAM_HOST_JITTER)
        self._drop = stream(seed, STREAM_HOST_DROP)
        self._feedback_drop = stream(seed, STREAM_HOST_FEEDBACK_DROP)
        self._k = 0
        self._held: tuple[float, ...] | None = None  # the last command that reached the drives
        self._last: Sample | None = None
        self._stalls_done: set[int] = set()
        self.fault_stats = HostFaultStats()

    # the Arm's settings and counters are the inner link's
    @property
    def period_s(self) -> float:  # type: ignore[override]
        return self.inner.period_s

    @property
    def mode(self) -> str:  # type: ignore[override]
        return self.inner.mode

    @property
    def stats(self) -> Any:  # type: ignore[override]
        return self.inner.stats

    @property
    def n_joints(self) -> int:  # type: ignore[override]
        return self.inner.n_joints

    @property
    def opened_at(self) -> float | None:  # type: ignore[override]
        return self.inner.opened_at

    @property
    def peer_alive(self) -> Any:  # type: ignore[override]
        return self.inner.peer_alive

    @peer_alive.setter
    def peer_alive(self, alive: Any) -> None:  # the inner link's waits check it
        self.inner.peer_alive = alive

    def __getattr__(self, name: str) -> Any:  # anything else (drives, limits, ...) as is
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)

    def now(self) -> float:
        return self.inner.now()

    def open(self) -> None:
        self.inner.open()

    def close(self) -> None:
        self.inner.close()

    def safe_stop(self) -> None:
        self.inner.safe_stop()

    def enable(self) -> None:
        self.inner.enable()

    def disable(self) -> None:
        self.inner.disable()

    def faults(self) -> list[Fault]:  # type: ignore[override]
        return self.inner.faults()

    def clear_faults(self) -> None:
        self.inner.clear_faults()

    def traffic_log(self) -> str | None:
        return self.inner.traffic_log()

    def start(self) -> Sample:
        self._k = 0
        self._held = None
        self._last = self.inner.start()
        return self._last

    # ---- the faults ---------------------------------------------------------------------------
    def _stall(self, t: float) -> int | None:
        """Index of the stall that cycle time ``t`` falls in, or None."""
        t += 1e-9  # k·h is rounded: 40 · 2.5 ms is at 0.1 s, 48 · 2.5 ms not before 0.12 s
        for i, s in enumerate(self.faults.stalls):
            if s.at_s <= t < s.at_s + s.duration_s:
                return i
        return None

    def cycle(self, tau_Nm: Sequence[float], deadline: float | None = None) -> Sample:
        f, stats = self.faults, self.fault_stats
        k = self._k
        self._k += 1
        stats.cycles += 1
        realtime = self.mode == "realtime"
        sent = tuple(float(x) for x in tau_Nm)
        stall = self._stall(k * self.period_s)
        if stall is not None:
            stats.stalled_cycles += 1
            if realtime:
                if stall not in self._stalls_done:  # the host stops, once
                    self._stalls_done.add(stall)
                    stats.stalls += 1
                    time.sleep(f.stalls[stall].duration_s)
            elif self._held is not None:  # lockstep: the drives hold the last command
                sent = self._held
                if stall not in self._stalls_done:
                    self._stalls_done.add(stall)
                    stats.stalls += 1
        elif (
            f.drop_probability > 0
            and self._drop.random() < f.drop_probability
            and self._held is not None
        ):
            sent = self._held
            stats.dropped_commands += 1
        delay = 0.0
        if realtime:
            delay = f.latency_s + draw_jitter(self._jitter, f.jitter)
            stats.delay_sum_s += delay
            stats.max_delay_s = max(stats.max_delay_s, delay)
            if delay > 0:
                sleep_until(self.inner.now() + delay, self.inner.now)
        due = None if deadline is None else deadline + delay
        sample = self.inner.cycle(sent, due)
        self._held = sent
        if realtime:
            if f.feedback_delay_s > 0:
                sleep_until(self.inner.now() + f.feedback_delay_s, self.inner.now)
                sample = replace(sample, received_at=self.inner.now())
            sample = replace(sample, deadline=math.nan if deadline is None else float(deadline))
        if (
            f.feedback_drop_probability > 0
            and self._last is not None
            and self._feedback_drop.random() < f.feedback_drop_probability
        ):
            stats.dropped_feedback += 1
            sample = replace(sample, q_rad=self._last.q_rad, status=self._last.status)
        self._last = sample
        return sample

    def describe(self) -> dict[str, Any]:
        """What was injected, for meta.json."""
        s = self.fault_stats
        out = {
            "side": "host",
            "mode": self.mode,
            "faults": self.faults.describe(),
            "seed": self.seed,
            "cycles": s.cycles,
            "dropped_commands": s.dropped_commands,
            "dropped_feedback": s.dropped_feedback,
            "stalls": s.stalls,
            "stalled_cycles": s.stalled_cycles,
        }
        if self.mode == "realtime":
            out["mean_delay_s"] = s.delay_sum_s / s.cycles if s.cycles else 0.0
            out["max_delay_s"] = s.max_delay_s
        else:
            out["delays"] = "imposed by the virtual robot in simulated time"
        return out


def with_host_faults(arm: Arm, faults: TimingFaults | None, *, seed: int | None = None) -> Arm:
    """``arm`` wrapped in a :class:`TimingFaultArm` if ``faults`` has host-side faults (seeded
    by ``seed``, else the profile's), else ``arm`` itself."""
    if faults is None or not faults.host.active:
        return arm
    h = faults.host
    if arm.mode != "realtime" and not (
        h.drop_probability or h.feedback_drop_probability or h.stalls
    ):
        return arm  # lockstep delays only: the virtual robot imposes them
    return TimingFaultArm(arm, faults.host, seed=faults.seed if seed is None else seed)
