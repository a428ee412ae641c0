"""Errors in variables from encoder quantization, measured (docs/real-data.md).

    python tests/benchmarks/eiv_quantization.py

The simulated DFKI-sized arm of tests/test_identify_real.py (dfki-a0 θ with rotor inertia,
~500 Hz with 30 % jitter, 1.9e-4 rad encoder quantum, multisine torque): least-squares θ of the
exact filtered-dynamic rows (λ = 20 rad/s, real time stamps) with three-point velocities and
with the local-quadratic velocities identification uses, as % error against the true θ.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from test_identify_real import ROTOR, simulated_arm

from hil.model.estimators import least_squares
from hil.model.regressors import build_regression, velocity_half_window


def main() -> int:
    theta, t, q, tau = simulated_arm()
    h = float(np.median(np.diff(t)))
    lam = 20.0
    cols = [0, 1, 2, 3, 4, 9]
    print("% error of least squares, λ = 20 rad/s:  " + "  ".join(ROTOR.names[c] for c in cols))
    for m in (1, velocity_half_window(lam, t)):
        reg = build_regression("filtered_dynamic", q, tau, h, lam, model=ROTOR, t=t, half_window=m)
        est = least_squares(reg.Psi, reg.y)
        err = 100 * (est[cols] / theta[cols] - 1)
        label = "three-point velocities" if m == 1 else f"local quadratic, ±{m} samples"
        print(f"{label:40s}" + "".join(f"{e:+9.1f}" for e in err))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
