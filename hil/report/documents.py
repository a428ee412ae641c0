"""The report of each command, built from its JSON document, its text and its recordings.

One builder per command (``identify``, ``diagnose``, ``compare`` for ``hil control
--compare``); each reads only the document's keys it knows and skips what a document lacks (the
three kinds of ``hil identify`` document differ), then folds the whole document at the end, so
nothing the command found is missing from the page.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from drivers.recording import Recording, RecordingError, read_signals
from hil.report.page import Page

__all__ = ["COMMANDS", "build_report", "write_report"]

COMMANDS = ("identify", "diagnose", "compare")


def _pct(x: Any) -> str:
    return "–" if x is None or not math.isfinite(float(x)) else f"{100 * float(x):.2f} %"


def _joint_series(rec: Recording, prefix: str) -> list[tuple[str, Any, Any]]:
    t = rec.columns["t"]
    return [
        (f"{prefix}{j}", t, rec.columns[f"{prefix}{j}"])
        for j in range(1, rec.n_joints + 1)
        if f"{prefix}{j}" in rec.columns
    ]


def _recording_plots(page: Page, recordings: Sequence[Recording]) -> None:
    """Joint positions and torques of each recording against its own time stamps."""
    if not recordings:
        return
    page.heading("Recordings")
    for rec in recordings:
        name = Path(rec.path).name or str(rec.path)
        page.paragraph(
            f"{name}: {len(rec.columns['t'])} rows, {rec.n_joints} joints, torque "
            f"{rec.torque_source}"
            + (f"; {'; '.join(rec.findings_on_read)}" if rec.findings_on_read else ""),
            note=True,
        )
        page.plot(f"{name}: joint positions", "t [s]", "q [rad]", _joint_series(rec, "q"))
        page.plot(f"{name}: joint torques", "t [s]", "τ [Nm]", _joint_series(rec, "tau"))


def _errors(rows: list[dict[str, Any]], scheme: str) -> list[float | None]:
    """Table II's relative errors of ``scheme`` in %, None where it has none."""
    return [None if r.get(scheme + "_error") is None else 100 * r[scheme + "_error"] for r in rows]


def _errors(rows: list[dict[str, Any]], scheme: str) -> list[float | None]:
    """Table II's relative errors of ``scheme`` in %, None where it has none."""
    return [None if r.get(scheme + "_error") is None else 100 * r[scheme + "_error"] for r in rows]


