"""ODrive CANSimple: the emulated axis (virtual_robot.odrive_drive), its server
(virtual_robot.odrive_server) and the unmodified ``odrive-can`` client library driving it.

The library (odrive-can 2.1.0, pinned in pyproject.toml) takes a python-can bus: it runs here
in-process over python-can's ``virtual`` interface, asyncio as it is written.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import json
import math
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import can
import numpy as np
import pytest
from cli_run import assert_hil_run_equals_simulate, simulate_cli
from loop_clients import served_on

from drivers.protocol import odrive as od
from profiles.bench import load_bench
from profiles.drive import load_drive
from profiles.robot import load_robot
from virtual_robot.odrive_server import OdriveServer
from virtual_robot.odrive_simulate import run_torques
from virtual_robot.robot import LOCKSTEP, VirtualRobot
from virtual_robot.serve import build_core

PERIOD_S = 0.002
DRIVES = ("odrive-s1-d6374@1", "odrive-s1-d6374@2")  # robots/dfki-a0-odrive.toml


def _robot():
    """The DFKI double pendulum's links on two ODrive axes, node ids 1 and 2."""
    return load_robot("dfki-a0-odrive")


def _core() -> VirtualRobot:
    return VirtualRobot(_robot(), None, mode=LOCKSTEP, period_s=PERIOD_S)


def _served(
    channel: str, core: VirtualRobot | None = None, **kw: object
) -> contextlib.AbstractContextManager[OdriveServer]:
    return served_on(OdriveServer, core or _core(), channel, **kw)


def _frame(node: int, cmd: int, data: bytes = b"", **kw: object) -> can.Message:
    return can.Message(arbitration_id=od.can_id(node, cmd), data=data, is_extended_id=False, **kw)  # type: ignore[arg-type]


def _torques(n: int) -> np.ndarray:
    """Two smooth torque profiles within the axes' ±2.2 Nm."""
    t = np.arange(n) * PERIOD_S
    return np.column_stack([0.8 * np.sin(2 * np.pi * 2.0 * t), -0.5 * np.cos(2 * np.pi * 3.0 * t)])


# ---- byte layouts: ours against the library's own DBC -------------------------------------------
def test_layouts_match_the_odrive_can_dbc() -> None:
    """Our codec encodes what the library's DBC (odrive-cansimple-0.6.10, the vendor's
    CANSimple layouts) encodes, for every frame the emulation uses."""
    odrive_can = pytest.importorskip("odrive_can")
    dbc = odrive_can.get_dbc()

    def enc(name: str, **signals: object) -> bytes:
        msg = dbc.get_message_by_name(f"Axis3_{name}")
        full = {s.name: 0 for s in msg.signals} | signals
        assert msg.frame_id == od.can_id(3, msg.frame_id & 0x1F)
        return bytes(msg.encode(full))

    assert dbc.get_message_by_name("Axis3_Heartbeat").frame_id == od.can_id(3, od.HEARTBEAT)
    assert enc("Set_Axis_State", Axis_Requested_State=8) == od.pack_u32(od.CLOSED_LOOP_CONTROL)
    assert enc("Set_Controller_Mode", Control_Mode=1, Input_Mode=1) == od.pack_controller_mode(
        od.TORQUE_CONTROL, od.PASSTHROUGH
    )
    assert enc("Set_Input_Torque", Input_Torque=-1.25) == od.pack_input_torque(-1.25)
    assert enc("Get_Encoder_Estimates", Pos_Estimate=0.5, Vel_Estimate=-3.0) == (
        od.pack_encoder_estimates(0.5, -3.0)
    )
    hb = enc("Heartbeat", Axis_Error=od.WATCHDOG_TIMER_EXPIRED, Axis_State=1, Procedure_Result=13)
    assert hb[:7] == od.pack_heartbeat(od.WATCHDOG_TIMER_EXPIRED, od.IDLE, 13, False)[:7]
    decoded = dbc.get_message_by_name("Axis3_Heartbeat").decode(
        od.pack_heartbeat(od.ESTOP_REQUESTED, od.CLOSED_LOOP_CONTROL)
    )
    assert str(decoded["Axis_Error"]) == "ESTOP_REQUESTED"
    assert str(decoded["Axis_State"]) == "CLOSED_LOOP_CONTROL"
    for cmd, name in (
        (od.ESTOP, "Estop"),
        (od.REBOOT, "Reboot"),
        (od.CLEAR_ERRORS, "Clear_Errors"),
    ):
        msg = dbc.get_message_by_name(f"Axis3_{name}")
        assert msg.frame_id & 0x1F == cmd and msg.length == od.COMMAND_LENGTH[cmd]


