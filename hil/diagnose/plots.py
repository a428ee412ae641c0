"""Plots of a diagnosis: where the nominal residual lives, the before/after fit, and the
change since the user's model with what the findings make of it."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from hil.diagnose.pipeline import DiagnosisResult
from hil.diagnose.report import percent


def broken_at_gaps(t: np.ndarray) -> np.ndarray:
    """``t`` with NaN where the next sample is more than 3 median steps later or earlier (a
    segment the diagnosis did not simulate, another recording), so a line plot breaks there
    instead of drawing a line across."""
    t = np.asarray(t, dtype=float).copy()
    if len(t) < 3:
        return t
    dt = np.diff(t)
    step = np.median(np.abs(dt))
    jump = (dt > 3 * step) | (dt < 0)
    t[1:][jump] = np.nan
    return t


def plot_diagnosis(result: DiagnosisResult, out: Path) -> list[Path]:
    """residual.png (against time, velocity and position, per joint) and fit.png (held-out
    torque and simulated position, before and after)."""
    loc = result.arrays["location"]
    paths = []
    n = loc["residual"].shape[1]  # joints
    fig, axes = plt.subplots(n, 3, figsize=(14, 3.5 * n), squeeze=False)
    for j in range(n):
        ok = loc["usable"][:, j]
        e = loc["residual"][ok, j]
        axes[j, 0].plot(loc["t"][ok], e, ".", ms=1)
        axes[j, 0].set(
            xlabel="t [s] from each recording's start", ylabel=f"joint {j + 1} residual [Nm]"
        )
        axes[j, 1].plot(loc["v"][ok, j], e, ".", ms=1, alpha=0.4)
        axes[j, 1].set(xlabel=f"q̇{j + 1} [rad/s]")
        axes[j, 2].plot(loc["q"][ok, j], e, ".", ms=1, alpha=0.4)
        axes[j, 2].set(xlabel=f"q{j + 1} [rad]")
        for ax in axes[j]:
            ax.grid(alpha=0.3)
    found = (
        ", ".join(
            f"{f['effect']} (joint {f['joint'] or ('both' if n == 2 else 'all')})"
            for f in result.document["findings"]
        )
        or "none"
    )
    fig.suptitle(
        f"Nominal {'9-parameter ' if n == 2 else ''}model: torque residual F[τ] − Ψθ̂. "
        f"Findings: {found}",
        fontsize=10,
    )
    fig.tight_layout()
    paths.append(out / "residual.png")
    fig.savefig(paths[-1], dpi=90)
    plt.close(fig)

    fig, axes = plt.subplots(n, 2, figsize=(14, 3.5 * n), sharex="col", squeeze=False)
    test = result.arrays["test"]
    fit = result.document["fit"]
    idx = np.flatnonzero(test)
    t_test = broken_at_gaps(loc["t"][idx])  # held-out spans apart, as the simulations beside
    for j in range(n):
        ax = axes[j, 0]
        # rows the model cannot explain (a joint at rest or reversing) are gaps, not lines
        gap = np.where(loc["usable"][idx, j], 0.0, np.nan)
        for name, style in (("before", "-"), ("after", "-")):
            err = result.arrays["torque"][idx, j] - result.arrays[f"pred_{name}"][idx, j]
            ax.plot(
                t_test,
                err + gap,
                style,
                lw=0.6,
                label=f"{name} ({percent(fit[name]['torque_nrmse'][j])})",
            )
        ax.set(ylabel=f"joint {j + 1} torque error [Nm]", xlabel="t [s]")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
        sim = result.arrays["simulation"]
        ax = axes[j, 1]
        if sim:
            t_sim = broken_at_gaps(sim["t"])
            ax.plot(t_sim, sim["q"][:, j], "k", lw=1, label="recorded")
            for name, style in (("before", "-"), ("after", "--")):
                if name in sim:  # a fit that is not physical is not simulated
                    ax.plot(
                        t_sim,
                        sim[name][:, j],
                        style,
                        lw=0.8,
                        label=f"{name} ({percent(fit[name]['position_nrmse'][j])})",
                    )
            ax.set(ylabel=f"q{j + 1} [rad]", xlabel="t [s]")
            ax.legend(fontsize=8)
            ax.grid(alpha=0.3)
    fig.suptitle(
        f"Held-out fit, before and after modelling the findings ({fit['held_out']}); "
        "open-loop simulations restart every second",
        fontsize=10,
    )
    fig.tight_layout()
    paths.append(out / "fit.png")
    fig.savefig(paths[-1], dpi=90)
    plt.close(fig)
    return paths


def plot_change(arrays: dict[str, np.ndarray], nominal: dict, out: Path) -> Path:
    """change.png: per joint, the change judged against the nominal model (the paired
    difference r_rec − r_ref when the recording reruns the reference's motion, else the
    recording's residual against θ₀) and the found patterns' model of it, against time
    (:func:`hil.diagnose.drift.judge.change_arrays`)."""
    t, change, modelled, w = arrays["t"], arrays["change"], arrays["modelled"], arrays["weight"]
    n = change.shape[1]
    fig, axes = plt.subplots(n, 1, figsize=(14, 3 * n), sharex=True, squeeze=False)
    tb = broken_at_gaps(t)
    for j in range(n):
        ax = axes[j, 0]
        gap = np.where(w[:, j] > 0, 0.0, np.nan)  # rows the fit left out are gaps
        ax.plot(tb, change[:, j] + gap, lw=0.8, color="0.35", label="change")
        ax.plot(tb, modelled[:, j] + gap, lw=1.0, color="C1", label="findings' model of it")
        ax.set(ylabel=f"joint {j + 1} [Nm]")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    axes[-1, 0].set(xlabel="t [s] from each recording's start")
    found = ", ".join(
        f["effect"].replace("_", " ") + (f" (joint {f['joint']})" if f.get("joint") else "")
        for f in nominal.get("findings", [])
    )
    what = (
        "the recording less the reference, row by row"
        if nominal.get("source") == "reference"
        else "the recording's residual against the nominal model"
    )
    fig.suptitle(
        f"Change since the nominal model ({what}). Found: {found or 'nothing'}", fontsize=10
    )
    fig.tight_layout()
    path = out / "change.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


__all__ = [
    "broken_at_gaps",
    "plot_change",
    "plot_diagnosis",
]
