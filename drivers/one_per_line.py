"""The one-number-a-line log layout of Gaz et al. (2019) (the Franka Emika Panda's
``rbt_log/exciting_traj_{time,positions,torques}.txt``: one number a line, the ``n_joints``
values of a sample on consecutive lines), read into the standard recording
(:class:`drivers.recording.Recording`, the one every analysis reads; docs/urdf.md).

Imports :mod:`drivers.recording` and numpy.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from drivers.recording import Recording


def read_one_per_line_log(
    folder: str | Path, *, n_joints: int = 7, prefix: str = "exciting_traj"
) -> Recording:
    """Read ``<prefix>_{time,positions,torques}.txt`` of ``folder`` (one number a line; the
    position and torque files hold the ``n_joints`` values of a sample on consecutive lines).
    Raises ValueError with one line naming the file for a length mismatch or bad time stamps."""
    folder = Path(folder)

    def load(kind: str) -> np.ndarray:
        path = folder / f"{prefix}_{kind}.txt"
        try:
            return np.loadtxt(path, dtype=float, ndmin=1)
        except (OSError, ValueError) as exc:
            raise ValueError(f"{path}: cannot read: {exc}") from None

    t = load("time")
    out = {}
    for kind in ("positions", "torques"):
        x = load(kind)
        if x.size != t.size * n_joints:
            raise ValueError(
                f"{folder / f'{prefix}_{kind}.txt'}: {x.size} numbers, expected "
                f"{t.size} samples x {n_joints} joints = {t.size * n_joints}"
            )
        out[kind] = x.reshape(t.size, n_joints)
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise ValueError(f"{folder / f'{prefix}_time.txt'}: time stamps not strictly increasing")
    return Recording.from_arrays(t, out["positions"], out["torques"], source=folder)


__all__ = ["read_one_per_line_log"]
