"""Recording-format profiles (profiles/formats/*.toml): how to read a foreign CSV as a recording.

A format names, from the file's own headers, the time column, the joint positions q1..qN and one
or more torque sources (e.g. ``commanded`` and ``measured``), each with its loop delay: the
number of rows d such that the torque of file row i acts between the positions of rows i+d and
i+d+1 (docs/recordings.md). A format may hold several layouts (one producer writing two kinds
of file); the reader takes the first layout whose columns are all in the file's header, so a
layout is chosen by the columns the file has, never by guessing at what a column means.

Imports only the profile loader; :mod:`drivers.recording` reads files with it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from profiles.loader import Fields, ProfileError, load_toml

KIND = "formats"
LOOP_DELAY_MAX = 100  # rows; a larger delay is a wrong column, not a loop order


@dataclass(frozen=True)
class TorqueSource:
    """One torque signal of a layout: its columns tau1..tauN and its loop delay in rows."""

    name: str
    columns: tuple[str, ...]
    loop_delay: int
    description: str = ""


@dataclass(frozen=True)
class Layout:
    """One kind of file of a format: which header columns are t, q1..qN and the torques."""

    name: str
    time: str
    positions: tuple[str, ...]
    torques: dict[str, TorqueSource]
    default_torque: str

    @property
    def n_joints(self) -> int:
        return len(self.positions)

    def required(self) -> set[str]:
        """The columns a file must have to be of this layout (time, positions, every torque)."""
        cols = {self.time, *self.positions}
        for source in self.torques.values():
            cols.update(source.columns)
        return cols


@dataclass(frozen=True)
class RecordingFormat:
    name: str
    description: str
    source: str  # where the files come from and where the loop order was read (citation)
    layouts: tuple[Layout, ...]
    path: str

    def layout_for(self, header: list[str] | tuple[str, ...]) -> Layout | None:
        """The first layout whose columns are all in ``header`` (None if there is none)."""
        have = set(header)
        for layout in self.layouts:
            if layout.required() <= have:
                return layout
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
    f.only({"name", "time", "positions", "torques", "default_torque"})
    positions = _column_list(f, "positions")
    n = len(positions)
    tf = f.table("torques")
    if not tf.keys():
        raise f.error("torques", "must name at least one torque source")
    torques = {}
    for name in tf.data:
        sf = tf.table(name)
        sf.only({"columns", "loop_delay", "description"})
        columns = _column_list(sf, "columns")
        if len(columns) != n:
            raise sf.error("columns", f"must name {n} columns (one per joint), got {len(columns)}")
        torques[name] = TorqueSource(
            name=name,
            columns=columns,
            loop_delay=sf.integer("loop_delay", lo=-LOOP_DELAY_MAX, hi=LOOP_DELAY_MAX),
            description=sf.string("description", ""),
        )
    default = f.string("default_torque", next(iter(torques)))
    if default not in torques:
        raise f.error("default_torque", f"must be one of {', '.join(torques)}, got {default!r}")
    return Layout(
        name=f.string("name", ""),
        time=f.string("time"),
        positions=positions,
        torques=torques,
        default_torque=default,
    )


def _column_list(f: Fields, key: str) -> tuple[str, ...]:
    value = f.data.get(key)
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise f.error(key, "must be a non-empty list of column names")
    if len(set(value)) != len(value):
        raise f.error(key, "names a column twice")
    return tuple(value)


__all__ = [
    "LOOP_DELAY_MAX",
    "Layout",
    "ProfileError",
    "RecordingFormat",
    "TorqueSource",
    "load_format",
]
