"""Recordings of an n-joint arm with a concealed effect, made from a recording of the
effect-free arm (the n-joint virtual plant has no effects of its own yet).

The effect-free arm was driven by applied torques τ_a; an arm with the effect that applied the
same τ_a would have been commanded τ with τ_a = effect(τ), and would read its encoders through
the effect. Rewriting the recording's command (or angle) columns so gives that arm's recording:

- ``gain`` r on joint j: τ_j = τ_a,j / (1 + r) (exact: held torques stay held);
- ``angle`` δ on joint j: reading q_j + δ (exact);
- ``offset`` c on joint j: τ_j = τ_a,j − c (exact);
- ``cogging`` A sin(n q_j + φ) on joint j: τ_j = τ_a,j − A sin(n q_j,k + φ) at each sample, the
  cogging torque held over the interval (approximate: a real rotor's varies within it);
- a ``payload`` (:func:`with_payload`): a point mass m at c on the last body, its torque
  (Pinocchio's regressor of the last body at the point mass's ten parameters) at the recorded
  motion (Savitzky–Golay velocities and accelerations) added to every command (approximate in
  the same way).

Used by tests/test_diagnose_urdf.py and tests/benchmarks/diagnose_urdf_catalogue.py.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path


def with_effect(src: Path, out: Path, kind: str, joint: int, size: float, **extra: float) -> Path:
    """Copy the run directory ``src`` to ``out`` with the effect ``kind`` of ``size`` on
    ``joint`` (1-based) written into its signals.csv (module doc); ``extra``: cogging's
    ``periods_per_rev`` and ``phase_rad``."""
    shutil.copytree(src, out)
    lines = (src / "signals.csv").read_text().splitlines()
    header = lines[0].split(",")
    tau, q = header.index(f"tau{joint}"), header.index(f"q{joint}")
    rows = [lines[0]]
    for line in lines[1:]:
        f = line.split(",")
        if kind == "gain":
            f[tau] = repr(float(f[tau]) / (1.0 + size))
        elif kind == "angle":
            f[q] = repr(float(f[q]) + size)
        elif kind == "offset":
            f[tau] = repr(float(f[tau]) - size)
        elif kind == "cogging":
            n, phase = extra["periods_per_rev"], extra.get("phase_rad", 0.0)
            f[tau] = repr(float(f[tau]) - size * math.sin(n * float(f[q]) + phase))
        else:
            raise ValueError(f"unknown effect {kind!r}")
        rows.append(",".join(f))
    (out / "signals.csv").write_text("\n".join(rows) + "\n")
    return out


def with_payload(src: Path, out: Path, robot: str, mass_kg: float, centre_m: tuple) -> Path:
    """Copy the run directory ``src`` to ``out`` with a point mass ``mass_kg`` at ``centre_m``
    (the last body's frame) on ``robot``'s last body written into its torque columns."""
    import numpy as np
    from scipy.signal import savgol_filter

    from hil.diagnose.effects.payload import point_mass_standard
    from hil.model.urdf import UrdfArmModel

    shutil.copytree(src, out)
    lines = (src / "signals.csv").read_text().splitlines()
    header = lines[0].split(",")
    data = np.array([[float(x) for x in line.split(",")] for line in lines[1:]])
    model = UrdfArmModel.from_profile(robot)
    n = model.n_joints
    qi = [header.index(f"q{j}") for j in range(1, n + 1)]
    ti = [header.index(f"tau{j}") for j in range(1, n + 1)]
    h = float(np.median(np.diff(data[:, header.index("t")])))
    q = data[:, qi]
    dq = savgol_filter(q, 15, 3, deriv=1, delta=h, axis=0)
    ddq = savgol_filter(q, 15, 3, deriv=2, delta=h, axis=0)
    Y = model.standard_regressor(q, dq, ddq)[..., 10 * (n - 1) : 10 * n]
    data[:, ti] += Y @ point_mass_standard(mass_kg, np.asarray(centre_m, float))
    rows = [lines[0]] + [",".join(repr(float(x)) for x in row) for row in data]
    (out / "signals.csv").write_text("\n".join(rows) + "\n")
    return out
