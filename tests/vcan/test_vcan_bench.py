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
import threading
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
SLOW_GUEST_REALTIME = {
    **SLOW_GUEST,
    # 50 Hz: the drives' command watchdog (8 periods) becomes 160 ms, feedback timeout 1 s
    "period_s = 0.0025": "period_s = 0.02",
    "feedback_timeout_periods = 3": "feedback_timeout_periods = 50",
}
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


@pytest.fixture(scope="module")
def lockstep_run(vcan0, tmp_path_factory) -> dict:
    """`hil run --bench virtual-vcan` (lockstep) for 2 s, with a second client listening."""
    out = tmp_path_factory.mktemp("vcan-lockstep")
    bench = bench_copy("virtual-vcan", tmp_path_factory.mktemp("bench"), SLOW_GUEST)
    sniffer = Sniffer(vcan0)
    try:
        proc = hil(
            "run",
            "--bench",
            str(bench),
            "--experiment",
            "reyes-kelly",
            "--duration",
            str(DURATION_S),
            "--out",
            str(out),
            "--json",
            "--no-plot",
        )
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


@pytest.mark.vcan
def test_realtime_run_completes(vcan0, tmp_path):
    """The realtime variant, 2 s: the host's wall-clock loop and the robot's own clock over vcan0
    (at 50 Hz, see SLOW_GUEST_REALTIME)."""
    bench = bench_copy("virtual-vcan-realtime", tmp_path, SLOW_GUEST_REALTIME)
    experiment = tmp_path / "gentle.toml"
    experiment.write_text(GENTLE_EXPERIMENT)
    out = tmp_path / "run"
    proc = hil(
        "run",
        "--bench",
        str(bench),
        "--experiment",
        str(experiment),
        "--duration",
        str(DURATION_S),
        "--out",
        str(out),
        "--json",
        "--no-plot",
    )
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    rows = round(DURATION_S / 0.02)
    assert summary["status"] == "complete" and summary["rows"] == rows
    assert summary["timing"]["cycles"] == rows
    rec = read_signals(out)
    assert len(rec) == rows and np.all(np.isfinite(rec.q))
    assert np.all(np.isfinite(rec.columns["feedback_s"]))  # feedback in every period
    assert np.all(np.abs(rec.q[-1]) > 0.05)  # the drives were enabled and applied the torque
    meta = json.loads((out / "meta.json").read_text())
    assert meta["bench"] == "virtual-vcan-realtime" and meta["mode"] == "realtime"


def test_missing_vcan_interface_is_one_line_naming_the_command(tmp_path):
    """Runs everywhere: a bench on an interface that does not exist says how to create it."""
    bench = bench_copy("virtual-vcan", tmp_path, {'channel = "vcan0"': 'channel = "vcan9"'})
    proc = hil("run", "--bench", str(bench), "--duration", "0.1", "--out", str(tmp_path / "r"))
    assert proc.returncode == 3  # a link failure (docs/interop.md, exit codes)
    assert proc.stderr.count("\n") == 1, proc.stderr
    assert "vcan9 missing: run `ip link add dev vcan9 type vcan && ip link set up vcan9`" in (
        proc.stderr
    )
