"""Reading a recording: :func:`read_signals` on a run directory, this bench's signals.csv or a
foreign CSV or container file (streaming, in chunks of bounded memory, dropping at most a torn
last line), through a column plan (:mod:`.columns`) into the checked :class:`Recording`
(:mod:`.checks`).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from drivers import containers
from drivers.recording.checks import assemble
from drivers.recording.columns import column_plan, ignored_columns, is_ignored, kept_columns
from drivers.recording.data import (
    CHUNK_CHARS,
    JSON_TYPE_NAMES,
    MAX_LINE_CHARS,
    META_TYPES,
    PERIOD_MAX_S,
    PERIOD_MIN_S,
    Recording,
)
from drivers.recording.format import META, SIGNALS, RecordingError
from profiles.recording_format import (
    load_format,
)


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
    ignored = ignored_columns(fmt, ignore)
    with _open_csv(csv_path) as f:
        try:
            header = _read_header(f, csv_path)
            plan = column_plan(
                csv_path, header, meta, fmt, columns, torque, loop_delay, effort_scale, leave_out
            )
            keep = kept_columns(csv_path, header, plan, extra_columns, ignored)
            if len(set(header)) != len(header) and extra_columns:
                dup = next(h for h in header if header.count(h) > 1)
                raise RecordingError(f"{csv_path}: column {dup!r} appears twice in the header")
            skip = {i for i, c in enumerate(header) if c not in keep and is_ignored(c, ignored)}
            data, dropped = _parse_body(
                f, csv_path, header, [header.index(c) for c in keep], skip, progress
            )
        except UnicodeDecodeError as exc:
            raise RecordingError(f"{csv_path}: not UTF-8 text ({exc})") from None
        except OSError as exc:
            raise RecordingError(f"{csv_path}: cannot read ({exc.strerror})") from None
    where = csv_path.parent if path.is_dir() else csv_path
    rec = assemble(where, csv_path, data, keep, plan, meta, dropped)
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
        return list(_container_table(path, fmt)[0].names)
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


def _container_table(path: Path, fmt: str | Path | None) -> tuple[containers.Table, Any]:
    """An .npz, .mcap or a directory of one CSV per quantity as a :class:`containers.Table`
    (its columns named, nothing loaded yet), with the format profile it is read by (None for an
    .npz without ``fmt``)."""
    if not path.exists():
        raise RecordingError(f"{path}: cannot read (No such file or directory)")
    is_mcap = path.suffix.lower() == ".mcap"
    name = fmt if fmt is not None else (DEFAULT_MCAP_FORMAT if is_mcap else None)
    form = load_format(name) if name is not None else None
    try:
        if is_mcap:
            return containers.mcap_table(path, form), form
        if path.is_dir():
            return containers.csv_streams_table(path, form, _csv_table), form
        return containers.npz_table(path), form
    except containers.ContainerError as exc:
        raise RecordingError(str(exc)) from None


def _read_container(
    path: Path,
    fmt: str | Path | None,
    options: tuple[Any, ...],
    extra_columns: bool,
    min_rows: int,
) -> Recording:
    """An .npz, .mcap or a directory of one CSV per quantity: a :class:`containers.Table`, then
    the plan and the checks of every recording (:func:`column_plan`, :func:`assemble`)."""
    columns, torque, loop_delay, effort_scale, leave_out, ignore = options
    table, form = _container_table(path, fmt)
    plan = column_plan(
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
    keep = kept_columns(
        table.label, table.names, plan, extra_columns, ignored_columns(form, ignore)
    )
    try:
        data, keep = table.load(keep, list(dict.fromkeys(plan.sources.values())))
    except containers.ContainerError as exc:
        raise RecordingError(str(exc)) from None
    rec = assemble(path, table.label, data, keep, plan, table.meta, False, table.locate)
    rec.findings_on_read[:0] = table.notes
    if table.torque_source is not None and torque is None and plan.torque_source != "columns":
        rec.torque_source = table.torque_source  # our own MCAP: the commanded, held torque
    return _enough(rec, table.label, min_rows)


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


def _read_meta(meta_path: Path) -> dict[str, Any]:
    try:
        meta = json.loads(meta_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise RecordingError(f"{meta_path}: not valid JSON ({exc})") from None
    except OSError as exc:
        raise RecordingError(f"{meta_path}: cannot read ({exc.strerror})") from None
    if not isinstance(meta, dict):
        raise RecordingError(f"{meta_path}: not a JSON object")
    for key, types in META_TYPES.items():
        if key not in meta:
            continue
        value = meta[key]
        if isinstance(value, bool) or not isinstance(value, types):
            names = " or ".join(
                JSON_TYPE_NAMES[t] for t in types if not (t is int and float in types)
            )
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
