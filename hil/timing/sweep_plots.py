"""Plots of a timing-fault sweep (hil/timing/sweep.py): errors against the injected level."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from hil.model.closed_form import THETA_NAMES


def _x(doc: dict[str, Any]) -> tuple[np.ndarray, str]:
    levels = np.asarray(doc["levels"], dtype=float)
    if doc["unit"] == "probability":
        return 100 * levels, f"{doc['variable']} rate [%]"
    label = {"latency": "injected latency", "jitter": "jitter scale"}.get(doc["variable"], "level")
    return 1e3 * levels, f"{label} [ms]"


def _band(ax: Any, x: np.ndarray, stats: list[dict[str, Any]], j: int | None, scale: float,
          **style: Any) -> None:  # fmt: skip
    """mean ± std as error bars, min..max as a shaded band (over seeds)."""

    def col(key: str) -> np.ndarray:
        def value(s: dict[str, Any]) -> float:
            if s[key] is None:  # every run of that level failed
                return np.nan
            return s[key] if j is None else s[key][j]

        return np.array([value(s) for s in stats], dtype=float) * scale

    mean, std = col("mean"), col("std")
    ax.errorbar(x, mean, yerr=std, marker="o", ms=3.5, capsize=3, lw=1.2, **style)
    if any(s["n"] > 1 for s in stats):
        ax.fill_between(x, col("min"), col("max"), alpha=0.15, color=style.get("color"))


def plot_sweep(doc: dict[str, Any], out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x, xlabel = _x(doc)
    seeds = len(doc["seeds"])
    spread = f"mean ± std over {seeds} seeds, band min..max" if seeds > 1 else "deterministic"
    paths = []
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, (scheme, m) in enumerate(doc["control"].items()):
        c = colors[i % len(colors)]
        for row, key in enumerate(("max_position_error_rad", "rms_position_error_rad")):
            for j in range(2):
                ax = axes[row, j]
                _band(ax, x, m[key], j, 1e3, color=c, label=scheme.upper())
                base = m[key + "_baseline"]
                if base is not None:
                    ax.axhline(1e3 * base[j], color=c, ls="--", lw=0.9, alpha=0.8,
                               label=f"{scheme.upper()} lockstep, no fault")  # fmt: skip
                what = "max" if row == 0 else "RMS"
                ax.set_ylabel(f"{what} |e{j + 1}| [mrad]")
                title = f"joint {j + 1}: {what} position tracking error"
                last = next((s["mean"] for s in reversed(m[key]) if s["mean"]), None)
                if base is not None and last is not None and base[j] > 0 and i == 0:
                    change = 100 * (last[j] / base[j] - 1)
                    title += f" ({scheme.upper()} {change:+.1f} % at the last level)"
                ax.set_title(title, fontsize=10)
                ax.grid(True, alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel(xlabel)
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(
        f"Tracking error (khosla-kanade-tracking) against {doc['variable']}, lockstep with the "
        f"fault imposed; {spread}",
        fontsize=10,
    )
    fig.tight_layout()
    path = out / "sweep-tracking.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    paths.append(path)

    if doc["identify"]:
        fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.5))
        for i, (scheme, m) in enumerate(doc["identify"].items()):
            c = colors[i % len(colors)]
            _band(ax1, x, m["max_abs_relative_error"], None, 100, color=c, label=scheme)
            ax1.axhline(100 * m["max_abs_relative_error_baseline"], color=c, ls="--", lw=0.9)
        ax1.set_xlabel(xlabel)
        ax1.set_ylabel("worst |relative error| of θ̂1..θ̂9 [%]")
        ax1.set_title("identification (reyes-kelly, exact): worst parameter", fontsize=10)
        ax1.grid(True, alpha=0.3)
        ax1.legend(fontsize=8)
        first = next(iter(doc["identify"]))
        rel = doc["identify"][first]["relative_error"]
        for t in range(len(THETA_NAMES)):
            mean = np.array([np.nan if s["mean"] is None else abs(s["mean"][t]) for s in rel])
            mean = mean * 100
            ax2.plot(x, mean, marker="o", ms=3, lw=1, label=THETA_NAMES[t])
        ax2.set_xlabel(xlabel)
        ax2.set_ylabel("|relative error| [%] (mean over seeds)")
        ax2.set_title(f"{first}: each parameter", fontsize=10)
        ax2.set_yscale("symlog", linthresh=1.0)
        ax2.grid(True, alpha=0.3)
        ax2.legend(fontsize=7, ncol=3)
        fig.tight_layout()
        path = out / "sweep-parameters.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths
