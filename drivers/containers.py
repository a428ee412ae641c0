"""Recordings in other containers than one CSV: numpy ``.npz`` archives, MCAP files (ROS 2 bags,
Foxglove), and one CSV per quantity in a directory, joined on time (docs/recordings.md).

Each is turned into a :class:`Table`: column names (an array ``A`` of shape (N, k) gives the
columns ``A[0]`` .. ``A[k-1]``, a 1-D array the column ``A``; an MCAP message's fields by their
dotted path, ``header.stamp`` a time in s, ``position[0]`` ...), and a loader of the columns a
reading needs. :func:`drivers.recording.read_signals` then applies the format profile and the
checks every recording gets (t increasing, duplicates, gaps, NaN) to it, so that there is one
reader path whatever the container. A recording split over several streams (CSV files or MCAP
topics) has its columns named ``STREAM.COLUMN`` and is joined on the time of one of them by the
layout's rule (:class:`profiles.recording_format.Join`); rows that no sample of a stream is
close enough to are refused, never guessed.

:func:`write_mcap` writes a recording as ``sensor_msgs/JointState``-shaped JSON messages
(``hil run --mcap``).

Imports :mod:`profiles` (the format profiles) and the ``mcap`` library; the CSV parser is
passed in by :mod:`drivers.recording`, which imports this module.
"""

from __future__ import annotations

import json
import math
import struct
import zipfile
from array import array
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from profiles.recording_format import Join, Layout, RecordingFormat, Stream

JOINT_STATE_TOPIC = "/joint_states"
MCAP_MAGIC = b"\x89MCAP0\r\n"  # the first 8 bytes of every MCAP file (mcap.dev spec)
MCAP_META = "ddbench"  # the MCAP metadata record holding meta.json (written by write_mcap)


class ContainerError(ValueError):
    """A container that cannot be read; one line naming the file (and the row or message)."""


@dataclass
class Table:
    """Named float columns of one recording, loaded on demand.

    ``load(names, required)`` returns the columns ``names`` that are read (a (rows, k) array and
    their names): every ``required`` one (the time column first), and the others when they have
    the rows of the time column (an npz may hold arrays of other lengths beside the recording)."""

    label: Path  # the file (or directory) errors name
    names: list[str]
    load: Callable[[list[str], list[str]], tuple[np.ndarray, list[str]]]
    locate: Callable[[int], str]  # data row i -> "FILE: row i", for errors
    meta: dict[str, Any] = field(default_factory=dict)
    torque_source: str | None = None  # what the writer said the torque is (our own MCAP)
    notes: list[str] = field(default_factory=list)  # what reading it noticed (a torn end)


# --- numpy .npz ----------------------------------------------------------------------------------


def npz_table(path: Path) -> Table:
    """An ``.npz`` archive's numeric arrays of one or two dimensions, read from their headers;
    only the arrays a reading uses are loaded (``np.load`` holds an array whole: memory is the
    arrays used, not the archive)."""
    shapes = _npz_shapes(path)
    names: list[str] = []
    of: dict[str, tuple[str, int | None]] = {}  # column -> (array, index or None)
    for name, shape in shapes.items():
        if len(shape) == 1:
            names.append(name)
            of[name] = (name, None)
        elif len(shape) == 2:
            for k in range(shape[1]):
                names.append(f"{name}[{k}]")
                of[f"{name}[{k}]"] = (name, k)

    def load(cols: list[str], required: list[str]) -> tuple[np.ndarray, list[str]]:
        time = of[required[0]][0]
        n = shapes[time][0]
        for c in required:
            if shapes[of[c][0]][0] != n:
                raise ContainerError(
                    f"{path}: array {of[c][0]} has {shapes[of[c][0]][0]} rows, the time "
                    f"{time} {n} (arrays of one recording have one row per sample)"
                )
        kept = [c for c in cols if c in required or shapes[of[c][0]][0] == n]
        out = np.empty((n, len(kept)))
        arrays: dict[str, np.ndarray] = {}
        with np.load(path, allow_pickle=False) as archive:
            for j, c in enumerate(kept):
                array, k = of[c]
                if array not in arrays:
                    arrays[array] = np.asarray(archive[array], dtype=float)
                out[:, j] = arrays[array] if k is None else arrays[array][:, k]
        return out, kept

    return Table(path, names, load, lambda i: f"{path}: row {i}")


