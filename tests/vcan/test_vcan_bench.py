"""The `virtual-vcan` benches over a real Linux vcan0 (docs/vcan.md).

Tests marked ``vcan`` need the interface and skip without it; `make test-vcan` runs them inside a
QEMU guest with a stock Debian kernel (tests/vcan/run.sh). One lockstep run is shared by three of
them: it must equal `virtual-robot simulate` bit for bit, leave a candump-format ``bus.log`` that
python-can reads back, and be seen, frame for frame, by a second python-can client on vcan0.
"""

from __future__ import annotations

import contextlib
import json
import re
import socket
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import can
import numpy as np
import pytest
from cli_run import SLOW_GUEST, assert_same_recording, bench_copy, hil

from drivers.recording import read_signals
from profiles.experiment import load_experiment
from profiles.robot import load_robot
from virtual_robot.simulate import simulate

DURATION_S = 2.0
ROWS = 800  # 2 s at h = 2.5 ms
MAKE_VCAN0 = "ip link add dev vcan0 type vcan && ip link set up vcan0"
REALTIME_PERIOD_S = 0.02
FEEDBACK_TIMEOUT_PERIODS = 50
SLOW_GUEST_REALTIME = {
    **SLOW_GUEST,
    # 50 Hz, and the host stops after 50 periods (1 s) without feedback
    "period_s = 0.0025": f"period_s = {REALTIME_PERIOD_S}",
    "feedback_timeout_periods = 3": f"feedback_timeout_periods = {FEEDBACK_TIMEOUT_PERIODS}",
}
# The cicese drives' command watchdog (profiles/drives/dm1200a.toml, dm1015b.toml: watchdog_s):
# a host silent this long while the robot runs faults them (0x8250)
DRIVE_WATCHDOG_S = 0.5
# Torque steps for the 50 Hz run: the arm moves about 0.26 rad and settles, inside the bench's
# limits at any period (the paper's excitation is designed for h = 2.5 ms).
GENTLE_EXPERIMENT = """
name = "gentle-steps"
kind = "open_loop_torque"
period_s = 0.02
duration_s = 2.0
[[joints]]
step_Nm = 20.0
[[joints]]
step_Nm = 3.0
"""


@pytest.fixture(scope="module")
def vcan0() -> str:
    try:
        socket.if_nametoindex("vcan0")
    except OSError:
        pytest.skip(f"vcan0 missing (as root: `{MAKE_VCAN0}`; `make test-vcan` runs these in a VM)")
    return "vcan0"


class Sniffer:
    """A second python-can client on the interface, recording every frame it sees."""

    def __init__(self, channel: str) -> None:
        self.bus = can.Bus(interface="socketcan", channel=channel)
        # a lockstep run bursts faster than a slow guest may schedule this thread (root only)
        with contextlib.suppress(OSError, AttributeError):
            self.bus.socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUFFORCE, 8 << 20)
        self.frames: list[can.Message] = []
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            msg = self.bus.recv(0.5)
            if msg is not None:
                self.frames.append(msg)

    def close(self) -> list[can.Message]:
        # drain what is still queued in the socket, then stop
        self.stop.set()
        self.thread.join(5.0)
        while (msg := self.bus.recv(0.2)) is not None:
            self.frames.append(msg)
        self.bus.shutdown()
        return self.frames


def run_for_json(bench: Path, experiment: str, out: Path) -> subprocess.CompletedProcess:
    """`hil run --bench BENCH --experiment EXPERIMENT` for DURATION_S, its summary on stdout."""
    return hil("run", "--bench", str(bench), "--experiment", experiment, "--duration",
               str(DURATION_S), "--out", str(out), "--json", "--no-plot")  # fmt: skip


@pytest.fixture(scope="module")
def lockstep_run(vcan0, tmp_path_factory) -> dict:
    """`hil run --bench virtual-vcan` (lockstep) for 2 s, with a second client listening."""
    out = tmp_path_factory.mktemp("vcan-lockstep")
    bench = bench_copy("virtual-vcan", tmp_path_factory.mktemp("bench"), SLOW_GUEST)
    sniffer = Sniffer(vcan0)
    try:
        proc = run_for_json(bench, "reyes-kelly", out)
    finally:
        seen = sniffer.close()
    assert proc.returncode == 0, proc.stderr
    return {"out": out, "summary": json.loads(proc.stdout), "seen": seen}