# ---- hil identify ---------------------------------------------------------------------------
def _identify(page: Page, doc: dict[str, Any]) -> None:
    facts = [
        f"{k.replace('_', ' ')}: {doc[k]}"
        for k in ("robot", "recording", "validation_recording", "rows", "estimator")
        if doc.get(k) is not None
    ]
    page.bullets(facts)
    for disc, entry in doc.get("discretizations", {}).items():
        rows = entry.get("table_ii", [])
        schemes = list(entry.get("schemes", {}))
        if rows:
            page.heading(f"Table II, {disc} discretization")
            page.table(
                ["parameter", "reference", *(f"{s} (error)" for s in schemes)],
                [
                    [
                        r["parameter"],
                        r["measured"],
                        *(
                            f"{r[s]:.4g} ({100 * r[s + '_error']:+.1f} %)"
                            if r.get(s) is not None and r.get(s + "_error") is not None
                            else "–"
                            for s in schemes
                        ),
                    ]
                    for r in rows
                ],
            )
            page.plot(
                f"Relative error of each parameter to the reference ({disc})",
                "parameter index",
                "relative error [%]",
                [(s, list(range(1, len(rows) + 1)), _errors(rows, s)) for s in schemes],
                points=True,
            )
        validation_rows = []
        for scheme, res in entry.get("schemes", {}).items():
            for where, v in (res.get("validation") or {}).items():
                if isinstance(v, dict) and "torque_nrmse" in v:
                    validation_rows.append(
                        [f"{scheme}, {where}", " / ".join(_pct(x) for x in v["torque_nrmse"]),
                         " / ".join(_pct(x) for x in v.get("position_nrmse") or []) or "–"]
                    )  # fmt: skip
        if validation_rows:
            page.heading(f"Validation, {disc} discretization (NRMSE per joint)")
            page.table(["θ, recording", "torque", "simulated position"], validation_rows)
    ident = doc.get("identification")
    if isinstance(ident, dict) and ident.get("parameters"):
        page.heading("Identified parameters")
        page.bullets(list(ident.get("notes", [])))
        ref = doc.get("profile_theta") or []
        page.table(
            ["parameter", "unit", "estimate", "SE (blocked bootstrap)", "identified", "profile"],
            [
                [p.get("parameter"), p.get("unit"), p.get("estimate"),
                 p.get("se_blocked_bootstrap"), p.get("identified"),
                 ref[k] if k < len(ref) else None]
                for k, p in enumerate(ident["parameters"])
            ],
        )  # fmt: skip
    params = doc.get("parameters")
    if isinstance(params, list) and params and isinstance(params[0], dict) and "name" in params[0]:
        _urdf_parameters(page, doc, params)
    validation = doc.get("validation")
    if isinstance(validation, dict) and "torque_nrmse_identified" in validation:
        _held_out_verdict(page, validation)
    elif isinstance(validation, dict):
        rows = [
            [f"{who}, {where}", " / ".join(_pct(x) for x in v["torque_nrmse"]),
             " / ".join(_pct(x) for x in (v.get("simulation") or {}).get("position_nrmse", []))
             or "–"]
            for where, by_who in validation.items() if isinstance(by_who, dict)
            for who, v in by_who.items() if isinstance(v, dict) and "torque_nrmse" in v
        ]  # fmt: skip
        if rows:
            page.heading("Validation (NRMSE per joint)")
            page.table(["θ, recording", "torque", "simulated position (windows)"], rows)


def _urdf_parameters(page: Page, doc: dict[str, Any], params: list[dict[str, Any]]) -> None:
    """A URDF arm's base parameters: each scheme's estimate, the reported one and its SE ("n/i"
    where the data do not determine it)."""
    schemes = list(params[0].get("schemes", {}))
    page.heading(f"Base parameters ({doc.get('params_scheme', '')} reported)")
    page.table(
        ["parameter", "meaning", "unit", "reported", "SE (blocked bootstrap)", "nominal",
         *schemes],
        [
            [p["name"], p.get("meaning"), p.get("unit"),
             "n/i" if p.get("identified") is None else p["identified"],
             p.get("se_blocked_bootstrap"), p.get("nominal"),
             *(p.get("schemes", {}).get(sc) for sc in schemes)]
            for p in params
        ],
    )  # fmt: skip


def _held_out_verdict(page: Page, v: dict[str, Any]) -> None:
    """The held-out check that decides what a URDF arm's identification reports."""
    page.heading("Held-out validation")
    verdict = "passed" if v.get("passed") else f"failed ({v.get('reason')})"
    page.paragraph(
        f"On {v.get('on')}: the reported scheme {verdict}; schemes shown better than each "
        f"joint's mean: {', '.join(v.get('schemes_passed') or []) or 'none'}."
    )
    page.table(
        ["θ", "torque NRMSE per joint"],
        [
            [who, " / ".join(_pct(x) for x in v[f"torque_nrmse_{who}"])]
            for who in ("identified", "nominal")
            if v.get(f"torque_nrmse_{who}")
        ],
    )


# ---- hil diagnose ---------------------------------------------------------------------------
def _finding_words(f: dict[str, Any]) -> str:
    est = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in f.get("estimate", {}).items())
    ev = f.get("evidence", {})
    joint = f"joint {f['joint']}" if f.get("joint") else "every joint"
    words = (
        f"{f['effect'].replace('_', ' ')} on {joint}: {est}. It lowers the held-out error by "
        f"{_pct(ev.get('held_out_error_reduction'))} in {ev.get('blocks_improved', '?')} of "
        f"{ev.get('blocks', '?')} blocks."
    )
    if f.get("confounded_with"):
        words += f" The data cannot tell it from: {', '.join(f['confounded_with'])}."
    return words