def _npz_shapes(path: Path) -> dict[str, tuple[int, ...]]:
    """Array name -> shape of every numeric array in the archive, from the .npy headers."""
    out: dict[str, tuple[int, ...]] = {}
    try:
        with zipfile.ZipFile(path) as z:
            for info in z.infolist():
                if not info.filename.endswith(".npy"):
                    continue
                with z.open(info) as f:
                    version = np.lib.format.read_magic(f)
                    header = (
                        np.lib.format.read_array_header_1_0
                        if version == (1, 0)
                        else np.lib.format.read_array_header_2_0
                    )
                    shape, _, dtype = header(f)
                if dtype.kind in "biuf":
                    out[info.filename.removesuffix(".npy")] = tuple(shape)
    except (zipfile.BadZipFile, ValueError) as exc:
        raise ContainerError(f"{path}: not a numpy .npz archive ({exc})") from None
    except OSError as exc:
        raise ContainerError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not out:
        raise ContainerError(f"{path}: no numeric arrays in the archive")
    return out


# --- streams joined on time ----------------------------------------------------------------------


@dataclass
class _StreamData:
    stream: Stream
    label: str  # the file or "FILE topic" for errors
    names: list[str]
    data: np.ndarray
    locate: Callable[[int], str]


def layout_with_streams(form: RecordingFormat, available: Callable[[Stream], bool]) -> Layout:
    """The first layout of ``form`` with streams all of which are ``available`` (files in the
    directory, topics in the MCAP file)."""
    tried = []
    for layout in form.layouts:
        if not layout.streams:
            continue
        missing = [s for s in layout.streams.values() if not available(s)]
        if not missing:
            return layout
        tried.append(
            f"{layout.name or 'layout'}: " + ", ".join(s.file or s.topic or "" for s in missing)
        )
    if not tried:
        raise ContainerError(f"format {form.name} names no streams (files or topics) to read")
    raise ContainerError(f"not a {form.name} recording (missing {'; '.join(tried)})")


def csv_streams_table(
    directory: Path,
    form: RecordingFormat,
    read_csv: Callable[[Path], tuple[list[str], np.ndarray, Callable[[int], str]]],
) -> Table:
    """A directory holding one CSV per quantity (the layout's streams' files), joined on time."""
    try:
        layout = layout_with_streams(form, lambda s: (directory / (s.file or "")).is_file())
    except ContainerError as exc:
        raise ContainerError(f"{directory}: {exc}") from None
    parts = []
    for stream in layout.streams.values():
        path = directory / (stream.file or "")
        header, data, locate = read_csv(path)
        parts.append(_StreamData(stream, str(path), header, data, locate))
    return _joined(directory, parts, layout.join)


def _joined(label: Path, parts: list[_StreamData], join: Join | None) -> Table:
    """One table of the streams' columns (``STREAM.COLUMN``) on the rows of ``join.on``."""
    by_name = {p.stream.name: p for p in parts}
    on = by_name[join.on] if join is not None else parts[0]
    for p in parts:
        if p.stream.time not in p.names:
            shown = ", ".join(p.names[:8]) + (", ..." if len(p.names) > 8 else "")
            raise ContainerError(f"{p.label}: no time column {p.stream.time} ({shown})")
    names = [f"{p.stream.name}.{c}" for p in parts for c in p.names]
    where = {f"{p.stream.name}.{c}": (p, j) for p in parts for j, c in enumerate(p.names)}

    def load(cols: list[str], required: list[str]) -> tuple[np.ndarray, list[str]]:
        t_on = _stream_time(on, strict=False)  # the rows' own checks follow on read
        out = np.empty((len(t_on), len(cols)))
        picks: dict[str, Callable[[np.ndarray], np.ndarray]] = {}
        for j, c in enumerate(cols):
            part, k = where[c]
            if part is on:
                out[:, j] = part.data[:, k]
                continue
            if part.stream.name not in picks:
                picks[part.stream.name] = _resampler(part, on, t_on, join)
            column = part.data[:, k]
            if c in required:
                bad = ~np.isfinite(column)
                if bad.any():
                    i = int(np.argmax(bad))
                    raise ContainerError(
                        f"{part.locate(i)}: {c} = {float(column[i])!r} is not a finite number"
                    )
            out[:, j] = picks[part.stream.name](column)
        return out, cols

    return Table(label, names, load, on.locate)


