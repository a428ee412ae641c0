"""The checks of every recording read: the columns assembled into a :class:`Recording` with
the time stamps checked (monotonic, the period, gaps, irregular sampling), values bounded, a
joint whose torque is mostly zero noted; :func:`reassemble` for columns changed after reading.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from drivers.recording.columns import ColumnPlan
from drivers.recording.data import (
    GAP_FACTOR,
    IRREGULAR_FACTOR,
    MAX_ABS_VALUE,
    PERIOD_MAX_S,
    Recording,
)
from drivers.recording.format import SIGNALS, RecordingError


def assemble(
    where: Path,
    csv_path: Path,
    data: np.ndarray,
    keep: list[str],
    plan: ColumnPlan,
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


def _mostly_zero(columns: dict[str, np.ndarray], plan: ColumnPlan) -> list[str]:
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
    plan = ColumnPlan(
        sources={name: name for name in names},
        n_joints=rec.n_joints,
        torque_source=rec.torque_source,
        loop_delay=0,
        own_grid=False,
        identity=True,
    )
    data = np.column_stack([np.asarray(columns[name], float) for name in keep])
    csv_path = rec.path / SIGNALS if rec.path.is_dir() else rec.path
    out = assemble(rec.path, csv_path, data, keep, plan, rec.meta, False)
    timing = ("gap(s) in t", "irregular sampling")
    old = [f for f in rec.findings_on_read if not any(w in f for w in timing)]
    out.findings_on_read = [note, *old, *out.findings_on_read]
    return out


def _check_times(
    csv_path: Path,
    t: np.ndarray,
    dt: np.ndarray,
    plan: ColumnPlan,
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
