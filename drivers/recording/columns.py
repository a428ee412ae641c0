"""Column maps: which file columns become t, q1..qN, tau1..tauN (a recording-format profile,
``--columns``, ``--torque``, ``--leave-out-joints``, ``--ignore-columns``), the torque scale and
the loop delay the rows are realigned by (:func:`column_plan`, :func:`parse_column_map`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drivers.recording.format import RecordingError, base_columns
from profiles.recording_format import (
    LOOP_DELAY_MAX,
    TARGET_KINDS,
    RecordingFormat,
    load_format,
)


@dataclass
class ColumnPlan:
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


def ignored_columns(
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


def kept_columns(
    label: Path, header: list[str], plan: ColumnPlan, extra_columns: bool, ignored: tuple[str, ...]
) -> list[str]:
    """The file's columns to read: the plan's, and the others unless ``extra_columns`` is off or
    they are ignored (a column the plan uses may not be ignored)."""
    used = list(dict.fromkeys(plan.sources.values()))
    clash = [c for c in used if is_ignored(c, ignored)]
    if clash:
        raise RecordingError(f"{label}: column {clash[0]} is both read and ignored")
    if not extra_columns:
        return used
    return [c for c in header if c in used or not is_ignored(c, ignored)]


def is_ignored(column: str, ignored: tuple[str, ...]) -> bool:
    """``column`` is named in ``ignored``, itself or as its group (``A`` for ``A[k]``)."""
    return any(column == g or column.startswith(g + "[") for g in ignored)


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


def column_plan(
    csv_path: Path,
    header: list[str],
    meta: dict[str, Any],
    fmt: str | Path | RecordingFormat | None,
    columns: str | Mapping[str, str] | None,
    torque: str | None,
    loop_delay: int | None,
    effort_scale: Sequence[float] | None = None,
    leave_out: Sequence[int] | None = None,
) -> ColumnPlan:
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
    return ColumnPlan(
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
