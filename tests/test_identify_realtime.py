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

from drivers.realtime_times import (
    ROBOT_EVENTS,
    HostStampRows,
    host_stamp_trace,
    on_real_times,
)
from drivers.recording import Recording, read_signals
from hil.bench.run import run_experiment
from hil.cli import main as hil_main
from hil.cli_options import read_recording
from hil.identify.online import OnlineIdentifier
from hil.identify.schemes import identify, validate
from hil.model.openloop import simulate_open_loop, simulate_open_loop_chunks
from hil.model.params import robot_params
from profiles.experiment import load_experiment
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
    # the online RLS took each row on the host's stamps as they came, not the deadline grid
    assert "host's stamps" in a["online"]["sample_times"]
    assert a["online"]["batch_sample_times"] == f"the robot's clock ({ROBOT_EVENTS})"
    assert a["online"]["segments"] >= 1
    assert all(np.all(np.isfinite(v)) for v in a["online"]["theta"].values())


# --- online RLS and the paper discretization on real sample times (issue 12 item 1) -----------

THETA = robot_params("cicese").theta


def _on_irregular_times(n: int, stalls: tuple[tuple[float, float], ...]):
    """The host's own model (θ of the cicese profile, exactly) driven by eqs. (31)-(32) on the
    sample times of a realtime run with host stalls: the truth is THETA."""
    trace = realtime_like_trace(n, seed=4, stalls=stalls)
    t = trace.sample_s - trace.sample_s[0]
    tau = np.asarray(load_experiment("reyes-kelly").torque_rows(H, n), dtype=float)
    q = simulate_open_loop(THETA, tau, H, intervals_s=np.diff(t)).q
    return t, q, tau


def _worst_error(theta: np.ndarray) -> float:
    """Largest relative error of θ1..θ5 (the inertial and gravity parameters)."""
    return float(np.max(np.abs(theta[:5] - THETA[:5]) / THETA[:5]))


@pytest.mark.parametrize("discretization", ["exact", "paper"])
def test_online_rls_on_real_times_is_the_batch_fit_and_unbiased(discretization: str) -> None:
    """Pushed with each sample's real time, the online RLS is the batch fit on real times (the
    same rows, a gap splitting them alike) and near the truth; pushed on the deadline grid, as
    before, it is biased. ``paper``: its filters written over each interval give the paper's own
    accuracy; the grid ones are several times worse. Before: push() took no time, and
    identify() ran the paper's rows on k·h whatever the stamps."""
    # exact: a 50 ms stall (a gap: two segments) and a 15 ms one; paper: short stalls only
    # (its rows assume a segment starts at rest, which one after a gap does not)
    stalls = ((1.5, 0.015), (2.5, 0.05)) if discretization == "exact" else ((1.5, 0.015),)
    n = 1400
    t, q, tau = _on_irregular_times(n, stalls)
    gaps = np.flatnonzero(np.diff(t) > 10 * H) + 1
    segments = [slice(a, b) for a, b in zip([0, *gaps], [*gaps, n], strict=True)]
    assert len(segments) == (2 if discretization == "exact" else 1)
    real = OnlineIdentifier(H, schemes=("filtered_dynamic",), discretization=discretization)
    grid = OnlineIdentifier(H, schemes=("filtered_dynamic",), discretization=discretization)
    for k in range(n):
        real.push(q[k], tau[k], t[k])
        grid.push(q[k], tau[k])
    assert real.segments == len(segments)
    batch = identify(
        q, tau, H, schemes=("filtered_dynamic",), discretization=discretization, t=t,
        segments=segments,
    )["filtered_dynamic"]  # fmt: skip
    online = real.theta["filtered_dynamic"]
    assert real.streams["filtered_dynamic"].rows == batch.rows
    assert np.allclose(online, batch.theta_rls, rtol=1e-7, atol=1e-9)
    on_grid = _worst_error(grid.theta["filtered_dynamic"])
    if discretization == "exact":
        assert _worst_error(online) < 0.01 and on_grid > 0.05, (online, on_grid)
    else:  # the paper's own bias, as on equal intervals, and no more
        uniform = identify(
            simulate_open_loop(THETA, tau, H).q, tau, H, schemes=("filtered_dynamic",),
            discretization="paper",
        )["filtered_dynamic"]  # fmt: skip
        assert _worst_error(online) < 2 * _worst_error(uniform.theta_rls) < on_grid


