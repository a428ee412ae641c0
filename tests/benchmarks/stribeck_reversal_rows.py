"""Where the Stribeck data of a blind-like set lie, and what keeping reversal rows would cost.

    python tests/benchmarks/make_diagnose_set.py --seed 7 --out /tmp/set7
    python tests/benchmarks/stribeck_reversal_rows.py /tmp/set7

For every recording that conceals Stribeck friction (truth.json), on its joint: the filtered rows
(hil.diagnose.columns.recording_rows) whose interval slides slower than 2 v_s and slower than v_s
(v_s the truth's), split into those the diagnosis uses and those it leaves out, and of the left
out those it would use if a velocity reversal were not a reason to leave an interval out (only no
encoder motion); and the Stribeck shape exp(−(|q̇|/v_s)²) summed over the same groups (what
the column can carry). For every null recording: the nominal fit's residual per joint (RMS in
Nm, largest |r| / RMS) on the rows used today, and refitted with the reversal rows kept, their
friction columns integrated exactly across the sign switch on the cubic Hermite q̇
(hil.model.regressors). docs/diagnosis.md, "Where the blind-like sets miss", quotes the output.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from drivers.recording import read_signals
from hil.diagnose.columns import moving_average, recording_rows, row_weights, stribeck_column
from hil.diagnose.problem import fit_theta
from hil.model.regressors import _sign_and_abs_integrals, central_difference


def _stuck_only(rows) -> np.ndarray:
    """Weights of ``rows`` with only "no encoder motion" as a reason to leave an interval out."""
    q, k = rows.q, rows.k
    return row_weights(q[k + 1] == q[k], rows.h, rows.window)


def stribeck_rows(path: Path, joint: int, vs: float) -> dict[str, float]:
    r = read_signals(path)
    rows = recording_rows(r.q, r.tau, r.period_s)
    used = rows.weights[:, joint] > 0
    moving = _stuck_only(rows)[:, joint] > 0
    speed = np.abs(rows.v_mean[:, joint])
    shape = np.exp(-((speed / vs) ** 2))
    out: dict[str, float] = {"rows": int(used.sum()), "rows_reversals_kept": int(moving.sum())}
    for name, band in (("below_2vs", speed < 2 * vs), ("below_vs", speed < vs)):
        out[f"{name}_used"] = int(np.sum(band & used))
        out[f"{name}_left_out"] = int(np.sum(band & ~used))
        out[f"{name}_left_out_for_reversal_only"] = int(np.sum(band & ~used & moving))
    out["shape_used"] = round(float(shape[used].sum()), 1)
    out["shape_left_out_for_reversal_only"] = round(float(shape[~used & moving].sum()), 1)
    # breakaway ratio 1 + ΔF/F_c fitted at the truth's v_s (library column, exact across the
    # sign switch), on the rows used today and with the reversal rows kept
    X = stribeck_column(rows, joint, vs)
    for name, w in (("used_today", rows.weights), ("reversals_kept", _stuck_only(rows))):
        theta = fit_theta(np.concatenate([rows.Psi, X], axis=2), rows.y, w)
        out[f"ratio_at_truth_vs_{name}"] = round(1 + theta[-1] / theta[7 + joint], 3)
    return out


# A reversal fitted on 8 samples (3 before its interval): two parabolas meeting at zero velocity
# at t0, a stick of T_s between them, one jerk; T_s > STICK_MAX · h is a rest (left out).
STICK_MAX = 0.05


def _fitted_reversals(rows) -> tuple[np.ndarray, np.ndarray, list, list]:
    """Rows to leave out (K, n), the Coulomb column's interval means with the fitted reversals
    (K, n), the reversals (joint, row, t0, stick) kept, and every fitted (joint, stick / h)."""
    q, k, h = rows.q, rows.k, rows.h
    v = central_difference(q, h)
    ts = np.arange(-3, 5) * h
    grid, designs = [], []
    for stick in np.linspace(0, 2 * h, 41):
        for t0 in np.linspace(ts[1], ts[-2] - stick, 121):
            d1 = ts - t0
            d2 = np.where(d1 - stick > 0, d1 - stick, np.where(d1 < 0, d1, 0.0))
            designs.append(
                np.column_stack(
                    [
                        np.ones(8),
                        np.where(d1 < 0, d1**2 / 2, 0),
                        np.where(d2 > 0, d2**2 / 2, 0),
                        d2**3 / 6,
                    ]
                )
            )
            grid.append((t0, stick))
    X = np.array(designs)
    resid = np.eye(8)[None] - X @ np.linalg.pinv(X)
    leave = np.zeros((len(k), q.shape[1]), bool)
    coulomb = np.full((len(k), q.shape[1]), np.nan)
    kept, sticks = [], []
    for j in range(q.shape[1]):
        for i in np.flatnonzero(np.sign(v[k, j]) != np.sign(v[k + 1, j])):
            if k[i] < 3 or k[i] + 5 > len(q) or i < 2 or i + 3 > len(k):
                leave[i, j] = True
                continue
            local = q[k[i] - 3 : k[i] + 5, j] - q[k[i], j]
            g = int(np.argmin(np.einsum("i,gij,j->g", local, resid, local)))
            t0, stick = grid[g]
            sticks.append((j, stick / h))
            if stick > STICK_MAX * h:
                leave[i, j] = True
                continue
            before = -np.sign(np.linalg.pinv(X[g]) @ local)[1]  # sgn q̇ before t0: −sgn a⁻
            for m in range(i - 2, i + 3):
                into = np.clip((t0 - (m - i) * h) / h, 0.0, 1.0)  # share of interval m before t0
                coulomb[m, j] = before * (2 * into - 1)
            kept.append((j, i, t0, stick))
    return leave, coulomb, kept, sticks


def _fitted_rows(rows):
    """Ψ with the Coulomb columns of the fitted reversals, and weights that keep their rows
    but leave out a row whose window starts or ends within h of a reversal (its central-
    difference velocity there straddles the 2F/M jump in acceleration)."""
    leave, coulomb, kept, sticks = _fitted_reversals(rows)
    q, k, h, n = rows.q, rows.k, rows.h, rows.q.shape[1]
    still = (q[k + 1] == q[k]) | leave
    w = row_weights(still, h, rows.window)
    kink = np.zeros(len(q), bool)
    for _j, i, t0, _s in kept:
        at = k[i] + t0 / h
        kink[[int(np.floor(at)), int(np.ceil(at))]] = True
    start = k[np.clip(np.arange(len(k)) - rows.window + 1, 0, None)]
    w[kink[k + 1] | kink[start]] = 0.0
    Psi = rows.Psi.copy()
    v = central_difference(q, h)
    for j in range(n):
        # the Coulomb column's raw interval means are sgn integrals / h: swap in the fitted ones
        raw = np.where(np.isnan(coulomb[:, j]), 0.0, coulomb[:, j])
        fr = rows.model.friction_columns[n + j]
        # the Hermite sgn integral the rows hold, replaced where a reversal was fitted
        hermite = _sign_and_abs_integrals(q[k, j], q[k + 1, j], h * v[k, j], h * v[k + 1, j])[0]
        delta = np.where(np.isnan(coulomb[:, j]), 0.0, raw - hermite)
        Psi[:, j, fr] += moving_average(delta, rows.window)
    return Psi, w, sticks


def null_residual(path: Path) -> dict[str, list[float]]:
    r = read_signals(path)
    rows = recording_rows(r.q, r.tau, r.period_s)
    out: dict[str, list[float]] = {}
    fitted_psi, fitted_w, sticks = _fitted_rows(rows)
    for name, Psi, w in (
        ("used_today", rows.Psi, rows.weights),
        ("reversals_kept", rows.Psi, _stuck_only(rows)),
        ("reversals_fitted", fitted_psi, fitted_w),
    ):
        theta = fit_theta(Psi, rows.y, w)
        res = rows.y - Psi @ theta
        rms = [float(np.sqrt(np.mean(res[w[:, j] > 0, j] ** 2))) for j in range(res.shape[1])]
        peak = [float(np.max(np.abs(res[w[:, j] > 0, j]))) for j in range(res.shape[1])]
        out[f"{name}_rms_Nm"] = [round(x, 4) for x in rms]
        out[f"{name}_peak_over_rms"] = [round(p / s, 1) for p, s in zip(peak, rms, strict=True)]
        out[f"{name}_rows"] = [int(x) for x in (w > 0).sum(axis=0)]
    # fitted stick lengths at the reversals, in intervals h: how many of each, per joint
    for j in range(rows.q.shape[1]):
        lengths = np.round([s for jj, s in sticks if jj == j], 2)
        values, counts = np.unique(lengths, return_counts=True)
        out[f"fitted_sticks_over_h_joint{j + 1}"] = {
            f"{v:g}": int(c) for v, c in zip(values, counts, strict=True)
        }
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("set_dir", type=Path)
    args = ap.parse_args()
    truth = json.loads((args.set_dir / "truth.json").read_text())["recordings"]
    for e in truth:
        path = args.set_dir / e["recording"]
        for t in e["truth"]:
            if t["effect"] == "stribeck":
                got = stribeck_rows(path, t["joint"] - 1, t["magnitude"]["velocity_rad_s"])
                print(
                    json.dumps(
                        {
                            "recording": e["recording"],
                            "experiment": e["experiment"],
                            "joint": t["joint"],
                            **got,
                        }
                    )
                )
        if e["null"]:
            got = null_residual(path)
            print(
                json.dumps(
                    {
                        "recording": e["recording"],
                        "experiment": e["experiment"],
                        "null": True,
                        **got,
                    }
                )
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
