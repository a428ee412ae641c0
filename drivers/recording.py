"""The recording format (DESIGN.md): a run directory with signals.csv, meta.json, plots.

Row k of signals.csv: t = k·h; q = encoder reading sampled at t; tau = torque commanded at t and
held over [t, t + h) (zero-order hold), after quantization. Base columns t,q1,q2,tau1,tau2 in
s, rad, Nm; more columns may follow. Rows are written as they happen and flushed often, so a
crash leaves a readable partial recording; :func:`read_signals` reads one, dropping at most a
torn last line.

Shared by the host (``hil``) and the virtual robot's offline simulation, like the protocol codecs.
"""

from __future__ import annotations

import csv
import io
import json
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

BASE_COLUMNS = ("t", "q1", "q2", "tau1", "tau2")
SIGNALS = "signals.csv"
META = "meta.json"


class RecordingError(ValueError):
    """A recording that cannot be read; the message is one line naming the file."""


def write_json_atomic(path: Path, document: dict[str, Any]) -> None:
    """Write JSON so that a reader never sees half a file (write, then rename)."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(document, indent=2, sort_keys=False, default=_json_default) + "\n")
    os.replace(tmp, path)


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
    final status, so an interrupted run is recognisable as such.
    """

    def __init__(
        self,
        out_dir: str | Path,
        meta: dict[str, Any],
        extra_columns: Sequence[str] = (),
        flush_every: int = 50,
    ) -> None:
        self.dir = Path(out_dir)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.columns = (*BASE_COLUMNS, *extra_columns)
        self.meta = {
            **meta,
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
        elif issubclass(exc_type, KeyboardInterrupt):
            self.close("interrupted")
        else:
            self.close("failed", error=f"{exc_type.__name__}: {exc}")


def _fmt(value: float | int) -> str:
    # repr gives the shortest string that round-trips exactly: recordings are bit-comparable
    if type(value) is float or type(value) is int:
        return repr(value)
    if isinstance(value, int | np.integer):
        return str(int(value))
    return repr(float(value))


@dataclass
class Recording:
    """A loaded recording: columns as float arrays, plus meta.json if there was one."""

    path: Path
    columns: dict[str, np.ndarray]
    meta: dict[str, Any] = field(default_factory=dict)
    dropped_partial_row: bool = False

    @property
    def t(self) -> np.ndarray:
        return self.columns["t"]

    @property
    def q(self) -> np.ndarray:
        """Joint angles, shape (N, 2)."""
        return np.column_stack([self.columns["q1"], self.columns["q2"]])

    @property
    def tau(self) -> np.ndarray:
        """Held torques, shape (N, 2)."""
        return np.column_stack([self.columns["tau1"], self.columns["tau2"]])

    @property
    def period_s(self) -> float:
        if "period_s" in self.meta:
            return float(self.meta["period_s"])
        if len(self.t) < 2:
            raise RecordingError(f"{self.path}: fewer than two rows, cannot infer the period")
        return float(np.median(np.diff(self.t)))

    def __len__(self) -> int:
        return len(self.t)


def read_signals(path: str | Path) -> Recording:
    """Read a run directory or a bare CSV with at least the columns t,q1,q2,tau1,tau2.

    A torn last line (a crash mid-write) is dropped and flagged; any other malformed row is an
    error naming the file and line.
    """
    path = Path(path)
    csv_path = path / SIGNALS if path.is_dir() else path
    meta: dict[str, Any] = {}
    if path.is_dir() and (path / META).is_file():
        try:
            meta = json.loads((path / META).read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise RecordingError(f"{path / META}: not valid JSON ({exc})") from None
        if not isinstance(meta, dict):
            raise RecordingError(f"{path / META}: not a JSON object")
    try:
        text = csv_path.read_text()
    except OSError as exc:
        raise RecordingError(f"{csv_path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise RecordingError(f"{csv_path}: not UTF-8 text ({exc})") from None
    lines = text.splitlines()
    if not lines:
        raise RecordingError(f"{csv_path}: empty file, no header")
    header = next(csv.reader(io.StringIO(lines[0])), [])  # a blank first line: no columns
    header = [h.strip() for h in header]
    missing = [c for c in BASE_COLUMNS if c not in header]
    if missing:
        raise RecordingError(
            f"{csv_path}: missing column(s) {', '.join(missing)} (need {','.join(BASE_COLUMNS)})"
        )
    body = lines[1:]
    dropped = False
    if body and not text.endswith("\n"):
        body = body[:-1]  # the writer always ends rows with a newline: this one was torn
        dropped = True
    data = np.empty((len(body), len(header)))
    for i, line in enumerate(body):
        cells = line.split(",")
        if len(cells) != len(header):
            raise RecordingError(
                f"{csv_path}:{i + 2}: {len(cells)} fields, header has {len(header)}"
            )
        try:
            data[i] = [float(c) for c in cells]
        except ValueError:
            raise RecordingError(f"{csv_path}:{i + 2}: not a number in {line[:60]!r}") from None
    columns = {name: data[:, j] for j, name in enumerate(header)}
    return Recording(csv_path.parent if path.is_dir() else csv_path, columns, meta, dropped)


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

    fig, axes = plt.subplots(2, 2, figsize=(11, 6), sharex=True)
    for j in range(2):
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
