"""Least squares against instrumental variables on closed-loop runs with known θ
(docs/real-data.md, "Closed loop").

    python tests/benchmarks/iv_closed_loop.py [--seeds 8]      # about 10 s a seed
    python tests/benchmarks/iv_closed_loop.py --closed-form    # the 2-DOF model path's rows
        [--disturbance-nm 1.5] [--disturbance-hz 1.5] [--noise-rad 1e-5]

The 2-joint arm of the cicese profile (its URDF, hil.model.urdf) under PD tracking of a
three-sine reference with feedforward, an unmodelled torque disturbance of 1.5 Nm RMS acting on
the arm and 1 mrad encoder noise (tests/test_iv.py ``_closed_loop``, 20 s at 1 kHz), one run per
seed. Each run is fitted by the filtered dynamic rows' weighted least squares
(hil.identify.urdf.identify_torque) and by IV on its reference (hil.identify.iv), on all rows;
each θ is validated on the next seed's run (held-out torque NRMSE of the recorded torque, which
holds the disturbance's share: the true θ's NRMSE is printed beside). Prints the relative error
of each nonzero base parameter (mean ± SD over the seeds) and the held-out NRMSE.

``--closed-form``: the same arm as the 2-DOF closed form θ1..θ9 (hil.model.closed_form, the
`hil identify` model path), its exact filtered dynamic rows at λ from the data: weighted least
squares (hil.identify.schemes.identify_model, unbounded) against IV on the same rows
(hil.identify.iv.identify_torque_iv); by default the disturbance band-limited at 1.5 Hz (an
8 Hz one, as the URDF runs', lies mostly above the rows' filter, λ = 6.3 rad/s) and 1e-5 rad
encoder noise (tests/test_iv.py ``_closed_form_closed_loop``); held-out NRMSE on the next
seed's run by the model path's validation (hil.identify.schemes.torque_prediction_error).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/, for test_iv

from test_iv import _closed_form_arm, _closed_form_closed_loop, _closed_loop

from hil.identify.iv import identify_torque_iv
from hil.identify.schemes import identify_model, torque_prediction_error
from hil.identify.urdf import identify_torque, regression_rows, torque_nrmse
from hil.model.urdf import UrdfArmModel


def _urdf_runs(seeds: int) -> tuple[Any, np.ndarray, dict, dict]:
    """The URDF arm's estimates per seed and their held-out NRMSE on the next seed's run."""
    model = UrdfArmModel.from_profile("cicese")
    theta = model.base_theta()
    runs = [_closed_loop(model, theta, seed) for seed in range(seeds + 1)]
    errors: dict[str, list[np.ndarray]] = {"LS": [], "IV": []}
    held: dict[str, list[np.ndarray]] = {"LS": [], "IV": [], "truth": []}
    for s in range(seeds):
        ls = identify_torque(model, runs[s], held_out=0.0)
        iv = identify_torque_iv(model, runs[s], held_out=0.0, left_out_joints=ls.left_out_joints)
        rows = regression_rows(model, runs[s + 1]).leaving_out(ls.left_out_joints)
        for name, th in (("LS", ls.theta), ("IV", iv.theta), ("truth", theta)):
            held[name].append(torque_nrmse(th, rows))
            if name != "truth":
                errors[name].append(th)
    return model, theta, errors, held


def _closed_form_runs(seeds: int, **loop: float) -> tuple[Any, np.ndarray, dict, dict]:
    """The 2-DOF closed form's estimates per seed (the model path's rows) and their held-out
    NRMSE on the next seed's run."""
    model, theta = _closed_form_arm()
    runs = [_closed_form_closed_loop(seed=seed, **loop)[2] for seed in range(seeds + 1)]
    errors: dict[str, list[np.ndarray]] = {"LS": [], "IV": []}
    held: dict[str, list[np.ndarray]] = {"LS": [], "IV": [], "truth": []}
    for s in range(seeds):
        ls = identify_model(runs[s].t, runs[s].q, runs[s].tau, model)
        iv = identify_torque_iv(model, runs[s], held_out=0.0, lam=ls.lam)
        nxt = runs[s + 1]
        for name, th in (("LS", ls.theta_ls), ("IV", iv.theta), ("truth", theta)):
            held[name].append(
                np.array(torque_prediction_error(th, model, nxt.t, nxt.q, nxt.tau, ls.lam))
            )
            if name != "truth":
                errors[name].append(th)
    return model, theta, errors, held


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument(
        "--closed-form", action="store_true", help="the 2-DOF closed form's rows (model path)"
    )
    ap.add_argument("--disturbance-nm", type=float, default=1.5, help="--closed-form: RMS, Nm")
    ap.add_argument("--disturbance-hz", type=float, default=1.5, help="--closed-form: its band")
    ap.add_argument("--noise-rad", type=float, default=1e-5, help="--closed-form: encoder noise")
    args = ap.parse_args()
    if args.closed_form:
        model, theta, errors, held = _closed_form_runs(
            args.seeds, disturbance_Nm=args.disturbance_nm, disturbance_hz=args.disturbance_hz,
            noise_rad=args.noise_rad,
        )  # fmt: skip
    else:
        model, theta, errors, held = _urdf_runs(args.seeds)
    keep = np.flatnonzero(theta != 0)
    print(f"{args.seeds} closed-loop runs; relative error of each base parameter, mean ± SD")
    print("| parameter | true | least squares | IV on the reference |")
    print("|---|---|---|---|")
    for i in keep:
        cells = []
        for name in ("LS", "IV"):
            rel = (np.array(errors[name])[:, i] - theta[i]) / abs(theta[i])
            cells.append(f"{100 * rel.mean():+.1f} ± {100 * rel.std(ddof=1):.1f} %")
        label = model.names[i] if args.closed_form else model.meanings[i]
        print(f"| {label} | {theta[i]:.4g} | {cells[0]} | {cells[1]} |")
    print("\n| held-out torque NRMSE (next seed's run) | joint 1 | joint 2 |")
    print("|---|---|---|")
    for name, label in (("truth", "true θ"), ("LS", "least squares"), ("IV", "IV")):
        e = np.array(held[name])
        cells = [f"{m:.4f} ± {sd:.4f}" for m, sd in zip(e.mean(0), e.std(0, ddof=1), strict=True)]
        print(f"| {label} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