# ---- the axis and the server, frame by frame ----------------------------------------------------
def test_state_machine_limits_and_bad_frames() -> None:
    bus = can.Bus(interface="virtual", channel="odrive-unit")
    lines: list[str] = []
    server = OdriveServer(_core(), bus, idle_timeout_s=0.5, log=lines.append)
    a1, a2 = server.drives
    try:
        # power-on: IDLE in POSITION_CONTROL; closed loop refused with BAD_CONFIG, no torque
        server.handle(_frame(1, od.SET_AXIS_STATE, od.pack_u32(od.CLOSED_LOOP_CONTROL)))
        assert a1.state == od.IDLE and a1.axis_error == od.BAD_CONFIG
        assert any("only TORQUE_CONTROL" in line for line in lines)
        # a latched error refuses closed loop until Clear_Errors
        server.handle(_frame(1, od.SET_CONTROLLER_MODE, od.pack_controller_mode(1, 1)))
        server.handle(_frame(1, od.SET_AXIS_STATE, od.pack_u32(od.CLOSED_LOOP_CONTROL)))
        assert a1.state == od.IDLE and a1.procedure_result == od.INVALID_STATE
        server.handle(_frame(1, od.CLEAR_ERRORS, b"\x00"))
        server.handle(_frame(1, od.SET_AXIS_STATE, od.pack_u32(od.CLOSED_LOOP_CONTROL)))
        assert a1.state == od.CLOSED_LOOP_CONTROL and a1.axis_error == 0
        # out of range: clamped at ±torque_lim (2.2 Nm); non-finite: dropped, setpoint kept
        server.handle(_frame(1, od.SET_INPUT_TORQUE, od.pack_input_torque(100.0)))
        assert a1.torque_Nm == pytest.approx(2.2)
        t0, ignored = server.core.t, server.ignored
        server.handle(_frame(1, od.SET_INPUT_TORQUE, od.pack_input_torque(math.nan)))
        server.handle(_frame(1, od.SET_INPUT_TORQUE, od.pack_input_torque(-math.inf)))
        assert a1.input_torque_Nm == 100.0 and a1.torque_Nm == pytest.approx(2.2)
        # bad frames: ignored, counted, no time passes, nothing changes
        server.handle(_frame(1, od.SET_INPUT_TORQUE, b"\x00\x00"))  # short
        server.handle(_frame(9, od.SET_INPUT_TORQUE, od.pack_input_torque(1.0)))  # no axis 9
        server.handle(_frame(1, od.SET_INPUT_POS, bytes(8)))  # not emulated
        server.handle(_frame(1, od.GET_ERROR, is_remote_frame=True, dlc=8))  # RTR not emulated
        server.handle(
            can.Message(arbitration_id=od.can_id(1, od.ESTOP), data=b"", is_extended_id=True)
        )
        assert server.ignored == ignored + 7 and server.errors == 0
        assert server.core.t == t0 and a1.state == od.CLOSED_LOOP_CONTROL
        # lockstep: axis 2 is IDLE, so axis 1's torque alone makes the periods
        server.handle(_frame(1, od.SET_INPUT_TORQUE, od.pack_input_torque(0.5)))
        assert server.core.t == pytest.approx(t0 + PERIOD_S)
        # the watchdog: axis 2 in closed loop but never commanded; 0.5 s of periods -> IDLE
        server.handle(_frame(2, od.SET_CONTROLLER_MODE, od.pack_controller_mode(1, 1)))
        server.handle(_frame(2, od.SET_AXIS_STATE, od.pack_u32(od.CLOSED_LOOP_CONTROL)))
        server.handle(_frame(2, od.SET_INPUT_TORQUE, od.pack_input_torque(1.0)))
        for _ in range(round(0.5 / PERIOD_S) + 2):  # + the period still open
            server.handle(_frame(1, od.SET_INPUT_TORQUE, od.pack_input_torque(0.1)))
        assert a2.state == od.IDLE and a2.axis_error == od.WATCHDOG_TIMER_EXPIRED
        assert a2.torque_Nm == 0.0 and a1.state == od.CLOSED_LOOP_CONTROL
        assert any("watchdog" in line for line in lines)
        # Estop: IDLE, ESTOP_REQUESTED; Reboot: the power-on state
        server.handle(_frame(1, od.ESTOP))
        assert a1.state == od.IDLE and a1.axis_error & od.ESTOP_REQUESTED and a1.torque_Nm == 0
        server.handle(_frame(1, od.REBOOT, b"\x00"))
        assert a1.axis_error == 0 and a1.control_mode == od.POSITION_CONTROL
        # a silent host: every axis IDLE, torque 0
        server.handle(_frame(1, od.SET_CONTROLLER_MODE, od.pack_controller_mode(1, 1)))
        server.handle(_frame(1, od.SET_AXIS_STATE, od.pack_u32(od.CLOSED_LOOP_CONTROL)))
        server.handle(_frame(1, od.SET_INPUT_TORQUE, od.pack_input_torque(1.0)))
        assert a1.torque_Nm == pytest.approx(1.0)
        server.poll(now=time.monotonic() + 0.6)
        assert a1.state == od.IDLE and a1.torque_Nm == 0.0
        assert any("host silent" in line for line in lines)
    finally:
        bus.shutdown()