def test_online_rows_on_uncertain_stamps_are_left_out() -> None:
    """A robot that woke late to some SYNCs sampled after the host's stamp (the SYNC sent) says:
    taken as they are, the few rows around those samples pull θ̂ far off; left out by their
    SYNC→feedback round trip (the bracket of the robot's sample time), the rest give θ as with
    exact stamps."""
    n = 1400
    t, q, tau = _on_irregular_times(n, ((1.5, 0.015),))
    rng = np.random.default_rng(7)
    late = rng.random(n) < 0.05
    late[:5] = False
    late_by = np.where(late, rng.uniform(0.5e-3, 1.5e-3, n), 0.0)
    stamps = t - late_by  # the host sent the SYNC then; the robot sampled at t
    waited = late_by  # the SYNC→feedback round trip beyond its shortest (StampedRow)
    assert np.all(np.diff(stamps) > 0)
    checked = OnlineIdentifier(H, schemes=("filtered_dynamic",))
    trusting = OnlineIdentifier(H, schemes=("filtered_dynamic",))
    for k in range(n):
        checked.push(q[k], tau[k], stamps[k], uncertainty_s=waited[k])
        trusting.push(q[k], tau[k], stamps[k])
    assert 0 < checked.rows_uncertain < n / 3 and trusting.rows_uncertain == 0
    assert _worst_error(checked.theta["filtered_dynamic"]) < 0.01
    assert _worst_error(trusting.theta["filtered_dynamic"]) > 0.05


def test_paper_rows_on_equal_stamps_are_the_lti_ones() -> None:
    """The paper's filters written over each interval are its LTI filters when every interval
    is h (the per-interval form is the same recursion), so given the stamps k·h the estimate
    is today's to rounding; without stamps it is today's bit for bit (the LTI path)."""
    n = 800
    tau = np.asarray(load_experiment("reyes-kelly").torque_rows(H, n), dtype=float)
    q = simulate_open_loop(THETA, tau, H).q
    plain = identify(q, tau, H, discretization="paper")
    stamped = identify(q, tau, H, discretization="paper", t=np.arange(n) * H)
    for scheme, res in plain.items():
        assert np.allclose(stamped[scheme].theta_ls, res.theta_ls, rtol=1e-9), scheme


def test_host_stamp_rows_online_are_the_batch_reading() -> None:
    """Row by row as the run goes, the host's stamps give each row the time and interval torque
    that host_stamp_trace + on_real_times give the whole run after it (a stall and its catch-up
    burst included), one row behind the feedback."""
    n = 1500
    trace = realtime_like_trace(n, seed=2, stalls=((1.0, 0.05),))
    rng = np.random.default_rng(1)
    sent = trace.sample_s + 100.0
    received = sent + rng.uniform(1e-4, 6e-4, n)
    tau = rng.normal(0.0, 3.0, (n, 2))
    compute = 2.1e-4
    columns = {"t": np.arange(n) * H, "q1": np.zeros(n), "q2": np.zeros(n), "tau1": tau[:, 0],
               "tau2": tau[:, 1], "sync_sent_s": sent, "feedback_s": received}  # fmt: skip
    rec = Recording(Path("run"), columns, {"period_s": H})
    batch = on_real_times(rec, host_stamp_trace(rec, compute, bounded=False), "host")
    s, whole = batch.t, batch.tau
    stamps = HostStampRows(compute)
    rows = [stamps.push(sent[0], received[0], ())]
    rows += [stamps.push(sent[k], received[k], tau[k - 1]) for k in range(1, n)]
    assert rows[0] is None
    assert np.array_equal([r.t for r in rows[1:]], s[:-1])
    assert np.allclose([r.tau for r in rows[1:]], whole[:-1], rtol=0, atol=1e-9)
    round_trip = received - sent
    beyond = round_trip - np.minimum.accumulate(round_trip)
    assert np.allclose([r.uncertainty_s for r in rows[1:]], beyond[:-1], rtol=0, atol=1e-9)
    assert stamps.newest_s == s[-1]
    assert len(stamps.sample) <= 3  # only the rows still acting are kept
    with pytest.raises(ValueError, match="host stamps"):
        stamps.push(float("nan"), 1.0, tau[0])
