"""The identification targets of the 6-DOF ur5e arm (profiles/robots/ur5e.toml), shared by the
tests that identify it from a simulation and from a bus recording (tests/test_ur5e.py).

The CICESE targets of docs/identification.md (inertial and gravity parameters within 2 %,
viscous and Coulomb coefficients within 10 %) are relative errors; they mean something for a
parameter that carries part of the arm's torque, not for the 54 base parameters of a 6-DOF arm
of which many are products of inertia or centre-of-mass offsets near zero (nominal 1e-6 kg m²).
So, as for cicese3, whose centre-of-mass offsets (nominal 0) are judged by their torque (within
1 % of the joint's gravity parameter):

- a base parameter that carries at least ``SIGNIFICANT`` (5 %) of some joint's torque along the
  recording (RMS of Y_k β_k over RMS of τ_j) meets the relative target of its kind;
- every other parameter's error moves no joint's torque by more than ``SMALL_ERROR`` (1 %) of
  that joint's RMS torque.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from drivers.recording import Recording, read_signals
from hil.identify.urdf import regression_rows
from hil.model.regressors import SCHEMES
from hil.model.urdf import UrdfArmModel

SIGNIFICANT = 0.05  # share of a joint's RMS torque above which the relative targets apply
SMALL_ERROR = 0.01  # torque error of any other parameter, share of the joint's RMS torque
INERTIAL_TOLERANCE = 0.02  # CICESE targets (docs/identification.md)
FRICTION_TOLERANCE = 0.10


def torque_recording(run: Path) -> Recording:
    """The run's recording (drivers.recording.read_signals), its torques held over each period."""
    rec = read_signals(run)
    assert rec.torque_held, f"{run}: not this bench's recording of commanded torques"
    return rec


def torque_shares(model: UrdfArmModel, rec: Recording, delta: np.ndarray) -> np.ndarray:
    """(p, n): RMS over the recording of Y_k δ_k on joint j, over the RMS of τ_j."""
    rows = regression_rows(model, rec)
    per_parameter = np.sqrt(np.mean((rows.Y * delta) ** 2, axis=0)).T  # (p, n)
    return per_parameter / np.sqrt(np.mean(rows.tau**2, axis=0))


def check_targets(
    report: dict[str, Any], theta: list[float], shares: np.ndarray, model: UrdfArmModel, rec
) -> list[str]:
    """The parameters of one θ that miss the targets (empty when all meet them)."""
    nominal = np.array([x["nominal"] for x in report["parameters"]])
    theta = np.asarray(theta)
    error_shares = torque_shares(model, rec, theta - nominal)
    misses = []
    for k, x in enumerate(report["parameters"]):
        meaning = x["meaning"]
        if shares[k].max() >= SIGNIFICANT:
            friction = meaning.startswith(("fv", "fc"))
            tolerance = FRICTION_TOLERANCE if friction else INERTIAL_TOLERANCE
            if meaning.startswith("fo"):  # an offset: judged by its torque, as below
                tolerance = None
            if tolerance is not None:
                if abs(theta[k] - nominal[k]) > tolerance * abs(nominal[k]):
                    misses.append(f"{meaning}: {theta[k]:.6g} vs {nominal[k]:.6g}")
                continue
        if error_shares[k].max() > SMALL_ERROR:
            misses.append(f"{meaning}: error {error_shares[k].max():.4f} of a joint's torque")
    return misses


def check_ur5e_identified(
    report: dict[str, Any], run: Path, schemes: tuple[str, ...] = SCHEMES
) -> dict[str, list[str]]:
    """Every scheme's θ of ``identify.json`` (all three run) against the targets; returns the
    misses per scheme, and asserts the held-out torque is predicted as well as by the true
    parameters (within 0.01 NRMSE per joint) and the fit is physically consistent."""
    assert sorted(report["schemes"]) == sorted(SCHEMES)
    model = UrdfArmModel.from_profile("ur5e")
    rec = torque_recording(run)
    nominal = np.array([x["nominal"] for x in report["parameters"]])
    shares = torque_shares(model, rec, nominal)
    true = report["validation"]["torque_nrmse_nominal"]
    misses = {}
    for scheme in schemes:
        entry = report["schemes"][scheme]
        fit = entry["validation"]["torque_nrmse"]
        assert all(a < b + 0.01 for a, b in zip(fit, true, strict=True)), (scheme, fit, true)
        assert entry["physical_consistency"]["consistent"], scheme
        misses[scheme] = check_targets(report, entry["theta"], shares, model, rec)
    return misses


def main() -> int:
    """``python tests/ur5e_targets.py RUN IDENTIFY_JSON``: every scheme's misses (docs/urdf.md)."""
    import json
    import sys

    run, report = Path(sys.argv[1]), json.loads(Path(sys.argv[2]).read_text())
    for scheme, missed in check_ur5e_identified(report, run).items():
        print(f"{scheme}: {len(missed)} missed")
        for line in missed:
            print(f"  {line}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
