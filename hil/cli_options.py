"""Options shared by the `hil` commands: how to read a recording, and where to write output.

* :func:`add_recording_options` / :func:`read_recording`: ``--format``, ``--columns``,
  ``--torque``, ``--loop-delay`` for every command that reads a recording (identify --from and
  --validate, diagnose, replay), turned into :func:`drivers.recording.read_signals` arguments
  (docs/recordings.md).
* :func:`add_out_options` / :func:`prepare_out_dir`: ``--overwrite``; a command refuses to write
  into a non-empty output directory without it, so two runs never mix their files.

Bad values raise ``ValueError`` / :class:`~drivers.recording.RecordingError` with a one-line
message; ``hil``'s main turns them into ``hil <command>: error: ...`` and exit status 2.
Imports drivers and profiles only.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from drivers.recording import (
    SIGNALS,
    Recording,
    RecordingError,
    parse_column_map,
    read_signals,
)
from profiles.recording_format import LOOP_DELAY_MAX

TORQUE_SOURCES_HELP = "commanded (default), measured, or another source the --format offers"


def add_recording_options(p: argparse.ArgumentParser) -> None:
    """``--format``, ``--columns``, ``--torque``, ``--loop-delay`` (docs/recordings.md)."""
    g = p.add_argument_group("reading recordings (docs/recordings.md)")
    g.add_argument(
        "--format",
        dest="recording_format",
        default=None,
        metavar="NAME|FILE",
        help="recording-format profile of foreign CSVs (profiles/formats: dfki); default: this "
        "bench's t,q1,q2,tau1,tau2",
    )
    g.add_argument(
        "--columns",
        default=None,
        metavar="MAP",
        help="column map over the format's, e.g. t=time,q1=pos_meas1,q2=pos_meas2,"
        "tau1=tau_con1,tau2=tau_con2",
    )
    g.add_argument("--torque", default=None, metavar="SOURCE", help=TORQUE_SOURCES_HELP)
    g.add_argument(
        "--loop-delay",
        type=int,
        default=None,
        metavar="ROWS",
        help="the file's tau of row i acts between the q of rows i+d and i+d+1 (default: the "
        "format's; 0 for this bench's recordings)",
    )


def recording_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """The :func:`read_signals` keyword arguments the options ask for, checked."""
    columns = getattr(args, "columns", None)
    if columns is not None:
        try:
            parse_column_map(columns)
        except ValueError as exc:
            raise ValueError(f"--columns: {exc}") from None
    delay = getattr(args, "loop_delay", None)
    if delay is not None and abs(delay) > LOOP_DELAY_MAX:
        raise ValueError(
            f"--loop-delay must be in [-{LOOP_DELAY_MAX}, {LOOP_DELAY_MAX}] rows, got {delay}"
        )
    torque = getattr(args, "torque", None)
    if torque is not None and not torque.strip():
        raise ValueError("--torque names no torque source")
    return {
        "fmt": getattr(args, "recording_format", None),
        "columns": columns,
        "torque": torque,
        "loop_delay": delay,
    }


LARGE_RECORDING_BYTES = 50_000_000  # from here on, reading says what it does (~10 s per 100 MB)


def read_recording(
    args: argparse.Namespace,
    path: str | Path,
    *,
    command: str,
    min_rows: int = 2,
    extra_columns: bool = False,
    allow_gaps: bool = False,
    need_motion: bool = True,
) -> Recording:
    """Read ``path`` with the recording options of ``args``; print what the reader noticed
    (gaps, irregular sampling, dropped duplicates, the loop delay) on stderr. Refuse a
    recording with gaps unless ``allow_gaps`` (the command analyses ``rec.segments()``
    separately), and one where the arm never moves if ``need_motion``."""
    csv_path = Path(path) / SIGNALS if Path(path).is_dir() else Path(path)
    size = csv_path.stat().st_size if csv_path.is_file() else 0
    large = size >= LARGE_RECORDING_BYTES  # say what takes the time (seconds per 100 MB)
    if large:
        print(f"hil {command}: reading {csv_path} ({size / 1e6:.0f} MB) ...", file=sys.stderr)
        started = time.perf_counter()
    rec = read_signals(
        path, **recording_kwargs(args), extra_columns=extra_columns, min_rows=min_rows
    )
    if large:
        print(
            f"hil {command}: read {len(rec)} rows of {csv_path.name} in "
            f"{time.perf_counter() - started:.0f} s",
            file=sys.stderr,
        )
    for note in rec.findings_on_read:
        print(f"hil {command}: note: {rec.path}: {note}", file=sys.stderr)
    if not allow_gaps and len(rec.segments()) > 1:
        gap = next((f for f in rec.findings_on_read if "gap(s) in t" in f), "gaps in t")
        raise RecordingError(
            f"{rec.path}: {gap.split(';')[0]}; hil {command} does not splice segments: give "
            "it each segment as a recording of its own"
        )
    if need_motion and len(rec) and np.all(np.ptp(rec.q, axis=0) == 0):
        raise RecordingError(
            f"{rec.path}: the arm does not move (every q is constant): nothing to {command}"
        )
    return rec


def add_out_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="empty a non-empty --out directory first (without it, such a --out is refused)",
    )


def prepare_out_dir(
    out: str | Path, overwrite: bool, inputs: Sequence[str | Path | None] = ()
) -> Path:
    """Make sure ``out`` is absent or an empty directory to write into: refuse a non-empty one
    (files of an earlier run would mix with this one's) unless ``overwrite``, which empties it
    first, and never one that holds one of the command's ``inputs``."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: exists and is not a directory")
    if out.is_dir() and any(out.iterdir()):
        if not overwrite:
            raise ValueError(
                f"--out {out}: directory is not empty (files of another run would mix with "
                "this one's); pass --overwrite to empty it, or choose another directory"
            )
        here = Path.cwd().resolve()
        target = out.resolve()
        for item in inputs:
            if item is not None and (
                Path(item).resolve() == target or target in Path(item).resolve().parents
            ):
                raise ValueError(f"--out {out}: holds the input {item}; choose another directory")
        if target == here or target in here.parents or target == Path.home().resolve():
            raise ValueError(f"--out {out}: refusing to empty the current or home directory")
        for child in target.iterdir():
            if child.is_dir() and not child.is_symlink():
                shutil.rmtree(child)
            else:
                child.unlink()
    return out  # created by the command when it writes (a refused run leaves nothing)
