"""Replay of a timing trace (issue 6, part B): a realtime run, re-run in lockstep with its timing
imposed, reproduces its q."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from drivers.recording import read_signals
from hil.bench.run import UsageError, run_experiment
from hil.control.tracking import run_control
from hil.timing.replay import replay_run, trace_from_run
from profiles.effects import load_effects
from profiles.experiment import load_experiment
from profiles.robot import load_robot
from profiles.timing_faults import TimingTrace, read_trace, write_trace
from virtual_robot.simulate import simulate

# one worker runs the whole module under `pytest -n` (`--dist loadgroup`): its module
# fixtures are built once, not once per worker
pytestmark = pytest.mark.xdist_group("replay")

H = 0.0025
SLCAN = Path(__file__).resolve().parents[1] / "profiles" / "benches" / "virtual-slcan.toml"


def realtime_bench(tmp_path: Path) -> Path:
    """virtual-slcan under another name (its 0.1 s feedback budget outlasts VM stalls)."""
    text = SLCAN.read_text().replace('name = "virtual-slcan"', 'name = "slcan-rt"')
    path = tmp_path / "slcan-rt.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def realtime_ct(tmp_path_factory) -> Path:
    """1.5 s of computed-torque tracking over virtual-slcan in realtime."""
    tmp = tmp_path_factory.mktemp("rt")
    out = tmp / "ct"
    doc = run_control(
        str(realtime_bench(tmp)), "ct", out, duration_s=1.5, mode="realtime", plot=False,
        progress=False,
    )  # fmt: skip
    assert doc["run"]["status"] == "complete", doc["run"]["reason"]
    return out


def test_replay_reproduces_the_realtime_run(realtime_ct: Path, tmp_path: Path) -> None:
    """The robot's own times imposed in lockstep: the replay's q equals the recorded q (to the
    encoder count; in fact bit for bit), though the run's timing was anything but regular."""
    doc = replay_run(realtime_ct, tmp_path / "replay", plot=False)
    assert doc["trace_source"] == "robot events"
    rec, rep = read_signals(realtime_ct), read_signals(tmp_path / "replay" / "run")
    assert len(rep) == len(rec) == 600
    assert doc["comparison"]["max_abs_q_difference_counts"] == [0, 0]
    assert np.array_equal(rep.q, rec.q) and np.array_equal(rep.tau, rec.tau)
    # the recorded timing was not the lockstep grid: sample periods and delays vary
    trace = read_trace(tmp_path / "replay" / "timing-trace.csv")
    periods = np.diff(trace.sample_s)
    assert periods.max() - periods.min() > 2e-5
    assert np.all(trace.command_s > trace.sample_s)
    # and it matters: a plain lockstep run of the same experiment is not the recorded one
    plain = run_control(
        "virtual-inprocess", "ct", tmp_path / "plain", duration_s=1.5, plot=False,
        progress=False,
    )  # fmt: skip
    assert plain["run"]["status"] == "complete"
    assert np.max(np.abs(read_signals(tmp_path / "plain").q - rec.q)) > 1e-5


def test_replay_from_host_stamps_runs_and_says_so(realtime_ct: Path, tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "hil.cli", "replay", str(realtime_ct), "--trace-source", "host",
         "--bench", "virtual-inprocess", "--out", str(tmp_path / "h"), "--no-plot", "--json"],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    assert doc["trace_source"] == "host timestamps"
    assert "440 µs" in doc["notes"][0]  # the compute offset of a control run, stated
    c = doc["comparison"]
    assert c["rows_compared"] == 600
    assert all(np.isfinite(c["max_abs_q_difference_rad"]))


def test_trace_equal_to_a_latency_is_a_transport_delay(tmp_path: Path) -> None:
    """A trace with sample k at k·h and its command at k·h + 1 ms is the 1 ms delay effect."""
    n = 200
    sample = np.arange(n) * H
    write_trace(tmp_path / "trace.csv", TimingTrace(sample, sample + 0.001))
    (tmp_path / "fx.toml").write_text('name = "trace"\n[timing_faults.trace]\nfile = "trace.csv"\n')
    (tmp_path / "delay.toml").write_text('name = "d"\n[transport_delay]\ndelay_s = 0.001\n')
    run = run_experiment(
        "virtual-inprocess", "reyes-kelly", tmp_path / "run", duration_s=n * H,
        effects=str(tmp_path / "fx.toml"), plot=False, progress=False,
    )  # fmt: skip
    assert run["status"] == "complete"
    delay = load_effects(tmp_path / "delay.toml")
    simulate(load_robot("cicese"), load_experiment("reyes-kelly"), tmp_path / "sim",
             effects=delay, duration_s=n * H, plot=False)  # fmt: skip
    a, b = read_signals(tmp_path / "run"), read_signals(tmp_path / "sim")
    assert np.array_equal(a.q, b.q) and np.array_equal(a.tau, b.tau)


@pytest.mark.parametrize(
    ("rows", "message"),
    [
        ("k,sample,command\n0,0,0\n", "header"),
        ("k,sample_s,first_command_s,command_s\n0,0,0,0\n1,0,0,0\n", "must increase"),
        ("k,sample_s,first_command_s,command_s\n0,0.1,0.05,0.2\n", "row 0"),
        ("k,sample_s,first_command_s,command_s\n0,0,x,0\n", "non-numeric"),
        ("k,sample_s,first_command_s,command_s\n", "no rows"),
    ],
)
def test_bad_traces_are_one_line_errors(tmp_path: Path, rows: str, message: str) -> None:
    path = tmp_path / "t.csv"
    path.write_text(rows)
    with pytest.raises(ValueError, match=message) as err:
        read_trace(path)
    assert "\n" not in str(err.value)


def test_a_lockstep_run_is_not_replayable(tmp_path: Path) -> None:
    run_experiment("virtual-inprocess", "reyes-kelly", tmp_path / "lock", duration_s=0.05,
                   plot=False, progress=False)  # fmt: skip
    with pytest.raises(UsageError, match="not a realtime run"):
        trace_from_run(tmp_path / "lock")
