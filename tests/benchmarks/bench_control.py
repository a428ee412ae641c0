"""Benchmark: the cost of one control period of each tracking law (hil/control/controllers.py),
in-process, without the link: µs of CPU per call of PD, CT, FED and RFED (the law, its torque
split and the clipping) on

- the 2-DOF CICESE arm's closed form (hil.model.closed_form.ArmModel, the fast path),
- the same arm through its URDF (hil.model.urdf.UrdfArmModel, Pinocchio's RNEA regressor),
- the 3-DOF cicese3 and the 7-joint Panda through their URDFs.

Khosla & Kanade (1987) computed their CT law with a custom Newton–Euler in 1.2 ms per 2 ms
period; the bench's period is 2.5 ms. ``--json`` prints one JSON document. CPU time (the work is
single-threaded), median of 3 repeats of ``--calls`` calls.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np

from hil.control.controllers import SCHEMES, Gains, Reference, make_controller
from hil.model.closed_form import ArmModel
from hil.model.params import robot_params
from hil.model.urdf import UrdfArmModel

PERIOD_S = 0.0025


def arms() -> dict[str, tuple[object, np.ndarray]]:
    out: dict[str, tuple[object, np.ndarray]] = {
        "cicese (closed form)": (ArmModel(), robot_params("cicese").theta)
    }
    for label, robot in (
        ("cicese (URDF)", "cicese"),
        ("cicese3 (URDF)", "cicese3"),
        ("panda (URDF)", "panda"),
    ):
        model = UrdfArmModel.from_profile(robot)
        out[label] = (model, model.base_theta())
    return out


def law_us(model, theta: np.ndarray, scheme: str, calls: int, rng: np.random.Generator) -> float:
    n = model.n_joints
    ctl = make_controller(scheme, theta, Gains((40.0,) * n, (12.6,) * n), (1e3,) * n, model=model)
    states = rng.uniform(-1.0, 1.0, size=(calls, 5, n))
    runs = []
    for _ in range(3):
        start = time.process_time()
        for q, dq, qd, dqd, ddqd in states:
            ctl(0.0, q, dq, Reference(qd, dqd, ddqd))
        runs.append(time.process_time() - start)
    return statistics.median(runs) / calls * 1e6


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--calls", type=int, default=300)
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    rng = np.random.default_rng(0)
    table = {
        label: {s: round(law_us(m, th, s, args.calls, rng), 1) for s in SCHEMES}
        for label, (m, th) in arms().items()
    }
    if args.json:
        print(json.dumps({"period_s": PERIOD_S, "cpu_us_per_call": table}, indent=2))
        return 0
    print(f"CPU µs per control period (period {PERIOD_S * 1e3:g} ms)")
    print(f"{'arm':22s}" + "".join(f"{s.upper():>9s}" for s in SCHEMES))
    for label, row in table.items():
        print(f"{label:22s}" + "".join(f"{row[s]:>9.1f}" for s in SCHEMES))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
