"""moteus over CAN-FD on kernel SocketCAN (docs/protocol.md "CAN-FD: moteus", docs/vcan.md): the
unmodified ``moteus`` library's python-can transport, and this project's host, against
`virtual-robot serve --bench virtual-moteus-vcan` on a vcan of the CAN-FD MTU.

A new vcan interface has the CAN-FD MTU, 72 (linux drivers/net/can/vcan.c), and carries CAN-FD
frames as it is. An interface of the classic MTU, 16 (a real one without ``fd on``, or a vcan set
so), makes the kernel refuse every FD frame sent on it (EINVAL), which
``drivers.links.open_socketcan(fd=True)`` reports in one line before anything is sent. The
fixture makes ``vcanfd0``; needs root and the vcan module: `make test-vcan` runs these in its guest.
"""

from __future__ import annotations

import asyncio
import json
import shutil
import subprocess
import sys

import can
import numpy as np
import pytest
from cli_run import ROOT, SLOW_GUEST, assert_hil_run_equals_simulate, bench_copy, hil
from moteus_clients import MULTISINE, PERIOD_S, commands, library_run

from drivers.links import interface_mtu, open_socketcan
from profiles.robot import load_robot
from virtual_robot.moteus_simulate import run_commands

pytestmark = pytest.mark.vcan

FD_IF = "vcanfd0"  # the channel of benches/virtual-moteus-vcan.toml
ROWS = 60


def _ip(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=10)


@pytest.fixture(scope="module")
def vcanfd0():
    if shutil.which("ip") is None:
        pytest.skip("no `ip` command")
    made = _ip("link", "add", "dev", FD_IF, "type", "vcan")
    if made.returncode != 0:
        pytest.skip(
            f"cannot make {FD_IF} ({made.stderr.strip()}): needs root and the vcan module; "
            "`make test-vcan` runs this in a VM"
        )
    try:
        assert _ip("link", "set", "up", FD_IF).returncode == 0
        yield FD_IF
    finally:
        _ip("link", "del", FD_IF)


def test_moteus_library_over_socketcan_canfd_equals_the_offline_stepping(vcanfd0, tmp_path):
    """`virtual-robot serve --bench virtual-moteus-vcan` (a copy with the slow guest's silence
    bound) on vcanfd0; moteus.PythonCan(interface="socketcan", channel="vcanfd0") sends torque,
    then PD commands to both controllers: its replies equal run_commands bit for bit."""
    moteus = pytest.importorskip("moteus")
    bench = bench_copy("virtual-moteus-vcan", tmp_path, SLOW_GUEST)
    serve = subprocess.Popen(
        [sys.executable, "-m", "virtual_robot.cli", "serve", "--bench", str(bench)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    rows = commands(ROWS)
    try:
        info = json.loads(serve.stdout.readline())  # type: ignore[union-attr]
        assert info["event"] == "ready", serve.stderr.read()  # type: ignore[union-attr]
        assert info["protocol"] == "moteus" and info["channel"] == vcanfd0
        got = asyncio.run(
            library_run(lambda: moteus.PythonCan(interface="socketcan", channel=vcanfd0), rows)
        )
    finally:
        serve.terminate()
        serve.wait(30)
    ref = run_commands(load_robot("dfki-a0-moteus"), PERIOD_S, rows)
    for key in ("mode", "position_rev", "velocity_rev_s", "torque_Nm"):
        np.testing.assert_array_equal(got[key], ref[key], err_msg=key)
    assert np.ptp(ref["position_rev"][:, 0]) > 1e-4  # the arm moved


def test_hil_run_over_socketcan_canfd_equals_virtual_robot_simulate(vcanfd0, tmp_path):
    """This project's host (drivers/moteus_arm.py) on python-can socketcan with CAN-FD frames:
    `hil run --bench virtual-moteus-vcan` records the q and τ of `virtual-robot simulate`."""
    bench = bench_copy("virtual-moteus-vcan", tmp_path, SLOW_GUEST)
    host = assert_hil_run_equals_simulate(
        str(bench), "dfki-a0-moteus", MULTISINE, tmp_path, rows=150, timeout=600
    )
    assert np.ptp(host.q[:, 0]) > 0.05
    meta = json.loads((tmp_path / "h" / "meta.json").read_text())
    assert meta["channel"]["transport"] == "socketcan" and meta["channel"]["channel"] == vcanfd0


def test_classic_vcan_refuses_canfd_frames_and_the_bench_says_so(vcanfd0, tmp_path):
    """A new vcan has the CAN-FD MTU; set to the classic MTU (16), the kernel refuses an FD frame
    at send (EINVAL): open_socketcan(fd=True) says so in one line, naming the MTU command, and a
    moteus bench on such an interface stops before the run with that line."""
    assert interface_mtu(vcanfd0) == 72
    classic = "vcanc0"
    made = _ip("link", "add", "dev", classic, "type", "vcan")
    assert made.returncode == 0, made.stderr
    try:
        assert _ip("link", "set", classic, "mtu", "16").returncode == 0
        assert _ip("link", "set", "up", classic).returncode == 0
        raw = can.Bus(interface="socketcan", channel=classic, fd=True)
        try:
            with pytest.raises(can.CanOperationError) as refused:
                raw.send(can.Message(arbitration_id=0x8001, data=bytes(12), is_fd=True))
            assert refused.value.error_code == 22  # EINVAL: no FD frame on an MTU-16 interface
        finally:
            raw.shutdown()
        with pytest.raises(OSError, match=r"classic CAN only \(MTU 16\).*mtu 72"):
            open_socketcan(classic, fd=True)
        bench = bench_copy("virtual-moteus-vcan", tmp_path, {'"vcanfd0"': f'"{classic}"'})
        proc = hil("run", "--bench", str(bench), "--duration", "0.1", "--out", str(tmp_path / "r"))
        assert proc.returncode == 3, proc.stderr
        assert "classic CAN only (MTU 16)" in proc.stderr and "mtu 72" in proc.stderr
    finally:
        _ip("link", "del", classic)
