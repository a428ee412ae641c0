"""The docs/real-data.md tables: identification from one DFKI recording, validated on every
other recording of the same design, side by side with the owners' published model (the shipped
profile), same rows and same filter for both.

    python tests/benchmarks/real_data_table.py [--records DIR] [--torque commanded|measured]
        [--instruments target]

For each design (A.0: the six 2022-08-15 sys_id trajectories, profile dfki-a0; C.0: the seven
2022-09-14 ones, profile dfki-c0) and each recording as the fit: θ of the profile's model
(hil.identify.schemes.identify_model, λ from the data), then on every other recording of the design
the
held-out torque NRMSE of the identified θ and of the profile's θ (hil.identify.schemes.
torque_prediction_error at the fit's λ) and the restarted 0.1 s simulation (hil.model.openloop.
simulate_windows). A joint held at zero torque (C.0's passive-joint trajectories) has no
torque NRMSE (its spread is zero): means are over the joints and recordings where it is
defined. Prints one row per fit recording (means over its held-out recordings) and
the identified parameters and rotor inertia of each fit. About a minute on the dev VM.

``--instruments target``: each fit by instrumental variables on the recording's target
positions as well (hil.identify.iv.identify_torque_iv on the same rows, the fit's λ; what
`hil identify --instruments target` does), its held-out torque NRMSE beside least squares' on
the same held-out recordings; a recording IV refuses (no target positions, a reference that
does not track) is listed with the one-line reason.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from drivers.recording import read_signals
from hil.identify.iv import identify_torque_iv
from hil.identify.schemes import identify_model, torque_prediction_error
from hil.model.closed_form import ArmModel
from hil.model.openloop import simulate_windows
from profiles.robot import load_robot

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from realdata import realdata  # tests/realdata.py

RECORDS = realdata("dfki-double-pendulum") / "records"
DESIGNS = {
    "A.0": ("dfki-a0", "design_A.0__20220815__sys_id__trajectory_0*.csv"),
    "C.0": ("dfki-c0", "design_C.0__20220914__sys_id__trajectory_0*.csv"),
}
WINDOW_S = 0.1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", default=str(RECORDS))
    ap.add_argument("--torque", default="commanded")
    ap.add_argument("--terms", default=None, help="override the profile's model terms")
    ap.add_argument("--instruments", choices=("none", "target"), default="none")
    args = ap.parse_args()
    t_start = time.perf_counter()
    for design, (robot, pattern) in DESIGNS.items():
        files = sorted(Path(args.records).glob(pattern))
        if len(files) < 2:
            print(f"{design}: fewer than two recordings under {args.records}; skipped")
            continue
        profile = load_robot(robot)
        model = ArmModel(profile.terms)
        if args.terms is not None:
            model = ArmModel(tuple(t for t in args.terms.split(",") if t))
        ref = np.zeros(model.n_params)
        ref[:9] = profile.theta()[:9]
        profile_model = ArmModel(profile.terms)
        for term in model.terms:
            if term in profile.terms:
                ref[model.term_columns(term)] = profile.theta()[profile_model.term_columns(term)]
        recs = [read_signals(f, fmt="dfki", torque=args.torque) for f in files]
        print(f"\n== design {design}: profile {robot} ({profile.reference}); model terms: "
              f"{', '.join(model.terms) or 'none'}; torque {args.torque}")  # fmt: skip
        print(f"{'fit recording':16s}{'λ':>6s}  held-out torque NRMSE % (j1, j2)"
              f"{'':6s}held-out 0.1 s simulation % (j1, j2)")  # fmt: skip
        print(f"{'':22s}{'identified':>16s}{'profile':>16s}{'identified':>18s}{'profile':>16s}")
        wins = total = 0
        fits = []
        iv_wins, iv_total, iv_refused = 0, 0, []
        for i, rec in enumerate(recs):
            res = identify_model(rec.t, rec.q, rec.tau, model)
            fits.append(res)
            iv_theta = None
            if args.instruments == "target":
                try:
                    iv_theta = identify_torque_iv(model, rec, held_out=0.0, lam=res.lam).theta
                except ValueError as exc:
                    iv_refused.append(f"{files[i].name}: {str(exc).split(': ', 1)[-1]}")
            te, tp, se, sp, ti = [], [], [], [], []
            for k, other in enumerate(recs):
                if k == i:
                    continue
                a = torque_prediction_error(res.theta, model, other.t, other.q, other.tau, res.lam)
                if iv_theta is not None:
                    c = torque_prediction_error(
                        iv_theta, model, other.t, other.q, other.tau, res.lam
                    )
                    ti.append(c)
                    if np.isfinite(np.nanmean(c)):
                        iv_wins += int(np.nanmean(c) < np.nanmean(a))
                        iv_total += 1
                b = torque_prediction_error(ref, model, other.t, other.q, other.tau, res.lam)
                te.append(a)
                tp.append(b)
                if np.isfinite(np.nanmean(a)):  # a passive joint (τ ≡ 0) has no NRMSE
                    wins += int(np.nanmean(a) < np.nanmean(b))
                    total += 1
                for th, acc in ((res.theta, se), (ref, sp)):
                    sim = simulate_windows(
                        model, th, other.t, other.q, other.tau, window_s=WINDOW_S
                    )
                    acc.append(sim["position_nrmse"])
            te, tp, se, sp = (100 * np.nanmean(x, axis=0) for x in (te, tp, se, sp))
            print(
                f"{files[i].stem[-13:]:16s}{res.lam:6.1f}"
                f"{te[0]:9.1f}{te[1]:7.1f}{tp[0]:9.1f}{tp[1]:7.1f}"
                f"{se[0]:11.1f}{se[1]:7.1f}{sp[0]:9.1f}{sp[1]:7.1f}"
            )
            if ti:
                iv = 100 * np.nanmean(ti, axis=0)
                print(f"{'  IV on the target':22s}{iv[0]:9.1f}{iv[1]:7.1f}")
        print(f"identified θ predicts held-out torque better (mean of the two joints) than the "
              f"profile in {wins} of {total} fit/held-out pairs")  # fmt: skip
        if args.instruments == "target":
            print(f"IV predicts held-out torque better than least squares (mean of the two "
                  f"joints) in {iv_wins} of {iv_total} fit/held-out pairs; IV refused on "
                  f"{len(iv_refused)} of {len(recs)} fit recordings"
                  + "".join(f"\n  {line}" for line in iv_refused))  # fmt: skip
        names = model.names
        print("\nparameters (identified from each recording; '?' = not determined by it, "
              "blocked-bootstrap SE > 50 %):")  # fmt: skip
        print(f"{'':14s}{'profile':>10s}" + "".join(f"{f.stem[-2:]:>10s}" for f in files))
        for j, name in enumerate(names):
            cells = "".join(
                f"{r.theta[j]:>9.4g}{'' if r.identified[j] else '?'}"
                + (" " if r.identified[j] else "")
                for r in fits
            )
            print(f"{name:14s}{ref[j]:>10.4g}{cells}")
        if profile.rotor is not None and "rotor_inertia" in model.terms:
            col = model.term_columns("rotor_inertia").start
            irs = [profile.rotor.inertia_from_theta(r.theta[col]) for r in fits]
            print(
                f"rotor inertia Ir (kg m²): identified {', '.join(f'{x:.3g}' for x in irs)}; "
                f"median {np.median(irs):.3g}; profile {profile.rotor.inertia_kgm2:.3g}; "
                f"datasheet {profile.rotor.datasheet_inertia_kgm2:.3g}"
            )
        unphysical = [f.stem[-2:] for f, r in zip(files, fits, strict=True)
                      if not r.ls_consistency["consistent"]]  # fmt: skip
        print(f"plain least squares not physical (bounded fit reported) for: "
              f"{', '.join(unphysical) or 'none'}")  # fmt: skip
    print(f"\n({time.perf_counter() - t_start:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
