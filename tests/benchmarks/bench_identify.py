"""Benchmark: identification of 10 s at 400 Hz with all three schemes (`make bench`).

Targets (issue 4): batch least squares, all three schemes (regressions included), under 0.1 s;
recursive least squares over the same data, all three schemes, under 1 s; one online RLS update
well inside a 2.5 ms period. Also reports the whole online step (building the three regressor
rows from the newest sample, filters, three RLS updates), which is what a control cycle pays.
Medians of several repeats; ``--json`` prints one JSON document; exit 1 if a target is missed.

``--long MINUTES`` (issue 12/13, bounded memory): instead, write a MINUTES-long 1 kHz recording
(``t,q1,q2,tau1,tau2``: a multisine motion of the dfki-a0 arm with its rotor inertia, torques by
its inverse dynamics, 20 % timing jitter, a 1.9e-4 rad encoder quantum) and run
``hil identify --from it --robot dfki-a0`` under ``/usr/bin/time -v``; report its peak RSS and
wall time against the target (< 4 GB; the identification builds its rows in chunks into
per-block normal equations, so memory is O(N) for the recording's arrays and O(chunk · p) for
the regression, not O(N · p²)). The 10-minute run takes a few minutes on the dev VM.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time

import numpy as np

from drivers.recording import read_signals
from hil.identify.online import OnlineIdentifier
from hil.model.estimators import RecursiveLeastSquares, least_squares, recursive_least_squares
from hil.model.regressors import SCHEMES, build_regression
from profiles.experiment import load_experiment
from profiles.robot import load_robot
from virtual_robot.simulate import simulate

TARGET_BATCH_S = 0.1
TARGET_RLS_S = 1.0
PERIOD_S = 0.0025


def timed(fn, repeats: int) -> float:
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        runs.append(time.perf_counter() - start)
    return statistics.median(runs)


TARGET_LONG_RSS_BYTES = 4 * 1024**3


def write_long_recording(path: str, minutes: float, seed: int = 0) -> int:
    """A ``minutes``-long 1 kHz recording of the dfki-a0 arm (see the module doc); rows."""
    from hil.model.closed_form import ArmModel

    profile = load_robot("dfki-a0")
    model, theta = ArmModel(profile.terms), profile.theta()
    rng = np.random.default_rng(seed)
    n = int(minutes * 60 * 1000)
    t = np.r_[0.0, np.cumsum(0.001 * (1 + 0.2 * rng.uniform(-1, 1, n - 1)))]
    w = 2 * np.pi * np.array([0.3, 0.7, 1.3, 2.1])
    amp = np.array([[0.5, 0.3, 0.2, 0.1], [0.9, 0.5, 0.3, 0.2]])
    ph = rng.uniform(0, 2 * np.pi, amp.shape)
    quantum = 2 * np.pi / 32768
    with open(path, "w") as f:
        f.write("t,q1,q2,tau1,tau2\n")
        for s in range(0, n, 100_000):  # in blocks: the generator stays small too
            tt = t[s : s + 100_000, None, None]
            arg = w * tt + ph
            q = np.sum(amp * np.sin(arg), -1)
            dq = np.sum(amp * w * np.cos(arg), -1)
            ddq = np.sum(-amp * w**2 * np.sin(arg), -1)
            tau = model.torque(theta, q, dq, ddq)
            q = np.round(q / quantum) * quantum
            np.savetxt(f, np.column_stack([tt[:, 0, 0], q, tau]), fmt="%.9g", delimiter=",")
    return n


def long_run(minutes: float, as_json: bool) -> int:
    """Peak RSS of `hil identify` on a long generated recording (module doc)."""
    import os
    import re
    import subprocess

    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "long.csv")
        rows = write_long_recording(path, minutes)
        size = os.path.getsize(path)
        cmd = [
            "/usr/bin/time", "-v", sys.executable, "-m", "hil.cli", "identify", "--from", path,
            "--robot", "dfki-a0", "--no-plot", "--out", os.path.join(tmp, "out"), "--json",
        ]  # fmt: skip
        start = time.perf_counter()
        run = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.perf_counter() - start
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", run.stderr)
    rss = int(m.group(1)) * 1024 if m else -1
    ok = run.returncode == 0 and 0 < rss < TARGET_LONG_RSS_BYTES
    doc = {
        "minutes": minutes,
        "rows": rows,
        "csv_bytes": size,
        "exit_status": run.returncode,
        "peak_rss_bytes": rss,
        "wall_s": wall,
        "target_rss_bytes": TARGET_LONG_RSS_BYTES,
        "targets_met": ok,
    }
    if run.returncode != 0:
        doc["stderr_tail"] = run.stderr[-2000:]
    if as_json:
        print(json.dumps(doc))
    else:
        print(
            f"hil identify --robot dfki-a0 on {minutes:g} min at 1 kHz ({rows} rows, "
            f"{size / 1e6:.0f} MB CSV): peak RSS {rss / 1e6:.0f} MB (target < "
            f"{TARGET_LONG_RSS_BYTES / 1024**3:.0f} GiB), {wall:.0f} s wall, exit {run.returncode}"
        )
        if run.returncode != 0:
            print(run.stderr[-2000:])
    return 0 if ok else 1


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--long", type=float, default=None, metavar="MINUTES")
    args = parser.parse_args()
    if args.long is not None:
        return long_run(args.long, args.json)
    with tempfile.TemporaryDirectory() as tmp:
        simulate(load_robot("cicese"), load_experiment("reyes-kelly"), tmp, plot=False)
        rec = read_signals(tmp)
    q, tau, h = rec.q, rec.tau, rec.period_s

    def batch() -> None:
        for s in SCHEMES:
            r = build_regression(s, q, tau, h, 50.0, "exact")
            least_squares(r.Psi, r.y, r.weights)

    def rls() -> None:
        for s in SCHEMES:
            r = build_regression(s, q, tau, h, 50.0, "exact")
            recursive_least_squares(r.Psi, r.y, r.weights)

    batch_s = timed(batch, args.repeats)
    rls_s = timed(rls, max(3, args.repeats // 2))

    # one RLS update (eqs. 20-22) with a vector (m = 2) and a scalar (m = 1) prediction error
    reg = build_regression("filtered_dynamic", q, tau, h, 50.0, "exact")
    est = RecursiveLeastSquares(9)
    start = time.perf_counter()
    for k in range(len(reg.y)):
        est.update(reg.Psi[k], reg.y[k])
    update_vector_us = (time.perf_counter() - start) / len(reg.y) * 1e6
    reg1 = build_regression("filtered_power", q, tau, h, 50.0, "exact")
    est = RecursiveLeastSquares(9)
    start = time.perf_counter()
    for k in range(len(reg1.y)):
        est.update(reg1.Psi[k], reg1.y[k])
    update_scalar_us = (time.perf_counter() - start) / len(reg1.y) * 1e6

    online_us = {}
    for disc in ("exact", "paper"):
        online = OnlineIdentifier(h, discretization=disc)
        for qk, tk in zip(q, tau, strict=True):
            online.push(qk, tk)
        online_us[disc] = online.cost_per_sample_s() * 1e6

    doc = {
        "samples": len(q),
        "duration_s": len(q) * h,
        "batch_least_squares_all_schemes_s": batch_s,
        "recursive_least_squares_all_schemes_s": rls_s,
        "online_rls_update_us": {"vector_m2": update_vector_us, "scalar_m1": update_scalar_us},
        "online_step_all_schemes_us": online_us,
        "targets": {"batch_s": TARGET_BATCH_S, "rls_s": TARGET_RLS_S, "period_s": PERIOD_S},
    }
    ok = batch_s < TARGET_BATCH_S and rls_s < TARGET_RLS_S and update_vector_us * 1e-6 < PERIOD_S
    doc["targets_met"] = ok
    if args.json:
        print(json.dumps(doc))
    else:
        print(
            f"identification, 10 s at 400 Hz ({len(q)} samples), three schemes, exact mode:\n"
            f"  batch least squares (regressions + solve): {1e3 * batch_s:.1f} ms "
            f"(target < {1e3 * TARGET_BATCH_S:.0f} ms)\n"
            f"  recursive least squares:                   {1e3 * rls_s:.0f} ms "
            f"(target < {1e3 * TARGET_RLS_S:.0f} ms)\n"
            f"  one online RLS update: {update_vector_us:.0f} µs (vector error), "
            f"{update_scalar_us:.0f} µs (scalar) of a {1e3 * PERIOD_S:g} ms period\n"
            f"  whole online step, three schemes (rows + filters + updates): "
            f"{online_us['exact']:.0f} µs exact, {online_us['paper']:.0f} µs paper"
        )
    return 0 if ok else 1


if __name__ == "__main__":
    np.seterr(all="raise")
    sys.exit(main())
