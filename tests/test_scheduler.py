"""The realtime loop's scheduler on a simulated clock: no drift, the sleep/spin split, and what
happens when the OS refuses SCHED_FIFO or mlockall (no wall-clock timing in here)."""

from __future__ import annotations

import errno
import os
import random

import pytest

from hil.bench import scheduler as sched_mod
from hil.bench.scheduler import (
    MIN_SPIN_S,
    DeadlineScheduler,
    acquire_realtime,
    release_realtime,
)


class SimClock:
    """A clock that moves only when read (a clock read costs ``read_s``) or slept on; sleeps
    overshoot like Linux's: usually 5-60 µs, now and then 400 µs."""

    def __init__(self, seed: int = 1, read_s: float = 0.3e-6) -> None:
        self.t = 1000.0
        self.read_s = read_s
        self.rng = random.Random(seed)
        self.sleeps = 0

    def clock(self) -> float:
        self.t += self.read_s
        return self.t

    def sleep(self, d: float) -> None:
        assert d >= 0
        self.sleeps += 1
        late = self.rng.uniform(5e-6, 60e-6)
        if self.rng.random() < 0.002:
            late = 400e-6
        self.t += d + late

    def work(self, s: float) -> None:
        self.t += s


@pytest.mark.parametrize("period_s", [0.0025, 0.001])
def test_absolute_deadlines_do_not_drift_over_many_periods(period_s):
    sim = SimClock()
    s = DeadlineScheduler(period_s, clock=sim.clock, sleep=sim.sleep)
    t0 = s.start()
    n = 100_000
    worst = 0.0
    late_at_end = []
    for k in range(1, n + 1):
        sim.work(sim.rng.uniform(0, 0.3 * period_s))  # the cycle's own work
        release = s.wait_for(k)
        error = release - (t0 + k * period_s)
        assert error >= 0, f"released {error * 1e6:.2f} µs early at k = {k}"
        worst = max(worst, error)
        if k > n - 1000:
            late_at_end.append(error)
    # every release within the worst sleep overshoot (400 µs) of its own deadline, and the last
    # thousand as close as the first: no accumulation over 100,000 periods
    assert worst < 410e-6
    assert sorted(late_at_end)[len(late_at_end) // 2] < 2e-6  # median: spin ends within reads
    assert s.deadline(n) == pytest.approx(t0 + n * period_s, abs=1e-9)


def test_relative_sleeping_would_drift_and_the_simulation_shows_it():
    """The test above can fail: sleeping one period after each release drifts by the sum of the
    overshoots, which this simulated clock makes visible within 1000 periods."""
    sim = SimClock()
    h = 0.001
    t0 = sim.clock()
    for _ in range(1000):
        sim.sleep(h)
    assert sim.clock() - (t0 + 1000 * h) > 0.02  # > 20 ms behind after 1 s


def test_sleep_then_spin_split_and_adaptive_margin():
    sim = SimClock(seed=3)
    s = DeadlineScheduler(0.0025, clock=sim.clock, sleep=sim.sleep, spin_s=500e-6)
    s.start()
    for k in range(1, 2001):
        s.wait_for(k)
    r = s.report()
    assert r["waits"] == 2000 and sim.sleeps == 2000  # one sleep per wait
    # the margin adapted from 500 µs to the sleeps' p99 overshoot (≤ 60 µs, a few 400 µs) + 30
    assert MIN_SPIN_S * 1e6 <= r["spin_margin_us"] < 200
    assert r["sleep_overshoot_us"]["median"] == pytest.approx(32.5, abs=5)
    assert r["mean_sleep_us"] + r["mean_spin_us"] == pytest.approx(2500, rel=0.01)
    assert 0 < r["mean_spin_us"] < 200


def test_without_spin_it_sleeps_to_the_deadline_and_never_reads_the_clock_in_a_loop():
    sim = SimClock(seed=5)
    reads = 0
    clock = sim.clock

    def counting_clock() -> float:
        nonlocal reads
        reads += 1
        return clock()

    s = DeadlineScheduler(0.001, clock=counting_clock, sleep=sim.sleep, spin=False)
    t0 = s.start()
    for k in range(1, 2001):
        release = s.wait_for(k)
        # never early; late by the sleep's own overshoot only (the simulated 5-60 µs, or 400)
        assert 0 <= release - (t0 + k * 0.001) <= 401e-6
    r = s.report()
    assert reads == 1 + 2 * 2000  # start, then one read before and one after each sleep
    assert r["mean_spin_us"] == 0 and r["spin_margin_us"] == 0 and r["late_wakeups"] == 0
    assert r["method"] == "sleep to the deadline (no spin)"
    assert r["sleep_overshoot_us"]["median"] == pytest.approx(32.5, abs=5)


def test_a_deadline_already_past_returns_at_once():
    sim = SimClock()
    s = DeadlineScheduler(0.001, clock=sim.clock, sleep=sim.sleep)
    s.start()
    sim.work(0.0105)  # a 10 ms stall
    for k in range(1, 11):
        assert s.wait_for(k) > s.deadline(k)
    assert s.already_late == 10 and sim.sleeps == 0
    s.wait_for(12)  # back on the grid: the next deadline is waited for, not shifted
    assert s.already_late == 10


def _refuse(tid: int, priority: int) -> None:
    raise PermissionError(errno.EPERM, "Operation not permitted")


def _refuse_lock() -> None:
    raise OSError(errno.ENOMEM, "Cannot allocate memory")


def test_refusals_are_recorded_with_the_reason_and_warned_once(monkeypatch, capsys):
    monkeypatch.setattr(sched_mod, "_warned", False)
    got = acquire_realtime(set_fifo=_refuse, mlockall=_refuse_lock, peer_pid=os.getpid())
    assert got.policy == "SCHED_OTHER" and not got.memory_locked
    assert "EPERM" in got.realtime_refused and "ENOMEM" in got.memory_lock_refused
    assert got.peer["policy"] == "SCHED_OTHER" and "EPERM" in got.peer["refused"]
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "without SCHED_FIFO and memory lock" in err
    assert "EPERM" in err and "RLIMIT_RTPRIO" in err
    again = acquire_realtime(set_fifo=_refuse, mlockall=_refuse_lock)
    assert got.warned and not again.warned
    assert capsys.readouterr().err == ""  # once per process
    assert got.as_dict()["realtime_refused"] == got.realtime_refused


def test_granted_policy_is_reported_and_undone(monkeypatch):
    calls: list[tuple[int, int]] = []
    unlocked: list[bool] = []
    got = acquire_realtime(
        set_fifo=lambda tid, prio: calls.append((tid, prio)),
        mlockall=lambda: None,
        warn=lambda m: pytest.fail(f"warned: {m}"),
    )
    assert got.policy == "SCHED_FIFO" and got.memory_locked and not got.fell_back
    assert calls[0] == (0, sched_mod.RT_PRIORITY)  # the calling thread first
    restored: list[tuple] = []
    monkeypatch.setattr(sched_mod.os, "sched_setscheduler", lambda *a: restored.append(a))
    release_realtime(got, munlockall=lambda: unlocked.append(True))
    assert unlocked == [True] and len(restored) >= 1
    assert restored[-1][0] == 0  # the calling thread's previous policy is put back last


def test_memory_is_locked_before_the_realtime_policy_is_taken():
    """mlockall faults in every page (tens to hundreds of ms): at normal priority, not at
    SCHED_FIFO, where it would hold a CPU against every normal task meanwhile."""
    order: list[str] = []
    got = acquire_realtime(
        set_fifo=lambda tid, prio: order.append("fifo"),
        mlockall=lambda: order.append("mlockall"),
        warn=lambda m: pytest.fail(f"warned: {m}"),
    )
    release_realtime(got, munlockall=lambda: None)
    assert order[0] == "mlockall" and "fifo" in order


def test_off_does_not_try():
    got = acquire_realtime("off", set_fifo=_refuse, mlockall=_refuse_lock)
    assert got.policy == "SCHED_OTHER" and not got.fell_back and not got.warned
    with pytest.raises(ValueError, match="auto, off"):
        acquire_realtime("fifo")
