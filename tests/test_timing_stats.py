"""Timing statistics on synthetic timestamps: what is put in is what is measured."""

from __future__ import annotations

import numpy as np
import pytest

from hil.bench.timing_stats import cycle_timing, jitter_summary, loop_timing


def synthetic(
    n: int, h: float, latency_s: float, jitter_s: float = 0.0, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows as the loop records them: row 0 has no deadline; release = deadline + jitter."""
    rng = np.random.default_rng(seed)
    deadline = 10.0 + np.arange(n) * h
    release = deadline + rng.uniform(0, jitter_s, n)
    deadline[0] = np.nan
    feedback = release + latency_s
    return deadline, release, feedback


def test_an_injected_constant_1ms_latency_is_measured_as_1ms():
    d, r, f = synthetic(4000, 0.0025, 1e-3, jitter_s=20e-6)
    s = jitter_summary(0.0025, d, r, f)
    for key in ("median_us", "p99_us", "p999_us", "max_us"):
        assert s["latency"][key] == pytest.approx(1000.0, abs=1e-3)
    assert s["latency"]["n"] == 4000 and s["cycles"] == 3999
    assert s["deadline_misses"] == 0 and s["overruns"] == 0 and s["late_releases"] == 0
    assert 0 <= s["release_error"]["median_us"] <= 20 and s["release_error"]["max_us"] <= 20
    assert s["period_error"]["max_us"] <= 20  # the difference of two releases' jitter


def test_latency_beyond_a_period_is_a_deadline_miss_every_cycle():
    d, r, f = synthetic(1000, 0.001, 1.2e-3)
    s = jitter_summary(0.001, d, r, f)
    assert s["deadline_misses"] == 999 and s["deadline_misses_per_10k"] == pytest.approx(1e4)


def test_a_stall_is_one_overrun_and_its_release_error():
    h = 0.001
    d, r, f = synthetic(10_000, h, 150e-6)
    r[5000] += 2e-3  # released 2 ms late; the next cycle is on time again
    f[5000] += 2e-3
    s = jitter_summary(h, d, r, f)
    assert s["overruns"] == 1 and s["overruns_per_10k"] == pytest.approx(1e4 / 9998)
    assert s["release_error"]["max_us"] == pytest.approx(2000.0, abs=1e-3)
    assert s["period"]["max_us"] == pytest.approx(3000.0, abs=1e-3)
    assert s["period"]["min_us"] == pytest.approx(-1000.0, abs=1e-3)  # 1 ms then -1 ms: 0
    assert s["deadline_misses"] == 1  # feedback 2.15 ms after its deadline
    assert s["late_releases"] == 1


def test_lost_feedback_counts_as_missed():
    h = 0.0025
    d, r, f = synthetic(100, h, 200e-6)
    f[50] = np.nan
    c = cycle_timing(h, d, r, f)
    assert c.latency.size == 99 and c.late_feedback.sum() == 1
    assert jitter_summary(h, d, r, f, lost_feedback=1)["lost_feedback"] == 1


def test_loop_timing_keeps_hil_runs_figures():
    d, r, f = synthetic(1000, 0.0025, 300e-6, jitter_s=10e-6)
    t = loop_timing(0.0025, d.tolist(), r.tolist(), f.tolist())
    assert t["cycles"] == 1000 and t["deadline_misses"] == 0
    assert t["command_to_feedback_latency"]["p50_ms"] == pytest.approx(0.3)
    assert t["sync_lateness"]["max_ms"] <= 0.010
    assert t["jitter"]["latency"]["median_us"] == pytest.approx(300.0)


def test_mismatched_columns_are_refused():
    with pytest.raises(ValueError, match="one length"):
        cycle_timing(0.001, [0.0, 1.0], [0.0], [0.0])
