"""A realtime-like run made deterministically (issue 12): the virtual robot in lockstep with a
timing trace imposed (``[timing_faults.trace]``, the mechanism of `hil replay`), the trace being
what a realtime run with host stalls produces; the run directory then holds the robot's event
log of those times, as a realtime run's does. Used by tests/test_diagnose_realtime.py (2 joints)
and tests/test_diagnose_urdf.py (n joints)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from drivers.realtime_times import ROBOT_EVENTS
from profiles.timing_faults import TimingTrace, write_trace

H = 0.0025


def realtime_like_trace(
    n: int, seed: int, stalls: tuple[tuple[float, float], ...] = ((6.0, 0.06), (13.0, 0.03))
) -> TimingTrace:
    """Sample and command times of a realtime run at 400 Hz: releases on the deadline grid, late
    by the host's wake-up; a stall holds the releases back, then they come 0.4 ms apart until
    caught up; the robot samples on arrival and each drive's command acts ~0.3 ms later."""
    rng = np.random.default_rng(seed)
    release = np.empty(n)
    free = 0.0
    for k in range(n):
        t = k * H
        for at, length in stalls:
            if at <= t < at + length:
                t = at + length
        release[k] = max(t, free) + rng.exponential(2e-5)
        free = release[k] + 4e-4
    sample = release + 1e-4 + rng.exponential(3e-5, n)
    first = sample + 2.5e-4 + rng.exponential(5e-5, n)
    last = first + 2e-5 + rng.exponential(1e-5, n)
    return TimingTrace(sample, np.maximum.accumulate(last), first)


def write_events(path: Path, trace: TimingTrace) -> None:
    """The robot's event log of ``trace`` (virtual_robot EventLog): sample k, then the commands
    of cycle k (n = k + 1 SYNCs so far), joint 1's first."""
    assert trace.first_command_s is not None
    with open(path, "w") as f:
        f.write("event,n,t\n")
        for k in range(len(trace)):
            f.write(f"sample,{k},{float(trace.sample_s[k])!r}\n")
            f.write(f"command,{k + 1},{float(trace.first_command_s[k])!r}\n")
            f.write(f"command,{k + 1},{float(trace.command_s[k])!r}\n")


def lockstep_twin(root: Path, trace: TimingTrace, *run_options: str) -> Path:
    """``hil run --bench virtual-inprocess --mode lockstep RUN_OPTIONS`` with ``trace`` imposed,
    into ``root/run``, made to look like the realtime run the trace is of (its event log, mode
    realtime in meta.json). Returns the run directory."""
    write_trace(root / "trace.csv", trace)
    effects = root / "effects.toml"
    effects.write_text(f'name = "twin"\n[timing_faults.trace]\nfile = "{root / "trace.csv"}"\n')
    run = root / "run"
    subprocess.run(
        [sys.executable, "-m", "hil.cli", "run", "--bench", "virtual-inprocess", "--mode",
         "lockstep", *run_options, "--effects", str(effects), "--out", str(run), "--no-plot",
         "-q"],
        check=True, timeout=900,
    )  # fmt: skip
    write_events(run / ROBOT_EVENTS, trace)
    meta = json.loads((run / "meta.json").read_text())
    (run / "meta.json").write_text(json.dumps({**meta, "mode": "realtime"}))
    return run
