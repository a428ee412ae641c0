"""Realtime recordings diagnose like their lockstep twins (issue 12).

A realtime run's ``t`` is the deadline grid k·h; its samples were taken, and its commands took
effect, at other times (jitter, stalls, the catch-up burst after one). The analysis commands read
such a run on the real times (drivers/realtime_times.py) and the diagnosis integrates over them
(docs/diagnosis.md, "Realtime runs").

The slow test makes a realtime-like run deterministically: the virtual robot in lockstep with a
timing trace imposed (``[timing_faults.trace]``, the mechanism of `hil replay`), the trace being
what a realtime run with two host stalls produces; the run directory then holds the robot's
event log of those times, as a realtime run's does (tests/realtime_twin.py).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from realtime_twin import H, lockstep_twin, realtime_like_trace, write_events

from drivers.realtime_times import ROBOT_EVENTS, interval_torque, on_real_times, run_trace
from drivers.recording import RecordingWriter, read_signals
from hil.cli_options import read_recording
from hil.diagnose.columns import noise_model
from hil.model.openloop import simulate_open_loop
from hil.model.params import robot_params


def test_interval_torque_is_the_mean_of_what_acted() -> None:
    """τ̄_k over [s_k, s_{k+1}) against a brute-force integral of the switched torque."""
    rng = np.random.default_rng(1)
    s = np.cumsum(rng.uniform(0.3e-3, 5e-3, 60))
    a = s + rng.uniform(0.0, 4e-3, 60)  # some commands land after the next sample
    tau = rng.normal(0.0, 3.0, 60)
    got = interval_torque(tau, s, a)
    fine = np.linspace(s[0], s[-1], 400_001)
    a_sorted = np.maximum.accumulate(a)
    index = np.searchsorted(a_sorted, fine, side="right") - 1
    applied = np.where(index < 0, tau[0], tau[np.clip(index, 0, None)])
    for k in range(0, 59, 7):
        inside = (fine >= s[k]) & (fine < s[k + 1])
        assert got[k] == pytest.approx(applied[inside].mean(), abs=0.02)
    assert got[-1] == tau[-1]
    # commands on the samples themselves: the torque of the row, unchanged
    assert np.allclose(interval_torque(tau, s, s)[:-1], tau[:-1])


def test_realtime_run_is_read_on_the_robots_times(tmp_path: Path) -> None:
    trace = realtime_like_trace(2000, seed=2, stalls=((1.0, 0.05),))
    run = tmp_path / "rt"
    with RecordingWriter(run, {"period_s": H, "mode": "realtime", "kind": "hil run"}) as w:
        for k in range(2000):
            w.write([k * H, 0.01 * np.sin(k * H), 0.0, float(k % 7), 0.0])
    write_events(run / ROBOT_EVENTS, trace)
    rec = read_signals(run)
    found = run_trace(rec)
    assert found is not None and ROBOT_EVENTS in found[1]
    moved = on_real_times(rec, *found)
    assert np.array_equal(moved.t, trace.sample_s - trace.sample_s[0])
    assert np.array_equal(moved.q, rec.q)
    assert np.allclose(
        moved.tau[:-1, 0],
        interval_torque(rec.tau[:, 0], trace.sample_s, trace.first_command_s)[:-1],
    )
    assert moved.findings_on_read[0].startswith("realtime run read on the robot's clock")
    assert any("gap(s) in t" in f for f in moved.findings_on_read)  # the 50 ms stall
    # the analysis commands' reader does it by default, and not when told where t is
    args = argparse.Namespace(columns=None, loop_delay=None, torque=None, recording_format=None)
    assert np.array_equal(read_recording(args, run, command="x", allow_gaps=True).t, moved.t)
    args.columns = "t=t"
    assert np.array_equal(read_recording(args, run, command="x").t, np.arange(2000) * H)


def test_noise_on_irregular_stamps_is_the_encoders_not_the_jitter() -> None:
    """Third differences on jittered stamps as if regular count the motion as noise; the
    divided differences do not."""
    rng = np.random.default_rng(4)
    t = np.cumsum(rng.uniform(0.3e-3, 4.7e-3, 8000))
    q = np.c_[np.sin(2.0 * t), 0.5 * np.cos(3.0 * t)] + rng.normal(0.0, 1e-5, (8000, 2))
    noise = noise_model(q, t)
    sigma_v = np.asarray(noise.velocity_noise_rad_s)
    regular = noise_model(q, np.arange(8000) * np.median(np.diff(t)))
    assert np.all(sigma_v < 0.2 * np.asarray(regular.velocity_noise_rad_s))
    m, h = noise.half_window, np.median(np.diff(t))
    sigma_q = sigma_v * h / np.sqrt(3.0 / (m * (m + 1) * (2 * m + 1)))  # back from σ_v(m)
    assert sigma_q == pytest.approx([1e-5, 1e-5], rel=0.3)


def test_open_loop_simulation_on_real_intervals_is_exact() -> None:
    """Periods of their own length: the same as a fine regular grid holding the same torques."""
    theta = robot_params("cicese").theta
    rng = np.random.default_rng(0)
    tau = rng.normal(0.0, 5.0, (300, 2))
    regular = simulate_open_loop(theta, tau, H).q
    same = simulate_open_loop(theta, tau, H, intervals_s=np.full(299, H)).q
    assert np.array_equal(regular, same)
    intervals = rng.choice([0.0015, 0.0035], 299)
    got = simulate_open_loop(theta, tau, H, intervals_s=intervals)
    n = np.rint(intervals / 5e-4).astype(int)
    fine = simulate_open_loop(
        theta, np.vstack([np.repeat(tau[:-1], n, axis=0), tau[-1:]]), 5e-4, steps_per_period=1
    )
    at = np.concatenate([[0], np.cumsum(n)])
    assert np.abs(got.q - fine.q[at]).max() < 1e-10
    assert np.allclose(got.t, fine.t[at])
    with pytest.raises(ValueError, match="intervals_s"):
        simulate_open_loop(theta, tau, H, intervals_s=np.full(10, H))


def _diagnose(run: Path, *extra: str) -> dict:
    out = subprocess.run(
        [sys.executable, "-m", "hil.cli", "diagnose", str(run), "--json", "--no-plots", *extra],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


@pytest.mark.slow
def test_realtime_run_with_stalls_diagnoses_like_its_lockstep_twin(tmp_path: Path) -> None:
    """The default robot under a realtime timing with two host stalls: joint 1's Coulomb
    asymmetry found (7.17 / 8.049 Nm), no gain, no lag or delay, no cogging, nothing else."""
    n = 8000  # the `diagnosis` experiment, 20 s at 400 Hz
    run = lockstep_twin(tmp_path, realtime_like_trace(n + 1, seed=5), "--experiment", "diagnosis")
    doc = _diagnose(run)
    effects_found = {(f["effect"], f["joint"]) for f in doc["findings"]}
    assert effects_found == {("coulomb_asymmetry", 1), ("torque_offset", 1)}, doc["summary"]
    asym = next(f for f in doc["findings"] if f["effect"] == "coulomb_asymmetry")["estimate"]
    assert asym["positive_Nm"] == pytest.approx(7.17, rel=0.03)
    assert asym["negative_Nm"] == pytest.approx(8.049, rel=0.03)
    assert {t["kind"] for t in doc["timing"]} >= {"gaps", "irregular_sampling"}


def test_a_confounded_group_always_says_what_would_separate_it() -> None:
    """A realtime run with stalls reported joint 1's asymmetry confounded with an encoder offset;
    the summary said "The data cannot tell these apart: ." with nothing after the colon."""
    from hil.diagnose.report import SEPARATE, _separate

    group = frozenset({"angle_offset", "coulomb_asymmetry", "torque_offset"})
    why = _separate(group)
    assert "sweep of the joint's angle" in why and "torque sensor" in why
    pair = frozenset({"actuator_lag", "transport_delay"})
    assert _separate(pair) == SEPARATE[pair]
    assert _separate(frozenset({"cogging", "stribeck"}))
