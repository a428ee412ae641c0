"""The recording format (docs/design.md): a run directory with signals.csv, meta.json, plots.

Row k of signals.csv: t = k·h; q = encoder reading sampled at t; tau = torque commanded at t and
held over [t, t + h) (zero-order hold), after quantization. Base columns t,q1,q2,tau1,tau2 in
s, rad, Nm (an n-joint arm: t,q1..qn,tau1..taun, :func:`base_columns`); more columns may
follow. Rows are written as they happen and flushed often, so a
crash leaves a readable partial recording; :func:`read_signals` reads one, dropping at most a
torn last line.

Shared by the host (``hil``) and the virtual robot's offline simulation, like the protocol codecs.
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import math
import os
import re
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from drivers import containers
from drivers.process import interrupt_reason, process_stamp
from profiles.recording_format import (
    LOOP_DELAY_MAX,
    TARGET_KINDS,
    RecordingFormat,
    load_format,
)

BASE_COLUMNS = ("t", "q1", "q2", "tau1", "tau2")


def base_columns(n_joints: int = 2) -> tuple[str, ...]:
    """``t, q1..qn, tau1..taun``: the base columns of an n-joint recording (2: BASE_COLUMNS)."""
    if n_joints < 1:
        raise ValueError(f"a recording has at least one joint, got {n_joints}")
    joints = range(1, n_joints + 1)
    return ("t", *(f"q{j}" for j in joints), *(f"tau{j}" for j in joints))


SIGNALS = "signals.csv"
META = "meta.json"


class RecordingError(ValueError):
    """A recording that cannot be read; the message is one line naming the file."""


def write_json_atomic(path: Path, document: dict[str, Any]) -> None:
    """Write JSON so that a reader never sees half a file (write, then rename); strict JSON
    (:func:`dumps_strict`: no NaN or Infinity)."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(dumps_strict(document, indent=2) + "\n")
    os.replace(tmp, path)


def dumps_strict(document: Any, **kwargs: Any) -> str:
    """``document`` as strict JSON (RFC 8259 has no NaN or Infinity, and strict parsers refuse
    Python's): every non-finite number becomes null, with a ``<key>_null_reason`` beside it
    (:func:`strict_json`); numpy scalars and arrays as numbers and lists, paths as strings.
    ``allow_nan=False`` is the guard: a non-finite number that gets past the sanitiser fails
    here, loudly, instead of writing invalid JSON."""
    return json.dumps(strict_json(document), allow_nan=False, default=_json_default, **kwargs)


def strict_json(value: Any) -> Any:
    """A copy of ``value`` (dicts, lists, tuples, numpy arrays and scalars, floats) in which
    every NaN or ±Infinity is None. In a dict, a key whose value was (or held) a non-finite
    number gets ``<key>_null_reason`` beside it saying which (``"NaN"``, or ``"NaN at index
    3, Infinity at index 5"`` for a list), so a null is never silent."""
    cleaned, _ = _strict(value)
    return cleaned


def _strict(value: Any) -> tuple[Any, str | None]:
    """(value with non-finite numbers as None, what was replaced or None)."""
    if isinstance(value, bool) or value is None or isinstance(value, int | str):
        return value, None
    if isinstance(value, np.ndarray):
        value = value.tolist()
    elif isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float):
        if math.isfinite(value):
            return value, None
        return None, "NaN" if math.isnan(value) else ("Infinity" if value > 0 else "-Infinity")
    if isinstance(value, Mapping):
        out: dict[Any, Any] = {}
        reasons: dict[str, str] = {}
        for key, item in value.items():
            out[key], why = _strict(item)
            if why is not None:
                reasons[f"{key}_null_reason"] = why
        for key, why in reasons.items():
            out.setdefault(key, f"not a finite number: {why}")
        return out, None  # its own keys say what they hold
    if isinstance(value, list | tuple):
        items, whys = [], []
        for i, item in enumerate(value):
            cleaned, why = _strict(item)
            items.append(cleaned)
            if why is not None and len(whys) < 3:
                whys.append(f"{why} at index {i}" if " at index " not in why else f"[{i}]: {why}")
        return items, (", ".join(whys) if whys else None)
    return value, None


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serializable: {type(value).__name__}")


class RecordingWriter:
    """Incremental writer of a run directory. Use as a context manager; rows go out as they come.

    ``meta`` is written at once with ``"status": "running"`` and rewritten on close with the
    final status, so an interrupted run is recognisable as such. It also gets the writing
    process's stamp (:func:`drivers.process.process_stamp`), so that a run whose writer was
    killed (meta.json still ``running``) reads as ``died`` (:func:`drivers.process.run_status`),
    whichever command wrote it.
    """

    def __init__(
        self,
        out_dir: str | Path,
        meta: dict[str, Any],
        extra_columns: Sequence[str] = (),
        flush_every: int = 50,
        n_joints: int = 2,
    ) -> None:
        self.dir = Path(out_dir)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.columns = (*base_columns(n_joints), *extra_columns)
        self.meta = {
            **meta,
            **process_stamp(),
            "status": "running",
            "columns": list(self.columns),
            "started_unix": time.time(),
        }
        self.rows = 0
        self.flush_every = max(1, flush_every)
        write_json_atomic(self.dir / META, self.meta)
        self._file = open(self.dir / SIGNALS, "w", newline="")  # noqa: SIM115 (closed in close())
        self._file.write(",".join(self.columns) + "\n")
        self._file.flush()

    def write(self, row: Sequence[float | int]) -> None:
        if len(row) != len(self.columns):
            raise ValueError(
                f"row has {len(row)} values, recording has {len(self.columns)} columns"
            )
        if {*map(type, row)} <= _PLAIN:  # the common row: repr each value, as _fmt would
            self._file.write(",".join(map(repr, row)) + "\n")
        else:
            self._file.write(",".join(_fmt(v) for v in row) + "\n")
        self.rows += 1
        if self.rows % self.flush_every == 0:
            self._file.flush()

    def close(self, status: str = "complete", **extra_meta: Any) -> None:
        if self._file.closed:
            return
        self._file.flush()
        self._file.close()
        self.meta.update(extra_meta)
        self.meta.update(status=status, rows=self.rows, finished_unix=time.time())
        write_json_atomic(self.dir / META, self.meta)

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.close("complete")
        elif issubclass(exc_type, KeyboardInterrupt):  # Ctrl-C, SIGTERM, SIGHUP: say which
            self.close("interrupted", reason=interrupt_reason())
        else:
            self.close("failed", error=f"{exc_type.__name__}: {exc}")


_PLAIN = {float, int}  # the value types _fmt writes as their repr (not bool, not numpy's)


def _fmt(value: float | int) -> str:
    # repr gives the shortest string that round-trips exactly: recordings are bit-comparable
    if type(value) is float or type(value) is int:
        return repr(value)
    if isinstance(value, int | np.integer):
        return str(int(value))
    return repr(float(value))


# --- reading -------------------------------------------------------------------------------------