def _diagnose(page: Page, doc: dict[str, Any]) -> None:
    page.paragraph(doc.get("summary", ""))
    findings = doc.get("findings", [])
    page.heading("Findings")
    if findings:
        page.bullets([_finding_words(f) for f in findings])
        page.table(
            ["effect", "joint", "estimate", "held-out error reduction", "blocks improved"],
            [
                [f["effect"], f.get("joint") or "all",
                 ", ".join(f"{k} {v}" for k, v in f.get("estimate", {}).items()),
                 _pct(f.get("evidence", {}).get("held_out_error_reduction")),
                 f"{f.get('evidence', {}).get('blocks_improved', '?')} / "
                 f"{f.get('evidence', {}).get('blocks', '?')}"]
                for f in findings
            ],
        )  # fmt: skip
    else:
        page.paragraph("None: nothing the candidates describe improves the held-out fit.")
    page.bullets(list(doc.get("notes", [])) + [t["note"] for t in doc.get("timing", [])])
    fit = doc.get("fit", {})
    if "before" in fit:
        page.heading(f"Fit on held-out data ({fit.get('held_out', '')})")
        n = len(fit["before"]["torque_nrmse"])
        rows = []
        for stage in ("before", "after"):
            if stage in fit:
                pos = fit[stage].get("position_nrmse") or [None] * n
                rows += [
                    [f"{stage}, joint {j + 1}", _pct(fit[stage]["torque_nrmse"][j]), _pct(pos[j])]
                    for j in range(n)
                ]
        page.table(["model, joint", "torque NRMSE", "simulated position NRMSE"], rows)
        page.plot(
            "Held-out torque NRMSE per joint, before and after modelling the findings",
            "joint",
            "NRMSE [%]",
            [
                (stage, list(range(1, n + 1)), [100 * x for x in fit[stage]["torque_nrmse"]])
                for stage in ("before", "after")
                if stage in fit
            ],
            points=True,
        )
    joints = doc.get("location", {}).get("joints", [])
    if joints:
        page.heading("Where the nominal model's residual lives")
        page.table(
            ["joint", "residual RMS [Nm]", "robust scale [Nm]", "carried by"],
            [
                [j["joint"], j["residual_rms_Nm"], j["robust_scale_Nm"],
                 ", ".join(j.get("carried_by", [])) or "nothing in particular (noise-like)"]
                for j in joints
            ],
        )  # fmt: skip
    tested = doc.get("candidates_tested", {})
    if tested:
        page.heading("Candidates tested")
        page.table(
            ["candidate", "held-out error reduction", "t statistic", "blocks improved"],
            [
                [name, _pct(ev.get("held_out_error_reduction")), ev.get("t_statistic"),
                 f"{ev.get('blocks_improved', '?')} / {ev.get('blocks', '?')}"]
                for name, ev in tested.items()
            ],
        )  # fmt: skip


# ---- hil control --compare --------------------------------------------------------------------
def _compare_runs(doc: dict[str, Any]) -> list[dict[str, Any]]:
    """Every run of the comparison, parameter set by parameter set, scheme by scheme."""
    return [
        run
        for by_scheme in doc.get("results", {}).values()
        for run in by_scheme.values()
        if isinstance(run, dict)
    ]


