"""Why the real-interval lag/delay columns moved the DFKI A.0 rotor-inertia selection: the
figures of docs/real-data-diagnosis.md, "The start-up step and the lag columns".

    python tests/benchmarks/dfki_rate_start_up.py [--records DIR] [--fit 04] [--held-out 05]

The pair is read as `hil diagnose A B --format dfki --robot tests/data/dfki/dfki-a0-rigid.toml`
reads it. Prints, per recording, the first intervals and torques (the drive switched on from
0 Nm) and how far the lag/delay candidate's columns on joint 2 stand out in the weighted rows
whose filter window holds the first intervals (the largest |X1 − X2| there over its RMS in
the other weighted rows; the probe difference is the τ̈ part). Then the first-round evidence
of the joint-2 lag/delay candidate (`rate:2`) and of `rotor_inertia`, with the columns over
the real intervals and over the median interval (what the diagnosis used before): held-out
reduction (trimmed), blocks improved, the total held-out error change (drop; < 0: worse in
total) and each recording's first block; ``--without-start-up``: with the start-up rows left
out. Slow: about a minute on a loaded machine.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from hil.cli_options import read_recording
from hil.diagnose import candidates, problem
from hil.diagnose.columns import torque_rate_column
from hil.diagnose.stats import evidence
from hil.model.closed_form import ArmModel
from hil.model.params import robot_params

sys.path.insert(0, str(Path(__file__).resolve().parent))  # this directory
from diagnose_real_data import RECORDS

RIGID = Path(__file__).resolve().parents[1] / "data" / "dfki" / "dfki-a0-rigid.toml"
STEM = "design_A.0__20220815__sys_id__trajectory_"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", type=Path, default=RECORDS)
    ap.add_argument("--fit", default="04")
    ap.add_argument("--held-out", default="05")
    ap.add_argument(
        "--without-start-up",
        action="store_true",
        help="leave out (weight 0) the rows whose window holds one of the first 8 intervals",
    )
    args = ap.parse_args()
    options = argparse.Namespace(recording_format="dfki")
    recs = [
        read_recording(options, args.records / f"{STEM}{i}.csv", command="diagnose", joints=2)
        for i in (args.fit, args.held_out)
    ]
    profile = robot_params(str(RIGID))
    model = ArmModel(profile.terms)
    prob, theta = problem.build_problem([(r.q, r.tau, r.period_s, r.t) for r in recs], model)
    for name, rec, rows in zip((args.fit, args.held_out), recs, prob.rows, strict=True):
        dt = np.diff(rec.t)
        x = torque_rate_column(rows, 1)[:, 1, :]
        diff = x[:, 0] - x[:, 1]
        # the weighted rows whose window holds one of the first 8 intervals
        start = (rows.k < 8 + rows.window) & (rows.weights[:, 1] > 0)
        rest = (rows.k >= 8 + rows.window) & (rows.weights[:, 1] > 0)
        print(
            f"trajectory {name}: first intervals {np.round(dt[:6] * 1e3, 2).tolist()} ms "
            f"(median {np.median(dt) * 1e3:.2f}); torque rows 0-2 j2 "
            f"{np.round(rec.tau[:3, 1], 3).tolist()} Nm; window {rows.window} intervals; "
            f"|X1 - X2| j2 in the start-up rows up to {np.abs(diff[start]).max():.2f}, "
            f"{np.abs(diff[start]).max() / np.sqrt(np.mean(diff[rest] ** 2)):.0f}x its RMS "
            "elsewhere"
        )
    if args.without_start_up:
        at = 0
        for rows in prob.rows:
            prob.w[at : at + rows.rows][rows.k < 8 + rows.window] = 0.0
            at += rows.rows
    ranges = np.ptp(np.concatenate([r.q for r in recs]), axis=0)
    library = {
        c.key: c for c in candidates.candidates(theta, ranges, problem.usable_speeds(prob), model)
    }
    rate = library["rate:2"]
    median = replace(
        rate, columns=lambda rows, _v: torque_rate_column(replace(rows, stamps=None), 1)
    )
    first_blocks = [0, int(prob.blocks[prob.rows[0].rows])]
    base = problem.design_cv(prob, [])
    for label, cand in (
        ("rate:2, real intervals", rate),
        ("rate:2, median interval", median),
        ("rotor_inertia", library["rotor_inertia"]),
    ):
        prob.forget((cand.key, 0))  # both rate:2 variants share the key: built afresh
        cv = problem.terms_cv(prob, [], cand)
        ev = evidence(base, cv, [1])
        ratio = cv.held_out_sse[first_blocks, 1] / base.held_out_sse[first_blocks, 1]
        print(
            f"{label:24s} reduction {100 * ev.reduction:+.1f} %, {ev.blocks_improved}/"
            f"{ev.blocks} blocks, drop {ev.drop:+.0f}, first blocks' error x "
            f"{np.round(ratio, 2).tolist()}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
