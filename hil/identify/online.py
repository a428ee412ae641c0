"""Online identification: recursive least squares updated every control cycle, while the
experiment runs (Reyes & Kelly 1997, eqs. (20)-(22) on the regressions of eqs. (24), (28), (30)).

:class:`OnlineIdentifier` takes one sample at a time — the encoder reading q_k and the torque
held over period k — and keeps θ̂(k) of each scheme. It uses the same row builders and the same
filter coefficients as the batch path (:mod:`hil.model.regressors`), with the filter states carried
from sample to sample, so at the end of a run its θ̂ equals :func:`hil.model.estimators.
recursive_least_squares` over the recording (a test checks it).

Real sample times (``push(q, tau, t)``, a realtime run: :class:`drivers.realtime_times.
HostStampRows` gives each row's time and interval torque from the host's stamps as they come):
the rows are the batch's on real times, ``exact`` over each interval's own length and ``paper``
with its filters written over each interval (:func:`hil.model.regressors.filter_over_intervals`);
an interval longer than GAP_FACTOR periods is a gap, where the rows start afresh (window and
filters; θ̂ and P kept), as the batch fit starts each segment. Without ``t`` every interval is h,
and the numbers are the ones computed before real times were known.

A time stamp off by δ makes the velocities of the samples around it wrong by about δ/Δt, and a
few such rows dominate a least-squares fit (every row on the host's stamps of a 20 s realtime
run, off by more than 1 ms on 8 % of the samples, gave θ̂ 258 % off:
docs/identification.md). The host's stamps bracket each sample: the robot sampled between the
SYNC going out and its feedback coming back, so ``uncertainty_s`` (that round trip beyond its
shortest, :class:`drivers.realtime_times.StampedRow`) bounds the error. An
``exact`` row enters only when every sample it is built from (velocities at both ends of its
interval: 4 samples) is known to within STAMP_UNCERTAINTY_MAX periods; the others are left out
before the filters, not weighted to zero after them. That changes nothing in the equations the
fit uses: every ``exact`` row is its own interval's balance, so any subset of them, filtered
alike on both sides (or summed, for supplied energy), holds exactly. ``paper`` rows filter the
sampled signals themselves, and a row cannot be left out of them: they take every sample.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Sequence

import numpy as np
from scipy.signal import lfilter

from drivers.recording import GAP_FACTOR
from hil.model.closed_form import N_PARAMS
from hil.model.estimators import PAPER_P0, RecursiveLeastSquares
from hil.model.regressors import (
    DISCRETIZATIONS,
    SCHEMES,
    Kinematics,
    filter_coefficients,
    filter_over_intervals,
    kinematics,
    raw_rows,
    stick_memory,
)

# Samples a row needs: paper uses q_{k−1}, q_k (backward difference); exact needs
# q_{k−2}..q_{k+1} to have central velocities at both ends of the interval [t_{k−1}, t_k].
WINDOW = {"paper": 2, "exact": 4}
# An ``exact`` row enters the online fit only when the sample times it is built from are known to
# within this fraction of the period (module docstring): an error δ changes its velocities by
# about δ/h, so 5 % at most on one row, and the real error is mostly far less than the bound.
STAMP_UNCERTAINTY_MAX = 0.05


class _StreamFilter:
    """One filter run sample by sample: the LTI one (scipy.signal.lfilter with carried state),
    or, given each row's interval, :func:`filter_over_intervals` with its state carried."""

    def __init__(self, name: str, lam: float, h: float, shape: tuple[int, ...]) -> None:
        self.name, self.lam = name, lam
        self.b, self.a = filter_coefficients(name, lam, h)
        order = max(len(self.a), len(self.b)) - 1
        self.zi = np.zeros((order, *shape)) if order else None
        self.state: tuple[np.ndarray, np.ndarray] | None = None

    def step(self, x: np.ndarray, dt: float | None = None) -> np.ndarray:
        if dt is not None:
            y, self.state = filter_over_intervals(self.name, self.lam, [dt], x[None], self.state)
            return y[0]
        if self.zi is None:
            return lfilter(self.b, self.a, x[None], axis=0)[0]
        y, self.zi = lfilter(self.b, self.a, x[None], axis=0, zi=self.zi)
        return y[0]