# ---- the client library, unmodified -------------------------------------------------------------
async def _library_run(channel: str, torques: np.ndarray) -> tuple[np.ndarray, np.ndarray, list]:
    """odrive-can brings both axes up (torque control, passthrough, closed loop), then per
    period sends each axis its torque and waits for its encoder estimates."""
    from odrive_can import ODriveCAN
    from odrive_can.odrive import DriveError

    axes = [
        ODriveCAN(axis_id=n, can_bus=can.Bus(interface="virtual", channel=channel)) for n in (1, 2)
    ]
    queues: list[asyncio.Queue] = [asyncio.Queue() for _ in axes]
    for q, axis in zip(queues, axes, strict=True):
        axis.feedback_callback = lambda msg, _axis, q=q: q.put_nowait(
            (msg.data["Pos_Estimate"], msg.data["Vel_Estimate"])
        )
    notes: list = []
    try:
        for axis in axes:
            await axis.start()
            axis.check_alive()
            axis.check_errors()
            axis.set_controller_mode("TORQUE_CONTROL", "PASSTHROUGH")
            await axis.set_axis_state("CLOSED_LOOP_CONTROL")
        pos = np.zeros(torques.shape)
        vel = np.zeros(torques.shape)
        for k, row in enumerate(torques):
            for axis, tau in zip(axes, row, strict=True):
                axis.set_input_torque(float(tau))
            for j, q in enumerate(queues):
                pos[k, j], vel[k, j] = await asyncio.wait_for(q.get(), 2.0)
        # a silent client: the lockstep server's host-silence check stops both axes
        await asyncio.sleep(0.9)
        notes.append([axis.axis_state for axis in axes])
        # Estop through the library's own frame: the heartbeat reports the error
        axes[0]._send_message("Estop")
        await asyncio.sleep(0.3)
        try:
            axes[0].check_errors()
        except DriveError as exc:
            notes.append(str(exc))
        axes[0].clear_errors()
        await asyncio.sleep(0.3)
        axes[0].check_errors()
        return pos, vel, notes
    finally:
        for axis in axes:
            axis.stop()
            axis._bus.shutdown()  # the library leaves its bus to __del__


def test_odrive_can_library_drives_the_virtual_axes_in_lockstep() -> None:
    """The library's estimates equal the offline stepping of the same torques: the position to
    the encoder count (and bit for bit: both are the float32 of count / cpr), the velocity bit
    for bit (the float32 of the same window difference)."""
    pytest.importorskip("odrive_can")
    torques = _torques(150)
    with _served("odrive-lib", idle_timeout_s=0.5) as server:
        pos, vel, notes = asyncio.run(_library_run("odrive-lib", torques))
        assert server.errors == 0
    ref = run_torques(_robot(), PERIOD_S, torques)
    cpr = load_drive(DRIVES[0]).counts_per_rev
    np.testing.assert_array_equal(np.round(pos * cpr), ref["counts"])
    np.testing.assert_array_equal(pos, ref["pos_rev"])
    np.testing.assert_array_equal(vel, ref["vel_rev_s"])
    assert np.ptp(ref["counts"][:, 0]) > 100  # the arm moved: the comparison is not of zeros
    assert notes[0] == ["IDLE", "IDLE"]
    assert "ESTOP_REQUESTED" in notes[1]