# An interval this many times the median interval is a gap (rows lost or cut out): the rows on
# either side are different segments, which the analysis must not splice.
GAP_FACTOR = 10.0
# Intervals outside [1/f, f] × median (and not gaps) make the sampling "irregular" (a finding).
IRREGULAR_FACTOR = 1.5
# A sample period must lie in [PERIOD_MIN_S, PERIOD_MAX_S): a bench samples at ≥ 1 Hz (slower is
# t in ms, or a wrong period_s), and 1 µs is below any loop this bench or a real arm runs.
PERIOD_MIN_S = 1e-6
PERIOD_MAX_S = 1.0
CHUNK_CHARS = 1 << 22  # characters of text parsed at once: bounded memory, fast C parsing
# The longest line a reader takes (characters, without its newline): a recording's row is tens
# of numbers of at most ~25 characters each, so 128 KiB is thousands of columns; past it (a file
# with no newline, a field of megabytes, /dev/zero) the reader stops in one line, having held
# at most this much of it.
MAX_LINE_CHARS = 128 * 1024
# The largest |q| (rad) and |tau| (Nm) a recording may hold. Physically: 1e6 rad is 160,000
# turns, 1e6 Nm a hundred times the largest arm's joint torque, so a value past it is a unit, a
# parse or a logging fault, never a measurement. Numerically: every row the analyses build is a
# low-degree polynomial in q, its divided differences (h >= PERIOD_MIN_S = 1e-6 s) and tau, so
# with |q|, |tau| <= 1e6 each stays far inside float64's range and the solvers never see an
# overflow (a 1e300 ends in NaN rows, and LAPACK then prints on stdout and fails with no file,
# row or column named). Not tuned to any recording: any bound between the two arguments would do.
MAX_ABS_VALUE = 1e6
# meta.json fields an analysis reads, with the JSON types they must have
_META_TYPES: dict[str, tuple[type, ...]] = {
    "period_s": (float, int),
    "rows": (int,),
    "status": (str,),
    "robot": (str, type(None)),
    "mode": (str, type(None)),
    "kind": (str, type(None)),
    "protocol": (str, type(None)),
    "bench": (str, type(None)),
    "bench_profile": (str, type(None)),
    "experiment": (str, type(None)),
    "experiment_profile": (str, type(None)),
    "effects": (str, type(None)),
    "seed": (int, type(None)),
    "columns": (list,),
}


_JSON_NAMES = {int: "an integer", float: "a number", str: "a string", list: "a list",
               type(None): "null"}  # fmt: skip


@dataclass
class Recording:
    """A loaded recording: columns as float arrays, plus meta.json if there was one.

    ``columns`` holds ``t``, ``q1..qN``, ``tau1..tauN`` in this project's convention (row k's
    tau held over [t_k, t_{k+1}), whatever the file's own loop order was) and, unless the reader
    was told otherwise, the file's other columns (realigned rows, original names). ``t`` is the
    file's own time stamps, never replaced by k·h; ``period_s`` is a nominal period for display
    and defaults only. ``findings_on_read`` says what the reader noticed (gaps, irregular
    sampling, dropped duplicates, the loop delay applied); ``segments()`` the row ranges between
    gaps, which an analysis must not splice.
    """

    path: Path
    columns: dict[str, np.ndarray]
    meta: dict[str, Any] = field(default_factory=dict)
    dropped_partial_row: bool = False
    n_joints: int = 0  # 0: count the q1, tau1, q2, tau2, ... pairs in ``columns``
    torque_source: str = "commanded"
    loop_delay: int = 0
    time_source: str = "stamps"
    time_column: str = "t"  # the file's column the times came from
    findings_on_read: list[str] = field(default_factory=list)
    segment_starts: tuple[int, ...] = ()  # rows where a segment begins after a gap (not 0)
    file_joints: tuple[int, ...] = ()  # the file's joint number of q1..qN when some were left out
    # q and tau stacked once, by prefix, with the column arrays they were stacked from (not
    # copied by dataclasses.replace: a segment stacks its own)
    _stacked: dict[str, tuple[list[np.ndarray], np.ndarray]] = field(
        default_factory=dict, init=False, repr=False, compare=False
    )

    def __post_init__(self) -> None:
        if not self.n_joints:
            while (
                f"q{self.n_joints + 1}" in self.columns
                and f"tau{self.n_joints + 1}" in self.columns
            ):
                self.n_joints += 1

    @property
    def joints_text(self) -> str:
        """The joints in words for messages: "1 joint (q1)", "7 joints (q1..q7)"."""
        n = self.n_joints
        return "1 joint (q1)" if n == 1 else f"{n} joints (q1..q{n})"

    @classmethod
    def from_arrays(
        cls,
        t: np.ndarray,
        q: np.ndarray,
        tau: np.ndarray,
        *,
        source: str | Path = "",
        held: bool = False,
    ) -> Recording:
        """A recording of real sample times ``t`` (N,), positions ``q`` and torques ``tau``
        (N, n) made in memory (a log in another layout, a synthetic test), named ``source``.
        ``held``: row k's torque is a command held over [t_k, t_{k+1}), as this bench records
        it (:attr:`torque_held`); else a torque sampled with the positions at t_k."""
        t, q, tau = (np.asarray(x, dtype=float) for x in (t, q, tau))
        n = q.shape[1]
        columns = {"t": t}
        columns |= {f"q{j + 1}": q[:, j] for j in range(n)}
        columns |= {f"tau{j + 1}": tau[:, j] for j in range(n)}
        meta = {"period_s": float(np.median(np.diff(t)))} if held and len(t) > 1 else {}
        source_name = "commanded" if held else "measured"
        return cls(Path(source), columns, meta, n_joints=n, torque_source=source_name)

    @property
    def torque_held(self) -> bool:
        """Whether row k's torque is a command held over [t_k, t_{k+1}) (this bench's own
        recordings: commanded torques with meta.json's period beside them), not a torque
        sampled with the positions at t_k (a foreign file's, taken as such)."""
        return self.torque_source == "commanded" and "period_s" in self.meta

    def write_csv(self, path: str | Path) -> None:
        """``t,q1..qn,tau1..taun`` with a header line (a bare CSV :func:`read_signals` reads)."""
        n = self.n_joints
        header = ",".join(["t", *(f"q{j}" for j in range(1, n + 1))])
        header += "," + ",".join(f"tau{j}" for j in range(1, n + 1))
        data = np.column_stack([self.t, self.q, self.tau])
        np.savetxt(path, data, delimiter=",", header=header, comments="", fmt="%.9g")

    @property
    def t(self) -> np.ndarray:
        """The real sample times, s."""
        return self.columns["t"]

    @property
    def dt(self) -> np.ndarray:
        """The real intervals t_{k+1} − t_k, s, shape (N − 1,)."""
        return np.diff(self.t)

    @property
    def q(self) -> np.ndarray:
        """Joint angles, shape (N, n_joints), read-only (stacked once, :meth:`_joint_stack`)."""
        return self._joint_stack("q")

    @property
    def tau(self) -> np.ndarray:
        """Held torques, shape (N, n_joints), read-only: row k's acts over [t_k, t_{k+1})."""
        return self._joint_stack("tau")

    def _joint_stack(self, prefix: str) -> np.ndarray:
        """The columns ``prefix``1..N side by side, stacked on first use and kept while the
        same column arrays stand in ``columns`` (a long recording's q is ten megabytes; the
        property is read in per-chunk code). Read-only: every caller shares it."""
        cols = [self.columns[f"{prefix}{j + 1}"] for j in range(self.n_joints)]
        kept = self._stacked.get(prefix)
        if kept is not None and all(a is b for a, b in zip(kept[0], cols, strict=True)):
            return kept[1]
        stacked = np.column_stack(cols)
        stacked.flags.writeable = False
        self._stacked[prefix] = (cols, stacked)
        return stacked

    @property
    def q_target(self) -> np.ndarray | None:
        """The controller's target positions (N, n_joints), rad, sampled with q (a format's
        ``[layouts.targets]``), or None when the recording has none."""
        return self._targets("q_target")

    @property
    def qd_target(self) -> np.ndarray | None:
        """The controller's target velocities (N, n_joints), rad/s, or None."""
        return self._targets("qd_target")

    def _targets(self, prefix: str) -> np.ndarray | None:
        if f"{prefix}1" not in self.columns:
            return None
        return self._joint_stack(prefix)

    @property
    def period_s(self) -> float:
        """Nominal period: meta.json's (checked against t on read), else the median interval.
        For display and defaults only; the real intervals are :attr:`dt`."""
        if "period_s" in self.meta:
            return float(self.meta["period_s"])
        if len(self.t) < 2:
            raise RecordingError(f"{self.path}: fewer than two rows, cannot infer the period")
        return float(np.median(np.diff(self.t)))

    def segments(self) -> list[slice]:
        """Row ranges between gaps (one slice when there is none): analyse them separately."""
        edges = [0, *self.segment_starts, len(self)]
        return [slice(a, b) for a, b in itertools.pairwise(edges) if b > a]

    def segment(self, rows: slice) -> Recording:
        """The recording restricted to ``rows`` (one of :meth:`segments`)."""
        start, stop, _ = rows.indices(len(self))
        return replace(
            self,
            columns={name: col[start:stop] for name, col in self.columns.items()},
            findings_on_read=list(self.findings_on_read),
            segment_starts=tuple(s - start for s in self.segment_starts if start < s < stop),
        )

    def __len__(self) -> int:
        return len(self.t)


