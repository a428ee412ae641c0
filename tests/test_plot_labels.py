"""Plots a person reads: angles in rad everywhere (as signals.csv), a failed or truncated run
marked as such on its plot, panel titles without raw identifiers."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
import pytest

from drivers.recording import Recording, plot_positions

matplotlib.use("Agg")


@pytest.fixture
def saved(monkeypatch: pytest.MonkeyPatch) -> list[dict]:
    """What each figure saved shows: its suptitle, axis labels and panel titles."""
    from matplotlib.figure import Figure

    figures: list[dict] = []

    def savefig(fig: Figure, path: object, **kwargs: object) -> None:
        figures.append(
            {
                "title": fig._suptitle.get_text() if fig._suptitle else "",
                "ylabels": [ax.get_ylabel() for ax in fig.axes],
                "titles": [ax.get_title() for ax in fig.axes],
                "vlines": sum(len(ax.lines) for ax in fig.axes),
            }
        )

    monkeypatch.setattr(Figure, "savefig", savefig)
    return figures


def _recording(meta: dict, torn: bool = False) -> Recording:
    t = np.arange(100) * 0.0025
    cols = {"t": t, "q1": np.sin(t), "q2": np.cos(t), "tau1": t, "tau2": -t}
    return Recording(Path("run"), cols, meta, torn)


def test_positions_plot_in_rad_and_a_complete_run_unmarked(saved, tmp_path) -> None:
    plot_positions(_recording({"status": "complete"}), tmp_path / "p.png", title="hil run: x")
    (fig,) = saved
    assert [y for y in fig["ylabels"] if y.startswith("q")] == ["q1 [rad]", "q2 [rad]"]
    assert fig["title"] == "hil run: x"


@pytest.mark.parametrize(
    ("meta", "torn", "mark"),
    [
        ({"status": "failed", "reason": "no feedback for 3 periods"}, False, "FAILED run: no feed"),
        ({"status": "interrupted"}, False, "INTERRUPTED run"),
        ({}, True, "TRUNCATED recording"),
    ],
)
def test_an_incomplete_run_is_marked_on_its_plot(saved, tmp_path, meta, torn, mark) -> None:
    plot_positions(_recording(meta, torn), tmp_path / "p.png", title="hil run: x")
    (fig,) = saved
    assert mark in fig["title"] and f"ends at t = {0.0025 * 99:.3f} s" in fig["title"]


def test_validation_panels_are_titled_in_words(saved, tmp_path) -> None:
    from hil.identify.plots import plot_validation

    rec = _recording({})
    panels = [(name, rec, np.arange(len(rec)), rec.q, [0.1, 0.2]) for name in ("fit", "held_out")]
    plot_validation("reyes-kelly", "exact", panels, tmp_path / "v.png")
    (fig,) = saved
    assert not any("held_out" in t for t in fig["titles"] + [fig["title"]])
    assert any(t.startswith("Held-out recording: joint 1") for t in fig["titles"])


def test_diagnosis_simulation_lines_break_at_skipped_segments():
    """Held-out simulations of separate segments (or recordings) are not joined by lines."""
    from hil.diagnose.plots import broken_at_gaps

    t = np.r_[np.arange(0, 1, 0.01), np.arange(5, 6, 0.01), np.arange(0, 1, 0.01)]
    b = broken_at_gaps(t)
    assert np.isnan(b).sum() == 2 and np.isnan(b[100]) and np.isnan(b[200])
    assert np.array_equal(b[:100], t[:100])
