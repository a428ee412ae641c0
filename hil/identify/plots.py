"""Identification plots: θ̂(k) against time per scheme (Reyes & Kelly 1997, Figs. 3, 5, 6) and
open-loop validation, recorded against simulated positions (Figs. 2, 4, 7)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from drivers.recording import Recording
from hil.identify.schemes import SCHEME_TITLES, SchemeResult
from hil.model.closed_form import THETA_UNITS
from plots.layout import fixed_margins


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_estimates(result: SchemeResult, reference: np.ndarray, path: Path) -> Path:
    """θ̂1..θ̂9(k) of recursive least squares against time, the reference dashed."""
    plt = _pyplot()
    fig, axes = plt.subplots(3, 3, figsize=(11, 7.5), sharex=True)
    for i, ax in enumerate(axes.flat):
        ax.plot(result.history_t, result.history[:, i], lw=1.2, label="RLS θ̂(k)")
        ax.axhline(reference[i], color="k", ls="--", lw=0.9, label="profile")
        final = result.history[-1, i]
        span = max(abs(reference[i]), abs(final)) * 1.6 + 1e-9
        lo, hi = min(reference[i], final), max(reference[i], final)
        ax.set_ylim(lo - 0.4 * span, hi + 0.4 * span)
        ax.set_title(f"θ{i + 1} [{THETA_UNITS[i]}]", fontsize=9)
        ax.tick_params(labelsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(
        f"{SCHEME_TITLES[result.scheme]} model ({result.discretization}, λ = {result.lam:g} rad/s):"
        " estimated θ̂(k)",
        fontsize=11,
    )
    fixed_margins(fig, wspace=0.28, hspace=0.32)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


_PANEL_TITLES = {"fit": "Fit recording", "held_out": "Held-out recording"}


def plot_validation(
    scheme: str,
    discretization: str,
    panels: list[tuple[str, Recording, np.ndarray, np.ndarray, list[float]]],
    path: Path,
) -> Path:
    """Recorded against simulated positions per joint, one column per recording
    (title, recording, the rows simulated q is given at, simulated q, position NRMSE per
    joint)."""
    plt = _pyplot()
    fig, axes = plt.subplots(2, len(panels), figsize=(5.5 * len(panels), 6), squeeze=False)
    for c, (name, rec, rows, q_sim, err) in enumerate(panels):
        title = _PANEL_TITLES.get(name, name)
        t = rec.t[rows]
        for j in range(2):
            ax = axes[j, c]
            ax.plot(t, rec.q[rows, j], lw=1.1, label="recorded")
            ax.plot(t, q_sim[:, j], lw=1.0, ls="--", label="simulated, identified θ")
            ax.set_ylabel(f"q{j + 1} [rad]")
            ax.set_title(f"{title}: joint {j + 1}, NRMSE {100 * err[j]:.1f} %", fontsize=9)
            ax.tick_params(labelsize=8)
        axes[1, c].set_xlabel("t [s]")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(
        f"Open-loop validation, {SCHEME_TITLES.get(scheme, scheme)} ({discretization})",
        fontsize=11,
    )
    fixed_margins(fig, left_in=1.0, wspace=0.22, hspace=0.38)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