@dataclass
class _Plan:
    """Which file columns become t, q1..qN, tau1..tauN, and how the torque is aligned."""

    sources: dict[str, str]  # canonical name -> file column
    n_joints: int
    torque_source: str
    loop_delay: int
    own_grid: bool  # t is this bench's k·period_s (checked exactly against meta.json)
    identity: bool  # the file is already in this project's convention, names and rows
    scale: dict[str, float] = field(default_factory=dict)  # tauJ -> N·m per file unit
    joints: tuple[int, ...] = ()  # the file's joint number of q1..qN (() : 1..N)
    notes: list[str] = field(default_factory=list)  # what the plan did, for findings_on_read


def read_signals(
    path: str | Path,
    *,
    fmt: str | None = None,
    columns: str | Mapping[str, str] | None = None,
    torque: str | None = None,
    loop_delay: int | None = None,
    extra_columns: bool = True,
    min_rows: int = 0,
    effort_scale: Sequence[float] | None = None,
    leave_out: Sequence[int] | None = None,
    ignore: Sequence[str] | None = None,
    progress: Callable[..., None] | None = None,
) -> Recording:
    """Read a run directory, a bare CSV with the columns t,q1..qN,tau1..tauN, or a foreign CSV.

    ``fmt``: a recording-format profile (profiles/formats/<name>.toml, or a path) naming the
    file's columns, its torque sources and their loop delays. ``columns``: a map
    ``"t=time,q1=pos1,..."`` (or a dict) from this project's names to the file's, applied over
    the format's. ``torque``: a torque source the format offers (default: the format's).
    ``loop_delay`` (rows): the file's tau of row i acts between the q of rows i+d and i+d+1;
    the reader shifts tau so row k's is held over [t_k, t_{k+1}) and drops the rows left without
    a torque (default: the torque source's, 0 for this project's files). ``extra_columns``:
    keep the file's other columns (False: only t, q, tau; less memory). ``min_rows``: fewer rows
    is an error. ``effort_scale``: N·m per file unit of the torque, one factor or one per joint of
    the file (gear ratio × motor torque constant; over the format's). ``leave_out``: the file's
    joint numbers (1-based) not to read; the others become q1..qM. ``ignore``: columns (or groups,
    ``NAME`` for ``NAME[k]``) not to read, over the format's ``ignore``.

    The container follows from the path: an ``.npz`` archive, an ``.mcap`` file (default format
    ``ros2-joint-state``), a directory a format names one CSV per quantity in (joined on time),
    else a CSV or a run directory (:mod:`drivers.containers`); every one gets the checks below.
    ``progress(stage, done, total, unit)``: told the megabytes read after every chunk of a CSV's
    text (a command's throttled progress line).

    Checked on read, each failure a one-line :class:`RecordingError` naming the file and line:
    a malformed row, NaN/inf in t, q or tau, t not strictly increasing, t inconsistent with
    meta.json's ``period_s``, a meta field of the wrong type or range. Noted in
    ``findings_on_read``: exact duplicate rows (dropped), gaps (segments), irregular intervals.
    A torn last line (a crash mid-write) is dropped and flagged.
    """
    path = Path(path)
    if isinstance(min_rows, bool) or not isinstance(min_rows, int) or min_rows < 0:
        raise ValueError(f"min_rows must be an integer >= 0, got {min_rows!r}")
    options = (columns, torque, loop_delay, effort_scale, leave_out, ignore)
    if _is_container(path, fmt):
        return _read_container(path, fmt, options, extra_columns, min_rows)
    csv_path = path / SIGNALS if path.is_dir() else path
    meta = _read_meta(path / META) if path.is_dir() and (path / META).is_file() else {}
    ignored = _ignored(fmt, ignore)
    with _open_csv(csv_path) as f:
        try:
            header = _read_header(f, csv_path)
            plan = _plan(
                csv_path, header, meta, fmt, columns, torque, loop_delay, effort_scale, leave_out
            )
            keep = _kept(csv_path, header, plan, extra_columns, ignored)
            if len(set(header)) != len(header) and extra_columns:
                dup = next(h for h in header if header.count(h) > 1)
                raise RecordingError(f"{csv_path}: column {dup!r} appears twice in the header")
            skip = {i for i, c in enumerate(header) if c not in keep and _is_ignored(c, ignored)}
            data, dropped = _parse_body(
                f, csv_path, header, [header.index(c) for c in keep], skip, progress
            )
        except UnicodeDecodeError as exc:
            raise RecordingError(f"{csv_path}: not UTF-8 text ({exc})") from None
        except OSError as exc:
            raise RecordingError(f"{csv_path}: cannot read ({exc.strerror})") from None
    where = csv_path.parent if path.is_dir() else csv_path
    rec = _assemble(where, csv_path, data, keep, plan, meta, dropped)
    return _enough(rec, csv_path, min_rows)


def _is_container(path: Path, fmt: str | Path | None) -> bool:
    """Whether :func:`read_signals` reads ``path`` as a container (:func:`_read_container`): an
    .npz, an .mcap, or a directory of one CSV per quantity that the format names."""
    return path.suffix.lower() in (".npz", ".mcap") or (
        fmt is not None
        and path.is_dir()
        and not (path / SIGNALS).exists()
        and any(layout.streams for layout in load_format(fmt).layouts)
    )