class _SchemeStream:
    def __init__(self, scheme: str, discretization: str, lam: float, h: float, p0: float):
        self.scheme, self.discretization = scheme, discretization
        self.lam, self.h = lam, h
        self.m = 2 if scheme == "filtered_dynamic" else 1
        self.rls = RecursiveLeastSquares(N_PARAMS, p0=p0)
        self.memory = stick_memory(lam, h)
        self.restart()
        self.rows = 0

    def restart(self) -> None:
        """A new segment (after a gap): filters from zero, no stuck interval in memory."""
        self.filters: dict[str, _StreamFilter] | None = None
        self.since_stuck = np.full(self.m, 10**9)

    def push_rows(
        self, q: np.ndarray, tau: np.ndarray, kin: Kinematics, dt: float | None = None
    ) -> None:
        """The newest row of the window; ``dt``: its own interval, for filters that follow
        the clock (``paper`` on real times)."""
        raw = raw_rows(self.scheme, self.discretization, q, tau, self.h, kin)
        if len(raw.index) == 0:
            return
        if self.filters is None:
            self.filters = {"y": _StreamFilter(raw.y_filter, self.lam, self.h, (self.m,))}
            for i, (name, _x) in enumerate(raw.parts):
                self.filters[f"part{i}"] = _StreamFilter(name, self.lam, self.h, (self.m, 9))
        y = self.filters["y"].step(raw.y[-1], dt)
        psi = sum(self.filters[f"part{i}"].step(x[-1], dt) for i, (_n, x) in enumerate(raw.parts))
        stuck = raw.stuck[-1]
        self.since_stuck = np.where(stuck, 0, self.since_stuck + 1)
        weight = (self.since_stuck > self.memory).astype(float)
        self.rls.update(psi, y, weight)
        self.rows += 1


class OnlineIdentifier:
    """θ̂(k) of several schemes, updated one sample at a time (``push``)."""

    def __init__(
        self,
        period_s: float,
        *,
        schemes: Sequence[str] = SCHEMES,
        discretization: str = "exact",
        lam: float = 50.0,
        p0: float = PAPER_P0,
    ) -> None:
        if discretization not in DISCRETIZATIONS:
            raise ValueError(f"unknown discretization {discretization!r}")
        for s in schemes:
            if s not in SCHEMES:
                raise ValueError(f"unknown scheme {s!r}; expected one of {', '.join(SCHEMES)}")
        self.period_s = period_s
        self.discretization = discretization
        self.window: deque[tuple[np.ndarray, np.ndarray, float, bool]] = deque(
            maxlen=WINDOW[discretization]
        )
        self.streams = {s: _SchemeStream(s, discretization, lam, period_s, p0) for s in schemes}
        self.samples = 0
        self.segments = 0  # segments begun (after gaps), on real times
        self.rows_uncertain = 0  # exact rows left out: a sample time not known well enough
        self.real_times: bool | None = None  # set by the first push: t given or not
        self.update_time_s = 0.0  # CPU spent in push(), for the cost report

    def push(
        self,
        q: Sequence[float],
        tau: Sequence[float],
        t: float | None = None,
        uncertainty_s: float = 0.0,
    ) -> None:
        """Add sample k: the encoder reading q_k and the torque held over [t_k, t_{k+1}) (on
        real times: its mean over the interval). ``t``: the sample's real time t_k, for every
        sample of a run or for none (then t_k = k·h); ``uncertainty_s``: how far off t_k may be
        (module docstring)."""
        started = time.perf_counter()
        if self.real_times is None:
            self.real_times = t is not None
        elif self.real_times != (t is not None):
            raise ValueError("give every sample its time t, or none of them")
        if t is not None and self.window:
            interval = t - self.window[-1][2]
            if not interval > 0:
                raise ValueError(f"sample times must increase: {t} after {self.window[-1][2]}")
            if interval > GAP_FACTOR * self.period_s:  # a gap: rows never span it
                self.window.clear()
                for stream in self.streams.values():
                    stream.restart()
        if t is not None and not self.window:
            self.segments += 1
        certain = uncertainty_s <= STAMP_UNCERTAINTY_MAX * self.period_s
        self.window.append(
            (np.asarray(q, dtype=float), np.asarray(tau, dtype=float), float(t or 0.0), certain)
        )
        self.samples += 1
        full = len(self.window) == self.window.maxlen
        if full and self.discretization == "exact" and not all(w[3] for w in self.window):
            self.rows_uncertain += 1
        elif full or self.discretization == "paper":
            qw = np.array([w[0] for w in self.window])
            tw = np.array([w[1] for w in self.window])
            times = np.array([w[2] for w in self.window]) if self.real_times else None
            kin = kinematics(self.discretization, qw, self.period_s, t=times)
            dt = None
            if times is not None and self.discretization == "paper":
                # the row's own interval; a segment's first row: the nominal period (as the
                # batch's iter_regression)
                dt = float(times[-1] - times[-2]) if len(times) > 1 else self.period_s
            for stream in self.streams.values():
                stream.push_rows(qw, tw, kin, dt)
        self.update_time_s += time.perf_counter() - started

    @property
    def theta(self) -> dict[str, np.ndarray]:
        """θ̂(k) of every scheme (a copy)."""
        return {s: st.rls.theta.copy() for s, st in self.streams.items()}

    def cost_per_sample_s(self) -> float:
        """Mean CPU time of one push (all schemes: rows, filters, RLS updates)."""
        return self.update_time_s / self.samples if self.samples else 0.0


__all__ = [
    "OnlineIdentifier",
]
