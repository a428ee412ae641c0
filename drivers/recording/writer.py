"""Writing a recording: :class:`RecordingWriter` (signals.csv rows as they happen, flushed often,
so a crash leaves a readable partial recording; meta.json at the end) and the run's
JointState .mcap beside it (:func:`write_run_mcap`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from drivers import containers
from drivers.process import interrupt_reason, process_stamp
from drivers.recording.format import META, SIGNALS, base_columns, write_json_atomic
from drivers.recording.reader import read_signals


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
