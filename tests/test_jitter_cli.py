"""`hil jitter` end to end over virtual-slcan: one JSON document, plots, meta.json, bus load.

No wall-clock gating: the figures are checked for structure and consistency, and the bus load
per cycle (a property of the frames, not of the machine's timing) against the frame lengths.
"""

from __future__ import annotations

import json

import pytest
from cli_run import hil

from drivers.recording import read_signals

# one worker runs the whole module under `pytest -n` (`--dist loadgroup`): its module
# fixtures are built once, not once per worker
pytestmark = pytest.mark.xdist_group("jitter_cli")


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("jitter")
    proc = hil(
        "jitter",
        "--bench",
        "virtual-slcan",
        "--rate",
        "400",
        "--duration",
        "2",
        "--pace-bus",
        # a VM stall longer than 3 periods would end the run; this test checks the report
        "--feedback-timeout-periods",
        "40",
        "--out",
        str(out),
        "--json",
    )
    return proc, out


def test_one_json_document_with_the_figures(run):
    proc, _ = run
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)  # one document, nothing else on stdout
    assert doc["status"] == "complete" and doc["rate_hz"] == 400 and doc["rows"] == 800
    t = doc["timing"]
    assert t["cycles"] == 799 and t["period_s"] == 0.0025
    for key in ("release_error", "period_error", "latency"):
        p = t[key]
        assert p["n"] >= 798
        assert 0 <= p["median_us"] <= p["p99_us"] <= p["p999_us"] <= p["max_us"]
    assert t["latency"]["median_us"] > 0
    for key in ("overruns", "overruns_per_10k", "deadline_misses", "lost_feedback"):
        assert key in t
    m = doc["machine"]
    assert m["cpu_count"] >= 1 and len(m["load_average_start"]) == len(m["load_average_end"]) == 3
    s = doc["scheduler"]
    assert s["policy"] in ("SCHED_FIFO", "SCHED_OTHER") and isinstance(s["memory_locked"], bool)
    if s["policy"] == "SCHED_OTHER":
        assert s["realtime_refused"]  # says why
    assert s["waits"] == 800 and s["mean_sleep_us"] > 0


def test_bus_load_of_the_paced_bus(run):
    proc, _ = run
    bus = json.loads(proc.stdout)["bus"]
    assert bus["paced"] is True and bus["bitrate"] == 1_000_000
    # per cycle: 2 RPDO (4 bytes), SYNC, 4 TPDO (6 bytes): 7 frames of about 640 bits in all
    assert bus["frames_per_cycle"] == pytest.approx(7.0, abs=0.01)
    assert 600 <= bus["bits_per_cycle"] <= 700
    assert bus["cycle_load_pct"] == pytest.approx(bus["bits_per_cycle"] / 2500 * 100)
    assert 0 < bus["load_pct"] < 40 and bus["interval_load_pct"]


def test_files_and_meta(run):
    _, out = run
    for name in ("signals.csv", "meta.json", "bus.log", "bench.toml"):
        assert (out / name).is_file(), name
    for name in ("jitter-histograms.png", "jitter-timeline.png"):
        assert (out / name).stat().st_size > 10_000, name
    rec = read_signals(out)
    assert len(rec) == 800 and rec.meta["kind"] == "hil jitter"
    assert rec.meta["period_s"] == 0.0025 and rec.meta["jitter"]["timing"]["cycles"] == 799
    assert rec.meta["timing"]["scheduler"]["waits"] == 800  # the loop's own report too
    assert "period_s = 0.0025" in (out / "bench.toml").read_text()
    assert "virtual-robot: paced bus at 1000000 bit/s" in (out / "virtual-robot.log").read_text()


def test_bad_requests_are_one_line_errors(tmp_path):
    proc = hil("jitter", "--rate", "0", "--out", str(tmp_path / "a"))
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.count("\n") == 1 and "--rate" in proc.stderr
    proc = hil("jitter", "--bench", "virtual-serial", "--pace-bus", "--out", str(tmp_path / "b"))
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "pace_bus" in proc.stderr
