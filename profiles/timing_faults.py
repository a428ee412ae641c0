"""Timing faults: the ``[timing_faults]`` table of a bench or an effects profile.

Faults are injected on either side of the link (docs/jitter.md, "Timing faults")::

    [timing_faults]
    seed = 7                        # optional; `--seed` overrides it; default 0

    [timing_faults.host]            # bench profiles only: the host's wrapper around its Arm
    latency_s = 0.001               # every frame the host sends (commands, SYNC) leaves late
    jitter = { distribution = "normal", scale_s = 0.0002 }   # extra delay per cycle, >= 0
    drop_probability = 0.01         # a command frame lost: the drives hold the previous torque
    feedback_delay_s = 0.0          # the host reads each cycle's feedback this late
    feedback_drop_probability = 0.0 # a feedback frame lost: the host reuses the previous one
    stall = [{ at_s = 2.0, duration_s = 0.05 }]   # the host stops for D at T

    [timing_faults.robot]           # the virtual robot (bench or effects profile)
    latency_s = 0.001               # a command takes effect this long after it arrives
    jitter = { distribution = "exponential", scale_s = 0.0001 }
    drop_probability = 0.01         # command frames ignored (the drive holds its torque)
    feedback_delay_s = 0.0          # feedback frames sent this late

    [timing_faults.trace]           # robot, lockstep only: impose a recorded timing trace
    file = "timing-trace.csv"       # relative to the profile: k,sample_s,first_command_s,command_s
    steps = "timing-steps.csv"      # optional: the robot's other integration times (column t)

Jitter is a non-negative extra delay J_k drawn per cycle: ``normal`` |N(0, σ)| (half-normal),
``uniform`` U(0, scale), ``exponential`` Exp(mean = scale). The delay of cycle k is
latency + J_k; frames on one link do not overtake each other.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from profiles.loader import Fields

DISTRIBUTIONS = ("normal", "uniform", "exponential")
MAX_DELAY_S = 1.0
# The longest a bench may wait for feedback (profiles/bench.py): a realtime run whose link was
# silent longer has ended, so a trace interval (sample to sample, sample to its command) beyond
# it is a corrupt trace, and a replay would integrate the plant over it.
MAX_FEEDBACK_BUDGET_S = 10.0
HOST_KEYS = {
    "latency_s",
    "jitter",
    "drop_probability",
    "feedback_delay_s",
    "feedback_drop_probability",
    "stall",
}
ROBOT_KEYS = {"latency_s", "jitter", "drop_probability", "feedback_delay_s"}


@dataclass(frozen=True)
class Jitter:
    distribution: str  # normal | uniform | exponential
    scale_s: float


@dataclass(frozen=True)
class Stall:
    at_s: float  # time of the first cycle that stalls (t = k·h >= at_s)
    duration_s: float


@dataclass(frozen=True)
class SideFaults:
    """The faults of one side of the link (all zero: no fault)."""

    latency_s: float = 0.0
    jitter: Jitter | None = None
    drop_probability: float = 0.0
    feedback_delay_s: float = 0.0
    feedback_drop_probability: float = 0.0  # host only
    stalls: tuple[Stall, ...] = ()  # host only

    @property
    def delays(self) -> bool:
        """Whether commands are delayed (latency, jitter or late feedback)."""
        return bool(
            self.latency_s > 0
            or self.feedback_delay_s > 0
            or (self.jitter is not None and self.jitter.scale_s > 0)
        )

    @property
    def active(self) -> bool:
        return bool(
            self.delays
            or self.drop_probability > 0
            or self.feedback_drop_probability > 0
            or self.stalls
        )

    @property
    def random(self) -> bool:
        """Whether the seed matters (random jitter or drops)."""
        return bool(
            (self.jitter is not None and self.jitter.scale_s > 0)
            or self.drop_probability > 0
            or self.feedback_drop_probability > 0
        )

    def describe(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "latency_s": self.latency_s,
            "drop_probability": self.drop_probability,
            "feedback_delay_s": self.feedback_delay_s,
        }
        if self.jitter is not None:
            out["jitter"] = {
                "distribution": self.jitter.distribution,
                "scale_s": self.jitter.scale_s,
            }
        if self.feedback_drop_probability:
            out["feedback_drop_probability"] = self.feedback_drop_probability
        if self.stalls:
            out["stall"] = [{"at_s": s.at_s, "duration_s": s.duration_s} for s in self.stalls]
        return out


@dataclass(frozen=True)
class TimingFaults:
    """``[timing_faults]`` of one profile."""

    source: str = "<none>"
    seed: int | None = None
    host: SideFaults = field(default_factory=SideFaults)
    robot: SideFaults = field(default_factory=SideFaults)
    trace: str | None = None  # path of a timing trace CSV (robot, lockstep)
    trace_steps: str | None = None  # path of its integration steps CSV, if any

    @property
    def active(self) -> bool:
        return self.host.active or self.robot.active or self.trace is not None

    def with_seed(self, seed: int | None) -> TimingFaults:
        """The same faults, seeded by ``seed`` if given (`--seed` overrides the profile)."""
        return self if seed is None else replace(self, seed=seed)

    def describe(self) -> dict[str, Any]:
        out: dict[str, Any] = {"source": self.source, "seed": self.seed}
        if self.host.active:
            out["host"] = self.host.describe()
        if self.robot.active:
            out["robot"] = self.robot.describe()
        if self.trace is not None:
            out["trace"] = self.trace
        return out


def _jitter(f: Fields) -> Jitter | None:
    if not f.has("jitter"):
        return None
    t = f.table("jitter")
    t.only({"distribution", "scale_s"})
    distribution = t.string("distribution", "normal")
    if distribution not in DISTRIBUTIONS:
        raise t.error(
            "distribution", f"must be one of {', '.join(DISTRIBUTIONS)}, got {distribution!r}"
        )
    return Jitter(distribution, t.number("scale_s", lo=0.0, hi=MAX_DELAY_S))


def _stalls(f: Fields) -> tuple[Stall, ...]:
    if not f.has("stall"):
        return ()
    raw = f.data["stall"]
    tables = [f.table("stall")] if isinstance(raw, dict) else f.tables("stall")
    out = []
    for t in tables:
        t.only({"at_s", "duration_s"})
        out.append(Stall(t.number("at_s", lo=0.0), t.number("duration_s", lo=0.0, hi=60.0)))
    return tuple(out)


def _side(f: Fields, allowed: set[str]) -> SideFaults:
    f.only(allowed)
    return SideFaults(
        latency_s=f.number("latency_s", 0.0, lo=0.0, hi=MAX_DELAY_S),
        jitter=_jitter(f),
        drop_probability=f.number("drop_probability", 0.0, lo=0.0, hi=1.0),
        feedback_delay_s=f.number("feedback_delay_s", 0.0, lo=0.0, hi=MAX_DELAY_S),
        feedback_drop_probability=f.number("feedback_drop_probability", 0.0, lo=0.0, hi=1.0),
        stalls=_stalls(f),
    )


def parse_timing_faults(f: Fields, *, host_allowed: bool) -> TimingFaults:
    """Parse ``f`` (the ``timing_faults`` table). ``host_allowed``: a bench profile (the host
    reads it); an effects profile configures the virtual robot only."""
    f.only({"seed", "host", "robot", "trace"})
    if f.has("host") and not host_allowed:
        raise f.error(
            "host",
            "host-side faults belong in a bench profile (the host never reads effects profiles)",
        )
    seed = f.integer("seed", None, lo=0, hi=2**63 - 1) if f.has("seed") else None
    host = _side(f.table("host"), HOST_KEYS) if f.has("host") else SideFaults()
    robot = _side(f.table("robot"), ROBOT_KEYS) if f.has("robot") else SideFaults()
    trace = trace_steps = None
    if f.has("trace"):
        t = f.table("trace")
        t.only({"file", "steps"})
        files = []
        for key in ("file", "steps"):
            if key == "steps" and not t.has(key):
                files.append(None)
                continue
            path = Path(t.string(key))
            if not path.is_absolute():
                path = Path(f.source).parent / path
            if not path.is_file():
                raise t.error(key, f"no such file: {path}")
            files.append(str(path))
        trace, trace_steps = files
    return TimingFaults(
        source=f.source, seed=seed, host=host, robot=robot, trace=trace, trace_steps=trace_steps
    )


def combine(*faults: TimingFaults | None) -> TimingFaults | None:
    """The faults of a bench and an effects profile together; one side (or the trace) may be
    configured in one of them only."""
    present = [t for t in faults if t is not None and t.active]
    if not present:
        return None
    if len(present) == 1:
        return present[0]
    a, b = present[0], present[1]
    for what, x, y in (
        ("host", a.host.active, b.host.active),
        ("robot", a.robot.active, b.robot.active),
        ("trace", a.trace is not None, b.trace is not None),
    ):
        if x and y:
            raise ValueError(
                f"{what}-side timing faults are set in both {a.source} and {b.source}: keep one"
            )
    return TimingFaults(
        source=f"{a.source} + {b.source}",
        seed=a.seed if a.seed is not None else b.seed,
        host=a.host if a.host.active else b.host,
        robot=a.robot if a.robot.active else b.robot,
        trace=a.trace or b.trace,
        trace_steps=a.trace_steps if a.trace else b.trace_steps,
    )


# numpy streams of a seed, one per kind of draw and side: changing a drop rate does not change
# the jitter sequence, and the host's jitter is the same sequence whichever side imposes it
STREAM_ROBOT_JITTER, STREAM_ROBOT_DROP, STREAM_HOST_JITTER = 1, 2, 3
STREAM_HOST_DROP, STREAM_HOST_FEEDBACK_DROP = 4, 5


def stream(seed: int | None, stream_id: int) -> np.random.Generator:
    """The numpy Generator of one stream of ``seed`` (default 0)."""
    return np.random.default_rng([int(seed or 0), stream_id])


def draw_jitter(rng: Any, jitter: Jitter | None) -> float:
    """One non-negative jitter sample J (seconds) from a numpy Generator."""
    if jitter is None or jitter.scale_s <= 0:
        return 0.0
    if jitter.distribution == "normal":
        return abs(float(rng.normal(0.0, jitter.scale_s)))
    if jitter.distribution == "uniform":
        return float(rng.uniform(0.0, jitter.scale_s))
    return float(rng.exponential(jitter.scale_s))


def to_toml(data: dict[str, Any]) -> str:
    """A profile's data as TOML (strings, numbers, booleans, lists and tables): enough to write
    a profile read with tomllib back out, e.g. an effects profile with timing faults added."""
    lines: list[str] = []

    def value(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, int):
            return str(v)
        if isinstance(v, float):
            if not math.isfinite(v):
                raise ValueError(f"cannot write {v} to TOML")
            return repr(v)
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, list | tuple):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        raise ValueError(f"cannot write {type(v).__name__} to TOML")

    def table(prefix: str, d: dict[str, Any]) -> None:
        scalars = {k: v for k, v in d.items() if not isinstance(v, dict)}
        subtables = {k: v for k, v in d.items() if isinstance(v, dict)}
        if prefix and (scalars or not subtables):
            lines.append(f"\n[{prefix}]")
        for k, v in scalars.items():
            lines.append(f"{k} = {value(v)}")
        for k, v in subtables.items():
            table(f"{prefix}.{k}" if prefix else k, v)

    table("", data)
    return "\n".join(lines).lstrip("\n") + "\n"


# ---- timing traces ----------------------------------------------------------------------------
TRACE_COLUMNS = ("k", "sample_s", "first_command_s", "command_s")


@dataclass
class TimingTrace:
    """Per cycle k, in robot seconds: when sample k is taken, when the first drive's command of
    cycle k (joint 1's) and when the whole command (every drive's) took effect; and ``steps``,
    the other times the robot integrated its plant up to (its period ticks, each frame), so a
    replay integrates on the same grid. Times may start anywhere (a robot's own clock)."""

    sample_s: np.ndarray
    command_s: np.ndarray
    first_command_s: np.ndarray | None = None  # None: every drive at command_s
    steps: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.first_command_s is None:
            self.first_command_s = self.command_s

    def __len__(self) -> int:
        return len(self.sample_s)


def _read_columns(path: Path, header: tuple[str, ...], what: str) -> np.ndarray:
    try:
        with open(path, newline="") as f:
            rows = list(csv.reader(f))
    except OSError as exc:
        raise ValueError(f"{path}: cannot read {what}: {exc.strerror}") from None
    if not rows or tuple(rows[0]) != header:
        raise ValueError(f"{path}: {what} needs the header {','.join(header)}")
    try:
        data = np.array([[float(x) for x in r] for r in rows[1:] if r], dtype=float)
    except ValueError:
        raise ValueError(f"{path}: {what} has a non-numeric value") from None
    if data.ndim != 2 or data.shape[0] < 1 or data.shape[1] != len(header):
        raise ValueError(f"{path}: {what} has no rows of {len(header)} values")
    if not np.all(np.isfinite(data)):
        raise ValueError(f"{path}: {what} has a missing value")
    return data


def read_trace(path: str | Path, steps: str | Path | None = None) -> TimingTrace:
    """A timing trace CSV (header ``k,sample_s,first_command_s,command_s``) and, optionally,
    its integration steps (header ``t``); ValueError with one line if bad."""
    path = Path(path)
    data = _read_columns(path, TRACE_COLUMNS, "timing trace")
    sample, first, command = data[:, 1], data[:, 2], data[:, 3]
    check_trace(sample, first, command, str(path))
    grid = None
    if steps is not None:
        grid = np.sort(_read_columns(Path(steps), ("t",), "timing steps")[:, 0])
    return TimingTrace(sample, np.maximum.accumulate(command), first, grid)


def check_trace(
    sample: np.ndarray,
    first: np.ndarray,
    command: np.ndarray,
    where: str,
    max_interval_s: float | None = MAX_FEEDBACK_BUDGET_S,
) -> None:
    """ValueError, one line naming ``where``, unless the times are a realtime run's: finite,
    samples increasing, sample_s <= first_command_s <= command_s, and no sample interval nor
    sample-to-command delay beyond ``max_interval_s`` (default :data:`MAX_FEEDBACK_BUDGET_S`;
    None: unbounded, for a recorded run read for analysis, where a longer stall is a gap the
    reader splits the run at, not a time to integrate over). Every reader of a trace (a trace
    file, a robot's event log, a run's host stamps) checks it here."""
    if len(sample) == 0:
        raise ValueError(f"{where}: no sample times")
    if not (np.all(np.isfinite(sample)) and np.all(np.isfinite(first))
            and np.all(np.isfinite(command))):  # fmt: skip
        raise ValueError(f"{where}: a sample or command time is not a finite number")
    steps = np.diff(sample)
    if np.any(steps <= 0):
        k = int(np.argmax(steps <= 0)) + 1
        raise ValueError(f"{where}: sample_s must increase (row {k} is not after row {k - 1})")
    if np.any(first < sample) or np.any(command < first):
        k = int(np.argmax((first < sample) | (command < first)))
        raise ValueError(f"{where}: row {k}: needs sample_s <= first_command_s <= command_s")
    longest = max(float(np.max(steps, initial=0.0)), float(np.max(command - sample)))
    if max_interval_s is not None and longest > max_interval_s:
        raise ValueError(
            f"{where}: an interval of {longest:.4g} s between samples or from a sample to its "
            f"command, beyond the longest feedback budget a bench allows "
            f"({max_interval_s:g} s): not the timing of a running realtime link"
        )


def write_trace(path: str | Path, trace: TimingTrace, steps: str | Path | None = None) -> Path:
    """Write ``trace`` (and its steps, if any, to ``steps``) exactly (repr of every float)."""
    path = Path(path)
    first = trace.first_command_s if trace.first_command_s is not None else trace.command_s
    with open(path, "w", newline="") as f:
        f.write(",".join(TRACE_COLUMNS) + "\n")
        for k, (s, a, c) in enumerate(zip(trace.sample_s, first, trace.command_s, strict=True)):
            f.write(f"{k},{float(s)!r},{float(a)!r},{float(c)!r}\n")
    if steps is not None and trace.steps is not None:
        with open(steps, "w", newline="") as f:
            f.write("t\n")
            f.writelines(f"{float(t)!r}\n" for t in trace.steps)
    return path


__all__ = [
    "TimingFaults",
    "TimingTrace",
    "check_trace",
    "combine",
    "parse_timing_faults",
    "read_trace",
    "write_trace",
]
