"""A recording's joint positions and torques against time (:func:`plot_positions`)."""

from __future__ import annotations

from pathlib import Path

from drivers.recording import Recording


def plot_positions(
    rec: Recording,
    out_png: str | Path,
    title: str = "",
    reference: Recording | None = None,
    reference_label: str = "reference",
) -> Path:
    """Joint positions (rad, as signals.csv) and torques against time (the layout of Reyes &
    Kelly Fig. 2). A run that did not complete (meta.json status) or whose last row was torn is
    marked so in the title and by a line where it ended."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = rec.n_joints
    fig, axes = plt.subplots(2, n, figsize=(5.5 * n, 6), sharex=True, squeeze=False)
    for j in range(n):
        ax = axes[0, j]
        ax.plot(rec.t, rec.q[:, j], lw=1.2, label="recorded")
        if reference is not None:
            ax.plot(reference.t, reference.q[:, j], lw=1.0, ls="--", label=reference_label)
            ax.legend(loc="best", fontsize=8)
        ax.set_ylabel(f"q{j + 1} [rad]")
        ax.grid(True, alpha=0.3)
        ax2 = axes[1, j]
        ax2.plot(rec.t, rec.tau[:, j], lw=0.8, color="tab:red")
        ax2.set_ylabel(f"τ{j + 1} [Nm]")
        ax2.set_xlabel("t [s]")
        ax2.grid(True, alpha=0.3)
    title = title or str(rec.path)
    status = rec.meta.get("status")
    ended = None
    if status not in (None, "complete"):
        ended = f"{str(status).upper()} run: {rec.meta.get('reason') or 'no reason given'}"
    elif rec.dropped_partial_row:
        ended = "TRUNCATED recording: its last row was torn"
    if ended is not None and len(rec):
        title = f"{title}\n{ended} (ends at t = {rec.t[-1]:.3f} s)"
        for ax in axes.flat:
            ax.axvline(rec.t[-1], color="tab:red", lw=1.0, ls=":")
    fig.suptitle(title, color="tab:red" if ended else "black", fontsize=10 if ended else None)
    fig.tight_layout()
    out_png = Path(out_png)
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    return out_png


__all__ = ["plot_positions"]
