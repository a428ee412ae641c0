"""A realtime run that its link's lateness ends says so, with what was seen and what to do.

Late (a stall past the feedback budget, the drives' command watchdog) is told from gone (the
robot process or the link closed): only the first gets the advice (hil/bench/run.py).
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

from cli_run import run_with_robot_paused

from drivers.arm import LinkStats
from hil.bench.run import _with_stall_advice, stalled
from profiles.bench import load_bench


def _arm(timeouts: int = 0, late: int = 0, longest: float = 0.0) -> SimpleNamespace:
    stats = LinkStats(timeouts=timeouts, late_feedback=late, max_feedback_wait_s=longest)
    return SimpleNamespace(stats=stats)


def test_late_is_told_from_gone() -> None:
    budget = "no feedback from node 1 within 100 ms (the feedback budget): virtual robot, drive"
    assert stalled(budget, _arm(timeouts=1))
    watchdog = "drive 2 left OPERATION ENABLED at t = 1.2 s: FAULT, error 0x8250 (command ...)"
    assert stalled(watchdog, _arm())
    gone = "the virtual robot process on /dev/pts/3 is gone"
    assert not stalled(gone, _arm())
    assert not stalled(gone, _arm(timeouts=1))
    assert not stalled("drive 1 left OPERATION ENABLED: FAULT, error 0x8400", _arm())
    assert not stalled(None, _arm(timeouts=1))


def test_advice_names_the_numbers_and_the_ways_out() -> None:
    bench = load_bench("virtual-slcan")
    refused = SimpleNamespace(realtime_refused="sched_setscheduler(SCHED_FIFO): EPERM")
    text = _with_stall_advice(
        "no feedback from node 1 within 100 ms (the feedback budget): ...",
        bench,
        _arm(timeouts=1, late=42, longest=0.0371),
        refused,
    )
    assert text.startswith("no feedback from node 1 within 100 ms")
    assert "42 late feedbacks" in text and "37 ms" in text and "load average" in text
    assert "kernel worker" in text  # the pty's part in it
    ways_out = ("--rate (now 400 Hz)", "--mode lockstep", "nice 19", "realtime priority",
                "virtual-socketcand")  # fmt: skip
    for way_out in ways_out:
        assert way_out in text, way_out
    granted = SimpleNamespace(realtime_refused=None)
    assert "realtime priority" not in _with_stall_advice(
        "no feedback from node 1 within 100 ms", bench, _arm(timeouts=1), granted
    )
    gone = "the virtual robot process on /dev/pts/3 is gone"
    assert _with_stall_advice(gone, bench, _arm(), granted) == gone
    socket = load_bench("virtual-socketcand")  # no pty: no kernel worker, no transport advice
    text = _with_stall_advice("no feedback from node 1 within 100 ms", socket, _arm(1), granted)
    assert "kernel worker" not in text and "virtual-socketcand" not in text
    assert "--mode lockstep" in text


def test_robot_stopped_past_the_budget_fails_with_advice(tmp_path: Path) -> None:
    """SIGSTOP the robot for 0.6 s, past the 0.25 s feedback budget: the run stops safely and
    its reason says the link was late, not gone, and what to do."""
    args = ["jitter", "--bench", "virtual-slcan", "--rate", "400", "--duration", "20", "--no-plot"]
    proc = run_with_robot_paused(args, tmp_path, 0.6)
    out, err = proc.stdout, proc.stderr
    meta = json.loads((tmp_path / "meta.json").read_text())
    assert proc.returncode == 1, err
    assert meta["status"] == "failed"
    assert "late, not gone" in meta["reason"] and "--mode lockstep" in meta["reason"], meta
    assert "late, not gone" in err
    # the jitter report says how close the run came to its budget (text and meta.json)
    timing = meta["jitter"]["timing"]
    assert timing["feedback_budget_s"] == 0.25 and timing["late_feedback"] >= 0
    assert 0 < timing["max_feedback_wait_s"] < 0.25  # the waits it survived
    assert "of the 250 ms feedback budget" in out
