"""`hil identify` of a realtime run (issue 13): read on its real times whether it ran the run
(`--bench … --mode realtime`) or was given it (`--from`), and validated on those times.

A realtime run's ``t`` is the deadline grid k·h; its samples were taken and its commands took
effect at other times (drivers/realtime_times.py). The fit's rows use the real intervals; the
validation's open-loop simulation must too, or a stall and the catch-up burst after it
(0.3 ms intervals) are integrated as 2.5 ms each and the model looks wrong when it is not.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest
from test_diagnose_realtime import realtime_like_trace, write_events

from drivers.realtime_times import ROBOT_EVENTS
from drivers.recording import read_signals
from hil.bench.run import run_experiment
from hil.cli import main as hil_main
from hil.cli_options import read_recording
from hil.identify.schemes import validate
from hil.model.openloop import simulate_open_loop, simulate_open_loop_chunks
from hil.model.params import robot_params
from profiles.timing_faults import write_trace

H = 0.0025
READER = argparse.Namespace(columns=None, loop_delay=None, torque=None, recording_format=None)


def test_chunked_simulation_on_real_intervals_is_the_whole_one() -> None:
    """The validation's chunked simulation takes the intervals the diagnosis's whole one does:
    the same rows, bit for bit, whatever the chunk; bad intervals refused before any chunk."""
    theta = robot_params("cicese").theta
    rng = np.random.default_rng(3)
    tau = rng.normal(0.0, 5.0, (500, 2))
    intervals = rng.choice([0.0004, H, 0.004, 0.03], 499, p=[0.2, 0.7, 0.08, 0.02])
    whole = simulate_open_loop(theta, tau, H, q0=(0.1, -0.2), intervals_s=intervals)
    pieces = list(
        simulate_open_loop_chunks(theta, tau, H, q0=(0.1, -0.2), intervals_s=intervals, chunk=97)
    )
    assert np.array_equal(np.concatenate([c.q for c in pieces]), whole.q)
    assert np.array_equal(np.concatenate([c.t for c in pieces]), whole.t)
    for bad in (np.full(10, H), np.r_[intervals[:-1], -H]):
        with pytest.raises(ValueError, match="intervals_s"):
            simulate_open_loop_chunks(theta, tau, H, intervals_s=bad)


def test_realtime_run_validates_like_its_lockstep_twin_with_the_true_theta(tmp_path: Path) -> None:
    """The cicese arm under a realtime timing with two host stalls (the virtual robot in
    lockstep with the trace imposed, the mechanism of `hil replay`, so deterministic), read on
    the robot's clock: the profile's own θ validates as on the same run in plain lockstep.
    Simulated on the nominal period instead it gave 53 % / 28 % position NRMSE here."""
    n = 1600  # 4 s of the Reyes & Kelly excitation at 400 Hz
    trace = realtime_like_trace(n + 1, seed=5, stalls=((1.5, 0.06), (2.7, 0.03)))
    write_trace(tmp_path / "trace.csv", trace)
    effects = tmp_path / "effects.toml"
    effects.write_text(f'name = "twin"\n[timing_faults.trace]\nfile = "{tmp_path / "trace.csv"}"\n')
    for name, fx in (("rt", str(effects)), ("lockstep", None)):
        run = run_experiment("virtual-inprocess", "reyes-kelly", tmp_path / name,
                             duration_s=n * H, effects=fx, plot=False, progress=False)  # fmt: skip
        assert run["status"] == "complete", run["reason"]
    rt = tmp_path / "rt"
    write_events(rt / ROBOT_EVENTS, trace)
    meta = json.loads((rt / "meta.json").read_text())
    (rt / "meta.json").write_text(json.dumps({**meta, "mode": "realtime"}))

    rec = read_recording(READER, rt, command="identify", allow_gaps=True)
    assert len(rec.segments()) == 3  # the two stalls are gaps
    intervals = np.diff(rec.t)
    assert intervals.min() < 0.5e-3 < H < 0.02 < intervals.max()  # catch-up bursts and stalls
    theta = robot_params("cicese").theta
    realtime = validate(theta, rec)
    lockstep = validate(theta, read_signals(tmp_path / "lockstep"))
    # the same model error as in lockstep (the world's plant is not the host's model), no more
    worst = max(lockstep["position_nrmse"])
    assert max(realtime["position_nrmse"]) < 1.5 * worst, (realtime, lockstep)
    assert max(realtime["torque_nrmse"]) < 2 * max(lockstep["torque_nrmse"]) + 0.01
    assert len(realtime["simulated_q"]) == len(rec)


def test_identify_over_a_realtime_bench_reads_its_run_as_from_does(tmp_path: Path, capsys) -> None:
    """`hil identify --bench virtual-slcan --mode realtime` and `hil identify --from` its fit
    run: one reader (real times), the same θ and validation to the last bit."""
    common = ["--schemes", "filtered_dynamic", "--no-plot", "--json"]
    ran = tmp_path / "ran"
    code = hil_main(
        ["identify", "--bench", "virtual-slcan", "--mode", "realtime", "--duration", "2",
         "--validation-experiment", "none", "--out", str(ran), *common]
    )  # fmt: skip
    first = capsys.readouterr()
    assert code == 0, first.err
    assert "realtime run read on the robot's clock" in first.err
    given = tmp_path / "given"
    code = hil_main(["identify", "--from", str(ran / "fit"), "--out", str(given), *common])
    second = capsys.readouterr()
    assert code == 0, second.err
    a, b = json.loads(first.out), json.loads(second.out)
    fd_a = a["discretizations"]["exact"]["schemes"]["filtered_dynamic"]
    fd_b = b["discretizations"]["exact"]["schemes"]["filtered_dynamic"]
    assert fd_a["theta"] == fd_b["theta"] and fd_a["rows"] == fd_b["rows"]
    assert fd_a["validation"] == fd_b["validation"]
    assert a["profile_validation"] == b["profile_validation"]
    assert "deadline grid" in a["online"]["sample_times"]  # the online RLS saw only k·h
