"""Recording-format profiles (profiles/formats/*.toml): how to read a foreign file as a recording.

A format names, from the file's own column names, the time column, the joint positions q1..qN and
one or more torque sources (e.g. ``commanded`` and ``measured``), each with its loop delay: the
number of rows d such that the torque of file row i acts between the positions of rows i+d and
i+d+1 (docs/recordings.md), and its conversion to N·m when the file holds raw effort units
(gear ratio × motor torque constant per joint). A layout may also name the controller's target
trajectory (``[layouts.targets]``: positions, velocities), columns to ignore, joints to leave out,
and, for a recording split over several tables (one CSV per quantity in a directory, or several
MCAP topics), the streams and the rule that joins them on time.

A set of columns is a list of names, or a string naming a group: the columns ``NAME[0]``,
``NAME[1]``, ... of the file (a 2-D numpy array in an ``.npz``, an array field of an MCAP
message), or the single column ``NAME`` (a 1-D array). A format may hold several layouts (one
producer writing two kinds of file); the reader takes the first layout whose columns are all in
the file's header, so a layout is chosen by the columns the file has, never by guessing at what
a column means.

Imports only the profile loader; :mod:`drivers.recording` reads files with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

from profiles.loader import Fields, ProfileError, load_toml

KIND = "formats"
LOOP_DELAY_MAX = 100  # rows; a larger delay is a wrong column, not a loop order
JOIN_RULES = ("nearest", "linear")
TARGET_KINDS = {"positions": "q_target", "velocities": "qd_target"}  # -> Recording column prefix


@dataclass(frozen=True)
class ColumnSet:
    """Columns given as a list (``names``) or as a group (``group``: NAME[0], NAME[1], ...)."""

    names: tuple[str, ...] = ()
    group: str | None = None

    def resolve(self, header: list[str] | tuple[str, ...] | set[str]) -> tuple[str, ...] | None:
        """The file's columns this set stands for (None: a column or the group is missing)."""
        have = set(header)
        if self.group is None:
            return self.names if set(self.names) <= have else None
        cols = []
        while f"{self.group}[{len(cols)}]" in have:
            cols.append(f"{self.group}[{len(cols)}]")
        if cols:
            return tuple(cols)
        return (self.group,) if self.group in have else None

    def describe(self) -> str:
        return f"{self.group}[...]" if self.group is not None else ", ".join(self.names)


@dataclass(frozen=True)
class TorqueSource:
    """One torque signal of a layout: its columns tau1..tauN, loop delay in rows, and the factor
    per joint from the file's unit to N·m (None: the file holds N·m)."""

    name: str
    columns: tuple[str, ...]
    loop_delay: int
    description: str = ""
    scale: tuple[float, ...] | None = None
    column_set: ColumnSet | None = None


@dataclass(frozen=True)
class Stream:
    """One table of a recording split over several: a CSV file in the recording's directory
    (``file``) or an MCAP topic (``topic``), with the column holding its own time."""

    name: str
    time: str
    file: str | None = None
    topic: str | None = None


@dataclass(frozen=True)
class Join:
    """How streams are joined on time: the rows are those of stream ``on``; each other stream's
    value at a row is its nearest sample, within ``tolerance_s`` (``nearest``), or interpolated
    linearly between its samples before and after the row's time, at most ``tolerance_s`` apart
    (``linear``; an end sample within ``tolerance_s`` outside the stream's span). A row the
    rule cannot fill is an error, not a guess."""

    on: str
    rule: str
    tolerance_s: float


