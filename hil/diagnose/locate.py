"""Where the nominal model's torque residual lives: which joint, when, where in state space.

For each joint the residual e = F[τ] − Ψθ̂ (Nm, usable rows) is grouped by a state variable
(direction of motion, speed, position, torque level, time since the last standstill or reversal)
and the share of its variance each grouping explains is the correlation ratio
η² = Σ_g n_g (ē_g − ē)² / Σ (e − ē)² (0: the grouping says nothing, 1: it says everything).
Time windows whose RMS stands out against the median window are listed too. Pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from hil.diagnose.problem import Problem

# A grouping that explains less than this share of the residual variance is not reported as
# carrying it.
MIN_ETA2 = 0.02
NEAR_STILL_S = 0.1
TIME_ORIGIN = "seconds from the first sample of each recording"


@dataclass
class Location:
    document: dict[str, Any]
    arrays: dict[str, Any]


def correlation_ratio(e: np.ndarray, groups: np.ndarray) -> tuple[float, dict[int, float]]:
    """η² of ``e`` grouped by integer labels, and each group's mean."""
    if len(e) == 0:
        return 0.0, {}
    total = float(np.sum((e - e.mean()) ** 2))
    means = {int(g): float(e[groups == g].mean()) for g in np.unique(groups)}
    between = sum(np.sum(groups == g) * (m - e.mean()) ** 2 for g, m in means.items())
    return (float(between / total) if total > 0 else 0.0), means


def _terciles(x: np.ndarray) -> np.ndarray:
    if len(x) == 0:
        return np.zeros(0, int)
    return np.searchsorted(np.quantile(x, [1 / 3, 2 / 3]), x)


def locate(prob: Problem, theta: np.ndarray) -> Location:
    """The residual of θ̂ on every joint, grouped (module doc)."""
    e_all = prob.y_raw - prob.Psi_raw @ theta
    # seconds from each recording's first sample: a recording stamped in Unix time (an .npz
    # log's 1.6e9 s) would otherwise report its bursts at 1660000000.12 s
    t = np.concatenate([r.t - (0.0 if r.stamps is None else r.stamps[0]) for r in prob.rows])
    recording = np.concatenate([np.full(r.rows, i) for i, r in enumerate(prob.rows)])
    v, q, tau = prob.v_mean, prob.q_mean, prob.y_raw
    # time since the joint last stood still or reversed (the rows the fit leaves out)
    since = np.concatenate([_since_still(r.weights, r.h) for r in prob.rows])
    joints = []
    for j in range(prob.n_joints):
        ok = prob.w[:, j] > 0
        e = e_all[ok, j]
        rms = float(np.sqrt(np.mean(e**2))) if len(e) else 0.0
        groupings = {
            "direction of motion": (v[ok, j] > 0).astype(int),
            "speed": _terciles(np.abs(v[ok, j])),
            "position": _terciles(q[ok, j]),
            "torque level": _terciles(tau[ok, j]),
            "time since standstill or reversal": (since[ok, j] < NEAR_STILL_S).astype(int),
        }
        labels = {
            "direction of motion": {0: "q̇ < 0", 1: "q̇ > 0"},
            "speed": {0: "slow third", 1: "middle third", 2: "fast third"},
            "position": {0: "low third", 1: "middle third", 2: "high third"},
            "torque level": {0: "low third", 1: "middle third", 2: "high third"},
            "time since standstill or reversal": {
                0: f"> {NEAR_STILL_S} s after",
                1: f"< {NEAR_STILL_S} s after",
            },
        }
        state = {}
        for name, g in groupings.items():
            eta2, means = correlation_ratio(e, g)
            state[name] = {
                "eta2": round(eta2, 4),
                "mean_residual_Nm": {labels[name][k]: round(m, 4) for k, m in means.items()},
            }
        ranked = sorted(state.items(), key=lambda kv: -kv[1]["eta2"])
        carried = [name for name, s in ranked if s["eta2"] >= MIN_ETA2]
        blocks = prob.blocks[ok]
        block_rms = np.sqrt(np.bincount(blocks, e**2) / np.maximum(np.bincount(blocks), 1))
        present = np.bincount(blocks) > 0
        med = float(np.median(block_rms[present])) if present.any() else 0.0
        windows = []
        for b in np.argsort(-block_rms)[:3]:
            if not present[b] or med <= 0 or block_rms[b] < 1.5 * med:
                continue
            tb = t[ok][blocks == b]
            window = {
                "t_s": [round(float(tb[0]), 3), round(float(tb[-1]), 3)],
                "rms_over_median": round(float(block_rms[b] / med), 2),
            }
            if len(prob.rows) > 1:  # blocks lie within one recording
                window["recording"] = int(recording[ok][blocks == b][0]) + 1
            windows.append(window)
        joints.append(
            {
                "joint": j + 1,
                "residual_rms_Nm": round(rms, 4),
                "robust_scale_Nm": round(float(prob.scale[j]), 4),
                "rows_left_out_stick_fraction": round(float(1 - ok.mean()), 4),
                "carried_by": carried,
                "state": state,
                "time_windows": windows,
            }
        )
    arrays = {"t": t, "residual": e_all, "v": v, "q": q, "usable": prob.w > 0}
    return Location({"joints": joints, "time_origin": TIME_ORIGIN}, arrays)


def _since_still(weights: np.ndarray, h: float) -> np.ndarray:
    """Seconds since the last row left out for stick or reversal, per joint (inf if none)."""
    K = len(weights)
    idx = np.arange(K)[:, None]
    last = np.where(weights == 0, idx, -(10**9))
    last = np.maximum.accumulate(last, axis=0)
    return np.where(last < 0, np.inf, (idx - last) * h)
