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
from hil.diagnose.columns import recording_rows, row_weights
from hil.diagnose.selection import fit_theta


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
    return out


def null_residual(path: Path) -> dict[str, list[float]]:
    r = read_signals(path)
    rows = recording_rows(r.q, r.tau, r.period_s)
    out: dict[str, list[float]] = {}
    for name, w in (("used_today", rows.weights), ("reversals_kept", _stuck_only(rows))):
        theta = fit_theta(rows.Psi, rows.y, w)
        res = rows.y - rows.Psi @ theta
        rms = [float(np.sqrt(np.mean(res[w[:, j] > 0, j] ** 2))) for j in range(res.shape[1])]
        peak = [float(np.max(np.abs(res[w[:, j] > 0, j]))) for j in range(res.shape[1])]
        out[f"{name}_rms_Nm"] = [round(x, 4) for x in rms]
        out[f"{name}_peak_over_rms"] = [round(p / s, 1) for p, s in zip(peak, rms, strict=True)]
        out[f"{name}_rows"] = [int(x) for x in (w > 0).sum(axis=0)]
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
