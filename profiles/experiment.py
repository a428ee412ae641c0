"""Experiment profile: open-loop excitation torques (Reyes & Kelly eqs. (31)-(32) and the like)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from profiles.loader import Fields, load_toml


@dataclass(frozen=True)
class Sine:
    """A_k sin(ω_k t + φ_k), optionally switched on only over [start_s, stop_s) with raised-cosine
    ramps of ``ramp_s`` seconds at both ends of the window (defaults: always on, no ramp)."""

    amplitude_Nm: float
    omega_rad_s: float
    phase_rad: float
    start_s: float = 0.0
    stop_s: float = math.inf
    ramp_s: float = 0.0

    @property
    def windowed(self) -> bool:
        return self.start_s > 0.0 or self.stop_s < math.inf or self.ramp_s > 0.0

    def window(self, t: np.ndarray) -> np.ndarray:
        """w(t) in [0, 1]: 0 outside [start, stop); ½(1 − cos(π u)) over the ramps, with u the
        distance to the nearer window edge in units of ``ramp_s``; 1 in between."""
        inside = (t >= self.start_s) & (t < self.stop_s)
        if self.ramp_s <= 0.0:
            return inside.astype(float)
        u = np.clip(np.minimum(t - self.start_s, self.stop_s - t) / self.ramp_s, 0.0, 1.0)
        return np.where(inside, 0.5 * (1.0 - np.cos(math.pi * u)), 0.0)


@dataclass(frozen=True)
class JointExcitation:
    """τ(t) = offset_Nm + step_Nm (1 − e^{−step_rate t}) + Σ_k w_k(t) A_k sin(ω_k t + φ_k) + p(t)
    (eqs. (31)-(32); the constant ``offset_Nm``, default 0, carries the mean of a designed
    periodic torque, hil/identify/excitation.py; w_k is a sine's time window, 1 by default; p(t) is
    the
    piecewise-linear torque through ``points`` (t_s, τ_Nm), held at its first value before the
    first point and at its last value after the last, 0 when there are no points)."""

    step_Nm: float
    step_rate_per_s: float
    sines: tuple[Sine, ...]
    offset_Nm: float = 0.0
    points: tuple[tuple[float, float], ...] = ()

    def torque(self, t: float | np.ndarray) -> float | np.ndarray:
        t_arr = np.asarray(t, dtype=float)
        tau = self.offset_Nm + self.step_Nm * (1.0 - np.exp(-self.step_rate_per_s * t_arr))
        for s in self.sines:
            wave = s.amplitude_Nm * np.sin(s.omega_rad_s * t_arr + s.phase_rad)
            tau = tau + (s.window(t_arr) * wave if s.windowed else wave)
        if self.points:
            times, levels = zip(*self.points, strict=True)
            tau = tau + np.interp(t_arr, times, levels)
        return float(tau) if np.ndim(t) == 0 else tau

    def peak_Nm(self) -> float:
        """Upper bound on |τ(t)| (offset, step, all amplitudes and the largest point)."""
        return (
            abs(self.offset_Nm)
            + abs(self.step_Nm)
            + sum(abs(s.amplitude_Nm) for s in self.sines)
            + max((abs(p[1]) for p in self.points), default=0.0)
        )


@dataclass(frozen=True)
class ExperimentProfile:
    name: str
    source: str
    kind: str
    period_s: float
    duration_s: float
    initial_q_rad: tuple[float, ...]
    joints: tuple[JointExcitation, ...]  # one per joint: 2 for the CICESE arm, n for a URDF arm

    @property
    def n_joints(self) -> int:
        return len(self.joints)

    def torque(self, t: float) -> tuple[float, ...]:
        """Commanded torques [Nm] at time t."""
        return tuple(j.torque(t) for j in self.joints)

    def torque_table(self, t: np.ndarray) -> np.ndarray:
        """Commanded torques at every time in ``t``, shape (len(t), n_joints)."""
        return np.column_stack([j.torque(t) for j in self.joints])

    def check_joints(self, n: int, robot: str) -> None:
        """ValueError (one line) unless the experiment drives exactly ``n`` joints."""
        if self.n_joints != n:
            raise ValueError(
                f"{self.source}: experiment {self.name} drives {self.n_joints} joint(s), "
                f"robot {robot} has {n}"
            )

    def torque_rows(self, period_s: float, n: int) -> TorqueRows:
        """τ(k·h) for k = 0..n−1, computed a block at a time (memory bounded by the block)."""
        return TorqueRows(self, period_s, n)


class TorqueRows:
    """Row k = the commanded torques at t = k·h, as a list; rows are read in order.

    The values are exactly ``torque_table(np.arange(n) * h)`` (element-wise, same arithmetic),
    computed :data:`ROW_BLOCK` rows at a time instead of all at once: a 24 h run needs no more
    memory than a 1 s one.
    """

    def __init__(self, experiment: ExperimentProfile, period_s: float, n: int) -> None:
        self.experiment, self.h, self.n = experiment, period_s, n
        self._start, self._rows = 0, []  # type: ignore[var-annotated]

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, k: int) -> list[float]:
        if not 0 <= k < self.n:
            raise IndexError(k)
        i = k - self._start
        if not 0 <= i < len(self._rows):
            self._start = k - k % ROW_BLOCK
            stop = min(self.n, self._start + ROW_BLOCK)
            self._rows = self.experiment.torque_table(np.arange(self._start, stop) * self.h)
            self._rows = self._rows.tolist()
            i = k - self._start
        return self._rows[i]


ROW_BLOCK = 4096
KINDS = ("open_loop_torque",)
# Bounds that say why (one-line errors before anything is allocated or started):
MAX_TORQUE_NM = 1e4  # no direct-drive joint comes near 10 kNm; the bench clamps far below
MAX_DURATION_S = 24 * 3600.0  # a day: longer runs are several runs
MAX_ROWS = 100_000_000  # rows of one recording (≈ 5 GB of CSV)
MIN_STEP_S = 1e-6  # integrator step: below 1 µs RK4 gains nothing and a run takes hours
MAX_PLANT_STEPS = 1_000_000_000
MAX_JOINTS = (
    64  # a serial arm; more entries are a mistake in the file  # ≈ 1.5 h of RK4 at 5 µs a step
)


def check_duration(duration_s: float, period_s: float, option: str = "--duration") -> int:
    """The number of periods of a run of ``duration_s`` at ``period_s``; ValueError (one line,
    naming ``option``) unless 0 < duration ≤ 24 h and the rows fit in one recording."""
    if not math.isfinite(duration_s) or duration_s <= 0:
        raise ValueError(f"{option} must be a finite number of seconds > 0, got {duration_s}")
    if duration_s > MAX_DURATION_S:
        raise ValueError(
            f"{option} {duration_s:g} s is longer than {MAX_DURATION_S:g} s (24 h): "
            "record a long test as several runs"
        )
    n = max(1, round(duration_s / period_s))
    if n > MAX_ROWS:
        raise ValueError(
            f"{option} {duration_s:g} s at a period of {period_s:g} s is {n} rows, more than "
            f"{MAX_ROWS} in one recording"
        )
    return n


def check_step(step_s: float, period_s: float, duration_s: float) -> float:
    """The integrator step; ValueError unless 1 µs ≤ step ≤ period and the run's plant steps
    stay within :data:`MAX_PLANT_STEPS`."""
    if not math.isfinite(step_s) or step_s <= 0:
        raise ValueError(f"--step must be a finite number of seconds > 0, got {step_s}")
    if step_s < MIN_STEP_S:
        raise ValueError(f"--step {step_s:g} s is below 1 µs: RK4 gains nothing there")
    if step_s > period_s:
        raise ValueError(
            f"--step {step_s:g} s is longer than the period {period_s:g} s: the plant integrates "
            "at least once per period"
        )
    steps = duration_s / step_s
    if steps > MAX_PLANT_STEPS:
        raise ValueError(
            f"--step {step_s:g} s over {duration_s:g} s is {steps:.3g} plant steps, more than "
            f"{MAX_PLANT_STEPS:.0e}: use a larger step or a shorter run"
        )
    return step_s


def _sine(st: Fields) -> Sine:
    st.only({"amplitude_Nm", "omega_rad_s", "phase_rad", "start_s", "stop_s", "ramp_s"})
    start = st.number("start_s", 0.0, lo=0.0)
    stop = st.number("stop_s", math.inf) if st.has("stop_s") else math.inf
    if stop <= start:
        raise st.error("stop_s", f"must be > start_s = {start}, got {stop}")
    ramp = st.number("ramp_s", 0.0, lo=0.0)
    if 2.0 * ramp > stop - start:
        raise st.error(
            "ramp_s", f"must be <= half the window (stop_s - start_s)/2 = {(stop - start) / 2}"
        )
    return Sine(
        st.number("amplitude_Nm", lo=-MAX_TORQUE_NM, hi=MAX_TORQUE_NM),
        st.number("omega_rad_s", lo=0.0, hi=1e6),
        st.number("phase_rad", 0.0),
        start_s=start,
        stop_s=stop,
        ramp_s=ramp,
    )


def _points(jt: Fields) -> tuple[tuple[float, float], ...]:
    """``points = [[t_s, tau_Nm], ...]``: at least 2, times >= 0 and strictly increasing."""
    raw = jt.data["points"]
    if not isinstance(raw, list) or len(raw) < 2:
        raise jt.error("points", "must be a list of at least 2 [t_s, tau_Nm] pairs")
    points: list[tuple[float, float]] = []
    for i, pair in enumerate(raw):
        if not isinstance(pair, list) or len(pair) != 2:
            raise jt.error(f"points[{i}]", f"must be a pair [t_s, tau_Nm], got {str(pair)[:40]}")
        row = Fields({"t": pair[0], "tau": pair[1]}, jt.source, f"{jt.prefix}points[{i}].")
        t = row.number("t", lo=0.0)
        if points and t <= points[-1][0]:
            raise jt.error(f"points[{i}]", f"times must increase, got {t} after {points[-1][0]}")
        points.append((t, row.number("tau", lo=-MAX_TORQUE_NM, hi=MAX_TORQUE_NM)))
    return tuple(points)


def load_experiment(name_or_path: str | Path) -> ExperimentProfile:
    data, source = load_toml("experiments", name_or_path)
    f = Fields(data, source)
    if data.get("kind") == "tracking":  # closed loop: profiles/tracking.py, `hil control`
        raise f.error("kind", "a tracking experiment is closed loop: run it with `hil control`")
    f.only({"name", "description", "kind", "period_s", "duration_s", "initial_q_rad", "joints"})
    kind = f.string("kind")
    if kind not in KINDS:
        raise f.error(
            "kind", f"unknown experiment kind {kind!r}; expected one of {', '.join(KINDS)}"
        )
    joint_tables = f.tables("joints")
    if not 1 <= len(joint_tables) <= MAX_JOINTS:
        raise f.error(
            "joints",
            f"must have 1 to {MAX_JOINTS} entries (one per joint), got {len(joint_tables)}",
        )
    joints = []
    for jt in joint_tables:
        jt.only({"step_Nm", "step_rate_per_s", "offset_Nm", "sines", "points"})
        sines = [_sine(st) for st in jt.tables("sines")] if jt.has("sines") else []
        joints.append(
            JointExcitation(
                jt.number("step_Nm", 0.0, lo=-MAX_TORQUE_NM, hi=MAX_TORQUE_NM),
                jt.number("step_rate_per_s", 1.0, lo=0.0, hi=1e6),
                tuple(sines),
                offset_Nm=jt.number("offset_Nm", 0.0, lo=-MAX_TORQUE_NM, hi=MAX_TORQUE_NM),
                points=_points(jt) if jt.has("points") else (),
            )
        )
    n = len(joints)
    initial = f.numbers("initial_q_rad", n, [0.0] * n, lo=-2 * math.pi, hi=2 * math.pi)
    return ExperimentProfile(
        name=f.string("name"),
        source=source,
        kind=kind,
        period_s=f.number("period_s", positive=True, hi=1.0),
        duration_s=f.number("duration_s", positive=True, hi=MAX_DURATION_S),
        initial_q_rad=tuple(initial),
        joints=tuple(joints),
    )


__all__ = [
    "ExperimentProfile",
    "JointExcitation",
    "Sine",
    "TorqueRows",
    "check_duration",
    "load_experiment",
]