@dataclass(frozen=True)
class Layout:
    """One kind of file of a format: which header columns are t, q1..qN and the torques."""

    name: str
    time: str
    positions: tuple[str, ...]
    torques: dict[str, TorqueSource]
    default_torque: str
    targets: dict[str, tuple[str, ...]] = field(default_factory=dict)  # TARGET_KINDS key -> cols
    ignore: tuple[str, ...] = ()  # columns (or groups) not read
    leave_out: tuple[int, ...] = ()  # joint numbers (1-based, the file's) not read
    streams: dict[str, Stream] = field(default_factory=dict)
    join: Join | None = None
    position_set: ColumnSet | None = None
    target_sets: dict[str, ColumnSet] = field(default_factory=dict)

    @property
    def n_joints(self) -> int:
        return len(self.positions)

    def missing(self, header: list[str] | tuple[str, ...]) -> list[str]:
        """What of this layout ``header`` lacks (columns, or groups as ``NAME[...]``)."""
        have = set(header)
        sets = [
            self.position_set or ColumnSet(self.positions),
            *(s.column_set or ColumnSet(s.columns) for s in self.torques.values()),
            *self.target_sets.values(),
        ]
        out = [] if self.time in have else [self.time]
        for cset in sets:
            if cset.group is not None:
                if cset.resolve(have) is None:
                    out.append(cset.describe())
            else:
                out.extend(c for c in cset.names if c not in have)
        return sorted(set(out))

    def resolve(self, header: list[str] | tuple[str, ...]) -> Layout | None:
        """This layout with its groups replaced by the file's columns (None: the file lacks a
        column or group of it). Raises :class:`ValueError` when the resolved sets disagree in
        length (a group of 7 positions and 6 torques)."""
        if self.time not in header:
            return None
        pos = self.position_set.resolve(header) if self.position_set else self.positions
        if pos is None or not set(pos) <= set(header):
            return None
        torques = {}
        for name, src in self.torques.items():
            cols = src.column_set.resolve(header) if src.column_set else src.columns
            if cols is None or not set(cols) <= set(header):
                return None
            if len(cols) != len(pos):
                raise ValueError(
                    f"torque {name!r} has {len(cols)} column(s) ({', '.join(cols)}), the "
                    f"positions {len(pos)}"
                )
            if src.scale is not None and len(src.scale) not in (1, len(pos)):
                raise ValueError(
                    f"torque {name!r}: the conversion has {len(src.scale)} factors for "
                    f"{len(pos)} joints"
                )
            torques[name] = replace(src, columns=cols)
        targets = {}
        for kind, cset in self.target_sets.items():
            cols = cset.resolve(header)
            if cols is None:
                return None
            if len(cols) != len(pos):
                raise ValueError(
                    f"target {kind} has {len(cols)} column(s), the positions {len(pos)}"
                )
            targets[kind] = cols
        if any(j > len(pos) for j in self.leave_out):
            raise ValueError(
                f"leave_out names joint {max(self.leave_out)}, the file has {len(pos)}"
            )
        return replace(self, positions=pos, torques=torques, targets=targets)


@dataclass(frozen=True)
class RecordingFormat:
    name: str
    description: str
    source: str  # where the files come from and where the loop order was read (citation)
    layouts: tuple[Layout, ...]
    path: str

    def layout_for(self, header: list[str] | tuple[str, ...]) -> Layout | None:
        """The first layout whose columns are all in ``header``, its groups resolved (None if
        there is none)."""
        for layout in self.layouts:
            resolved = layout.resolve(header)
            if resolved is not None:
                return resolved
        return None


def load_format(name_or_path: str | Path) -> RecordingFormat:
    """Load and check a recording-format profile (a shipped name such as ``dfki``, or a file)."""
    data, source = load_toml(KIND, name_or_path)
    f = Fields(data, source)
    f.only({"name", "description", "source", "licence", "layouts"})
    layouts = tuple(_layout(lf) for lf in f.tables("layouts"))
    if not layouts:
        raise f.error("layouts", "must hold at least one layout")
    return RecordingFormat(
        name=f.string("name"),
        description=f.string("description", ""),
        source=f.string("source", ""),
        layouts=layouts,
        path=source,
    )


def _layout(f: Fields) -> Layout:
    f.only(
        {
            "name", "time", "positions", "torques", "default_torque", "targets", "ignore",
            "leave_out", "streams", "join",
        }
    )  # fmt: skip
    pset = _column_set(f, "positions")
    n = len(pset.names) if pset.group is None else None
    tf = f.table("torques")
    if not tf.keys():
        raise f.error("torques", "must name at least one torque source")
    torques = {}
    for name in tf.data:
        sf = tf.table(name)
        sf.only({"columns", "loop_delay", "description", "scale", "gear_ratio", "torque_constant"})
        cset = _column_set(sf, "columns")
        if n is not None and cset.group is None and len(cset.names) != n:
            raise sf.error(
                "columns", f"must name {n} columns (one per joint), got {len(cset.names)}"
            )
        width = n if n is not None and cset.group is None else None
        torques[name] = TorqueSource(
            name=name,
            columns=cset.names,
            loop_delay=sf.integer("loop_delay", lo=-LOOP_DELAY_MAX, hi=LOOP_DELAY_MAX),
            description=sf.string("description", ""),
            scale=_scale(sf, width),
            column_set=cset if cset.group is not None else None,
        )
    default = f.string("default_torque", next(iter(torques)))
    if default not in torques:
        raise f.error("default_torque", f"must be one of {', '.join(torques)}, got {default!r}")
    target_sets = {}
    if f.has("targets"):
        tg = f.table("targets")
        tg.only(set(TARGET_KINDS))
        for kind in tg.data:
            cset = _column_set(tg, kind)
            if n is not None and cset.group is None and len(cset.names) != n:
                raise tg.error(kind, f"must name {n} columns (one per joint)")
            target_sets[kind] = cset
    ignore = ()
    if f.data.get("ignore", []) != []:
        ignore = _names(f, "ignore")
    leave_out = ()
    if f.has("leave_out"):
        value = f.data["leave_out"]
        if not isinstance(value, list) or not all(
            isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in value
        ):
            raise f.error("leave_out", "must be a list of joint numbers (1, 2, ...)")
        if n is not None and any(v > n for v in value):
            raise f.error("leave_out", f"names a joint over {n}")
        leave_out = tuple(sorted(set(value)))
    streams, join = _streams(f)
    time = f.string("time")
    if streams and "." not in time:
        raise f.error("time", "must be STREAM.COLUMN in a layout with streams")
    return Layout(
        name=f.string("name", ""),
        time=time,
        positions=pset.names,
        torques=torques,
        default_torque=default,
        targets={k: s.names for k, s in target_sets.items() if s.group is None},
        ignore=ignore,
        leave_out=leave_out,
        streams=streams,
        join=join,
        position_set=pset if pset.group is not None else None,
        target_sets=target_sets,
    )


