"""Why the energy schemes fail on the real Panda of Gaz et al. (2019): the figures of
docs/urdf.md, "Why the energy schemes failed on the real Panda".

    .venv/bin/python tests/benchmarks/panda_energy_cause.py     # about 15 s CPU; skips without data

Prints, on the first 75 % of the recording (the held-out check is on the last 25 %):
1. the raw three-point velocity's departure from the smoothed one, per joint
   (hil.identify.urdf.velocity_noise_ratio);
2. for supplied-energy and filtered-power rows on raw and smoothed positions: the share of the
   rows' RMS the torque scheme's θ leaves unexplained, the share their own least squares leaves,
   and that least squares' held-out torque NRMSE per joint;
3. the supplied energy balanced over windows of W seconds instead of from the start;
4. other tries: the rigid body held at the torque scheme's (friction from the energy rows);
   the consistent fit on the raw positions; the logger's stale samples dropped;
5. how many independent numbers the scalar rows carry (2BT, B their 95 % bandwidth) against the
   torque rows', and the parameters' count.
Reads the data from ../shared only (GPL-3, never copied).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from drivers.one_per_line import read_one_per_line_log
from drivers.process import limit_blas_threads
from drivers.recording import Recording
from hil.identify.urdf import (
    ENERGY_VELOCITY_HALF_WINDOW,
    identify_energy,
    identify_torque,
    inside_edges,
    smoothed_positions,
    smoothing_cutoff_hz,
    torque_nrmse,
    torque_over_intervals,
    velocity_noise_ratio,
)
from hil.model.regressors import data_bandwidth, excitation_bandwidth, iter_rows
from hil.model.urdf import UrdfArmModel

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import gaz_reference  # tests/gaz_reference.py


def main() -> int:
    limit_blas_threads()
    if not gaz_reference.available():
        print(f"Panda data of Gaz et al. not found at {gaz_reference.MODEL_DIR}: skipped")
        return 0
    rec = read_one_per_line_log(gaz_reference.LOG_DIR)
    model = UrdfArmModel.from_profile("panda")
    cutoff = smoothing_cutoff_hz(rec)
    torque = identify_torque(model, rec, cutoff_hz=cutoff)
    split = torque.fit_until_s
    held = torque.rows.select(torque.rows.t >= split)
    lam = data_bandwidth(rec.q, rec.t)
    ratio = velocity_noise_ratio(rec, cutoff)
    print(f"1. raw velocity noise / RMS per joint: {np.round(ratio, 3).tolist()}")

    t = rec.t
    keep = inside_edges(t)
    positions = {"raw": rec.q[keep], "smoothed": smoothed_positions(rec, cutoff)(t[keep])}
    tau = torque_over_intervals(rec)[keep]

    def rows(scheme: str, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        chunks = list(iter_rows(scheme, q, tau, t[keep], lam, model,
                                half_window=ENERGY_VELOCITY_HALF_WINDOW))  # fmt: skip
        return (np.concatenate([c.y[:, 0] for c in chunks]),
                np.concatenate([c.Psi[:, 0] for c in chunks]),
                np.concatenate([c.t for c in chunks]))  # fmt: skip

    print("2. rows' RMS unexplained by the torque scheme's θ / by their own least squares; "
          "that least squares' held-out torque NRMSE per joint")  # fmt: skip
    saved = {}
    for kind, q in positions.items():
        for scheme in ("supplied_energy", "filtered_power"):
            y, Psi, ty = rows(scheme, q)
            fit = ty < split
            own = np.linalg.lstsq(Psi[fit], y[fit], rcond=None)[0]
            rms = np.sqrt(np.mean(y[fit] ** 2))
            by_torque = np.sqrt(np.mean((y[fit] - Psi[fit] @ torque.theta) ** 2)) / rms
            by_own = np.sqrt(np.mean((y[fit] - Psi[fit] @ own) ** 2)) / rms
            nrmse = torque_nrmse(own, held)
            print(f"   {scheme:16s} {kind:8s}: {by_torque:6.1%} / {by_own:6.2%}; "
                  f"{np.round(nrmse, 2).tolist()}")  # fmt: skip
            saved[scheme, kind] = (y, Psi, ty)

    y, Psi, ty = saved["supplied_energy", "raw"]
    step = float(np.median(np.diff(ty)))
    print("3. supplied energy over windows of W s (raw positions): held-out torque NRMSE")
    for window in (0.05, 0.25, 1.0, 2.0):
        n = max(1, round(window / step))
        start = np.arange(0, len(y) - n, max(1, n // 4))
        yw, Pw, tw = y[start + n] - y[start], Psi[start + n] - Psi[start], ty[start + n]
        own = np.linalg.lstsq(Pw[tw < split], yw[tw < split], rcond=None)[0]
        print(f"   W = {window:4.2f} s: {np.round(torque_nrmse(own, held), 2).tolist()}")

    print("4. other tries: held-out torque NRMSE per joint")
    friction = list(model.friction_columns)
    rigid = [i for i in range(model.n_params) if i not in friction]
    for scheme in ("supplied_energy", "filtered_power"):
        y, Psi, ty = saved[scheme, "raw"]
        fit = ty < split
        theta = torque.theta.copy()  # rigid body held at the torque scheme's, friction fitted
        theta[friction] = np.linalg.lstsq(
            Psi[fit][:, friction], y[fit] - Psi[fit][:, rigid] @ theta[rigid], rcond=None
        )[0]
        print(f"   {scheme:16s} raw, rigid body at the torque scheme's: "
              f"{np.round(torque_nrmse(theta, held), 2).tolist()}")  # fmt: skip
        res = identify_energy(model, rec, scheme, consistent=True)  # raw positions
        print(f"   {scheme:16s} raw, --consistent: "
              f"{np.round(torque_nrmse(res.theta, held), 2).tolist()}")  # fmt: skip
    fresh = np.r_[True, np.any(rec.q[1:] != rec.q[:-1], axis=1)]  # stale: q repeated
    cleaned = Recording.from_arrays(rec.t[fresh], rec.q[fresh], rec.tau[fresh], source="fresh")
    for scheme in ("supplied_energy", "filtered_power"):
        res = identify_energy(model, cleaned, scheme)
        print(f"   {scheme:16s} raw, {np.sum(~fresh)} stale samples dropped: "
              f"{np.round(torque_nrmse(res.theta, held), 2).tolist()}")  # fmt: skip

    span = split - t[0]
    fit_rows = torque.rows.t < split
    print(f"5. independent numbers in {span:.2f} s (2BT) against {model.n_params} parameters:")
    for scheme in ("supplied_energy", "filtered_power"):
        y, _, ty = saved[scheme, "smoothed"]
        b = excitation_bandwidth(y[ty < split][:, None], ty[ty < split]) / (2 * np.pi)
        print(f"   {scheme:16s} rows: B = {b:.2f} Hz, 2BT = {2 * b * span:.0f}")
    bands = [
        excitation_bandwidth(torque.rows.tau[fit_rows][:, [j]], torque.rows.t[fit_rows])
        / (2 * np.pi)
        for j in range(model.n_joints)
    ]
    print(f"   torque rows, 7 joints: B = {np.round(bands, 2).tolist()} Hz, "
          f"2BT summed = {sum(2 * b * span for b in bands):.0f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