def test_offline_stepping_follows_the_torque() -> None:
    """run_torques is physics, not an echo: a constant torque on the hanging pendulum's first
    joint accelerates it that way, and a torque beyond ±torque_lim acts as ±2.2 Nm."""
    n = 50
    up = run_torques(_robot(), PERIOD_S, [[1.0, 0.0]] * n)
    assert up["counts"][-1, 0] > 10 and up["vel_rev_s"][-1, 0] > 0
    big = run_torques(_robot(), PERIOD_S, [[50.0, 0.0]] * n)
    lim = run_torques(_robot(), PERIOD_S, [[2.2, 0.0]] * n)
    np.testing.assert_array_equal(big["counts"], lim["counts"])


async def _one_axis_over(bus: can.BusABC, torques: list[float]) -> tuple[list, list, str]:
    from odrive_can import ODriveCAN

    axis = ODriveCAN(axis_id=1, can_bus=bus)
    got: asyncio.Queue = asyncio.Queue()
    axis.feedback_callback = lambda msg, _axis: got.put_nowait(
        (msg.data["Pos_Estimate"], msg.data["Vel_Estimate"])
    )
    try:
        await axis.start()
        axis.set_controller_mode("TORQUE_CONTROL", "PASSTHROUGH")
        await axis.set_axis_state("CLOSED_LOOP_CONTROL")
        pos, vel = [], []
        for tau in torques:
            axis.set_input_torque(tau)
            p, v = await asyncio.wait_for(got.get(), 2.0)
            pos.append(p)
            vel.append(v)
        await axis.set_axis_state("IDLE")
        return pos, vel, axis.axis_state
    finally:
        axis.stop()