def recording_names(path: str | Path, fmt: str | Path | None = None) -> list[str]:
    """The column names :func:`read_signals` sees in ``path`` read with the format ``fmt``: a
    CSV's (or a run directory's signals.csv's) header, a container's columns (an .npz array's
    ``NAME[k]``, an MCAP field's, the joined streams'), before any column map. Raises
    :class:`RecordingError` in one line when it cannot be read."""
    path = Path(path)
    if _is_container(path, fmt):
        if not path.exists():
            raise RecordingError(f"{path}: cannot read (No such file or directory)")
        is_mcap = path.suffix.lower() == ".mcap"
        name = fmt if fmt is not None else (DEFAULT_MCAP_FORMAT if is_mcap else None)
        form = load_format(name) if name is not None else None
        try:
            if is_mcap:
                return list(containers.mcap_table(path, form).names)
            if path.is_dir():
                return list(containers.csv_streams_table(path, form, _csv_table).names)
            return list(containers.npz_table(path).names)
        except containers.ContainerError as exc:
            raise RecordingError(str(exc)) from None
    csv_path = path / SIGNALS if path.is_dir() else path
    with _open_csv(csv_path) as f:
        try:
            return _read_header(f, csv_path)
        except UnicodeDecodeError as exc:
            raise RecordingError(f"{csv_path}: not UTF-8 text ({exc})") from None


def _enough(rec: Recording, label: Path, min_rows: int) -> Recording:
    if len(rec) < min_rows:
        what = "no rows (header only)" if len(rec) == 0 else f"only {len(rec)} row(s)"
        raise RecordingError(f"{label}: {what}; need at least {min_rows}")
    return rec


DEFAULT_MCAP_FORMAT = "ros2-joint-state"  # an .mcap read without --format (hil run --mcap)


def _read_container(
    path: Path,
    fmt: str | Path | None,
    options: tuple[Any, ...],
    extra_columns: bool,
    min_rows: int,
) -> Recording:
    """An .npz, .mcap or a directory of one CSV per quantity: a :class:`containers.Table`, then
    the plan and the checks of every recording (:func:`_plan`, :func:`_assemble`)."""
    columns, torque, loop_delay, effort_scale, leave_out, ignore = options
    if not path.exists():
        raise RecordingError(f"{path}: cannot read (No such file or directory)")
    is_mcap = path.suffix.lower() == ".mcap"
    name = fmt if fmt is not None else (DEFAULT_MCAP_FORMAT if is_mcap else None)
    form = load_format(name) if name is not None else None
    try:
        if is_mcap:
            table = containers.mcap_table(path, form)
        elif path.is_dir():
            table = containers.csv_streams_table(path, form, _csv_table)
        else:
            table = containers.npz_table(path)
    except containers.ContainerError as exc:
        raise RecordingError(str(exc)) from None
    plan = _plan(
        table.label,
        table.names,
        table.meta,
        form,
        columns,
        torque,
        loop_delay,
        effort_scale,
        leave_out,
    )
    plan.own_grid = False  # a container's t is its own stamps, never this bench's grid
    keep = _kept(table.label, table.names, plan, extra_columns, _ignored(form, ignore))
    try:
        data, keep = table.load(keep, list(dict.fromkeys(plan.sources.values())))
    except containers.ContainerError as exc:
        raise RecordingError(str(exc)) from None
    rec = _assemble(path, table.label, data, keep, plan, table.meta, False, table.locate)
    rec.findings_on_read[:0] = table.notes
    if table.torque_source is not None and torque is None and plan.torque_source != "columns":
        rec.torque_source = table.torque_source  # our own MCAP: the commanded, held torque
    return _enough(rec, table.label, min_rows)


MCAP = "run.mcap"  # hil run --mcap: the run as JointState messages beside signals.csv


def write_run_mcap(run_dir: str | Path) -> Path:
    """Write ``run_dir/run.mcap`` from the run's signals.csv and meta.json: one JSON
    ``sensor_msgs/JointState`` per row (stamp t, position q, effort tau) and meta.json as
    metadata (:func:`drivers.containers.write_mcap`); ``read_signals`` reads it back, equal to
    signals.csv (t to the nanosecond of a ROS stamp, q and tau exactly)."""
    run_dir = Path(run_dir)
    rec = read_signals(run_dir, extra_columns=False)
    out = run_dir / MCAP
    containers.write_mcap(out, rec.t, rec.q, rec.tau, rec.meta, torque_source=rec.torque_source)
    return out


def _csv_table(csv_path: Path) -> tuple[list[str], np.ndarray, Callable[[int], str]]:
    """Header and every column of one CSV (a stream of a joined recording), as floats."""
    with _open_csv(csv_path) as f:
        try:
            header = _read_header(f, csv_path)
            if len(set(header)) != len(header):
                dup = next(h for h in header if header.count(h) > 1)
                raise RecordingError(f"{csv_path}: column {dup!r} appears twice in the header")
            data, _ = _parse_body(f, csv_path, header, list(range(len(header))))
        except UnicodeDecodeError as exc:
            raise RecordingError(f"{csv_path}: not UTF-8 text ({exc})") from None
    return header, data, lambda i: f"{csv_path}:{i + 2}"


def _open_csv(csv_path: Path) -> io.TextIOWrapper:
    """The CSV opened as text (a one-line error if it cannot be)."""
    try:
        # utf-8-sig: a byte-order mark before the header (Excel's "CSV UTF-8") is dropped
        return open(csv_path, encoding="utf-8-sig", newline=None)
    except OSError as exc:
        raise RecordingError(f"{csv_path}: cannot read ({exc.strerror})") from None


def _read_header(f: io.TextIOBase, csv_path: Path) -> list[str]:
    """The first line's column names, stripped."""
    first = f.readline(MAX_LINE_CHARS + 2)  # bounded: a file with no newline too
    if not first:
        raise RecordingError(f"{csv_path}: empty file, no header")
    _check_line_length(csv_path, 1, len(first.rstrip("\n")))
    try:
        return [h.strip() for h in next(csv.reader(io.StringIO(first)), [])]
    except csv.Error as exc:
        raise RecordingError(f"{csv_path}:1: header is not CSV ({exc})") from None


def _ignored(
    fmt: str | Path | RecordingFormat | None, ignore: Sequence[str] | None
) -> tuple[str, ...]:
    """The columns (or groups) not to read: ``ignore`` and the format's layouts' (all of them:
    the layout is chosen afterwards, by the columns used)."""
    names = list(ignore or ())
    if fmt is not None:
        form = fmt if isinstance(fmt, RecordingFormat) else load_format(fmt)
        for layout in form.layouts:
            names.extend(layout.ignore)
    return tuple(names)


def _kept(
    label: Path, header: list[str], plan: _Plan, extra_columns: bool, ignored: tuple[str, ...]
) -> list[str]:
    """The file's columns to read: the plan's, and the others unless ``extra_columns`` is off or
    they are ignored (a column the plan uses may not be ignored)."""
    used = list(dict.fromkeys(plan.sources.values()))
    clash = [c for c in used if _is_ignored(c, ignored)]
    if clash:
        raise RecordingError(f"{label}: column {clash[0]} is both read and ignored")
    if not extra_columns:
        return used
    return [c for c in header if c in used or not _is_ignored(c, ignored)]


def _is_ignored(column: str, ignored: tuple[str, ...]) -> bool:
    """``column`` is named in ``ignored``, itself or as its group (``A`` for ``A[k]``)."""
    return any(column == g or column.startswith(g + "[") for g in ignored)


