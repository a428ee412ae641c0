"""`hil run`: record one experiment over a bench (virtual or real), as the recording format says."""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path
from typing import Any

import numpy as np

from drivers.links import open_arm
from drivers.recording import RecordingWriter, plot_positions, read_signals
from hil import __version__
from hil.launch import VirtualRobotProcess
from hil.loop import extra_columns, run_loop
from profiles.bench import BenchProfile, load_bench
from profiles.experiment import load_experiment


class UsageError(ValueError):
    """A request the bench refuses (e.g. a real bench without --confirm-real)."""


def _progress(done: int, total: int) -> None:
    print(f"hil: {done}/{total} periods ({100 * done / total:.0f} %)", file=sys.stderr)


def run_experiment(
    bench_name: str,
    experiment_name: str,
    out_dir: str | Path,
    *,
    duration_s: float | None = None,
    mode: str | None = None,
    effects: str | None = None,
    seed: int | None = None,
    confirm_real: bool = False,
    plot: bool = True,
    progress: bool = True,
) -> dict[str, Any]:
    """Run an open-loop experiment over a bench; returns the summary that `--json` prints."""
    bench: BenchProfile = load_bench(bench_name)
    if not bench.virtual and not confirm_real:
        raise UsageError(
            f"bench {bench.name} drives a real arm on {bench.channel}: pass "
            "--confirm-real once you have checked the limits in " + bench.source
        )
    if effects is not None and not bench.virtual:
        raise UsageError("--effects only applies to a virtual bench")
    experiment = load_experiment(experiment_name)
    mode = mode or bench.mode
    realtime = mode == "realtime"
    h = bench.period_s
    duration = experiment.duration_s if duration_s is None else duration_s
    if not duration > 0:
        raise UsageError(f"--duration must be > 0, got {duration}")
    n = max(1, round(duration / h))
    torques = experiment.torque_table(np.arange(n) * h).tolist()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)

    launcher = (
        VirtualRobotProcess(
            bench, mode=mode, effects=effects, seed=seed, log_path=out / "virtual-robot.log"
        )
        if bench.virtual
        else contextlib.nullcontext()
    )
    with launcher as robot:
        channel = robot.channel if bench.virtual else {}
        arm = open_arm(bench, channel, mode=mode, log_dir=out)
        meta = {
            "kind": "hil run",
            "version": __version__,
            "bench": bench.name,
            "bench_profile": bench.source,
            "protocol": bench.protocol,
            "transport": bench.transport,
            "channel": channel or bench.channel,
            "virtual": bench.virtual,
            "mode": mode,
            "period_s": h,
            "duration_s": n * h,
            "experiment": experiment.name,
            "experiment_profile": experiment.source,
            "effects": effects,
            "seed": seed,
            "robot": bench.robot,
        }
        if abs(experiment.period_s - h) > 1e-12:
            meta["note"] = f"experiment period {experiment.period_s} s; the bench's {h} s is used"
        with RecordingWriter(
            out, meta, extra_columns=extra_columns(2, realtime), flush_every=1 if realtime else 50
        ) as writer:
            with arm:
                arm.enable()
                result = run_loop(
                    arm,
                    lambda k, _s: torques[k],
                    n,
                    writer,
                    realtime=realtime,
                    progress=_progress if progress else None,
                )
            reason = result.reason
            factor = n * h / result.wall_time_s if result.wall_time_s else None
            if bench.virtual and result.status == "failed" and not robot.alive():
                reason = f"virtual robot (pid {robot.pid}) is gone; {reason}"
            writer.close(
                result.status,
                reason=reason,
                timing=result.timing,
                wall_time_s=result.wall_time_s,
                realtime_factor=factor,
                link=vars(arm.stats),
                traffic_log=arm.traffic_log(),
            )
    summary = {
        "out_dir": str(out),
        "signals": str(out / "signals.csv"),
        "rows": result.rows,
        "status": result.status,
        "reason": reason,
        "bench": bench.name,
        "mode": mode,
        "wall_time_s": round(result.wall_time_s, 4),
        "realtime_factor": round(factor, 2) if factor else None,
        "timing": result.timing,
        "traffic_log": arm.traffic_log(),
        "plot": None,
    }
    if plot and result.rows > 1:
        summary["plot"] = str(
            plot_positions(
                read_signals(out),
                out / "positions.png",
                title=f"hil run: {bench.name} ({mode}), {experiment.name}",
            )
        )
    return summary
