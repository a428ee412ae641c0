"""Recordings of an n-joint arm with a concealed effect, made from a recording of the
effect-free arm (the n-joint virtual plant has no effects of its own yet).

The effect-free arm was driven by applied torques τ_a; an arm with the effect that applied the
same τ_a would have been commanded τ with τ_a = effect(τ), and would read its encoders through
the effect. Rewriting the recording's command (or angle) columns so gives that arm's recording:

- ``gain`` r on joint j: τ_j = τ_a,j / (1 + r) (exact: held torques stay held);
- ``angle`` δ on joint j: reading q_j + δ (exact);
- ``offset`` c on joint j: τ_j = τ_a,j − c (exact);
- ``cogging`` A sin(n q_j + φ) on joint j: τ_j = τ_a,j − A sin(n q_j,k + φ) at each sample, the
  cogging torque held over the interval (approximate: a real rotor's varies within it).

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
