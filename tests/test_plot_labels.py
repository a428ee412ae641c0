"""Plots a person reads: angles in rad everywhere (as signals.csv), a failed or truncated run
marked as such on its plot, panel titles without raw identifiers."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import matplotlib
import numpy as np
import pytest

from drivers.recording import Recording
from plots.positions import plot_positions

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


def test_diagnosis_torque_error_is_drawn_against_time(monkeypatch, tmp_path):
    """fit.png's torque panels: the held-out rows against their time, as the position panels
    beside them, not against the row index; lines break where the held-out rows skip."""
    from matplotlib.figure import Figure

    from hil.diagnose.plots import plot_diagnosis

    rng = np.random.default_rng(0)
    rows = 400
    t = 3.0 + np.cumsum(0.0025 * rng.uniform(0.6, 1.4, rows))  # irregular stamps
    test = np.zeros(rows, dtype=bool)
    test[200:300] = test[350:] = True  # two held-out spans
    zeros = np.zeros((rows, 2))
    loc = {"t": t, "residual": zeros, "v": zeros, "q": zeros, "usable": np.ones((rows, 2), bool)}
    arrays = {"location": loc, "test": test, "torque": rng.normal(size=(rows, 2)),
              "pred_before": zeros, "pred_after": zeros, "simulation": {}}  # fmt: skip
    fit = {name: {"torque_nrmse": [0.1, 0.2]} for name in ("before", "after")}
    doc = {"findings": [], "fit": {**fit, "held_out": "the last 20 %"}}
    drawn: dict[str, Figure] = {}
    monkeypatch.setattr(Figure, "savefig", lambda fig, path, **kw: drawn.update({path.name: fig}))
    plot_diagnosis(SimpleNamespace(document=doc, arrays=arrays), tmp_path)  # what it reads
    torque_axes = drawn["fit.png"].axes[0::2]  # joint j: (torque, position)
    for ax in torque_axes:
        assert ax.get_xlabel() == "t [s]"
        x = np.asarray(ax.lines[0].get_xdata(), dtype=float)
        held = t[test]
        assert np.array_equal(x[~np.isnan(x)], np.delete(held, 100))  # NaN where rows skip
        assert np.isnan(x[100])
