"""Replay of a timing trace: re-run a recorded realtime run in lockstep with its timing imposed.

A realtime run is timed by the wall clock: every sample k was taken at some time s_k and the
command of cycle k took effect at some time a_k, with the jitter of that moment. The replay
runs the same experiment (the open-loop excitation of `hil run`, or the controller of
`hil control` with the same scheme, θ̃, gains and duration) in lockstep, where the virtual robot
takes sample k at s_k and applies the command of cycle k at a_k (a ``[timing_faults.trace]``
in a generated effects profile, virtual_robot/timing_faults.py). So a jitter effect seen once
can be studied again, deterministically, and varied.

Where the times come from (:func:`trace_from_run`):

* ``robot-events.csv`` (written by the virtual robot of every realtime run over a virtual CAN
  bench): the robot's own clock, exactly when it sampled and when each command took effect.
  Replaying it reproduces the recorded q within the encoder quantization.
* otherwise (a serial bench, a real bench, a CSV from elsewhere): the host's timestamps in
  ``signals.csv`` (hil/bench/loop.py ``TIMING_COLUMNS``): s_k = sync_sent_s[k] − sync_sent_s[0] and
  a_k = feedback_s[k] − sync_sent_s[0] + ``compute_s`` (the host's time from feedback to its
  command leaving, which the recording does not hold). The one-way link latency cancels out
  (SYNC and command cross the same link); the error is what the host's stamps miss.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drivers.realtime_times import (
    COMPUTE_S,
    DEFAULT_COMPUTE_S,
    ROBOT_EVENTS,
    host_stamp_trace,
    robot_event_trace,
)
from drivers.recording import (
    Recording,
    RecordingError,
    dumps_strict,
    read_signals,
    write_json_atomic,
)
from hil.bench.run import UsageError
from profiles.bench import load_bench
from profiles.drive import load_drive
from profiles.loader import load_toml
from profiles.robot import load_robot
from profiles.timing_faults import TimingTrace, to_toml, write_trace

TRACE_FILE = "timing-trace.csv"
STEPS_FILE = "timing-steps.csv"
REPLAY_JSON = "replay.json"


@dataclass
class TraceSource:
    trace: TimingTrace
    source: str  # "robot events" | "host timestamps"
    path: str
    notes: list[str]


def _usage(read: Callable[..., TimingTrace], *args: Any) -> TimingTrace:
    try:
        return read(*args)
    except RecordingError as exc:
        raise UsageError(str(exc)) from None


def trace_from_run(
    run_dir: str | Path, *, source: str = "auto", compute_s: float | None = None
) -> tuple[Recording, TraceSource]:
    """The recording of ``run_dir`` and its timing trace (module docstring). ``source``:
    "auto" (robot events if present), "robot" or "host"; ``compute_s``: host stamps only
    (default: :data:`COMPUTE_S` of the run's kind)."""
    rec = read_signals(run_dir, min_rows=2)
    if rec.meta.get("mode") != "realtime" and "sync_sent_s" not in rec.columns:
        raise UsageError(f"{run_dir}: not a realtime run (meta.json mode {rec.meta.get('mode')})")
    events = Path(run_dir) / ROBOT_EVENTS
    notes: list[str] = []
    if source == "robot" or (source == "auto" and events.is_file()):
        if not events.is_file():
            raise UsageError(f"{events}: no robot event log (a realtime run over a CAN bench)")
        if rec.meta.get("protocol") == "serial":
            raise UsageError(f"{events}: serial runs sample per request; use --trace-source host")
        trace = _usage(robot_event_trace, events, len(rec))
        return rec, TraceSource(trace, "robot events", str(events), notes)
    if compute_s is None:
        compute_s = COMPUTE_S.get(rec.meta.get("kind", ""), DEFAULT_COMPUTE_S)
    trace = _usage(host_stamp_trace, rec, compute_s)
    notes.append(
        f"times from the host's stamps; command = feedback + {compute_s * 1e6:.0f} µs (assumed)"
    )
    return rec, TraceSource(trace, "host timestamps", str(rec.path / "signals.csv"), notes)


def replay_profiles(
    rec: Recording, trace_path: Path, steps_path: Path | None, out: Path, bench_name: str | None
) -> tuple[str, str]:
    """A bench (the recorded one, or ``bench_name``; without its timing faults) and an effects
    profile (the recorded run's effects, its timing faults replaced by the trace), written to
    ``out``. Returns (bench, effects) names or paths for the runner."""
    meta = rec.meta
    bench_ref = bench_name or meta.get("bench_profile") or meta.get("bench") or "virtual-slcan"
    bench = load_bench(bench_ref)
    if not bench.virtual:
        raise UsageError(f"bench {bench.name} is not virtual: a replay runs on the virtual robot")
    if bench.timing_faults is not None:  # the trace is the timing: no faults on top of it
        data, _ = load_toml("benches", bench_ref)
        data.pop("timing_faults", None)
        data["name"] = f"{bench.name}-replay"
        bench_path = out / "replay-bench.toml"
        bench_path.write_text(to_toml(data))
        bench_ref = str(bench_path)
    effects_ref = meta.get("effects") or bench.effects
    data = dict(load_toml("effects", effects_ref)[0]) if effects_ref else {}
    data["name"] = f"{data.get('name', 'none')}-replay"
    data["description"] = f"replay of {rec.path}: its effects, its timing trace"
    trace: dict[str, str] = {"file": str(trace_path.resolve())}
    if steps_path is not None:
        trace["steps"] = str(steps_path.resolve())
    data["timing_faults"] = {"trace": trace}
    effects_path = out / "replay-effects.toml"
    effects_path.write_text(to_toml(data))
    return bench_ref, str(effects_path)


def _rerun(rec: Recording, bench: str, effects: str, out: Path) -> dict[str, Any]:
    """The recorded experiment again, in lockstep over ``bench`` with ``effects``."""
    meta = rec.meta
    kind = meta.get("kind")
    n = len(rec)
    h = rec.period_s  # meta.json's, checked against t on read (the run's own t = k·h)
    if kind in ("hil run", "hil jitter"):
        from hil.bench.run import run_experiment

        experiment = meta.get("experiment_profile") or meta.get("experiment")
        if experiment is None:
            raise UsageError(
                f"{rec.path}: a `hil jitter` run without --experiment holds zero torque: the "
                "arm stays at rest, there is nothing to replay"
            )
        return run_experiment(
            bench,
            experiment,
            out,
            duration_s=n * h,
            mode="lockstep",
            effects=effects,
            seed=meta.get("seed"),
            plot=False,
            progress=False,
        )
    if kind == "hil control":
        from hil.control.tracking import LabelledParams, run_control
        from hil.model.params import ParamSet

        p = meta["params"]
        params = LabelledParams(
            p["label"], ParamSet(np.asarray(p["theta"], float), p["source"], p.get("scheme"))
        )
        gains = meta.get("gains", {})
        doc = run_control(
            bench,
            meta["scheme"],
            out,
            params=params,
            experiment=meta.get("experiment_profile") or meta["experiment"],
            duration_s=n * h,
            mode="lockstep",
            effects=effects,
            seed=meta.get("seed"),
            kp=gains.get("kp"),
            kv=gains.get("kv"),
            plot=False,
            progress=False,
        )
        return doc["run"]
    raise UsageError(
        f"{rec.path}: cannot replay a {kind!r} run (`hil run`, `hil control` and "
        "`hil jitter --experiment` runs)"
    )


def counts_per_rad(robot: str) -> np.ndarray:
    """Encoder counts per radian of each joint's drive."""
    drives = [load_drive(d) for d in load_robot(robot).drives]
    return np.array([d.counts_per_rev / (2 * np.pi) for d in drives])


def compare_q(recorded: Recording, replayed: Recording, robot: str) -> dict[str, Any]:
    """How far the replay's q is from the recording's, in rad and in encoder counts."""
    n = min(len(recorded), len(replayed))
    dq = replayed.q[:n] - recorded.q[:n]
    counts = np.rint(np.abs(dq) * counts_per_rad(robot)).astype(int)
    dtau = replayed.tau[:n] - recorded.tau[:n]
    return {
        "rows_compared": int(n),
        "max_abs_q_difference_rad": np.max(np.abs(dq), axis=0).tolist(),
        "max_abs_q_difference_counts": counts.max(axis=0).tolist(),
        "rms_q_difference_rad": np.sqrt(np.mean(dq**2, axis=0)).tolist(),
        "rows_with_equal_q": int(np.sum(np.all(counts == 0, axis=1))),
        "max_abs_tau_difference_Nm": np.max(np.abs(dtau), axis=0).tolist(),
    }


def replay_run(
    run_dir: str | Path,
    out_dir: str | Path,
    *,
    bench: str | None = None,
    source: str = "auto",
    compute_s: float | None = None,
    plot: bool = True,
) -> dict[str, Any]:
    """Replay ``run_dir`` in lockstep with its timing trace; write ``out_dir`` (the replay run,
    the trace, the profiles, replay.json) and return replay.json's document."""
    rec, ts = trace_from_run(run_dir, source=source, compute_s=compute_s)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    steps_path = out / STEPS_FILE if ts.trace.steps is not None else None
    trace_path = write_trace(out / TRACE_FILE, ts.trace, steps_path)
    bench_ref, effects_ref = replay_profiles(rec, trace_path, steps_path, out, bench)
    run = _rerun(rec, bench_ref, effects_ref, out / "run")
    if run.get("status") != "complete":
        raise RuntimeError(f"replay run {run.get('status')}: {run.get('reason')}")
    replayed = read_signals(out / "run")
    robot = rec.meta.get("robot") or load_bench(bench_ref).robot
    delays = ts.trace.command_s - ts.trace.sample_s
    periods = np.diff(ts.trace.sample_s)
    doc: dict[str, Any] = {
        "kind": "hil replay",
        "recorded": str(rec.path),
        "recorded_kind": rec.meta.get("kind"),
        "replay": str(out / "run"),
        "bench": bench_ref,
        "effects_profile": effects_ref,
        "trace": str(trace_path),
        "trace_source": ts.source,
        "trace_from": ts.path,
        "notes": ts.notes,
        "trace_statistics": {
            "cycles": len(ts.trace),
            "sample_period_ms": _stats(periods * 1e3),
            "sample_to_command_ms": _stats(delays * 1e3),
            "commands_after_next_sample": int(
                np.sum(ts.trace.command_s[:-1] > ts.trace.sample_s[1:])
            ),
        },
        "comparison": compare_q(rec, replayed, robot),
        "plot": None,
    }
    if plot:
        doc["plot"] = str(_plot(rec, replayed, robot, out / "replay.png"))
    write_json_atomic(out / REPLAY_JSON, doc)
    return doc


def _stats(a: np.ndarray) -> dict[str, float]:
    if len(a) == 0:
        return {}
    return {
        "p50": float(np.median(a)),
        "p99": float(np.percentile(a, 99)),
        "min": float(a.min()),
        "max": float(a.max()),
    }


def _plot(recorded: Recording, replayed: Recording, robot: str, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = min(len(recorded), len(replayed))
    counts = (replayed.q[:n] - recorded.q[:n]) * counts_per_rad(robot)
    fig, ax = plt.subplots(figsize=(9, 3.5))
    for j in range(2):
        ax.plot(recorded.t[:n], counts[:, j], lw=0.8, label=f"joint {j + 1}")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("q replay − q recorded [counts]")
    ax.set_title(f"replay of {recorded.path.name} in lockstep with its timing trace")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def format_replay(doc: dict[str, Any]) -> str:
    c, s = doc["comparison"], doc["trace_statistics"]
    lines = [
        f"replay:   {doc['replay']} (lockstep, trace from {doc['trace_source']})",
        f"trace:    {s['cycles']} cycles; sample period p50 {s['sample_period_ms']['p50']:.3f} ms "
        f"(max {s['sample_period_ms']['max']:.3f}); sample→command p50 "
        f"{s['sample_to_command_ms']['p50']:.3f} ms (max {s['sample_to_command_ms']['max']:.3f})",
        "q replay − q recorded, max per joint: "
        + ", ".join(
            f"{r:.3g} rad ({n} counts)"
            for r, n in zip(
                c["max_abs_q_difference_rad"], c["max_abs_q_difference_counts"], strict=True
            )
        )
        + f"; {c['rows_with_equal_q']}/{c['rows_compared']} rows equal in counts",
    ]
    lines += [f"note:     {n}" for n in doc["notes"]]
    if doc.get("plot"):
        lines.append(f"plot:     {doc['plot']}")
    return "\n".join(lines)


def dumps(doc: dict[str, Any]) -> str:
    return dumps_strict(doc)


__all__ = [
    "format_replay",
    "replay_run",
    "trace_from_run",
]
