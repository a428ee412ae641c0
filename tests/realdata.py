"""Where the real recordings of ../shared/realdata are: beside the repository (or beside a folder
holding it, for a git worktree), or under $DDBENCH_REALDATA. Tests that need them skip with a
message when they are absent (the Panda data is GPL-3 and never enters this tree)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np


def realdata(name: str) -> Path:
    """``shared/realdata/<name>``, found as the module docstring says (may not exist)."""
    if os.environ.get("DDBENCH_REALDATA"):
        return Path(os.environ["DDBENCH_REALDATA"]) / name
    repo = Path(__file__).resolve().parents[1]
    for parent in repo.parents:
        if (parent / "shared" / "realdata" / name).is_dir():
            return parent / "shared" / "realdata" / name
    return repo.parent / "shared" / "realdata" / name


KUKA = "kuka-lwr4-flobaroid"


def kuka_columns(run: int) -> tuple[list[str], np.ndarray]:
    """``measurements_<run>.npz`` of the KUKA LWR4+ as the standard CSV's columns: the header
    (t, q1..q7, tau1..tau7) and the (rows, 15) array, t from 0 (what :func:`kuka_csv` writes)."""
    import numpy as np

    data = np.load(realdata(KUKA) / f"measurements_{run}.npz")
    q, tau = data["positions"], data["torques"]
    n = q.shape[1]
    names = ["t", *(f"q{j + 1}" for j in range(n)), *(f"tau{j + 1}" for j in range(n))]
    return names, np.column_stack([data["times"] - data["times"][0], q, tau])


def kuka_csv(run: int, folder: str | Path, *, targets: bool = False) -> Path:
    """``measurements_<run>.npz`` of the KUKA LWR4+ (LGPL-3, read from ../shared only) written as
    this project's standard CSV (t from 0, q1..q7, tau1..tau7) in ``folder``, a temporary
    directory: the data never enters the tree. The owners' velocities and accelerations are left
    out (hil derives its own).

    ``targets``: also q_target1..7, the files' ``target_positions`` × 180/π. As stored they are
    the reference in rad multiplied by π/180 once more (a degree conversion applied twice): the
    ratio of the positions' extremes to theirs is 57.28–57.32 (180/π = 57.296) on all 14
    joint-runs; so converted, the measured positions follow them 1.406 s (run 1) and 0.709 s
    (run 3) later within 1.2–5.6 mrad RMS (docs/real-data.md, "Closed loop").
    ``target_velocities`` is not written: it is the derivative of the targets on run 3 but twice
    it on run 1, and ``target_accelerations`` is exactly −``target_positions``."""
    import numpy as np

    names, data = kuka_columns(run)
    n = (len(names) - 1) // 2
    arrays = [data]
    if targets:
        names += [f"q_target{j + 1}" for j in range(n)]
        arrays.append(np.load(realdata(KUKA) / f"measurements_{run}.npz")["target_positions"]
                      * (180.0 / np.pi))  # fmt: skip
    path = Path(folder) / f"kuka_measurements_{run}.csv"
    np.savetxt(path, np.column_stack(arrays), delimiter=",", header=",".join(names), comments="",
               fmt="%.10g")  # fmt: skip
    return path