def _stream_time(part: _StreamData, strict: bool = True) -> np.ndarray:
    """The stream's time column, checked finite and (``strict``: a stream joined onto another's
    rows) strictly increasing: the join needs its order."""
    k = part.names.index(part.stream.time)
    t = part.data[:, k]
    bad = ~np.isfinite(t)
    if bad.any():
        i = int(np.argmax(bad))
        raise ContainerError(
            f"{part.locate(i)}: {part.stream.name}.{part.stream.time} = {float(t[i])!r} is not "
            "a finite number"
        )
    if not strict:
        return t
    back = np.diff(t) <= 0
    if back.any():
        i = int(np.argmax(back)) + 1
        raise ContainerError(
            f"{part.locate(i)}: {part.stream.time} goes from {float(t[i - 1])!r} to "
            f"{float(t[i])!r} s (a stream joined on time must increase)"
        )
    return t


def _resampler(
    part: _StreamData, on: _StreamData, t_on: np.ndarray, join: Join | None
) -> Callable[[np.ndarray], np.ndarray]:
    """Values of ``part`` at the times ``t_on``. ``nearest``: the stream's sample nearest to the
    row's time, which must lie within ``join.tolerance_s`` of it. ``linear``: interpolated
    between the stream's samples before and after the row's time, which may be at most
    ``tolerance_s`` apart (a longer interval is a gap the interpolation would bridge); before
    the first or after the last sample, the end sample within ``tolerance_s``. A row no rule
    fills refuses the join in one line."""
    assert join is not None
    t = _stream_time(part)
    if len(t) == 0:
        raise ContainerError(f"{part.label}: no rows to join")
    tol = join.tolerance_s * (1 + 1e-9) + 4 * np.spacing(np.abs(t_on))
    i = np.clip(np.searchsorted(t, t_on), 1, max(len(t) - 1, 1))
    lo = np.maximum(i - 1, 0)
    near = np.where(np.abs(t_on - t[lo]) <= np.abs(t[i] - t_on), lo, i) if len(t) > 1 else lo
    dist = np.abs(t[near] - t_on)
    inside = np.zeros(len(t_on), dtype=bool)
    if join.rule == "linear" and len(t) > 1:
        inside = (t_on > t[0]) & (t_on < t[-1]) & (dist > 0)
        dist = np.where(inside, t[i] - t[lo], dist)  # the interval interpolated across
    far = dist > tol
    if far.any():
        r = int(np.argmax(far))
        at = f"{on.stream.name}.{on.stream.time} = {float(t_on[r])!r} s ({on.locate(r)})"
        ms, d = f"{join.tolerance_s * 1e3:g} ms", f"{float(dist[r]) * 1e3:.3g} ms"
        what = (
            f"the samples around {at} are {d} apart, over the {ms} the join interpolates across"
            if inside[r]
            else f"no sample within {ms} of {at}; the nearest is {d} away"
        )
        raise ContainerError(
            f"{part.label}: {what}: the streams' times do not match (another clock, rate or span?)"
        )
    if join.rule == "nearest" or len(t) < 2:
        return lambda column: column[near]
    return lambda column: np.interp(t_on, t, column)


# --- MCAP ----------------------------------------------------------------------------------------


