"""Plots of tracking runs, in the layout of Khosla & Kanade (1987) Figs. 7-22.

Per run: ``tracking.png`` (reference and measured position and velocity per joint, Figs. 7-10),
``errors.png`` (position and velocity tracking errors per joint, Figs. 11-16) and
``torque_split.png`` (the sent torque and its parts per joint; for CT the inertial,
Coriolis/centrifugal, gravity and friction parts of Figs. 20-22). Per comparison:
``errors_<params>.png`` (every scheme's errors, one row per scheme, each on its own scale) and
``torques_<params>.png`` (applied torques per scheme, Figs. 17-19).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from drivers.recording import Recording, read_signals
from hil.control.signals import central_velocity, sample_times
from hil.control.trajectory import PointToPoint
from plots.layout import fixed_margins

PART_COLORS = {
    "inertial": "tab:blue",
    "coriolis": "tab:orange",
    "gravity": "tab:green",
    "friction": "tab:purple",
    "feedback": "tab:gray",
}


def read_control_log(path: str | Path) -> dict[str, np.ndarray]:
    """control.csv as columns (a torn last line is dropped)."""
    lines = Path(path).read_text().splitlines()
    header = lines[0].split(",")
    rows = [ln.split(",") for ln in lines[1:]]
    rows = [r for r in rows if len(r) == len(header)]
    data = np.array(rows, dtype=float).reshape(len(rows), len(header))
    return {name: data[:, j] for j, name in enumerate(header)}


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _errors(rec: Recording, trajectory: PointToPoint) -> tuple[np.ndarray, ...]:
    """Sample times, reference, measured velocity and errors, as hil.control.tracking measures
    them."""
    t = sample_times(rec)
    qd, dqd, _ = trajectory.at(t)
    dq = central_velocity(t, rec.q)
    return t, qd, dqd, dq, qd - rec.q, dqd - dq


def plot_run(run_dir: str | Path, trajectory: PointToPoint, scheme: str, label: str) -> list[Path]:
    """tracking.png, errors.png, torque_split.png of one run directory."""
    plt = _pyplot()
    run_dir = Path(run_dir)
    rec = read_signals(run_dir)
    q = rec.q
    nj = q.shape[1]
    width = 5.5 * nj
    t, qd, dqd, dq, e, ev = _errors(rec, trajectory)
    name = f"{scheme.upper()} ({label} parameters)"
    paths = []

    fig, axes = plt.subplots(2, nj, figsize=(width, 6), sharex=True, squeeze=False)
    for j in range(nj):
        axes[0, j].plot(t, qd[:, j], "k--", lw=1.0, label="reference")
        axes[0, j].plot(t, q[:, j], lw=1.2, label="measured")
        axes[0, j].set_ylabel(f"q{j + 1} [rad]")
        axes[1, j].plot(t, dqd[:, j], "k--", lw=1.0, label="reference")
        axes[1, j].plot(t, dq[:, j], lw=1.0, label="measured (central difference)")
        axes[1, j].set_ylabel(f"q̇{j + 1} [rad/s]")
        axes[1, j].set_xlabel("t [s]")
        for ax in axes[:, j]:
            ax.grid(True, alpha=0.3)
            ax.legend(loc="best", fontsize=7)
    fig.suptitle(f"Position and velocity tracking, {name}")
    paths.append(_save(fig, run_dir / "tracking.png", plt))

    fig, axes = plt.subplots(2, nj, figsize=(width, 6), sharex=True, squeeze=False)
    for j in range(nj):
        axes[0, j].plot(t, e[:, j], lw=1.0, color="tab:red")
        axes[0, j].set_ylabel(f"e{j + 1} = q{j + 1}d − q{j + 1} [rad]")
        axes[1, j].plot(t, ev[:, j], lw=0.8, color="tab:red")
        axes[1, j].set_ylabel(f"ė{j + 1} [rad/s]")
        axes[1, j].set_xlabel("t [s]")
        for ax in axes[:, j]:
            ax.grid(True, alpha=0.3)
    fig.suptitle(f"Tracking errors, {name}")
    paths.append(_save(fig, run_dir / "errors.png", plt))

    control_csv = run_dir / "control.csv"
    if control_csv.is_file():
        log = read_control_log(control_csv)
        parts = [p for p in PART_COLORS if f"{p}1" in log]
        tl = log["t"]
        fig, axes = plt.subplots(1, nj, figsize=(width, 4), sharex=True, squeeze=False)
        for j in range(nj):
            ax = axes[0, j]
            ax.plot(t, rec.tau[:, j], color="k", lw=1.2, label="sent (quantized)")
            for part in parts:
                ax.plot(tl, log[f"{part}{j + 1}"], lw=0.9, color=PART_COLORS[part], label=part)
            ax.set_ylabel(f"τ{j + 1} [Nm]")
            ax.set_xlabel("t [s]")
            ax.grid(True, alpha=0.3)
            ax.legend(loc="best", fontsize=7)
        fig.suptitle(f"Applied torque and its parts, {name}")
        paths.append(_save(fig, run_dir / "torque_split.png", plt))
    return paths


def plot_comparison(
    out_dir: str | Path,
    runs: dict[str, dict[str, Any]],
    trajectory: PointToPoint,
    label: str,
    file_label: str,
) -> list[Path]:
    """errors_<label>.png and torques_<label>.png over every scheme of one parameter set."""
    plt = _pyplot()
    out_dir = Path(out_dir)
    loaded = {}
    for scheme, run in runs.items():
        if run.get("rows", 0) >= 2:
            loaded[scheme] = read_signals(run["out_dir"])
    if not loaded:
        return []
    paths = []
    n = len(loaded)
    nj = next(iter(loaded.values())).q.shape[1]
    # a row per scheme (position errors of every joint, then velocity errors); with more
    # joints than schemes a row per joint instead (each scheme's two errors side by side), so
    # an arm of 6 joints is not one strip 12 panels wide
    by_joint = nj > n
    rows, cols = (nj, 2 * n) if by_joint else (n, 2 * nj)
    fig, axes = plt.subplots(
        rows, cols, figsize=(3.75 * cols, 2.2 * rows + 0.8), sharex=True, squeeze=False
    )

    def panel(i: int, j: int, velocity: int) -> Any:
        return axes[j, 2 * i + velocity] if by_joint else axes[i, nj * velocity + j]

    for i, (scheme, rec) in enumerate(loaded.items()):
        t, _, _, _, e, ev = _errors(rec, trajectory)
        for j in range(nj):
            ax = panel(i, j, 0)
            ax.plot(t, e[:, j], lw=0.9, color="tab:red")
            ax.set_title(f"{scheme.upper()}: position error, joint {j + 1}", fontsize=8)
            ax.set_ylabel("rad", fontsize=8)
            ax = panel(i, j, 1)
            ax.plot(t, ev[:, j], lw=0.7, color="tab:blue")
            ax.set_title(f"{scheme.upper()}: velocity error, joint {j + 1}", fontsize=8)
            ax.set_ylabel("rad/s", fontsize=8)
    for ax in axes.flat:
        ax.grid(True, alpha=0.3)
        ax.tick_params(labelsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]", fontsize=8)
    fig.suptitle(f"Tracking errors per scheme ({label} parameters); each panel on its own scale")
    paths.append(_save(fig, out_dir / f"errors_{file_label}.png", plt))

    fig, axes = plt.subplots(1, nj, figsize=(6 * nj, 4), sharex=True, squeeze=False)
    for scheme, rec in loaded.items():
        for j in range(nj):
            axes[0, j].plot(rec.t, rec.tau[:, j], lw=0.9, label=scheme.upper())
    for j in range(nj):
        axes[0, j].set_ylabel(f"τ{j + 1} [Nm]")
        axes[0, j].set_xlabel("t [s]")
        axes[0, j].grid(True, alpha=0.3)
        axes[0, j].legend(loc="best", fontsize=8)
    fig.suptitle(f"Applied torques ({label} parameters)")
    paths.append(_save(fig, out_dir / f"torques_{file_label}.png", plt))
    return paths


def _save(fig: Any, path: Path, plt: Any) -> Path:
    fixed_margins(fig)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
