"""The DFKI lab's MIT-mode driver (mini-cheetah-motor-driver-socketcan) on a real kernel CAN
socket against the virtual double pendulum (docs/protocol.md "CAN: MIT mode").

The driver opens a raw SocketCAN socket with CAN_RAW_LOOPBACK off. On a vcan interface such
frames never reach another socket (vcan delivers looped-back frames only), so the driver and
the virtual robot talk over a vxcan pair, the kernel's virtual CAN tunnel, which hands every
frame to its peer as a real bus does: the driver on one end, the robot (python-can socketcan)
on the other. Needs root and the vxcan module; `make test-vcan` runs it in its guest.
"""

from __future__ import annotations

import shutil
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest

from drivers.links import open_socketcan
from drivers.protocol import mit
from profiles.bench import load_bench
from profiles.drive import load_drive
from profiles.robot import load_robot
from virtual_robot.mit_server import MitDriveServer
from virtual_robot.mit_simulate import run_commands
from virtual_robot.serve import build_core

pytestmark = pytest.mark.vcan

HOST_END, ROBOT_END = "mitc0", "mitr0"
DFKI_FILE = (
    Path(__file__).parents[1] / "data" / "dfki" / "design_A.0__20220815__sys_id__trajectory_00.csv"
)
ROWS = 100
AK80_6 = mit.MitRanges.of(load_drive("ak80-6").mit)  # type: ignore[arg-type]


def _ip(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=10)


@pytest.fixture
def vxcan_pair():
    if shutil.which("ip") is None:
        pytest.skip("no `ip` command")
    made = _ip("link", "add", HOST_END, "type", "vxcan", "peer", "name", ROBOT_END)
    if made.returncode != 0:
        pytest.skip(
            f"cannot make a vxcan pair ({made.stderr.strip()}): needs root and the vxcan "
            "module; `make test-vcan` runs this in a VM"
        )
    try:
        for end in (HOST_END, ROBOT_END):
            assert _ip("link", "set", "up", end).returncode == 0
        yield HOST_END, ROBOT_END
    finally:
        _ip("link", "del", HOST_END)


def test_dfki_driver_over_kernel_socketcan_equals_offline_stepping(vxcan_pair) -> None:
    canmotorlib = pytest.importorskip("motor_driver.canmotorlib")
    host_end, robot_end = vxcan_pair
    core = build_core(load_bench("virtual-mit-inprocess"), effects=None, mode=None)
    bus = open_socketcan(robot_end)
    server = MitDriveServer(core, bus, log=print)
    stop = threading.Event()
    thread = threading.Thread(target=server.serve_forever, args=(stop,), daemon=True)
    thread.start()
    data = np.genfromtxt(DFKI_FILE, delimiter=",", names=True, max_rows=ROWS)
    tau = np.clip(np.column_stack([data["tau_con1"], data["tau_con2"]]), -6.0, 6.0)
    try:
        # the guest's emulated CPU is slow: a generous socket timeout (a constructor argument)
        shoulder = canmotorlib.CanMotorController(host_end, 1, "AK80_6_V1p1", socket_timeout=30.0)
        elbow = canmotorlib.CanMotorController(host_end, 2, "AK80_6_V1p1", socket_timeout=30.0)
        assert shoulder.enable_motor() is not None and elbow.enable_motor() is not None
        got = []
        sent = []
        for t1, t2 in tau:
            p1 = shoulder.send_rad_command(0.0, 0.0, 0.0, 0.0, t1)[0]
            p2 = elbow.send_rad_command(0.0, 0.0, 0.0, 0.0, t2)[0]
            got.append((p1, p2))
            sent.append((t1, t2))
        shoulder.disable_motor()
        elbow.disable_motor()
        assert not any(d.motor_mode for d in server.drives)
    finally:
        stop.set()
        thread.join()
        bus.shutdown()
    assert server.ignored == 0 and server.errors == 0
    # the commands as the drive decodes them: the driver's own conversion (its axis direction
    # flips τ), decoded with the firmware's scaling
    r = AK80_6
    spans = ((-r.p_max, r.p_max), (-r.v_max, r.v_max), (0.0, r.kp_max), (0.0, r.kd_max))
    rows = []
    for t1, t2 in sent:
        row = []
        for t in (t1, t2):
            raw = shoulder.convert_physical_rad_to_raw(0.0, 0.0, 0.0, 0.0, t)
            bits = (16, 12, 12, 12, 12)
            ranges = (*spans, (-r.t_max, r.t_max))
            values = [
                mit.uint_to_float(u, lo, hi, n)
                for u, (lo, hi), n in zip(raw, ranges, bits, strict=True)
            ]
            row.append(mit.MitCommand(*values))
        rows.append(row)
    off = run_commands(load_robot("dfki-a0"), 0.002, rows)
    for j in range(2):
        expected = [
            -mit.uint_to_float(mit.float_to_uint(p, -12.5, 12.5, 16), -12.5, 12.5, 16)
            for p in off["p"][:, j]
        ]
        assert [p[j] for p in got] == pytest.approx(expected, abs=1e-12)
    assert np.ptp([p[0] for p in got]) > 0.0
