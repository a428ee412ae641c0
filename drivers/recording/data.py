"""The :class:`Recording` a reader returns (columns as float arrays, meta.json, what the reader
noticed) and the limits every reader holds a file to (sample period, line length, value range,
gaps and irregular sampling, meta.json field types).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from drivers.recording.format import RecordingError

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
META_TYPES: dict[str, tuple[type, ...]] = {
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


JSON_TYPE_NAMES = {int: "an integer", float: "a number", str: "a string", list: "a list",
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
