"""`hil jitter`: how well does the realtime loop keep time on this machine and link?

Runs the realtime loop over a bench at ``--rate`` (the period h = 1/rate replaces the bench's, in
a copy of the profile written to the run directory, so the virtual robot runs at that rate too)
holding zero torque, or an experiment's torques (``--experiment``), and reports per cycle
(:mod:`hil.bench.timing_stats`): the release error against the absolute deadline, the period error
from one release to the next, the command-to-feedback latency, deadline misses (feedback after
the next deadline), overruns (a period longer than 1.5 h) and lost feedback. Also what the
machine was doing: CPU count, load average at start and end, the scheduling policy and memory
lock the loop actually got (:mod:`hil.bench.scheduler`), and for CAN the bus load of the cyclic
phase, as ``canbusload`` computes it (:mod:`hil.timing.bus_load`).

Output: a table on stdout (or one JSON document with ``--json``), ``jitter-histograms.png`` and
``jitter-timeline.png`` in the run directory, and the same numbers under ``"jitter"`` in its
meta.json. :func:`measure` is the same as a function (used by the sweeps of
``hil.timing.sweep`` and by the benchmark).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import importlib.util
import json
import os
import platform
from pathlib import Path
from typing import Any

import numpy as np

from drivers.arm import Sample
from drivers.recording import META, read_signals, write_json_atomic
from hil.bench.run import UsageError, bench_meta, check_bench, record_over_bench
from hil.bench.scheduler import POLICIES
from hil.bench.timing_stats import cycle_timing, jitter_summary
from hil.bench.variant import write_bench_variant
from hil.cli_options import (
    add_bench_option,
    add_drive_options,
    add_out_options,
    add_report_options,
    drive_kwargs,
    prepare_out_dir,
    print_document,
    run_exit,
)
from profiles.bench import MAX_FEEDBACK_BUDGET_S
from profiles.experiment import check_duration, load_experiment

DEFAULT_DURATION_S = 10.0
MAX_RATE_HZ = 5000.0
SWEEP_MODULE = "hil.timing.sweep"  # PART B: `--sweep` studies (add_sweep_arguments, run_sweep)


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_bench_option(p)
    p.add_argument(
        "--rate", type=float, default=None, help="loop rate in Hz (default: the bench's 1/period_s)"
    )
    p.add_argument(
        "--duration",
        type=float,
        default=DEFAULT_DURATION_S,
        help=f"seconds of loop (default {DEFAULT_DURATION_S:g})",
    )
    add_out_options(p, "run directory (default: a new runs/jitter-BENCH[-RATEhz]/<date>T<time>)")
    p.add_argument(
        "--experiment",
        default=None,
        help="torques from this experiment profile (default: hold zero torque)",
    )
    add_drive_options(p, mode=False)  # realtime by nature
    p.add_argument(
        "--realtime-policy",
        choices=POLICIES,
        default="auto",
        help="auto: try SCHED_FIFO and mlockall, fall back with a warning; off: do not try",
    )
    p.add_argument(
        "--feedback-budget",
        type=float,
        default=None,
        metavar="SECONDS",
        help="how late feedback may be before the host calls the link dead (default: the "
        "bench's feedback_budget_s, 0.1 s); later than a period is counted as late",
    )
    p.add_argument(
        "--feedback-timeout-periods",
        type=int,
        default=None,
        help="the same budget in periods (older option, kept as an alias of --feedback-budget)",
    )
    p.add_argument(
        "--pace-bus",
        action="store_true",
        help="virtual CAN bench: frames take their bit time at the bitrate (pace_bus = true)",
    )
    p.add_argument(
        "--bitrate", type=int, default=None, help="CAN bitrate in bit/s (default: the bench's)"
    )
    add_report_options(p, plot="skip the PNG plots")
    if importlib.util.find_spec(SWEEP_MODULE) is not None:  # PART B's studies, once they exist
        importlib.import_module(SWEEP_MODULE).add_sweep_arguments(p)


def main(args: argparse.Namespace) -> int:
    if getattr(args, "sweep", None):
        return int(importlib.import_module(SWEEP_MODULE).run_sweep(args))
    rate = args.rate
    out = prepare_out_dir(args.out, args.overwrite, default=_default_group(args.bench, rate))
    overrides: dict[str, Any] = {}
    if args.pace_bus:
        overrides["pace_bus"] = True
    if args.bitrate is not None:
        overrides["bitrate"] = args.bitrate
    summary = measure(
        args.bench,
        rate,
        args.duration,
        out,
        experiment=args.experiment,
        realtime_policy=args.realtime_policy,
        feedback_timeout_periods=args.feedback_timeout_periods,
        feedback_budget_s=args.feedback_budget,
        bench_overrides=overrides,
        **drive_kwargs(args),
    )
    print_document(args, summary, lambda: format_table(summary))
    return run_exit(
        "jitter",
        summary["status"],
        f"run {summary['status']}: {summary['reason']} "
        f"(figures of the {summary['rows']} rows recorded are above)",
    )


def _default_group(bench: str, rate: float | None) -> str:
    """The runs/ group of a run without --out: jitter-BENCH[-RATEhz]."""
    name = Path(bench).stem
    return f"jitter-{name}" + (f"-{rate:g}hz" if rate else "")


# ---- the machine ----------------------------------------------------------------------------
def machine_state() -> dict[str, Any]:
    """What can make timing figures differ between machines and runs."""
    state: dict[str, Any] = {
        "cpu_count": os.cpu_count(),
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "platform": platform.platform(),
        "python": platform.python_version(),
        "euid": os.geteuid(),
    }
    with contextlib.suppress(AttributeError, OSError):
        state["cpus_allowed"] = len(os.sched_getaffinity(0))
    with contextlib.suppress(OSError), open("/proc/cpuinfo") as f:
        for line in f:
            if line.startswith("model name"):
                state["cpu_model"] = line.split(":", 1)[1].strip()
                break
    return state


# ---- one measurement ----------------------------------------------------------------------------
def measure(
    bench: str | Path,
    rate_hz: float | None,
    duration_s: float,
    out_dir: str | Path,
    *,
    experiment: str | None = None,
    effects: str | None = None,
    seed: int | None = None,
    realtime_policy: str = "auto",
    spin: bool = True,
    feedback_timeout_periods: int | None = None,
    feedback_budget_s: float | None = None,
    bench_overrides: dict[str, Any] | None = None,
    confirm_real: bool = False,
    plot: bool = True,
    progress: bool = True,
) -> dict[str, Any]:
    """One realtime timing run; returns the summary (``hil jitter --json``'s document).

    ``bench_overrides``: more top-level fields for the run's copy of the bench profile (e.g. a
    study's timing faults). The summary is also stored under ``"jitter"`` in meta.json.
    """
    base = check_bench(str(bench), confirm_real=confirm_real, effects=effects)
    rate = 1.0 / base.period_s if rate_hz is None else float(rate_hz)
    if not 1.0 <= rate <= MAX_RATE_HZ:
        raise UsageError(f"--rate must be within 1..{MAX_RATE_HZ:g} Hz, got {rate:g}")
    try:
        check_duration(float(duration_s), 1.0 / rate)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    overrides: dict[str, Any] = {"period_s": 1.0 / rate}
    if feedback_timeout_periods is not None and feedback_budget_s is not None:
        raise UsageError("--feedback-budget or --feedback-timeout-periods, not both")
    if feedback_timeout_periods is not None:  # the alias, in periods of this rate
        if not 1 <= feedback_timeout_periods <= 100_000:
            raise UsageError(
                "--feedback-timeout-periods must be within 1..100000, got "
                f"{feedback_timeout_periods}"
            )
        feedback_budget_s = feedback_timeout_periods / rate
    if feedback_budget_s is not None:
        if not 1.0 / rate <= feedback_budget_s <= MAX_FEEDBACK_BUDGET_S:
            raise UsageError(
                f"--feedback-budget must be within one period ({1.0 / rate:g} s) and "
                f"{MAX_FEEDBACK_BUDGET_S:g} s, got {feedback_budget_s:g}"
            )
        overrides["feedback_budget_s"] = float(feedback_budget_s)
    elif base.feedback_budget_s < 1.0 / rate:  # a slow rate: at least one period
        overrides["feedback_budget_s"] = 1.0 / rate
    overrides.update(bench_overrides or {})
    run_bench = write_bench_variant(base.source, out / "bench.toml", overrides, by="hil jitter")
    h = run_bench.period_s
    n = max(2, round(duration_s / h))
    torques = None
    if experiment is not None:
        excitation = load_experiment(experiment)
        excitation.check_joints(2, "of the bench (2-DOF)")  # the buses carry two drives today
        torques = excitation.torque_rows(h, n)
    zero = [0.0, 0.0]

    def command(k: int, sample: Sample) -> list[float]:
        return torques[k] if torques is not None else zero

    machine_start = machine_state()

    def meta(channel: dict[str, Any]) -> dict[str, Any]:
        return {
            **bench_meta("hil jitter", run_bench, channel, "realtime"),
            "bench_profile_base": base.source,
            "rate_hz": rate,
            "duration_s": n * h,
            "experiment": experiment,
            "effects": effects,
            "seed": seed,
            "robot": run_bench.robot,
            "machine_at_start": machine_start,
        }

    run = record_over_bench(
        run_bench,
        out,
        command,
        n,
        meta,
        mode="realtime",
        effects=effects,
        seed=seed,
        progress=progress,
        realtime_policy=realtime_policy,
        spin=spin,
    )
    machine_end = machine_state()
    result = run.result
    rec = read_signals(out)
    deadline, release, feedback = (
        rec.columns[c] for c in ("deadline_s", "sync_sent_s", "feedback_s")
    )
    meta_doc = json.loads((out / META).read_text())
    link = meta_doc.get("link", {})
    timing = jitter_summary(h, deadline, release, feedback, lost_feedback=link.get("timeouts", 0))
    # the link's own count of late feedback (later than a period, within the budget) and the
    # longest wait: how close the run came to its feedback budget
    for key in ("late_feedback", "max_feedback_wait_s", "feedback_budget_s"):
        if key in result.timing:
            timing[key] = result.timing[key]
    machine = {
        **{k: v for k, v in machine_start.items() if k != "load_average"},
        "load_average_start": machine_start["load_average"],
        "load_average_end": machine_end["load_average"],
    }
    summary: dict[str, Any] = {
        "status": result.status,
        "reason": run.reason,
        "bench": run_bench.name,
        "bench_profile": run_bench.source,
        "transport": run_bench.transport,
        "protocol": run_bench.protocol,
        "rate_hz": rate,
        "period_s": h,
        "duration_s": n * h,
        "rows": result.rows,
        "out_dir": str(out),
        "signals": str(out / "signals.csv"),
        "timing": timing,
        "scheduler": result.timing.get("scheduler", {}),
        "machine": machine,
        "link": {
            "frames_sent": link.get("frames_sent"),
            "frames_received": link.get("frames_received"),
            "timeouts": link.get("timeouts"),
            "errors": len(link.get("errors", [])),
        },
        "bus": _bus(run_bench, run.traffic_log, h),
        "plots": [],
    }
    if plot and result.rows > 2:
        summary["plots"] = _plots(rec.t, deadline, release, feedback, h, out, summary)
    meta_doc["jitter"] = {k: v for k, v in summary.items() if k not in ("out_dir", "signals")}
    write_json_atomic(out / META, meta_doc)
    return summary


def _bus(bench: Any, traffic_log: str | None, period_s: float) -> dict[str, Any] | None:
    """canbusload's figures for a CAN run, None for a serial one."""
    if bench.protocol != "can":
        return None
    out: dict[str, Any] = {"bitrate": bench.bitrate, "paced": bench.pace_bus}
    if traffic_log is None or not Path(traffic_log).is_file():
        out["note"] = "no bus.log"
        return out
    from hil.timing.bus_load import cyclic_bus_load

    out.update(cyclic_bus_load(traffic_log, bench.bitrate, period_s))
    out["paced"] = bench.pace_bus
    return out


def _plots(
    t: np.ndarray,
    deadline: np.ndarray,
    release: np.ndarray,
    feedback: np.ndarray,
    h: float,
    out: Path,
    summary: dict[str, Any],
) -> list[str]:
    from hil.timing.jitter_plots import plot_histograms, plot_timeline

    sched = summary["scheduler"]
    title = (
        f"hil jitter: {summary['bench']} at {summary['rate_hz']:g} Hz, "
        f"{summary['timing']['cycles']} cycles, {sched.get('policy', '?')}"
        f"{', memory locked' if sched.get('memory_locked') else ''}"
    )
    c = cycle_timing(h, deadline, release, feedback)
    return [
        str(plot_histograms(c, h, out / "jitter-histograms.png", title)),
        str(
            plot_timeline(
                t, release - deadline, feedback - release, h, out / "jitter-timeline.png", title
            )
        ),
    ]


# ---- the table ----------------------------------------------------------------------------------
def format_table(s: dict[str, Any]) -> str:
    """The summary as the text table `hil jitter` prints."""
    t, m, sched = s["timing"], s["machine"], s["scheduler"]
    lines = [
        f"hil jitter: {s['bench']} ({s['transport']}), {s['rate_hz']:g} Hz "
        f"(h = {s['period_s'] * 1e6:.0f} µs), {s['duration_s']:g} s, {t['cycles']} cycles: "
        f"{s['status']}",
        f"machine: {m.get('cpu_count')} CPUs, load average {_load(m['load_average_start'])} at "
        f"start, {_load(m['load_average_end'])} at end; "
        f"{sched.get('policy', '?')}"
        + (f" priority {sched['priority']}" if sched.get("policy") == "SCHED_FIFO" else "")
        + (", memory locked" if sched.get("memory_locked") else ", memory not locked"),
    ]
    refused = [r for r in (sched.get("realtime_refused"), sched.get("memory_lock_refused")) if r]
    if refused:
        lines.append("  refused: " + "; ".join(dict.fromkeys(refused)))
    lines += [
        "",
        f"{'[µs]':<32}{'median':>9}{'p99':>9}{'p99.9':>9}{'max':>9}",
    ]
    for key, label in (
        ("release_error", "release − deadline"),
        ("period_error", "period error |P − h|"),
        ("latency", "command → feedback latency"),
    ):
        p = t[key]
        if not p.get("n"):
            lines.append(f"{label:<32}{'-':>9}")
            continue
        lines.append(
            f"{label:<32}{p['median_us']:9.1f}{p['p99_us']:9.1f}{p['p999_us']:9.1f}"
            f"{p['max_us']:9.1f}"
        )
    lines += [
        "",
        f"deadline misses (feedback after the next deadline): {t['deadline_misses']} "
        f"({_per10k(t['deadline_misses_per_10k'])} per 10,000 cycles)",
        f"overruns (period > {t['overrun_threshold_us']:.0f} µs = 1.5 h): {t['overruns']} "
        f"({_per10k(t['overruns_per_10k'])} per 10,000 cycles)",
        f"late releases (> {t['late_release_threshold_us']:.0f} µs): {t['late_releases']}; "
        f"lost feedback: {t['lost_feedback']}; link errors: {s['link']['errors']}",
    ]
    if "late_feedback" in t:  # how close the run came to its feedback budget
        lines.append(
            f"late feedback (> one period): {t['late_feedback']}; longest wait "
            f"{t['max_feedback_wait_s'] * 1e3:.1f} ms of the {t['feedback_budget_s'] * 1e3:g} ms "
            "feedback budget"
        )
    if sched.get("waits"):
        over = sched.get("sleep_overshoot_us", {})
        spun = (
            f"spun {sched['mean_spin_us']:.0f} µs (margin {sched['spin_margin_us']:.0f} µs)"
            if sched.get("spin_margin_us")
            else "no spin"
        )
        lines.append(
            f"scheduler: per cycle slept {sched['mean_sleep_us']:.0f} µs, {spun}; sleep "
            f"overshoot median {over.get('median', float('nan')):.0f}, p99 "
            f"{over.get('p99', float('nan')):.0f} µs"
        )
    bus = s.get("bus")
    if bus and bus.get("frames"):
        lines.append(
            f"bus: {bus['bitrate'] / 1e6:g} Mbit/s{' (paced)' if bus['paced'] else ''}, "
            f"{bus['frames_per_cycle']:.1f} frames and {bus['bits_per_cycle']:.0f} bits per "
            f"cycle: load {bus['load_pct']:.1f} % (max 1 s interval "
            f"{bus['max_interval_load_pct']:.1f} %; the cycle's frames need "
            f"{bus['cycle_load_pct']:.1f} % of each period)"
        )
    if s["plots"]:
        lines.append("plots: " + ", ".join(s["plots"]))
    lines.append(f'recording: {s["signals"]} (numbers also in meta.json, "jitter")')
    return "\n".join(lines)


def _load(values: list[float]) -> str:
    return " ".join(f"{v:.2f}" for v in values)


def _per10k(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f}"