@pytest.mark.vcan
def test_lockstep_run_equals_offline_simulation(lockstep_run, tmp_path):
    summary, out = lockstep_run["summary"], lockstep_run["out"]
    assert summary["status"] == "complete" and summary["rows"] == ROWS
    simulate(
        load_robot("cicese"),
        load_experiment("reyes-kelly"),
        tmp_path,
        duration_s=DURATION_S,
        plot=False,
    )
    ref, rec = read_signals(tmp_path), read_signals(out)
    assert_same_recording(rec, ref)
    meta = json.loads((out / "meta.json").read_text())
    assert meta["bench"] == "virtual-vcan" and meta["mode"] == "lockstep"
    assert meta["channel"]["transport"] == "socketcan" and meta["channel"]["channel"] == "vcan0"


# `candump -L`: (seconds.microseconds) interface id#data, then python-can's R/T direction flag
CANDUMP_LINE = re.compile(r"^\(\d+\.\d{6}\) vcan0 [0-9A-F]{3}#(?:[0-9A-F]{2}){0,8} [RT]$")


@pytest.mark.vcan
def test_bus_log_is_candump_format_read_by_python_can(lockstep_run):
    log = Path(lockstep_run["summary"]["traffic_log"])
    assert log.name == "bus.log"
    lines = log.read_text().splitlines()
    bad = [line for line in lines if not CANDUMP_LINE.match(line)]
    assert lines and not bad, bad[:3]
    frames = list(can.LogReader(str(log)))
    assert len(frames) == len(lines)
    ids = [m.arbitration_id for m in frames]
    assert ids.count(0x080) >= ROWS  # one SYNC per period
    assert {0x181, 0x182, 0x201, 0x202, 0x281, 0x282} <= set(ids)  # PDOs of both drives


@pytest.mark.vcan
def test_second_client_on_vcan0_sees_the_traffic(lockstep_run):
    """What vcan loopback is for: any other SocketCAN client sees the host-robot conversation."""
    seen = lockstep_run["seen"]
    logged = list(can.LogReader(lockstep_run["summary"]["traffic_log"]))

    def frames(msgs: list[can.Message]) -> Counter:
        return Counter((m.arbitration_id, bytes(m.data)) for m in msgs)

    assert all(m.channel == "vcan0" for m in seen)
    # every frame of the host's log crossed vcan0, where the second client saw it
    missing = frames(logged) - frames(seen)
    assert not missing, list(missing.items())[:5]
    assert [m.arbitration_id for m in seen].count(0x080) >= ROWS


class StallMonitor:
    """How long this guest left a thread that asked to run every TICK_S waiting: the longest
    time any process here (the host, the robot) could go without the CPU. A software-emulated
    guest has no bound on it: when the host machine is loaded, qemu's vCPU threads wait, and
    the whole guest with them."""

    TICK_S = 0.002

    def __init__(self) -> None:
        self.longest_s = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        last = time.monotonic()
        while not self._stop.wait(self.TICK_S):
            now = time.monotonic()
            self.longest_s = max(self.longest_s, now - last - self.TICK_S)
            last = now

    def __enter__(self) -> StallMonitor:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5.0)


# What the realtime run's stop says, for each bound a stall can trip: (words of its one line,
# the silence that trips it). The robot counts its own stall as one period (virtual_robot/
# drive.py), so a pause of the whole guest trips the host's feedback budget, and the watchdog
# only when the host alone was held up.
STALL_STOPS = (
    ("0x8250", DRIVE_WATCHDOG_S),  # first: the host's line for it also says "no feedback"
    ("no feedback", FEEDBACK_TIMEOUT_PERIODS * REALTIME_PERIOD_S),
)


def stopped_by_a_stall(stderr: str, longest_s: float) -> str:
    """Why a realtime run that stopped is excused (the skip's words): its one error line is
    the stop of a bound of STALL_STOPS, and the guest stalled at least that long (two periods
    less: the host sends once a period). Otherwise an AssertionError: a stop the guest's
    stalls do not explain."""
    errors = [line for line in stderr.splitlines() if "error" in line]
    assert len(errors) == 1, stderr
    tripped = [bound for what, bound in STALL_STOPS if what in errors[0]]
    assert tripped, f"the run stopped for another reason: {errors[0]}"
    assert longest_s >= tripped[0] - 2 * REALTIME_PERIOD_S, (
        f"the run stopped ({errors[0]}) but the guest never stalled that long (longest "
        f"{longest_s * 1000:.0f} ms)"
    )
    return (
        f"the guest stalled {longest_s * 1000:.0f} ms (host load), over the "
        f"{tripped[0] * 1000:.0f} ms bound; the run stopped as it must: {errors[0]}"
    )