def mcap_table(path: Path, form: RecordingFormat) -> Table:
    """An MCAP file's topics named by the format's streams: JSON-encoded messages, or ROS 2 CDR
    when ``mcap-ros2-support`` is installed; each message a row of its numeric fields. A file
    without its summary (a recorder killed mid-write) is read up to its last whole record, and
    the recording says so (``Table.notes``)."""
    from mcap.reader import make_reader

    notes: list[str] = []
    try:
        with open(path, "rb") as f:
            if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
                raise ContainerError(f"{path}: not an MCAP file (no MCAP magic at its start)")
            f.seek(0)
            try:
                summary = make_reader(f).get_summary()
            except _MCAP_ERRORS:
                summary = None
            if summary is not None:
                topics = {c.topic for c in summary.channels.values()}
            else:  # no summary (cut short): the channels of the records up to where it ends
                f.seek(0)
                torn: list[str] = []
                topics = {c.topic for _, c, _ in _records(f, None, torn)}
                if torn and not topics:
                    raise ContainerError(f"{path}: not a readable MCAP file ({torn[0]})")
            try:
                layout = layout_with_streams(form, lambda s: s.topic in topics)
            except ContainerError as exc:
                have = ", ".join(sorted(topics)) or "none"
                raise ContainerError(f"{path}: {exc}; topics in the file: {have}") from None
            f.seek(0)
            meta, torque_source = _mcap_meta(make_reader(f)) if summary else ({}, None)
            want = {s.topic: s for s in layout.streams.values()}
            rows: dict[str, _Rows] = {
                topic: _Rows(path, topic, s.time) for topic, s in want.items()
            }
            f.seek(0)
            torn = []
            if summary is not None:
                messages = make_reader(f).iter_messages(topics=list(want))
            else:
                messages = _records(f, set(want), torn)
            for schema, channel, message in messages:
                rows[channel.topic].add(_decode(path, schema, channel, message), message)
            if torn:
                notes.append(
                    f"the file ends without its summary ({torn[0]}): a recorder stopped "
                    f"mid-write? read the {sum(len(r) for r in rows.values())} whole messages "
                    "before it"
                )
    except ContainerError:
        raise
    except _MCAP_ERRORS as exc:
        raise ContainerError(f"{path}: not a readable MCAP file ({exc})") from None
    except OSError as exc:
        raise ContainerError(f"{path}: cannot read ({exc.strerror or exc})") from None
    parts = [rows[s.topic].part(s) for s in layout.streams.values()]
    table = _joined(path, parts, layout.join)
    table.meta, table.torque_source, table.notes = meta, torque_source, notes
    return table


def _mcap_errors() -> tuple[type[BaseException], ...]:
    from mcap.exceptions import McapError

    # the mcap library raises struct.error and EOFError too on a file that is not MCAP at all
    return (McapError, struct.error, EOFError, ValueError)


_MCAP_ERRORS = _mcap_errors()


def _records(f: Any, topics: set[str] | None, torn: list[str]) -> Iterator[tuple[Any, Any, Any]]:
    """(schema, channel, message) of the file's records in order, read as a stream (no summary
    needed; a chunk's messages once the chunk is whole), up to the first record that does not
    read (its error appended to ``torn``)."""
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader

    schemas: dict[int, Any] = {}
    channels: dict[int, Any] = {}
    records = iter(StreamReader(f).records)
    while True:
        try:
            record = next(records)
        except StopIteration:
            return
        except _MCAP_ERRORS as exc:
            torn.append(f"{type(exc).__name__}: {exc}".rstrip(": ")[:120])
            return
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message) and record.channel_id in channels:
            channel = channels[record.channel_id]
            if topics is None or channel.topic in topics:
                yield schemas.get(channel.schema_id), channel, record