def _read_meta(meta_path: Path) -> dict[str, Any]:
    try:
        meta = json.loads(meta_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise RecordingError(f"{meta_path}: not valid JSON ({exc})") from None
    except OSError as exc:
        raise RecordingError(f"{meta_path}: cannot read ({exc.strerror})") from None
    if not isinstance(meta, dict):
        raise RecordingError(f"{meta_path}: not a JSON object")
    for key, types in _META_TYPES.items():
        if key not in meta:
            continue
        value = meta[key]
        if isinstance(value, bool) or not isinstance(value, types):
            names = " or ".join(_JSON_NAMES[t] for t in types if not (t is int and float in types))
            got = json.dumps(value)[:40]
            raise RecordingError(f"{meta_path}: field {key!r} must be {names}, got {got}")
    if "period_s" in meta:
        h = float(meta["period_s"])
        if not (math.isfinite(h) and PERIOD_MIN_S <= h < PERIOD_MAX_S):
            raise RecordingError(
                f"{meta_path}: field 'period_s' must be a finite number of seconds in "
                f"[{PERIOD_MIN_S:g}, {PERIOD_MAX_S:g}), got {meta['period_s']!r}"
            )
    if "rows" in meta and meta["rows"] < 0:
        raise RecordingError(f"{meta_path}: field 'rows' must be >= 0, got {meta['rows']}")
    if "columns" in meta and not all(isinstance(c, str) for c in meta["columns"]):
        raise RecordingError(f"{meta_path}: field 'columns' must be a list of strings")
    return meta


_CANONICAL = re.compile(r"^(t|q[1-9][0-9]*|tau[1-9][0-9]*)$")


def parse_column_map(text: str | Mapping[str, str]) -> dict[str, str]:
    """``"t=time,q1=pos1,tau1=tau_con1"`` (or a dict) → {canonical name: file column}, checked:
    names are t, qJ or tauJ, each given once, file columns non-empty."""
    if isinstance(text, Mapping):
        pairs = [(str(k), str(v)) for k, v in text.items()]
    else:
        pairs = []
        for item in str(text).split(","):
            if not item.strip():
                continue
            name, sep, column = item.partition("=")
            if not sep:
                raise ValueError(f"column map: {item.strip()!r} is not NAME=COLUMN")
            pairs.append((name.strip(), column.strip()))
    out: dict[str, str] = {}
    for name, column in pairs:
        if not _CANONICAL.match(name):
            raise ValueError(f"column map: {name!r} is not t, qJ or tauJ (J = 1, 2, ...)")
        if not column:
            raise ValueError(f"column map: {name}= names no column")
        if name in out:
            raise ValueError(f"column map: {name} given twice")
        out[name] = column
    if not out:
        raise ValueError("column map: empty (expected e.g. t=time,q1=pos1,tau1=tau_con1)")
    return out


def _plan(
    csv_path: Path,
    header: list[str],
    meta: dict[str, Any],
    fmt: str | Path | RecordingFormat | None,
    columns: str | Mapping[str, str] | None,
    torque: str | None,
    loop_delay: int | None,
    effort_scale: Sequence[float] | None = None,
    leave_out: Sequence[int] | None = None,
) -> _Plan:
    try:
        overrides = parse_column_map(columns) if columns is not None else {}
    except ValueError as exc:
        raise RecordingError(f"{csv_path}: {exc}") from None
    if loop_delay is not None and (
        isinstance(loop_delay, bool)
        or not isinstance(loop_delay, int | np.integer)
        or abs(int(loop_delay)) > LOOP_DELAY_MAX
    ):
        raise RecordingError(
            f"{csv_path}: loop delay must be an integer number of rows in "
            f"[-{LOOP_DELAY_MAX}, {LOOP_DELAY_MAX}], got {loop_delay!r}"
        )
    have = set(header)
    sources: dict[str, str] = {}
    scale: tuple[float, ...] | None = None
    targets: dict[str, tuple[str, ...]] = {}
    out_joints: set[int] = set(leave_out or ())
    if fmt is not None:
        form = fmt if isinstance(fmt, RecordingFormat) else load_format(fmt)
        try:
            layout = form.layout_for(header)
        except ValueError as exc:
            raise RecordingError(f"{csv_path}: format {form.name}: {exc}") from None
        if layout is None:
            need = "; ".join(
                f"{lay.name or 'layout'}: {', '.join(lay.missing(header))}" for lay in form.layouts
            )
            raise RecordingError(f"{csv_path}: not a {form.name} file (missing {need})")
        source_name = torque if torque is not None else layout.default_torque
        if source_name not in layout.torques:
            raise RecordingError(
                f"{csv_path}: format {form.name} ({layout.name}) has no {source_name!r} torque "
                f"(offers {', '.join(layout.torques)})"
            )
        src = layout.torques[source_name]
        scale = src.scale
        targets = layout.targets
        out_joints |= set(layout.leave_out)
        n = layout.n_joints
        sources["t"] = layout.time
        for j in range(n):
            sources[f"q{j + 1}"] = layout.positions[j]
            sources[f"tau{j + 1}"] = src.columns[j]
        default_delay = src.loop_delay
    else:
        if torque not in (None, "commanded"):
            raise RecordingError(
                f"{csv_path}: a file read without --format holds one torque, 'commanded' "
                f"(got {torque!r}); name the column with --columns tau1=...,tau2=..."
            )
        source_name = "commanded"
        default_delay = 0
        n = 0
        while {f"q{n + 1}", f"tau{n + 1}"} <= have | set(overrides):
            n += 1
        if not overrides:
            # one q and one tau per joint, at least one joint (a pendulum has one); a q or tau
            # beyond the last pair is a joint with half its columns, not to be dropped quietly
            unpaired = {f"q{n + 1}": f"tau{n + 1}", f"tau{n + 1}": f"q{n + 1}"}
            missing = [c for c in base_columns(max(n, 1)) if c not in have]
            missing += [o for c, o in unpaired.items() if c in have and o not in missing]
            if missing:
                raise RecordingError(
                    f"{csv_path}: missing column(s) {', '.join(missing)} "
                    f"(need t,q1..qN,tau1..tauN: a q and a tau per joint)"
                )
        for name in ("t", *(f"{p}{j + 1}" for p in ("q", "tau") for j in range(n))):
            sources[name] = name
        # this project's own names for the controller's targets (Recording.q_target), read
        # when the file has them for every joint
        for kind, prefix in TARGET_KINDS.items():
            names = tuple(f"{prefix}{j + 1}" for j in range(n))
            if n and set(names) <= have:
                targets[kind] = names
    for name, column in overrides.items():
        joint = int(name.removeprefix("tau").removeprefix("q")) if name != "t" else 0
        if joint > n:
            raise RecordingError(
                f"{csv_path}: column map names {name} but the recording has {n} joint(s) "
                f"(map q1..qN and tau1..tauN together)"
            )
        sources[name] = column
    if any(name.startswith("tau") for name in overrides):
        source_name = "columns"
        scale = None  # a torque named by --columns is in N·m unless --effort-scale says not
    if n < 1:
        raise RecordingError(f"{csv_path}: no joints (map q1 and tau1 at least)")
    missing = sorted({c for c in sources.values() if c not in have})
    if missing:
        raise RecordingError(
            f"{csv_path}: no column(s) {', '.join(missing)} in the header "
            f"({', '.join(header[:12])}{', ...' if len(header) > 12 else ''})"
        )
    if effort_scale is not None:
        scale = tuple(float(x) for x in effort_scale)
        if len(scale) not in (1, n) or not all(math.isfinite(x) and x != 0 for x in scale):
            raise RecordingError(
                f"{csv_path}: the effort conversion must be 1 or {n} nonzero factors (one per "
                f"joint of the file), got {len(scale)}"
            )
    notes: list[str] = []
    if scale is not None:
        factors = scale * n if len(scale) == 1 else scale
        shown = ", ".join(f"{x:g}" for x in factors)
        notes.append(f"torque converted from the file's unit to N·m: × [{shown}] per joint")
    for kind, cols in targets.items():
        prefix = TARGET_KINDS[kind]
        for j, column in enumerate(cols):
            sources[f"{prefix}{j + 1}"] = column
    joints = tuple(range(1, n + 1))
    if out_joints:
        bad = sorted(j for j in out_joints if not 1 <= j <= n)
        if bad:
            raise RecordingError(
                f"{csv_path}: cannot leave out joint {bad[0]}: the file has joints 1..{n}"
            )
        joints = tuple(j for j in joints if j not in out_joints)
        if not joints:
            raise RecordingError(f"{csv_path}: every joint left out; nothing to read")
        renamed = {"t": sources["t"]}
        for name, column in sources.items():
            m = re.match(r"^([a-z_]+?)([1-9][0-9]*)$", name)
            if m and int(m.group(2)) in joints:
                renamed[f"{m.group(1)}{joints.index(int(m.group(2))) + 1}"] = column
        sources = renamed
        notes.append(
            f"left out joint(s) {', '.join(map(str, sorted(out_joints)))} of the file's {n}: "
            f"q1..q{len(joints)} are its joints {', '.join(map(str, joints))}"
        )
    by_joint = {}
    if scale is not None:
        factors = scale * n if len(scale) == 1 else scale
        by_joint = {f"tau{k + 1}": factors[j - 1] for k, j in enumerate(joints)}
    delay = int(loop_delay) if loop_delay is not None else default_delay
    own = fmt is None and sources["t"] == "t"
    identity = fmt is None and delay == 0 and not notes and all(k == v for k, v in sources.items())
    return _Plan(
        sources=sources,
        n_joints=len(joints),
        torque_source=source_name,
        loop_delay=delay,
        own_grid=own and "period_s" in meta,
        identity=identity,
        scale=by_joint,
        joints=joints if out_joints else (),
        notes=notes,
    )


def _check_line_length(csv_path: Path, line_no: int, length: int) -> None:
    if length > MAX_LINE_CHARS:
        raise RecordingError(
            f"{csv_path}:{line_no}: line longer than {MAX_LINE_CHARS // 1024} KiB (a file "
            "without newlines, a huge field, or not a CSV recording at all)"
        )


def _line_chunks(f: io.TextIOBase, csv_path: Path, line_no: int) -> Iterator[list[str]]:
    """The file's remaining lines in lists of about :data:`CHUNK_CHARS` characters, each line
    ending in its newline but perhaps the very last (torn); a line longer than
    :data:`MAX_LINE_CHARS` stops the reading, having held at most a chunk and that line."""
    rest = ""
    while True:
        block = f.read(CHUNK_CHARS)
        if not block:
            _check_line_length(csv_path, line_no, len(rest))
            if rest:
                yield [rest]
            return
        parts = (rest + block).split("\n")
        rest = parts.pop()
        if parts:
            longest = max(range(len(parts)), key=lambda i: len(parts[i]))
            _check_line_length(csv_path, line_no + longest, len(parts[longest]))
        _check_line_length(csv_path, line_no + len(parts), len(rest))
        if parts:
            line_no += len(parts)
            yield [p + "\n" for p in parts]


def _parse_body(
    f: io.TextIOBase,
    csv_path: Path,
    header: list[str],
    keep: list[int],
    skip: set[int] | None = None,
    progress: Callable[..., None] | None = None,
) -> tuple[np.ndarray, bool]:
    """Parse the rows after the header into a (rows, len(keep)) float array, chunk by chunk:
    the text of at most :data:`CHUNK_CHARS` characters is held at once (lines of at most
    :data:`MAX_LINE_CHARS`); the array grows in place. The fields ``skip`` (ignored columns,
    e.g. text) are not parsed; they read as NaN. ``progress``: as :func:`read_signals`'s."""
    ncols = len(header)
    cap = 0
    out = np.empty((0, len(keep)))
    rows = 0
    dropped = False
    size = os.fstat(f.fileno()).st_size if hasattr(f, "fileno") else 0
    line_no = 2  # file line of the chunk's first row (the header is line 1)
    for lines in _line_chunks(f, csv_path, line_no):
        if not lines[-1].endswith("\n"):
            lines.pop()  # the writer always ends rows with a newline: this one was torn
            dropped = True
        if not lines:
            break
        block = _parse_chunk(lines, csv_path, ncols, line_no, skip)
        if rows + len(block) > cap:
            if cap == 0:  # size the array from the first chunk's bytes per row
                per_row = max(1.0, sum(len(s) for s in lines) / len(lines))
                cap = max(len(block), int(size / per_row * 1.02) + 16)
            else:
                cap = max(rows + len(block), int(cap * 1.25))
            out.resize((cap, len(keep)), refcheck=False)
        out[rows : rows + len(block)] = block[:, keep]
        rows += len(block)
        if progress is not None and size:
            done = f.buffer.tell() if hasattr(f, "buffer") else 0
            progress(f"reading {csv_path.name}", done // 1_000_000, size // 1_000_000, "MB")
        line_no += len(lines)
        if dropped:
            break
    out.resize((rows, len(keep)), refcheck=False)
    return out, dropped


def _parse_chunk(
    lines: list[str], csv_path: Path, ncols: int, line_no: int, skip: set[int] | None = None
) -> np.ndarray:
    """Rows of text → floats: numpy's C parser first; where it refuses (or skips a blank line),
    line by line, for the exact error or for what Python's float() accepts and it does not.
    Fields ``skip`` are not parsed (NaN)."""
    if skip:
        return _parse_chunk_skipping(lines, csv_path, ncols, line_no, skip)
    try:
        block = np.loadtxt(lines, delimiter=",", comments=None, dtype=float, ndmin=2)
        if block.shape == (len(lines), ncols):
            return block
    except Exception:  # any refusal: the line-by-line parse below says why
        pass
    block = np.empty((len(lines), ncols))
    for i, line in enumerate(lines):
        text = line.rstrip("\n")
        cells = text.split(",")
        if len(cells) != ncols:
            raise RecordingError(
                f"{csv_path}:{line_no + i}: {len(cells)} fields, header has {ncols}"
            )
        try:
            block[i] = [float(c) for c in cells]
        except ValueError:
            raise RecordingError(
                f"{csv_path}:{line_no + i}: not a number in {text[:60]!r}"
            ) from None
    return block


def _parse_chunk_skipping(
    lines: list[str], csv_path: Path, ncols: int, line_no: int, skip: set[int]
) -> np.ndarray:
    """:func:`_parse_chunk` of a file with ignored columns: numpy's parser on the others, after
    every line's field count is checked (its ``usecols`` would not)."""
    for i, line in enumerate(lines):
        if line.count(",") != ncols - 1:
            n = line.count(",") + 1
            raise RecordingError(f"{csv_path}:{line_no + i}: {n} fields, header has {ncols}")
    use = [j for j in range(ncols) if j not in skip]
    block = np.full((len(lines), ncols), np.nan)
    try:
        block[:, use] = np.loadtxt(
            lines, delimiter=",", comments=None, dtype=float, ndmin=2, usecols=use
        )
        return block
    except Exception:  # the line that refused, below
        pass
    for i, line in enumerate(lines):
        cells = line.rstrip("\n").split(",")
        try:
            block[i, use] = [float(cells[j]) for j in use]
        except ValueError:
            raise RecordingError(
                f"{csv_path}:{line_no + i}: not a number in {line.rstrip()[:60]!r}"
            ) from None
    return block


def _assemble(
    where: Path,
    csv_path: Path,
    data: np.ndarray,
    keep: list[str],
    plan: _Plan,
    meta: dict[str, Any],
    dropped: bool,
    locate: Callable[[int], str] | None = None,
) -> Recording:
    """Check t, drop exact duplicates, find gaps, apply the loop delay, the torque's conversion
    and the joints left out: the :class:`Recording`. ``locate(i)`` names data row i in an error
    (default: ``csv_path`` and its line, i + 2)."""
    if locate is None:

        def locate(i: int) -> str:
            return f"{csv_path}:{i + 2}"

    col = {name: j for j, name in enumerate(keep)}
    used = [col[plan.sources[name]] for name in plan.sources]
    findings: list[str] = []
    if dropped:
        findings.append("dropped a torn last line (a crash mid-write)")
    n_rows = len(data)
    # NaN / inf where the analysis reads: the file's line
    for name, j in zip(plan.sources, used, strict=True):
        bad = ~np.isfinite(data[:, j])
        if bad.any():
            i = int(np.argmax(bad))
            raise RecordingError(
                f"{locate(i)}: {plan.sources[name]} = {float(data[i, j])!r} is not a finite number"
            )
        if name != "t":  # t: its own checks below (increasing, its period)
            beyond = np.abs(data[:, j]) > MAX_ABS_VALUE
            if beyond.any():
                i = int(np.argmax(beyond))
                unit = "rad" if name.startswith("q") else "Nm"
                raise RecordingError(
                    f"{locate(i)}: {plan.sources[name]} = {float(data[i, j])!r}: value "
                    f"out of range (|{name}| <= {MAX_ABS_VALUE:g} {unit} for any arm; wrong "
                    "units or a logging fault?)"
                )
    t = data[:, col[plan.sources["t"]]]
    dt = np.diff(t)
    back = dt < 0
    if back.any():
        i = int(np.argmax(back)) + 1
        raise RecordingError(
            f"{locate(i)}: t steps back from {float(t[i - 1])!r} to {float(t[i])!r} s "
            "(rows out of order? t must increase)"
        )
    rows = np.arange(n_rows)
    same_t = np.flatnonzero(dt == 0) + 1
    if len(same_t):
        vals = data[:, used]
        differs = np.any(vals[same_t] != vals[same_t - 1], axis=1)
        if differs.any():
            i = int(same_t[np.argmax(differs)])
            raise RecordingError(
                f"{locate(i)}: t = {float(t[i])!r} s again with other values (two "
                "samples at one time)"
            )
        # An exact copy of the row before carries no information; kept, it would count the
        # same sample twice (with period_s from meta.json: time stretched, θ1 off by 4×).
        findings.append(
            f"dropped {len(same_t)} exact duplicate row(s) (first at "
            f"{_within(locate(int(same_t[0])), csv_path)})"
        )
        rows = np.delete(rows, same_t)
        t = t[rows]
        dt = np.diff(t)
    starts = _check_times(csv_path, t, dt, plan, meta, findings)
    n = len(rows)
    if "rows" in meta and meta.get("status") == "complete" and meta["rows"] != n_rows:
        findings.append(f"meta.json says {meta['rows']} rows, the file holds {n_rows}")
    # loop delay: the file's tau of row i acts over [t_{i+d}, t_{i+d+1}); per segment, so that a
    # torque never crosses a gap
    d = plan.loop_delay
    tau_rows = rows
    if d != 0 or len(same_t):
        edges = [0, *starts, n]
        keep_pos, tau_pos, new_starts = [], [], []
        length = 0
        lost = 0
        for a, b in itertools.pairwise(edges):
            if b - a <= abs(d):
                lost += b - a
                continue
            if length:
                new_starts.append(length)
            k = np.arange(a + max(d, 0), b + min(d, 0))
            keep_pos.append(k)
            tau_pos.append(k - d)
            length += len(k)
            lost += (b - a) - len(k)
        keep_idx = np.concatenate(keep_pos) if keep_pos else np.zeros(0, dtype=int)
        tau_idx = np.concatenate(tau_pos) if tau_pos else np.zeros(0, dtype=int)
        tau_rows = rows[tau_idx]
        rows = rows[keep_idx]
        starts = new_starts
        if d != 0:
            findings.append(
                f"loop delay {d}: the file's torque of row i acts between rows {_row(d)} and "
                f"{_row(d + 1)}; shifted to this project's hold, {lost} row(s) dropped at "
                "segment ends"
            )
    if plan.identity and len(rows) == n_rows:
        columns = {name: data[:, j] for j, name in enumerate(keep)}
    else:
        columns = {"t": data[rows, col[plan.sources["t"]]]}
        for j in range(plan.n_joints):
            columns[f"q{j + 1}"] = data[rows, col[plan.sources[f"q{j + 1}"]]]
        for j in range(plan.n_joints):
            tau = data[tau_rows, col[plan.sources[f"tau{j + 1}"]]]
            scale = plan.scale.get(f"tau{j + 1}")
            columns[f"tau{j + 1}"] = tau * scale if scale is not None else tau
        for name, source in plan.sources.items():
            if name not in columns:  # the controller's targets: sampled with q
                columns[name] = data[rows, col[source]]
        taken = set(plan.sources.values())
        for name in keep:
            if name not in columns and name not in taken:
                columns[name] = data[rows, col[name]]
    findings.extend(plan.notes)
    if not plan.own_grid and len(rows):
        findings.extend(_mostly_zero(columns, plan))
    return Recording(
        where,
        columns,
        meta,
        dropped,
        n_joints=plan.n_joints,
        torque_source=plan.torque_source,
        loop_delay=d,
        time_source="stamps",
        time_column=plan.sources["t"],
        findings_on_read=findings,
        segment_starts=tuple(int(s) for s in starts),
        file_joints=plan.joints,
    )


def _within(where: str, label: Path) -> str:
    """A row's place without the file's name: ``line 5`` for ``FILE:5``, ``row 7`` for
    ``FILE: row 7``."""
    rest = where.removeprefix(f"{label}:").strip()
    return f"line {rest}" if rest.isdigit() else rest


MOSTLY_ZERO = 0.5  # a joint whose torque is exactly 0 in more than this share of rows is noted


def _mostly_zero(columns: dict[str, np.ndarray], plan: _Plan) -> list[str]:
    """A note naming the joints whose torque is exactly zero in most rows (a joint without a
    drive or sensor, a logger writing 0 for 'no value'): to leave out, or to look at."""
    notes = []
    for j in range(plan.n_joints):
        share = float(np.mean(columns[f"tau{j + 1}"] == 0.0))
        if share > MOSTLY_ZERO:
            file_joint = plan.joints[j] if plan.joints else j + 1
            notes.append(
                f"joint {j + 1} ({plan.sources[f'tau{j + 1}']}): torque exactly 0 in "
                f"{share:.0%} of rows: a passive joint (keep it: its torque is 0), or one "
                f"whose drive or sensor was not logged (leave it out: --leave-out-joints "
                f"{file_joint} or the format's leave_out)?"
            )
    return notes


def reassemble(rec: Recording, columns: dict[str, np.ndarray], note: str) -> Recording:
    """``rec`` with new ``columns`` (same rows, same names; e.g. a realtime run moved onto its
    real sample times, drivers/realtime_times.py), checked as on read: t increasing, gaps and
    irregular intervals noted afresh. ``note`` comes first in ``findings_on_read``; the reader's
    other notes that were not about the old time stamps are kept."""
    names = ["t", *(f"{p}{j + 1}" for p in ("q", "tau") for j in range(rec.n_joints))]
    keep = list(columns)
    plan = _Plan(
        sources={name: name for name in names},
        n_joints=rec.n_joints,
        torque_source=rec.torque_source,
        loop_delay=0,
        own_grid=False,
        identity=True,
    )
    data = np.column_stack([np.asarray(columns[name], float) for name in keep])
    csv_path = rec.path / SIGNALS if rec.path.is_dir() else rec.path
    out = _assemble(rec.path, csv_path, data, keep, plan, rec.meta, False)
    timing = ("gap(s) in t", "irregular sampling")
    old = [f for f in rec.findings_on_read if not any(w in f for w in timing)]
    out.findings_on_read = [note, *old, *out.findings_on_read]
    return out


def _check_times(
    csv_path: Path,
    t: np.ndarray,
    dt: np.ndarray,
    plan: _Plan,
    meta: dict[str, Any],
    findings: list[str],
) -> list[int]:
    """t against meta.json's period_s, gaps and irregular intervals; returns the rows where a
    segment begins after a gap. ``t`` is strictly increasing here."""
    if len(t) < 2:
        return []
    if plan.own_grid:
        # this bench's writer: t = k·h exactly (repr round-trips), from 0
        h = float(meta["period_s"])
        k = np.rint(t / h)
        off = np.abs(t - k * h) > 1e-6 * h + 4 * np.spacing(np.abs(t))
        if off.any():
            i = int(np.argmax(off))
            raise RecordingError(
                f"{csv_path}:{i + 2}: t = {float(t[i])!r} s is not a multiple of meta.json's "
                f"period_s = {h!r} s (t in other units, or period_s wrong?)"
            )
        steps = np.diff(k)
        if np.median(steps) != 1:
            raise RecordingError(
                f"{csv_path}: t advances {np.median(steps):g} × meta.json's period_s = {h!r} s "
                "per row; this bench writes one period per row (t in ms, or period_s wrong?)"
            )
        if k[0] != 0:
            raise RecordingError(
                f"{csv_path}:2: t starts at {float(t[0])!r} s; this bench writes t = k·period_s "
                "from 0 (t shifted, or the first rows cut out?)"
            )
        gaps = np.flatnonzero(steps > 1)
        _note_gaps(findings, t, gaps, (steps[gaps] - 1).astype(int))
        return [int(g) + 1 for g in gaps]
    med = float(np.median(dt))
    if med >= PERIOD_MAX_S:
        raise RecordingError(
            f"{csv_path}: the median interval of {plan.sources['t']} is {med:g} s, not a "
            f"dynamics recording (t in ms?)"
        )
    if "period_s" in meta:
        h = float(meta["period_s"])
        if not 0.5 <= med / h <= 2.0:
            raise RecordingError(
                f"{csv_path}: median interval of {plan.sources['t']} {med:g} s is inconsistent "
                f"with meta.json's period_s = {h!r} s"
            )
    is_gap = dt > GAP_FACTOR * med
    gaps = np.flatnonzero(is_gap)
    _note_gaps(findings, t, gaps, np.rint(dt[gaps] / med).astype(int) - 1)
    inner = dt[~is_gap]
    if len(inner) and (
        inner.max() > IRREGULAR_FACTOR * med or inner.min() < med / IRREGULAR_FACTOR
    ):
        late = int(np.sum(inner > IRREGULAR_FACTOR * med))
        findings.append(
            f"irregular sampling: intervals {inner.min() * 1e3:.3g} to {inner.max() * 1e3:.3g} "
            f"ms, median {med * 1e3:.3g} ms, {late} over {IRREGULAR_FACTOR:g}× the median; "
            "the real time stamps are kept"
        )
    return [int(g) + 1 for g in gaps]


def _row(offset: int) -> str:
    return f"i{offset:+d}" if offset else "i"


def _note_gaps(findings: list[str], t: np.ndarray, gaps: np.ndarray, missing: np.ndarray) -> None:
    if not len(gaps):
        return
    shown = ", ".join(
        f"{t[g]:.6g} to {t[g + 1]:.6g} s (~{m} rows)"
        for g, m in zip(gaps[:3], missing[:3], strict=True)
    )
    more = f" and {len(gaps) - 3} more" if len(gaps) > 3 else ""
    findings.append(
        f"{len(gaps)} gap(s) in t: {shown}{more}; {len(gaps) + 1} segments, not to be spliced"
    )


def plot_positions(
    rec: Recording,
    out_png: str | Path,
    title: str = "",
    reference: Recording | None = None,
    reference_label: str = "reference",
) -> Path:
    """Joint positions (rad, as signals.csv) and torques against time (the layout of Reyes &
    Kelly Fig. 2). A run that did not complete (meta.json status) or whose last row was torn is
    marked so in the title and by a line where it ended."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = rec.n_joints
    fig, axes = plt.subplots(2, n, figsize=(5.5 * n, 6), sharex=True, squeeze=False)
    for j in range(n):
        ax = axes[0, j]
        ax.plot(rec.t, rec.q[:, j], lw=1.2, label="recorded")
        if reference is not None:
            ax.plot(reference.t, reference.q[:, j], lw=1.0, ls="--", label=reference_label)
            ax.legend(loc="best", fontsize=8)
        ax.set_ylabel(f"q{j + 1} [rad]")
        ax.grid(True, alpha=0.3)
        ax2 = axes[1, j]
        ax2.plot(rec.t, rec.tau[:, j], lw=0.8, color="tab:red")
        ax2.set_ylabel(f"τ{j + 1} [Nm]")
        ax2.set_xlabel("t [s]")
        ax2.grid(True, alpha=0.3)
    title = title or str(rec.path)
    status = rec.meta.get("status")
    ended = None
    if status not in (None, "complete"):
        ended = f"{str(status).upper()} run: {rec.meta.get('reason') or 'no reason given'}"
    elif rec.dropped_partial_row:
        ended = "TRUNCATED recording: its last row was torn"
    if ended is not None and len(rec):
        title = f"{title}\n{ended} (ends at t = {rec.t[-1]:.3f} s)"
        for ax in axes.flat:
            ax.axvline(rec.t[-1], color="tab:red", lw=1.0, ls=":")
    fig.suptitle(title, color="tab:red" if ended else "black", fontsize=10 if ended else None)
    fig.tight_layout()
    out_png = Path(out_png)
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    return out_png


__all__ = [
    "BASE_COLUMNS",
    "META",
    "SIGNALS",
    "Recording",
    "RecordingError",
    "RecordingWriter",
    "dumps_strict",
    "parse_column_map",
    "plot_positions",
    "read_signals",
    "reassemble",
    "recording_names",
    "strict_json",
    "write_json_atomic",
    "write_run_mcap",
]
