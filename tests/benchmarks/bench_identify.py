"""Benchmark: identification of 10 s at 400 Hz with all three schemes (`make bench`).

Targets (issue 4): batch least squares, all three schemes (regressions included), under 0.1 s;
recursive least squares over the same data, all three schemes, under 1 s; one online RLS update
well inside a 2.5 ms period. Also reports the whole online step (building the three regressor
rows from the newest sample, filters, three RLS updates), which is what a control cycle pays.
Medians of several repeats; ``--json`` prints one JSON document; exit 1 if a target is missed.
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
from hil.estimators import RecursiveLeastSquares, least_squares, recursive_least_squares
from hil.online import OnlineIdentifier
from hil.regressors import SCHEMES, build_regression
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


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
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