class _Rows:
    """One topic's messages flattened to rows of floats, every message with the same fields."""

    def __init__(self, path: Path, topic: str, time: str) -> None:
        self.path, self.topic, self.time = path, topic, time
        self.names: list[str] | None = None
        self.strings: dict[str, Any] = {}
        self.values = array("d")  # 8 bytes a number while the messages are read
        self.count = 0

    def add(self, obj: Any, message: Any) -> None:
        numbers: dict[str, float] = {}
        strings: dict[str, Any] = {}
        _flatten(obj, "", numbers, strings)
        numbers["log_time"] = message.log_time * 1e-9
        numbers["publish_time"] = message.publish_time * 1e-9
        k = self.count + 1
        if self.names is None:
            self.names, self.strings = list(numbers), strings
        elif list(numbers) != self.names:
            extra = [n for n in numbers if n not in self.names]
            gone = [n for n in self.names if n not in numbers]
            raise ContainerError(
                f"{self.path}: {self.topic} message {k} has other fields than message 1 "
                f"({'new ' + ', '.join(extra[:3]) if extra else 'no ' + ', '.join(gone[:3])}; "
                "an array changed length?)"
            )
        elif strings != self.strings:
            key = next(s for s in strings if strings[s] != self.strings.get(s))
            raise ContainerError(
                f"{self.path}: {self.topic} message {k}: {key} changes from "
                f"{self.strings.get(key)!r} to {strings[key]!r} (joints renamed or reordered "
                "within the recording)"
            )
        self.values.extend(numbers.values())
        self.count += 1

    def __len__(self) -> int:
        return self.count

    def part(self, stream: Stream) -> _StreamData:
        if not self.count or self.names is None:
            raise ContainerError(f"{self.path}: topic {self.topic} has no messages")
        if stream.time not in self.names:
            raise ContainerError(
                f"{self.path}: topic {self.topic} has no field {stream.time} "
                f"(fields: {', '.join(self.names[:8])}{', ...' if len(self.names) > 8 else ''})"
            )
        topic = self.topic
        return _StreamData(
            stream,
            f"{self.path} topic {topic}",
            self.names,
            np.frombuffer(self.values, dtype=float).reshape(self.count, len(self.names)),
            lambda i: f"{self.path}: {topic} message {i + 1}",
        )


_STAMPS = (("sec", "nanosec"), ("sec", "nsec"), ("secs", "nsecs"))  # ROS 2, Foxglove, ROS 1


def _flatten(obj: Any, prefix: str, numbers: dict[str, float], strings: dict[str, Any]) -> None:
    """Numeric leaves by dotted path (``a.b[2]``); a {sec, nanosec} time as one value in s;
    strings (and lists of them, e.g. JointState's ``name``) kept aside, to check they stay."""
    if isinstance(obj, dict):
        keys = set(obj)
        for sec, frac in _STAMPS:
            if keys == {sec, frac}:
                numbers[prefix] = float(obj[sec]) + float(obj[frac]) * 1e-9
                return
        for key, value in obj.items():
            _flatten(value, f"{prefix}.{key}" if prefix else str(key), numbers, strings)
    elif isinstance(obj, list | tuple):
        if obj and all(isinstance(v, str) for v in obj):
            strings[prefix] = tuple(obj)
            return
        for i, value in enumerate(obj):
            _flatten(value, f"{prefix}[{i}]", numbers, strings)
    elif isinstance(obj, bool | int | float):
        numbers[prefix] = float(obj)
    elif isinstance(obj, str):
        strings[prefix] = obj
    elif isinstance(obj, np.ndarray):
        _flatten(obj.tolist(), prefix, numbers, strings)
    elif hasattr(obj, "__slots__"):  # a decoded ROS 2 message
        _flatten({k: getattr(obj, k) for k in obj.__slots__}, prefix, numbers, strings)


_ros2_decoders: dict[int, Any] = {}


def _decode(path: Path, schema: Any, channel: Any, message: Any) -> Any:
    encoding = channel.message_encoding
    if encoding == "json":
        try:
            return json.loads(message.data)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ContainerError(
                f"{path}: {channel.topic} message at log time {message.log_time} ns is not "
                f"JSON ({exc})"
            ) from None
    if encoding == "cdr" and schema is not None:
        try:
            from mcap_ros2.decoder import DecoderFactory
        except ImportError:
            raise ContainerError(
                f"{path}: topic {channel.topic} is ROS 2 CDR; reading it needs the "
                "mcap-ros2-support package (pip install mcap-ros2-support)"
            ) from None
        if schema.id not in _ros2_decoders:
            _ros2_decoders[schema.id] = DecoderFactory().decoder_for(encoding, schema)
        return _ros2_decoders[schema.id](message.data)
    raise ContainerError(
        f"{path}: topic {channel.topic} is encoded as {encoding!r}; read are json and ROS 2 cdr"
    )


