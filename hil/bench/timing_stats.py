"""Timing statistics of a realtime run, from its per-cycle timestamps (pure, numpy only).

A realtime recording has, for every row k, ``deadline_s`` (t_open + k·h, the instant period k
starts; NaN for row 0, the start-up sample), ``sync_sent_s`` (when the SYNC / sampling request
went out: the *release* of the cycle) and ``feedback_s`` (when the last feedback frame of the
cycle was in). All host seconds on one monotonic clock. From them:

* release error e_k = release_k − deadline_k: how late the cycle started against its absolute
  deadline (the scheduler's error; ≥ 0 unless the clock was read early);
* period P_k = release_k − release_{k−1} and period error |P_k − h| (period-to-period jitter;
  about the difference of two consecutive release errors, so up to twice e_k);
* overrun: P_k > 1.5 h (a cycle stretched by at least half a period);
* command-to-feedback latency l_k = feedback_k − release_k;
* deadline miss (late feedback): feedback_k > deadline_k + h, the feedback of period k came after
  period k + 1 had begun, so the command computed from it was late for its period;
* late release: e_k > 10 % of h.

:func:`timing_statistics` keeps the figures ``hil run`` has always written (ms); the "jitter"
entry of :func:`loop_timing` has the fuller set in µs (median, p99, p99.9, max).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

LATE_FRACTION = 0.1  # a SYNC sent later than 10 % of a period after its deadline: late release
OVERRUN_FACTOR = 1.5  # a period longer than 1.5 h is an overrun


def percentiles_us(values: Sequence[float] | np.ndarray) -> dict[str, float | int]:
    """n, median, p99, p99.9, max and mean of ``values`` (seconds), in µs."""
    a = np.asarray(values, dtype=float)
    a = a[np.isfinite(a)]
    if a.size == 0:
        return {"n": 0}
    p50, p99, p999 = np.percentile(a, [50, 99, 99.9])
    return {
        "n": int(a.size),
        "median_us": float(p50 * 1e6),
        "p99_us": float(p99 * 1e6),
        "p999_us": float(p999 * 1e6),
        "max_us": float(a.max() * 1e6),
        "mean_us": float(a.mean() * 1e6),
    }


def _percentiles_ms(values: Sequence[float]) -> dict[str, float]:
    if not len(values):
        return {}
    a = np.asarray(values, dtype=float)
    return {
        "p50_ms": float(np.percentile(a, 50) * 1e3),
        "p99_ms": float(np.percentile(a, 99) * 1e3),
        "max_ms": float(a.max() * 1e3),
        "mean_ms": float(a.mean() * 1e3),
    }


def timing_statistics(
    period_s: float, lateness: Sequence[float], latency: Sequence[float]
) -> dict[str, Any]:
    """Deadline misses and latency percentiles (ms) of a realtime run (``hil run``'s figures).

    ``lateness[i]`` is the release error of row i + 1, ``latency[i]`` the latency of row i.
    """
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
        "sync_lateness": _percentiles_ms(lateness),
        "command_to_feedback_latency": _percentiles_ms(latency),
    }


@dataclass(frozen=True)
class CycleTiming:
    """Per-cycle figures (seconds) of rows that have a deadline (k ≥ 1)."""

    release_error: np.ndarray  # release − deadline, per row with a deadline
    period: np.ndarray  # release_k − release_{k−1}, between consecutive rows with deadlines
    latency: np.ndarray  # feedback − release, every row with both
    late_feedback: np.ndarray  # bool per row with a deadline: feedback after deadline + h


def cycle_timing(
    period_s: float,
    deadline_s: Sequence[float] | np.ndarray,
    release_s: Sequence[float] | np.ndarray,
    feedback_s: Sequence[float] | np.ndarray,
) -> CycleTiming:
    """The per-cycle figures of a realtime recording's three timestamp columns."""
    deadline = np.asarray(deadline_s, dtype=float)
    release = np.asarray(release_s, dtype=float)
    feedback = np.asarray(feedback_s, dtype=float)
    if not deadline.shape == release.shape == feedback.shape or deadline.ndim != 1:
        raise ValueError("deadline, release and feedback must be 1-D arrays of one length")
    timed = np.isfinite(deadline) & np.isfinite(release)
    both = timed[1:] & timed[:-1]
    period = np.diff(release)[both]
    latency = (feedback - release)[np.isfinite(feedback) & np.isfinite(release)]
    with np.errstate(invalid="ignore"):
        late = (feedback[timed] > deadline[timed] + period_s) | ~np.isfinite(feedback[timed])
    return CycleTiming(release[timed] - deadline[timed], period, latency, late)


def jitter_summary(
    period_s: float,
    deadline_s: Sequence[float] | np.ndarray,
    release_s: Sequence[float] | np.ndarray,
    feedback_s: Sequence[float] | np.ndarray,
    *,
    lost_feedback: int = 0,
) -> dict[str, Any]:
    """Release error, period error, latency (µs percentiles), overruns, deadline misses.

    ``lost_feedback``: cycles whose feedback never came (the link's timeouts; a realtime run
    stops at the first, so it is 0 or 1 unless the link tolerates losses).
    """
    c = cycle_timing(period_s, deadline_s, release_s, feedback_s)
    cycles = int(c.release_error.size)
    overruns = int(np.count_nonzero(c.period > OVERRUN_FACTOR * period_s))
    misses = int(np.count_nonzero(c.late_feedback))
    late_releases = int(np.count_nonzero(c.release_error > LATE_FRACTION * period_s))

    def per_10k(count: int, of: int) -> float | None:  # None (JSON null): no cycles to count
        return 1e4 * count / of if of else None

    return {
        "period_s": period_s,
        "rate_hz": 1.0 / period_s,
        "cycles": cycles,
        "release_error": percentiles_us(c.release_error),
        "period_error": percentiles_us(np.abs(c.period - period_s)),
        "period": percentiles_us(c.period)
        | ({"min_us": float(c.period.min() * 1e6)} if c.period.size else {}),
        "latency": percentiles_us(c.latency),
        "overruns": overruns,
        "overruns_per_10k": per_10k(overruns, int(c.period.size)),
        "overrun_threshold_us": OVERRUN_FACTOR * period_s * 1e6,
        "deadline_misses": misses,
        "deadline_misses_per_10k": per_10k(misses, cycles),
        "late_releases": late_releases,
        "late_release_threshold_us": LATE_FRACTION * period_s * 1e6,
        "lost_feedback": int(lost_feedback),
    }


def loop_timing(
    period_s: float,
    deadline_s: Sequence[float],
    release_s: Sequence[float],
    feedback_s: Sequence[float],
    *,
    lost_feedback: int = 0,
) -> dict[str, Any]:
    """What the loop runner puts in meta.json's "timing": :func:`timing_statistics` of the rows
    (row 0, the start-up sample, has latency but no deadline) plus "jitter"
    (:func:`jitter_summary`)."""
    deadline = np.asarray(deadline_s, dtype=float)
    release = np.asarray(release_s, dtype=float)
    feedback = np.asarray(feedback_s, dtype=float)
    lateness = (release - deadline)[1:].tolist()
    latency = (feedback - release).tolist()
    timing = timing_statistics(period_s, lateness, latency)
    timing["jitter"] = jitter_summary(
        period_s, deadline, release, feedback, lost_feedback=lost_feedback
    )
    return timing


__all__ = [
    "CycleTiming",
    "cycle_timing",
    "jitter_summary",
    "percentiles_us",
    "timing_statistics",
]
