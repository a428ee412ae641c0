"""Would a physically consistent nominal fit let `hil diagnose --robot panda` test candidates on
the real Panda recording of Gaz et al. (2019)? (issue 14; docs/urdf.md, "Diagnosis of the Panda
recording").

    python tests/benchmarks/panda_consistent_nominal.py

The diagnosis's nominal least-squares fit of that recording is not physical, so it says "I cannot
tell" and tests nothing. This script builds the diagnosis's own rows (hil.diagnose.problem.
build_problem, real stamps), fits the training part (the first 75 %) twice, by weighted least
squares and by identification's physically consistent fit (hil.identify.urdf.consistent_fit:
every body's pseudo-inertia positive definite, friction ≥ 0), and prints for each whether it is
physical and its held-out torque NRMSE per joint on the last 25 %. A consistent fit could only
be the diagnosis's basis if it is physical and predicts the held-out torque about as well as
least squares. Reads the data from ../shared/realdata (GPL-3, never copied into the tree); says
so and exits when it is absent. About 15 s CPU.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from realdata import realdata  # tests/realdata.py

from drivers.one_per_line import read_one_per_line_log
from hil.cli_options import read_recording
from hil.diagnose.heldout import held_out_masks, nrmse_or_none
from hil.diagnose.problem import build_problem, fit_theta
from hil.identify.urdf import consistent_fit
from hil.model.urdf import UrdfArmModel


def main() -> int:
    folder = realdata("panda-gaz2019") / "rbt_log"
    if not folder.is_dir():
        print(f"{folder} not present (GPL-3 data, kept out of the tree): nothing to measure")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        csv = Path(tmp) / "panda.csv"
        read_one_per_line_log(folder).write_csv(csv)
        options = argparse.Namespace(
            columns=None, loop_delay=None, torque=None, recording_format=None
        )
        rec = read_recording(options, csv, command="diagnose", allow_gaps=True)
    model = UrdfArmModel.from_profile("panda")
    prob, _ = build_problem([(rec.q, rec.tau, rec.period_s, rec.t)], model)
    train, test, _ = held_out_masks(prob)
    w_train = prob.w * train[:, None]
    theta_ls = fit_theta(prob.Psi_raw, prob.y_raw, w_train)
    rows = train & (prob.w.sum(axis=1) > 0)
    sw = np.sqrt(w_train[rows])
    started = time.process_time()
    standard = consistent_fit(model, prob.Psi_raw[rows] * sw[..., None], prob.y_raw[rows] * sw,
                              theta_ls)  # fmt: skip
    cpu = time.process_time() - started
    usable = (prob.w > 0).sum(axis=0).tolist()
    print(f"usable rows per joint: {usable}; consistent fit {cpu:.1f} s CPU")
    for name, theta in (("least squares", theta_ls), ("consistent", model.base_theta(standard))):
        pred = prob.Psi_raw @ theta
        nrmse = [nrmse_or_none(prob.y_raw, pred, test & (prob.w[:, j] > 0), j) for j in range(7)]
        check = model.physical_consistency(theta)
        cells = " / ".join("n/a" if x is None else f"{100 * x:.1f}" for x in nrmse)
        print(f"{name}: held-out torque NRMSE % {cells}")
        print(f"  physical: {check['consistent']}  {'; '.join(check['violations'][:3])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
