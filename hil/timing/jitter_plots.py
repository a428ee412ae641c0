"""Histograms and a timeline of a realtime run's timing (``hil jitter``), matplotlib, PNG."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hil.bench.timing_stats import OVERRUN_FACTOR, CycleTiming


def _log_bins(values_us: np.ndarray, n: int = 80) -> np.ndarray:
    top = max(float(values_us.max()) if values_us.size else 1.0, 2.0)
    return np.logspace(-1, np.log10(top * 1.05), n)


def plot_histograms(c: CycleTiming, period_s: float, out_png: str | Path, title: str) -> Path:
    """Release error, period error and command-to-feedback latency, log-log, p99 marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    h_us = period_s * 1e6
    panels = (
        ("release − deadline [µs]", c.release_error * 1e6, None),
        ("|period − h| [µs]", np.abs(c.period - period_s) * 1e6, (OVERRUN_FACTOR - 1) * h_us),
        ("command → feedback latency [µs]", c.latency * 1e6, h_us),
    )
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    for ax, (label, values, limit) in zip(axes, panels, strict=True):
        v = values[np.isfinite(values)]
        v = np.clip(v, 0.1, None)  # a log axis: sub-0.1 µs (and early) values in the first bin
        if v.size:
            ax.hist(v, bins=_log_bins(v), color="tab:blue", alpha=0.8)
            p99 = float(np.percentile(v, 99))
            ax.axvline(p99, color="tab:orange", ls="--", lw=1, label=f"p99 {p99:.0f} µs")
            ax.axvline(float(v.max()), color="tab:red", ls=":", lw=1, label=f"max {v.max():.0f} µs")
        if limit is not None:
            name = "overrun (1.5 h)" if "period" in label else "h"
            ax.axvline(limit, color="k", lw=1, label=f"{name}: {limit:.0f} µs")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(label)
        ax.set_ylabel("cycles")
        ax.grid(True, which="both", alpha=0.25)
        ax.legend(fontsize=8, loc="upper right")
    fig.suptitle(title)
    fig.tight_layout()
    out = Path(out_png)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


def plot_timeline(
    t_s: np.ndarray,
    release_error_s: np.ndarray,
    latency_s: np.ndarray,
    period_s: float,
    out_png: str | Path,
    title: str,
) -> Path:
    """Release error and latency of every row against its time (stalls show as spikes)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(12, 3.8))
    for values, label, alpha in (
        (release_error_s, "release − deadline", 1.0),
        (latency_s, "command → feedback latency", 0.5),
    ):
        ax.plot(t_s, np.clip(values * 1e6, 0.1, None), ".", ms=1.5, alpha=alpha, label=label)
    ax.axhline(period_s * 1e6, color="k", lw=1, label="h")
    ax.set_yscale("log")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("µs")
    ax.grid(True, which="both", alpha=0.25)
    ax.legend(fontsize=8, loc="upper right", markerscale=5)
    ax.set_title(title)
    fig.tight_layout()
    out = Path(out_png)
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out