# odrive-can's ODriveCAN.__del__ shuts its bus down again after stop(): on a closed slcan port
# python-can raises inside __del__ (unraisable, after the test's work is done)
@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_virtual_robot_serve_odrive_bench_over_slcan() -> None:
    """End to end from the CLI: ``virtual-robot serve --bench virtual-odrive-slcan`` and the
    library on the announced slcan pty; axis 2 stays IDLE (torque 0), so its estimates are the
    offline stepping with axis 2 at zero torque."""
    pytest.importorskip("odrive_can")
    proc = subprocess.Popen(
        [sys.executable, "-m", "virtual_robot.cli", "serve", "--bench", "virtual-odrive-slcan"],
        cwd=Path(__file__).resolve().parents[1],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        info = json.loads(proc.stdout.readline())  # type: ignore[union-attr]
        assert info["event"] == "ready" and info["protocol"] == "odrive"
        bus = can.Bus(interface="slcan", channel=info["channel"])
        torques = [0.6] * 40 + [-0.6] * 40
        pos, _vel, state = asyncio.run(_one_axis_over(bus, torques))
    finally:
        proc.terminate()
        proc.wait(10)
        # finalize the library's objects here, not inside a later test's ast.parse: CPython
        # 3.11's traceback formatting of an unraisable exception parses too (SystemError)
        gc.collect()
    assert state == "IDLE"
    ref = run_torques(_robot(), PERIOD_S, [[t, 0.0] for t in torques])
    np.testing.assert_array_equal(np.array(pos), ref["pos_rev"][:, 0])
    assert ref["counts"][39, 0] > 20


ODRIVE_MULTISINE = """
name = "odrive-multisine"
kind = "open_loop_torque"
period_s = 0.002
duration_s = 0.3
[[joints]]
sines = [{ amplitude_Nm = 1.2, omega_rad_s = 9.0, phase_rad = 0.3 }]
[[joints]]
sines = [{ amplitude_Nm = 0.5, omega_rad_s = 14.0, phase_rad = 1.0 }]
"""


def test_library_reads_what_virtual_robot_simulate_writes(tmp_path: Path) -> None:
    """`virtual-robot simulate --robot dfki-a0-odrive` of an experiment writes, row for row, the
    positions odrive-can reads when it sends that experiment's torques (row k+1 is the estimate
    after period k), to the encoder count."""
    pytest.importorskip("odrive_can")
    sim, tau = simulate_cli("dfki-a0-odrive", ODRIVE_MULTISINE, tmp_path)
    sim = sim.columns
    with _served("odrive-sim", idle_timeout_s=0.5):
        pos, _vel, _notes = asyncio.run(_library_run("odrive-sim", tau))
    q = 2.0 * np.pi * pos[:-1]
    np.testing.assert_array_equal(q[:, 0], sim["q1"][1:])
    np.testing.assert_array_equal(q[:, 1], sim["q2"][1:])
    assert np.ptp(sim["q1"]) > 0.05


def test_hil_run_over_the_odrive_bench_equals_virtual_robot_simulate(tmp_path: Path) -> None:
    """This project's host on CANSimple (drivers/odrive_arm.py): `hil run` of an experiment over
    the ODrive bench (slcan, lockstep) records the q and τ `virtual-robot simulate` writes for
    it, row for row, bit for bit."""
    host = assert_hil_run_equals_simulate(
        "virtual-odrive-slcan", "dfki-a0-odrive", ODRIVE_MULTISINE, tmp_path, rows=150
    )
    assert np.ptp(host.q[:, 0]) > 0.05


async def _realtime_run(channel: str) -> tuple[list[float], str, str]:
    from odrive_can import ODriveCAN
    from odrive_can.odrive import DriveError

    axis = ODriveCAN(axis_id=1, can_bus=can.Bus(interface="virtual", channel=channel))
    pos: list[float] = []
    axis.feedback_callback = lambda msg, _axis: pos.append(msg.data["Pos_Estimate"])
    try:
        await axis.start()
        axis.set_controller_mode("TORQUE_CONTROL", "PASSTHROUGH")
        await axis.set_axis_state("CLOSED_LOOP_CONTROL")
        for _ in range(15):  # 0.3 s of 1 Nm, a command every 20 ms
            axis.set_input_torque(1.0)
            await asyncio.sleep(0.02)
        await asyncio.sleep(0.9)  # silent: the axis' own watchdog (0.5 s)
        error = ""
        try:
            axis.check_errors()
        except DriveError as exc:
            error = str(exc)
        return pos, axis.axis_state, error
    finally:
        axis.stop()
        axis._bus.shutdown()


def test_realtime_cyclic_estimates_and_watchdog() -> None:
    """Realtime: the estimates arrive every encoder_period_s without being asked, the axis moves
    under the torque, and a client gone silent trips the axis' own watchdog: IDLE, and the
    library's check_errors raises WATCHDOG_TIMER_EXPIRED."""
    pytest.importorskip("odrive_can")
    core = build_core(load_bench("virtual-odrive-slcan"), effects=None, mode="realtime")
    with _served("odrive-rt", core) as server:
        pos, state, error = asyncio.run(_realtime_run("odrive-rt"))
        assert server.errors == 0
    assert len(pos) > 50  # ~1.5 s at 10 ms
    assert max(pos) > 0.01  # rev: the first joint went the torque's way
    assert state == "IDLE"
    assert "WATCHDOG_TIMER_EXPIRED" in error


def test_node_id_beyond_six_bits_is_refused() -> None:
    """`odrive-s1-d6374@70` cannot be addressed by CANSimple: the robot is refused up front."""
    robot = replace(_robot(), drives=("odrive-s1-d6374@1", "odrive-s1-d6374@70"))
    with pytest.raises(ValueError, match="node id 70: a CANSimple node id has 6 bits"):
        VirtualRobot(robot, None, mode=LOCKSTEP, period_s=PERIOD_S)


def test_hil_control_over_the_odrive_bench(tmp_path: Path) -> None:
    """Issue 28 item 4: this project's controllers on CANSimple drives. PD with gravity
    compensation tracks the Khosla & Kanade trajectory over the ODrive bench (slcan, lockstep):
    every period recorded, the law's torque held at the axes' 2.2 Nm limit where it asks for
    more, and the report says so."""
    from cli_run import hil

    from drivers.recording import read_signals

    out = tmp_path / "pd"
    proc = hil(
        "control", "--bench", "virtual-odrive-slcan", "--scheme", "pd", "--duration", "0.5",
        "--out", str(out), "--no-plot", "--json",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    run = report["run"]
    assert run["status"] == "complete" and run["rows"] == 250
    assert report["reference_torque"]["torque_limit_Nm"] == [2.2, 2.2]
    tau = np.asarray(read_signals(out).columns["tau1"])
    # CANSimple carries torque as float32: the limit is 2.2 rounded to float32
    assert len(tau) == 250 and np.abs(tau).max() <= float(np.float32(2.2))
    assert run["clipped_cycles"][0] > 0  # the shoulder's law asks for more than 2.2 Nm