def _compare(page: Page, doc: dict[str, Any]) -> None:
    page.bullets(
        [
            f"{k.replace('_', ' ')}: {doc[k]}"
            for k in ("bench", "robot", "experiment", "status")
            if doc.get(k) is not None
        ]
        + [f"failed: {f}" for f in doc.get("failures", [])]
    )
    runs = _compare_runs(doc)
    if runs:
        page.heading("Tracking errors")
        page.table(
            ["parameters / scheme", "status", "max |e| [rad]", "RMS e [rad]",
             "max |ė| [rad/s]", "clipped cycles"],
            [
                [f"{r.get('params')} / {str(r.get('scheme')).upper()}", r.get("status"),
                 r.get("max_position_error_rad"), r.get("rms_position_error_rad"),
                 r.get("max_velocity_error_rad_s"), r.get("clipped_cycles")]
                for r in runs
            ],
        )  # fmt: skip
        better = doc.get("max_position_error_reduction_vs_pd", {})
        if better:
            page.paragraph(
                "How many times smaller each scheme's maximum position error is than PD's, "
                "joint by joint:"
            )
            page.table(
                ["parameters / scheme", "× better than PD, per joint"],
                [
                    [f"{params} / {scheme.upper()}", " / ".join(f"{x:.1f}×" for x in factors)]
                    for params, by_scheme in better.items()
                    for scheme, factors in by_scheme.items()
                ],
            )
        n = max((len(r.get("max_position_error_rad") or []) for r in runs), default=0)
        page.plot(
            "Maximum position error per joint, each scheme and parameter set",
            "joint",
            "max |e| [rad]",
            [
                (f"{r.get('params')}/{r.get('scheme')}", list(range(1, n + 1)),
                 r.get("max_position_error_rad"))
                for r in runs
                if r.get("max_position_error_rad")
            ],
            points=True,
        )  # fmt: skip


def _compare_recordings(doc: dict[str, Any]) -> list[tuple[str, Recording]]:
    """Each run's recording, read from the path its document names (skipped if unreadable)."""
    out = []
    for r in _compare_runs(doc):
        path = r.get("signals") or r.get("out_dir")
        if not path:
            continue
        try:
            out.append((f"{r.get('params')}/{r.get('scheme')}", read_signals(path)))
        except (OSError, RecordingError):
            continue
    return out


def _compare_plots(page: Page, doc: dict[str, Any]) -> None:
    recs = _compare_recordings(doc)
    if not recs:
        return
    page.heading("Tracking runs")
    joints = recs[0][1].n_joints
    for j in range(1, joints + 1):
        series = [(label, rec.columns["t"], rec.columns[f"q{j}"]) for label, rec in recs]
        page.plot(f"Joint {j} position, every run", "t [s]", f"q{j} [rad]", series)
        page.plot(
            f"Joint {j} torque, every run",
            "t [s]",
            f"τ{j} [Nm]",
            [(label, rec.columns["t"], rec.columns[f"tau{j}"]) for label, rec in recs],
        )


BUILDERS: dict[str, tuple[str, Callable[[Page, dict[str, Any]], None]]] = {
    "identify": ("Identification report (hil identify)", _identify),
    "diagnose": ("Mismatch diagnosis report (hil diagnose)", _diagnose),
    "compare": ("Tracking control comparison (hil control --compare)", _compare),
}


def build_report(
    command: str,
    doc: dict[str, Any],
    *,
    text: str | None = None,
    recordings: Sequence[Recording] = (),
) -> str:
    """The HTML page of ``command``'s JSON document ``doc``, with ``text`` (what the command
    prints) and plots of ``recordings``."""
    if command not in BUILDERS:
        raise ValueError(f"no HTML report for {command!r}; one of {', '.join(COMMANDS)}")
    title, build = BUILDERS[command]
    page = Page(title)
    build(page, doc)
    if command == "compare":
        _compare_plots(page, doc)
    _recording_plots(page, recordings)
    if text:
        page.heading("As printed")
        page.preformatted(text)
    page.heading("The document")
    page.paragraph(
        "Every field of the JSON document the command wrote (--json prints the same).", note=True
    )
    page.document(doc)
    return page.render()


def write_report(
    path: str | os.PathLike[str],
    command: str,
    doc: dict[str, Any],
    *,
    text: str | None = None,
    recordings: Sequence[Recording] = (),
) -> Path:
    """Write :func:`build_report` to ``path`` (atomically: a reader never sees half a page);
    returns the path."""
    out = Path(path)
    page = build_report(command, doc, text=text, recordings=recordings)
    if out.parent != Path():
        out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(page, encoding="utf-8")
    os.replace(tmp, out)
    return out