@pytest.mark.vcan
def test_realtime_run_completes(vcan0, tmp_path):
    """The realtime variant, 2 s: the host's wall-clock loop and the robot's own clock over vcan0
    (at 50 Hz, see SLOW_GUEST_REALTIME): the path works (drives enabled, torque applied, a
    feedback in every period, the run complete). Timing is not judged here (`make bench` on the
    host measures it): under host load the emulated guest can stop for longer than the run's
    safety bounds, the host's feedback budget (1 s) and the drives' watchdog (0.5 s). A run
    that stops is then accepted only with the stop those bounds prescribe, in one line, and a
    stall of the guest measured beside it (StallMonitor) at least as long as the bound it
    tripped; the test then skips, saying so. A stop without such a stall fails."""
    bench = bench_copy("virtual-vcan-realtime", tmp_path, SLOW_GUEST_REALTIME)
    experiment = tmp_path / "gentle.toml"
    experiment.write_text(GENTLE_EXPERIMENT)
    out = tmp_path / "run"
    with StallMonitor() as stalls:
        proc = run_for_json(bench, str(experiment), out)
    if proc.returncode != 0:
        pytest.skip(stopped_by_a_stall(proc.stderr, stalls.longest_s))
    summary = json.loads(proc.stdout)
    rows = round(DURATION_S / REALTIME_PERIOD_S)
    assert summary["status"] == "complete" and summary["rows"] == rows
    assert summary["timing"]["cycles"] == rows
    rec = read_signals(out)
    assert len(rec) == rows and np.all(np.isfinite(rec.q))
    assert np.all(np.isfinite(rec.columns["feedback_s"]))  # feedback in every period
    assert np.all(np.abs(rec.q[-1]) > 0.05)  # the drives were enabled and applied the torque
    meta = json.loads((out / "meta.json").read_text())
    assert meta["bench"] == "virtual-vcan-realtime" and meta["mode"] == "realtime"


def test_a_stopped_realtime_run_is_excused_only_by_a_stall_as_long_as_its_bound():
    """Runs everywhere: the realtime test's judgement of a run that stopped."""
    feedback = "hil run: error: no feedback from node 1 within 1000 ms (the feedback budget): ..."
    watchdog = (
        "hil run: error: no feedback from node 2: the drives faulted (node 2 FAULT 0x8250 ..."
    )
    progress = "hil: 40/100 periods (40 %)\n"
    assert "1000 ms bound" in stopped_by_a_stall(progress + feedback + "\n", 1.3)
    assert "500 ms bound" in stopped_by_a_stall(watchdog + "\n", 0.6)
    for stderr, longest in ((feedback, 0.3), (watchdog, 0.1), ("hil run: error: limit", 5.0)):
        with pytest.raises(AssertionError):
            stopped_by_a_stall(stderr, longest)


def test_the_stall_monitor_sees_a_thread_held_off_the_cpu():
    """Runs everywhere: a thread that holds the interpreter 0.3 s (a switch interval longer
    than that) keeps the monitor's thread from running, as a paused guest keeps everything."""
    before = sys.getswitchinterval()
    with StallMonitor() as stalls:
        time.sleep(0.05)
        sys.setswitchinterval(1.0)
        try:
            end = time.monotonic() + 0.3
            while time.monotonic() < end:
                pass
        finally:
            sys.setswitchinterval(before)
        time.sleep(0.05)
    assert 0.25 <= stalls.longest_s < 5.0, stalls.longest_s


def test_missing_vcan_interface_is_one_line_naming_the_command(tmp_path):
    """Runs everywhere: a bench on an interface that does not exist says how to create it."""
    bench = bench_copy("virtual-vcan", tmp_path, {'channel = "vcan0"': 'channel = "vcan9"'})
    proc = hil("run", "--bench", str(bench), "--duration", "0.1", "--out", str(tmp_path / "r"))
    assert proc.returncode == 3  # a link failure (docs/interop.md, exit codes)
    assert proc.stderr.count("\n") == 1, proc.stderr
    assert "vcan9 missing: run `ip link add dev vcan9 type vcan && ip link set up vcan9`" in (
        proc.stderr
    )