def _scale(f: Fields, n: int | None) -> tuple[float, ...] | None:
    """``scale`` (N·m per file unit), or ``gear_ratio`` × ``torque_constant`` (N·m/A at the
    motor): a number for every joint, or a list of one per joint."""
    if f.has("scale") and (f.has("gear_ratio") or f.has("torque_constant")):
        raise f.error("scale", "give scale, or gear_ratio and torque_constant, not both")
    if f.has("gear_ratio") != f.has("torque_constant"):
        key = "torque_constant" if f.has("gear_ratio") else "gear_ratio"
        raise f.error(key, "missing (the conversion is gear_ratio × torque_constant)")
    keys = ["scale"] if f.has("scale") else ["gear_ratio", "torque_constant"]
    if not f.has(keys[0]):
        return None
    factors = []
    for key in keys:
        value = f.data[key]
        values = value if isinstance(value, list) else [value]
        if not values or not all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) and v != 0
            for v in values
        ):
            raise f.error(key, "must be a nonzero number or a list of them (one per joint)")
        if n is not None and len(values) not in (1, n):
            raise f.error(key, f"must hold 1 or {n} factors (one per joint), got {len(values)}")
        factors.append([float(v) for v in values])
    if len(factors) == 2:
        a, b = factors
        if len(a) != len(b) and 1 not in (len(a), len(b)):
            raise f.error(keys[1], f"has {len(b)} factors, gear_ratio {len(a)}")
        m = max(len(a), len(b))
        a, b = (x * m if len(x) == 1 else x for x in (a, b))
        return tuple(x * y for x, y in zip(a, b, strict=True))
    return tuple(factors[0])


def _streams(f: Fields) -> tuple[dict[str, Stream], Join | None]:
    if not f.has("streams"):
        if f.has("join"):
            raise f.error("join", "needs [layouts.streams] to join")
        return {}, None
    sf = f.table("streams")
    streams = {}
    for name in sf.data:
        if "." in name:
            raise sf.error(name, "a stream's name may not hold a dot")
        s = sf.table(name)
        s.only({"file", "topic", "time"})
        if s.has("file") == s.has("topic"):
            raise s.error("file", "give file (a CSV in the directory) or topic (MCAP), one")
        streams[name] = Stream(
            name=name,
            time=s.string("time"),
            file=s.string("file") if s.has("file") else None,
            topic=s.string("topic") if s.has("topic") else None,
        )
    if not streams:
        raise f.error("streams", "must name at least one stream")
    if len({s.file is None for s in streams.values()}) > 1:
        raise f.error("streams", "all files or all topics, not both")
    jf = f.table("join", {})
    jf.only({"on", "rule", "tolerance_s"})
    on = jf.string("on", next(iter(streams)))
    if on not in streams:
        raise jf.error("on", f"must be one of the streams ({', '.join(streams)}), got {on!r}")
    rule = jf.string("rule", "nearest")
    if rule not in JOIN_RULES:
        raise jf.error("rule", f"must be one of {', '.join(JOIN_RULES)}, got {rule!r}")
    if len(streams) > 1 and not jf.has("tolerance_s"):
        raise jf.error("tolerance_s", "missing (how far apart two streams' samples may be)")
    tol = jf.number("tolerance_s", 0.0, lo=0.0, hi=1.0)
    return streams, Join(on=on, rule=rule, tolerance_s=tol)


def _column_set(f: Fields, key: str) -> ColumnSet:
    value = f.data.get(key)
    if isinstance(value, str) and value:
        return ColumnSet(group=value)
    return ColumnSet(names=_names(f, key))


def _names(f: Fields, key: str) -> tuple[str, ...]:
    value = f.data.get(key)
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise f.error(key, "must be a non-empty list of column names, or a group's name")
    if len(set(value)) != len(value):
        raise f.error(key, "names a column twice")
    return tuple(value)


__all__ = [
    "JOIN_RULES",
    "LOOP_DELAY_MAX",
    "TARGET_KINDS",
    "ColumnSet",
    "Join",
    "Layout",
    "ProfileError",
    "RecordingFormat",
    "Stream",
    "TorqueSource",
    "load_format",
]
