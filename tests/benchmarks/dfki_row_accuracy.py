"""Where the diagnosis loses accuracy on the DFKI recordings (issue 26; docs/real-data-diagnosis.md,
"Where the diagnosis loses accuracy"): the owners' model (the profile's θ) on the last quarter of
a recording, by a plain zero-phase 8 Hz check and by the diagnosis's own rows, with the rows'
velocity half-window and momentum window as chosen and varied; and the velocity estimate's
scatter against an 8 Hz-smoothed velocity beside the noise model's white-noise figure.

    python tests/benchmarks/dfki_row_accuracy.py [RECORDING.csv ...] [--robot dfki-a0]

Default: A.0 trajectory_01 and 03 of ../shared/realdata. About 20 s a recording.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
from scipy.signal import butter, sosfiltfilt

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # tests/, for realdata

from realdata import realdata

import hil.diagnose.columns as columns
from drivers.recording import read_signals
from hil.diagnose.heldout import HELD_OUT_FRACTION
from hil.diagnose.pipeline import diagnose
from hil.model.closed_form import ArmModel
from hil.model.metrics import nrmse
from hil.model.params import robot_params
from hil.model.regressors import local_polynomial_velocity

PLAIN_CUTOFF_HZ = 8.0
EDGE_S = 0.5


def _pct(values) -> str:
    return " / ".join("–" if v is None else f"{100 * v:.1f}" for v in values)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("recordings", nargs="*")
    ap.add_argument("--robot", default="dfki-a0")
    args = ap.parse_args(argv)
    records = realdata("dfki-double-pendulum") / "records"
    paths = args.recordings or [
        records / f"design_A.0__20220815__sys_id__trajectory_0{k}.csv" for k in (1, 3)
    ]
    profile = robot_params(args.robot)
    model, theta = ArmModel(profile.terms), np.asarray(profile.theta)
    chosen = columns.noise_model
    for path in paths:
        rec = read_signals(path, fmt="dfki")
        t, q, tau = rec.t, rec.q, rec.tau
        h = float(np.median(np.diff(t)))
        sos = butter(4, PLAIN_CUTOFF_HZ, fs=1 / h, output="sos")
        qf, tf = sosfiltfilt(sos, q, axis=0), sosfiltfilt(sos, tau, axis=0)
        dq = np.gradient(qf, t, axis=0)
        pred = model.torque(theta, qf, dq, np.gradient(dq, t, axis=0))
        inside = (t > t[0] + EDGE_S) & (t < t[-1] - EDGE_S)
        last = inside & (np.arange(len(t)) >= round((1 - HELD_OUT_FRACTION) * len(t)))
        plain = [float(nrmse(tf[last, j], pred[last, j])) for j in range(2)]
        print(f"\n{Path(path).stem}: owners' model, held-out torque NRMSE % j1 / j2")
        print(f"  plain {PLAIN_CUTOFF_HZ:g} Hz zero-phase check, last quarter: {_pct(plain)}")
        for window, half in ((1, None), (1, 8), (2, None)):

            def varied(q, t, window=window, half=half):
                n = chosen(q, t)
                return dataclasses.replace(
                    n, window=n.window * window, half_window=half or n.half_window
                )

            columns.noise_model = varied
            try:
                doc = diagnose([rec], theta, nominal_theta=theta, model=model).document
            finally:
                columns.noise_model = chosen
            what = "as chosen" if (window, half) == (1, None) else (
                f"momentum window x{window}" if half is None else f"velocity half-window {half}"
            )  # fmt: skip
            print(f"  diagnosis rows, {what}: {_pct(doc['fit']['before']['torque_nrmse'])}"
                  + (f"  ({doc['noise']})" if what == "as chosen" else ""))  # fmt: skip
        noise = chosen(q, t)
        v_smooth = dq[200:-200]
        for m in (1, noise.half_window, 8):
            error = local_polynomial_velocity(q, t, m)[200:-200] - v_smooth
            scatter = np.sqrt(np.mean(error**2, axis=0))
            print(f"  velocity ±{m} samples: scatter against the {PLAIN_CUTOFF_HZ:g} Hz one "
                  f"{scatter.round(4).tolist()} rad/s"
                  + (f" (noise model: {[round(x, 4) for x in noise.velocity_noise_rad_s]})"
                     if m == noise.half_window else ""))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