def _mcap_meta(reader: Any) -> tuple[dict[str, Any], str | None]:
    for record in reader.iter_metadata():
        if record.name == MCAP_META:
            meta = json.loads(record.metadata.get("meta", "{}"))
            return (meta if isinstance(meta, dict) else {}), record.metadata.get("torque_source")
    return {}, None


# JSON Schema of the messages write_mcap writes (sensor_msgs/JointState's fields)
JOINT_STATE_SCHEMA = {
    "title": "sensor_msgs/JointState",
    "type": "object",
    "properties": {
        "header": {
            "type": "object",
            "properties": {
                "stamp": {
                    "type": "object",
                    "properties": {"sec": {"type": "integer"}, "nanosec": {"type": "integer"}},
                },
                "frame_id": {"type": "string"},
            },
        },
        "name": {"type": "array", "items": {"type": "string"}},
        "position": {"type": "array", "items": {"type": "number"}},
        "velocity": {"type": "array", "items": {"type": "number"}},
        "effort": {"type": "array", "items": {"type": "number"}},
    },
}


def write_mcap(
    path: Path,
    t: np.ndarray,
    q: np.ndarray,
    tau: np.ndarray,
    meta: dict[str, Any],
    *,
    torque_source: str = "commanded",
    joint_names: Iterable[str] | None = None,
) -> int:
    """Write rows (t, q, tau) as ``sensor_msgs/JointState``-shaped JSON messages on
    ``/joint_states`` (stamp = t, position = q, effort = tau; JSON numbers round-trip floats
    exactly, the stamp to the nanosecond), with ``meta`` (meta.json) as MCAP metadata. Returns
    the number of messages. Read back by the shipped format ``ros2-joint-state``."""
    from mcap.writer import Writer

    n = q.shape[1]
    names = list(joint_names) if joint_names is not None else [f"joint{j + 1}" for j in range(n)]
    tmp = path.with_suffix(path.suffix + ".tmp")
    with open(tmp, "wb") as f:
        writer = Writer(f)
        writer.start(profile="", library="ddbench")
        schema = writer.register_schema(
            name="sensor_msgs/JointState",
            encoding="jsonschema",
            data=json.dumps(JOINT_STATE_SCHEMA, allow_nan=False).encode(),
        )
        channel = writer.register_channel(JOINT_STATE_TOPIC, "json", schema)
        for k in range(len(t)):
            sec = math.floor(t[k])
            nanosec = round((float(t[k]) - sec) * 1e9)
            if nanosec >= 1_000_000_000:
                sec, nanosec = sec + 1, nanosec - 1_000_000_000
            stamp_ns = sec * 1_000_000_000 + nanosec
            body = {
                "header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": ""},
                "name": names,
                "position": [float(x) for x in q[k]],
                "velocity": [],
                "effort": [float(x) for x in tau[k]],
            }
            writer.add_message(
                channel,
                log_time=max(stamp_ns, 0),
                publish_time=max(stamp_ns, 0),
                data=json.dumps(body, allow_nan=False).encode(),  # rows checked finite on read
                sequence=k,
            )
        writer.add_metadata(
            MCAP_META,
            {
                "meta": json.dumps(meta, default=str, allow_nan=False),
                "torque_source": torque_source,
            },
        )
        writer.finish()
    tmp.replace(path)
    return len(t)


__all__ = [
    "JOINT_STATE_SCHEMA",
    "JOINT_STATE_TOPIC",
    "MCAP_META",
    "ContainerError",
    "Table",
    "csv_streams_table",
    "layout_with_streams",
    "mcap_table",
    "npz_table",
    "write_mcap",
]
