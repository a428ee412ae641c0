"""mjbots moteus: the codec (drivers.protocol.moteus) against the ``moteus`` library's own
encoder and parser, the emulated controller and its server (virtual_robot.moteus_drive,
moteus_server), and the unmodified ``moteus`` client library (1.1.1, pinned in pyproject.toml)
driving the virtual robot through an fdcanusb on a pty (virtual_robot.fdcanusb_device).
"""

from __future__ import annotations

import asyncio
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import can
import numpy as np
import pytest
from cli_run import assert_hil_run_equals_simulate, hil, simulate_cli
from loop_clients import serving
from moteus_clients import MULTISINE, PERIOD_S, commands, library_run

from drivers.protocol import moteus as mo
from profiles.bench import load_bench
from profiles.robot import load_robot
from virtual_robot.fdcanusb_device import FdcanusbPtyBus
from virtual_robot.moteus_drive import PositionCommand
from virtual_robot.moteus_server import MoteusServer
from virtual_robot.moteus_simulate import run_commands, torque_command
from virtual_robot.robot import LOCKSTEP, VirtualRobot
from virtual_robot.serve import build_core

ROOT = Path(__file__).resolve().parents[1]


def _robot():
    """The DFKI double pendulum's links on two qdd100 servos, moteus ids 1 and 2."""
    return load_robot("dfki-a0-moteus")


def _core() -> VirtualRobot:
    return VirtualRobot(_robot(), None, mode=LOCKSTEP, period_s=PERIOD_S)


# ---- codec: ours against the library's ---------------------------------------------------------
def test_codec_reads_the_library_commands_and_the_library_reads_our_replies() -> None:
    moteus = pytest.importorskip("moteus")
    from moteus import multiplex as mp
    from moteus.protocol import Register, parse_registers

    res = moteus.PositionResolution()
    res.position, res.velocity, res.feedforward_torque = mp.INT16, mp.INT32, mp.INT8
    res.kp_scale, res.watchdog_timeout = mp.INT16, mp.INT32
    c = moteus.Controller(id=5, position_resolution=res)
    cmd = c.make_position(
        position=math.nan,
        velocity=0.75,
        feedforward_torque=-1.5,
        kp_scale=0.25,
        kd_scale=0.5,
        maximum_torque=3.0,
        watchdog_timeout=0.05,
        query=True,
    )
    ours = {s.register: s.value for s in mo.parse(cmd.data) if s.kind == mo.WRITE_BASE}
    theirs = parse_registers(cmd.data).command
    assert ours.keys() == theirs.keys()
    for reg, value in theirs.items():
        assert ours[reg] == pytest.approx(value, nan_ok=True), hex(reg)
    assert ours[mo.MODE] == mo.POSITION_MODE and math.isnan(ours[mo.CMD_POSITION])
    reads = [(s.register, s.resolution) for s in mo.parse(cmd.data) if s.kind == mo.READ_BASE]
    assert reads == parse_registers(cmd.data).query
    # a reply of ours, in every resolution, read by the library
    for r in (mo.INT8, mo.INT16, mo.INT32, mo.F32):
        data = mo.pack_registers(mo.REPLY_BASE, mo.POSITION, r, [0.123, -2.5, 1.25])
        data += mo.pack_error(True, 0x123, 1)
        got = parse_registers(mo.pad_fd(data))
        scale = (0.01, 0.0001, 0.00001, 0)[r]
        for reg, v in ((Register.POSITION, 0.123), (Register.VELOCITY, -2.5)):
            assert got.response[reg] == pytest.approx(v, abs=scale + 1e-6)
        assert got.errors == [(0x123, 1)]
    # the line checksum: the library's
    from moteus.fdcanusb_device import _append_checksum

    line = b"can send 8005 0102 BF"
    assert mo.add_checksum(line) == _append_checksum(line)
    assert mo.strip_checksum(_append_checksum(line)) == (line, True)


# ---- the controller and its server, frame by frame ----------------------------------------------
def _pos(c, **kw) -> bytes:
    return bytes(c.make_position(**kw).data)


def test_modes_limits_watchdog_and_bad_frames() -> None:
    """Position mode with its PD and clamp; refused commands keep torque 0; bad frames and
    wrong ids are ignored; the watchdog sends a silent client's controller to TIMEOUT (torque 0)
    until a stop; a silent host stops every controller."""
    moteus = pytest.importorskip("moteus")
    bus = can.Bus(interface="virtual", channel="moteus-unit")
    host = can.Bus(interface="virtual", channel="moteus-unit")
    lines: list[str] = []
    server = MoteusServer(_core(), bus, idle_timeout_s=0.5, log=lines.append)
    c1, c2 = moteus.Controller(id=1), moteus.Controller(id=2)
    d1, d2 = server.drives

    def send(arb: int, data: bytes) -> None:
        server.handle(can.Message(arbitration_id=arb, data=data, is_fd=True, is_extended_id=True))

    def reply() -> dict:
        msg = host.recv(0.5)
        assert msg is not None
        from moteus.protocol import parse_registers

        return parse_registers(bytes(msg.data)).response | {
            "errors": parse_registers(bytes(msg.data)).errors,
            "id": msg.arbitration_id,
        }

    try:
        # out of range: the torque is clamped at the qdd100's 16 Nm, and at maximum_torque
        send(
            0x8001,
            _pos(
                c1, position=math.nan, kp_scale=0, kd_scale=0, feedforward_torque=100.0, query=True
            ),
        )
        r = reply()
        assert r["id"] == 0x100 and r[0] == mo.POSITION_MODE and r[3] == pytest.approx(16.0)
        send(
            0x8001,
            _pos(
                c1, feedforward_torque=5.0, kp_scale=0, kd_scale=0, maximum_torque=2.0, query=True
            ),
        )
        assert reply()[3] == pytest.approx(2.0)
        # refused: a non-finite feed-forward, a mode not emulated, a register not run
        t0, before = server.core.t, d1.command
        send(0x8001, _pos(c1, feedforward_torque=math.inf, kp_scale=0, query=True))
        assert reply()["errors"] == [(mo.MODE, 3)] and d1.command is before
        send(0x8001, bytes(c1.make_current(d_A=0.0, q_A=5.0, query=True).data))
        assert reply()["errors"] == [(mo.MODE, 3)] and d1.command is before
        send(0x8001, _pos(c1, feedforward_torque=1.0, velocity_limit=2.0, query=True))
        assert reply()["errors"] == [(mo.MODE, 3)] and d1.command is before
        # a stopped controller refuses nothing and applies no torque
        assert d2.mode == mo.STOPPED and d2.torque_Nm == 0.0
        # bad frames: ignored, counted, nothing applied, no time passes
        ignored = server.ignored
        send(0x8009, _pos(c1, feedforward_torque=1.0, query=True))  # no controller 9
        send(0x807F, _pos(c1, feedforward_torque=1.0, query=True))  # broadcast: not emulated
        send(0x18001, _pos(c1, feedforward_torque=1.0, query=True))  # another CAN prefix
        send(0x8001, b"\x0d\x20")  # a float32 write cut short
        send(0x8001, b"\x61\x00")  # an unknown subframe
        server.handle(can.Message(arbitration_id=0x8001, is_remote_frame=True, is_extended_id=True))
        assert server.ignored == ignored + 6 and server.errors == 0
        assert host.recv(0.05) is None and server.core.t == t0
        # PD: position 0.1 rev ahead with kp_scale 1 -> τ = kp · 0.1 rev (d1's velocity ~ 0)
        p = d1.position_rev
        send(
            0x8001, _pos(c1, position=p + 0.1, velocity=0.0, kp_scale=1.0, kd_scale=0.0, query=True)
        )
        assert reply()[3] == pytest.approx(d1.kp * 0.1, rel=1e-6)
        # the watchdog: controller 2 in position mode, never commanded again; its 0.1 s of
        # periods pass under controller 1's commands -> TIMEOUT, torque 0, a position refused
        send(0x8002, _pos(c2, feedforward_torque=1.0, kp_scale=0, kd_scale=0, query=True))
        reply()
        for _ in range(round(0.1 / PERIOD_S) + 2):
            send(0x0001, _pos(c1, feedforward_torque=0.0, kp_scale=0, kd_scale=0))
        assert d2.mode == mo.TIMEOUT_MODE and d2.torque_Nm == 0.0
        assert any("watchdog" in line for line in lines)
        send(0x8002, _pos(c2, feedforward_torque=1.0, kp_scale=0, kd_scale=0, query=True))
        r = reply()
        assert r[0] == mo.TIMEOUT_MODE and r["errors"] == [(mo.MODE, 3)] and d2.torque_Nm == 0
        send(0x8002, bytes(c2.make_stop(query=True).data))
        assert reply()[0] == mo.STOPPED
        # a silent host: every controller stopped, torque 0
        send(0x0001, _pos(c1, feedforward_torque=1.0, kp_scale=0, kd_scale=0))
        assert d1.torque_Nm == pytest.approx(1.0)
        server.poll(now=time.monotonic() + 0.6)
        assert d1.mode == mo.STOPPED and d1.torque_Nm == 0.0
        assert any("host silent" in line for line in lines)
    finally:
        bus.shutdown()
        host.shutdown()


def test_zero_velocity_damps_and_the_modes_not_run_are_refused() -> None:
    """The library's make_zero_velocity: mode 12, τ = −kd_scale · kd · v every period, no
    watchdog and no period's command needed; in TIMEOUT refused. make_brake, make_current,
    make_vfoc, make_stay_within and a mode beyond the firmware's 15: write error 3 (the
    firmware's code for a mode it lacks), logged with why, command and mode kept."""
    moteus = pytest.importorskip("moteus")
    from moteus.protocol import parse_registers

    bus = can.Bus(interface="virtual", channel="moteus-modes")
    host = can.Bus(interface="virtual", channel="moteus-modes")
    lines: list[str] = []
    server = MoteusServer(_core(), bus, idle_timeout_s=5.0, log=lines.append)
    c1, c2 = moteus.Controller(id=1), moteus.Controller(id=2)
    d1, d2 = server.drives

    def send(arb: int, data: bytes) -> dict:
        server.handle(can.Message(arbitration_id=arb, data=data, is_fd=True, is_extended_id=True))
        msg = host.recv(0.5)
        assert msg is not None
        got = parse_registers(bytes(msg.data))
        return got.response | {"errors": got.errors}

    try:
        torque = _pos(c1, position=math.nan, kp_scale=0, kd_scale=0, feedforward_torque=3.0)
        send(0x8001, torque + bytes(c1.make_query().data))
        send(0x8002, _pos(c2, feedforward_torque=0.0, kp_scale=0, kd_scale=0, query=True))
        for _ in range(20):  # 3 Nm on joint 1 for 20 periods (controller 2 sets the pace)
            send(0x8001, _pos(c1, feedforward_torque=3.0, kp_scale=0, kd_scale=0, query=True))
            send(0x8002, _pos(c2, feedforward_torque=0.0, kp_scale=0, kd_scale=0, query=True))
        r = send(0x8001, bytes(c1.make_zero_velocity(kd_scale=0.5, query=True).data))
        assert r[0] == mo.ZERO_VELOCITY_MODE and r[2] > 0.05  # moving up
        assert r[3] == pytest.approx(-0.5 * d1.kd * r[2], rel=1e-5)
        t0 = server.core.t
        rows = []
        for _ in range(round(0.1 / PERIOD_S) + 10):  # past the 0.1 s watchdog: none in mode 12
            send(0x8002, _pos(c2, feedforward_torque=0.0, kp_scale=0, kd_scale=0, query=True))
            rows.append(send(0x8001, bytes(c1.make_query().data)))
        assert server.core.t > t0  # periods passed without a command to controller 1
        assert all(r[0] == mo.ZERO_VELOCITY_MODE for r in rows)
        for r in rows:  # the damping law, against the velocity it reads
            assert r[3] == pytest.approx(-0.5 * d1.kd * r[2], rel=1e-5, abs=1e-6)
        # refused: the modes not run, each with its reason; mode 12 and its command kept
        before = d1.command
        for frame, name in (
            (c1.make_brake(query=True), "brake"),
            (c1.make_current(d_A=0.0, q_A=2.0, query=True), "current"),
            (c1.make_vfoc(theta=0.0, voltage=1.0, query=True), "voltage foc"),
            (c1.make_stay_within(lower_bound=-0.1, upper_bound=0.1, query=True), "stay within"),
        ):
            r = send(0x8001, bytes(frame.data))
            assert r["errors"] == [(mo.MODE, 3)] and r[0] == mo.ZERO_VELOCITY_MODE, name
            assert d1.command is before
            assert any(f"({name}) is not emulated" in line for line in lines), name
        no_such = mo.pack_registers(mo.WRITE_BASE, mo.MODE, mo.INT8, [16])
        assert send(0x8001, no_such + mo.pack_read(mo.MODE, mo.INT8, 1))["errors"] == [(mo.MODE, 3)]
        assert any("no such mode" in line for line in lines)
        # in TIMEOUT (controller 2 silent past its watchdog): zero velocity refused until a stop
        for _ in range(round(0.1 / PERIOD_S) + 2):
            send(0x8001, _pos(c1, feedforward_torque=0.0, kp_scale=0, kd_scale=0, query=True))
        assert d2.mode == mo.TIMEOUT_MODE
        r = send(0x8002, bytes(c2.make_zero_velocity(query=True).data))
        assert r[0] == mo.TIMEOUT_MODE and r["errors"] == [(mo.MODE, 3)]
        send(0x8002, bytes(c2.make_stop(query=True).data))
        r = send(0x8002, bytes(c2.make_zero_velocity(query=True).data))  # kd_scale 1
        assert r[0] == mo.ZERO_VELOCITY_MODE and d2.command.kd_scale == 1.0
        assert server.errors == 0
    finally:
        bus.shutdown()
        host.shutdown()


def test_offline_stepping_follows_the_torque_and_the_pd() -> None:
    """run_commands is physics, not an echo: +1 Nm accelerates the first joint that way; a
    torque beyond the 16 Nm clamp acts as 16 Nm; the position PD pulls toward its target with
    kp (p_c − p) + kd (v_c − v)."""
    n = 50
    up = run_commands(_robot(), PERIOD_S, [[torque_command(1.0), torque_command(0.0)]] * n)
    assert up["position_rev"][-1, 0] > 1e-3 and up["velocity_rev_s"][-1, 0] > 0
    big = run_commands(_robot(), PERIOD_S, [[torque_command(80.0), torque_command(0.0)]] * n)
    lim = run_commands(_robot(), PERIOD_S, [[torque_command(16.0), torque_command(0.0)]] * n)
    np.testing.assert_array_equal(big["position_rev"], lim["position_rev"])
    hold = PositionCommand(position_rev=0.05, velocity_rev_s=0.0)
    pd = run_commands(_robot(), PERIOD_S, [[hold, hold]] * 400)
    p, v, tau = (pd[k][-1, 0] for k in ("position_rev", "velocity_rev_s", "torque_Nm"))
    assert (
        p > 1e-3
    )  # pulled up against gravity, the qdd100's default gains (4 Nm/rev) too weak to get there
    assert tau == pytest.approx(4.0 * (0.05 - p) - 0.1 * v, rel=1e-5)  # the position-mode law


# ---- the client library, unmodified -------------------------------------------------------------
@pytest.mark.parametrize("via", ["fdcanusb", "pythoncan"])
def test_moteus_library_in_lockstep_equals_the_offline_stepping(via: str) -> None:
    """The library's replies (mode, position, velocity, torque, float32) equal the offline
    stepping of the same commands bit for bit, through torque and PD phases, over both its
    transports that run here: the fdcanusb (a pty) and python-can (CAN-FD frames on
    python-can's virtual bus)."""
    moteus = pytest.importorskip("moteus")
    rows = commands(200)
    if via == "fdcanusb":
        bus: can.BusABC = FdcanusbPtyBus()
        where = bus.channel_path  # type: ignore[attr-defined]
        make = lambda: moteus.Fdcanusb(where)  # noqa: E731
    else:
        where = "moteus-pythoncan"
        bus = can.Bus(interface="virtual", channel=where)
        make = lambda: moteus.PythonCan(interface="virtual", channel=where)  # noqa: E731
    with serving(MoteusServer(_core(), bus, idle_timeout_s=2.0)) as server:
        got = asyncio.run(library_run(make, rows))
        assert server.errors == 0 and server.ignored == 0
    ref = run_commands(_robot(), PERIOD_S, rows)
    for key in ("mode", "position_rev", "velocity_rev_s", "torque_Nm"):
        np.testing.assert_array_equal(got[key], ref[key], err_msg=key)
    assert np.ptp(ref["position_rev"][:, 0]) > 0.01  # the arm moved
    assert np.any(ref["torque_Nm"][100:, 0] != 0)  # the PD acted


def test_virtual_robot_serve_moteus_bench_equals_virtual_robot_simulate(tmp_path: Path) -> None:
    """End to end from the CLI: `virtual-robot serve --bench virtual-moteus-fdcanusb`, the
    library on the announced pty sending an experiment's torques, and `virtual-robot simulate
    --robot dfki-a0-moteus` of that experiment: the same q (2π × position) and τ, row for row."""
    moteus = pytest.importorskip("moteus")
    sim, tau = simulate_cli("dfki-a0-moteus", MULTISINE, tmp_path)
    sim = sim.columns
    rows = [[torque_command(t) for t in row] for row in tau]
    serve = subprocess.Popen(
        [sys.executable, "-m", "virtual_robot.cli", "serve", "--bench", "virtual-moteus-fdcanusb"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        info = json.loads(serve.stdout.readline())  # type: ignore[union-attr]
        assert info["event"] == "ready" and info["protocol"] == "moteus"
        got = asyncio.run(library_run(lambda: moteus.Fdcanusb(info["channel"]), rows))
    finally:
        serve.terminate()
        serve.wait(10)
    np.testing.assert_array_equal(2 * np.pi * got["position_rev"][:, 0], sim["q1"])
    np.testing.assert_array_equal(2 * np.pi * got["position_rev"][:, 1], sim["q2"])
    np.testing.assert_array_equal(got["torque_Nm"][:, 0], sim["tau1"])
    assert np.ptp(sim["q1"]) > 0.05


async def _silent_run(path: str) -> tuple[list[int], list[float]]:
    """2 Nm for 0.2 s, 0.3 s of silence, a position command (refused in TIMEOUT), a stop and a
    position command again: the mode and torque each reply reports."""
    import moteus

    c = moteus.Controller(id=1, transport=moteus.Fdcanusb(path))
    modes, torques = [], []

    def note(r: object) -> None:
        modes.append(r.values[moteus.Register.MODE])  # type: ignore[attr-defined]
        torques.append(r.values[moteus.Register.TORQUE])  # type: ignore[attr-defined]

    kw = {"position": math.nan, "kp_scale": 0, "kd_scale": 0, "feedforward_torque": 2.0}
    for _ in range(10):  # a command every 20 ms
        note(await c.set_position(**kw, query=True))
        await asyncio.sleep(0.02)
    await asyncio.sleep(0.3)  # silent: the controller's own watchdog (0.1 s)
    note(await c.query())
    note(await c.set_position(**kw, query=True))  # refused: only a stop leaves TIMEOUT
    note(await c.set_stop(query=True))
    note(await c.set_position(**kw, query=True))
    await c.set_stop()
    return modes, torques


def test_realtime_watchdog_sends_a_silent_client_to_timeout() -> None:
    """Realtime: the controller's own timer runs its watchdog; a client silent for 0.3 s finds
    it in TIMEOUT (mode 11) with torque 0, as the firmware reports it; a position command does
    not leave TIMEOUT (torque stays 0), a stop does, and position mode works again."""
    pytest.importorskip("moteus")
    core = build_core(load_bench("virtual-moteus-fdcanusb"), effects=None, mode="realtime")
    bus = FdcanusbPtyBus()
    with serving(MoteusServer(core, bus)) as server:
        modes, torques = asyncio.run(_silent_run(bus.channel_path))
        assert server.errors == 0
    assert modes[:10] == [mo.POSITION_MODE] * 10 and torques[:10] == [2.0] * 10
    assert modes[10:] == [mo.TIMEOUT_MODE, mo.TIMEOUT_MODE, mo.STOPPED, mo.POSITION_MODE]
    assert torques[10:] == [0.0, 0.0, 0.0, 2.0]
    assert core.drives[0].mode == mo.STOPPED and core.drives[0].torque_Nm == 0.0


def test_hil_run_over_the_moteus_bench_equals_virtual_robot_simulate(tmp_path: Path) -> None:
    """This project's host on the register protocol (drivers/moteus_arm.py, drivers/fdcanusb.py):
    `hil run` of an experiment over the moteus bench (fdcanusb pty, lockstep) records the q and τ
    `virtual-robot simulate` writes for it, row for row, bit for bit."""
    host = assert_hil_run_equals_simulate(
        "virtual-moteus-fdcanusb", "dfki-a0-moteus", MULTISINE, tmp_path, rows=150
    )
    assert np.ptp(host.q[:, 0]) > 0.05


def test_hil_identify_over_the_moteus_bench_runs_the_arms_own_excitation(tmp_path: Path) -> None:
    """`hil identify --bench virtual-moteus-fdcanusb` with the default excitation: the arm's own
    dfki-a0-moteus-excitation and -validation (hil excite designs within the bench's limits),
    not reyes-kelly (the CICESE arm's 97 Nm torques, which clamped at the qdd100's 16 Nm spin
    the light DFKI links past the bench's 20 rad/s within 0.1 s, as the first run shows): the
    runs stay inside the bench's limits and θ1..θ5 come out within 0.5 % of the profile's."""
    from drivers.recording import read_signals
    from hil.identify.outcome import arm_experiment

    assert arm_experiment("cicese", "excitation", "reyes-kelly") == "reyes-kelly"
    bench = ["--bench", "virtual-moteus-fdcanusb"]
    paper = hil("identify", *bench, "--experiment", "reyes-kelly", "--out", str(tmp_path / "p"))
    assert paper.returncode != 0 and "velocity" in paper.stderr and "beyond 20.0" in paper.stderr
    out = tmp_path / "id"
    proc = hil("identify", *bench, "--duration", "2", "--out", str(out), "--no-plot", "--json")
    assert proc.returncode == 0, proc.stderr
    for run, experiment in (("fit", "excitation"), ("validation", "validation")):
        meta = json.loads((out / run / "meta.json").read_text())
        assert meta["experiment"] == f"dfki-a0-moteus-{experiment}"
        rec = read_signals(out / run).columns
        assert len(rec["t"]) == 1000
        for q in ("q1", "q2"):
            dq = np.diff(rec[q]) / PERIOD_S
            assert 5.0 < np.max(np.abs(dq)) < 20.0  # excited, inside the bench's limit
    report = json.loads(proc.stdout)
    assert report["selection"]["usable"]
    for row in report["discretizations"]["exact"]["table_ii"][:5]:
        assert abs(row["filtered_dynamic_error"]) < 5e-3, row


# ---- the fdcanusb pty, line by line -------------------------------------------------------------
def test_fdcanusb_pty_answers_lines_and_refuses_bad_ones() -> None:
    """A `can send` is answered OK and becomes a CAN-FD frame; a wrong checksum, an unknown
    command and unreadable hex are answered ERR and deliver nothing; the first line with a
    checksum switches the replies to checksummed ones (what the moteus library expects on a pty)."""
    import os

    bus = FdcanusbPtyBus()
    fd = os.open(bus.channel_path, os.O_RDWR | os.O_NOCTTY)
    try:

        def say(line: bytes) -> tuple[can.Message | None, bytes]:
            os.write(fd, line + b"\n")
            msg = bus.recv(0.5)
            time.sleep(0.05)
            return msg, os.read(fd, 4096)

        msg, out = say(b"can send 8001 0000 BF")
        assert out == b"OK\r\n" and msg is not None and msg.arbitration_id == 0x8001
        assert bytes(msg.data) == b"\x00\x00" and msg.bitrate_switch and msg.is_extended_id
        bad = (None, mo.add_checksum(b"ERR checksum mismatch") + b"\r\n")
        assert (
            say(b"can send 8001 01 BF *00") == bad
        )  # a checksum, even wrong: checksummed from here
        msg, out = say(b"frobnicate")
        assert msg is None and out.startswith(b"ERR unknown command")
        msg, out = say(mo.add_checksum(b"can send 8001 0G BF"))
        assert msg is None and out.startswith(b"ERR") and bus.malformed == 3
        msg, out = say(mo.add_checksum(b"can send 8002 0102 BF"))
        assert msg is not None and out == mo.add_checksum(b"OK") + b"\r\n"
        bus.send(can.Message(arbitration_id=0x201, data=b"\x21\x00\x00", is_fd=True))
        time.sleep(0.05)
        line = os.read(fd, 4096).rstrip(b"\r\n")
        assert mo.strip_checksum(line) == (b"rcv 201 210000 E B F", True)
    finally:
        os.close(fd)
        bus.shutdown()


def test_codec_round_trips_every_resolution() -> None:
    """pack_registers → parse gives the values back within one step of the resolution, NaN as
    NaN, and saturates beyond the integer range."""
    rng = np.random.default_rng(7)
    for r in (mo.INT8, mo.INT16, mo.INT32, mo.F32):
        values = [float(v) for v in rng.uniform(-1.2, 1.2, 6)] + [math.nan]
        subs = list(mo.parse(mo.pack_registers(mo.WRITE_BASE, mo.CMD_POSITION, r, values)))
        assert [s.register for s in subs] == list(range(mo.CMD_POSITION, mo.CMD_POSITION + 7))
        for s, v in zip(subs, values, strict=True):
            step = 0.0 if r == mo.F32 else mo.SCALES[s.register][r]  # the register's own scale
            top = (127, 32767, 2147483647, math.inf)[r] * step
            if math.isnan(v):
                assert math.isnan(s.value)  # type: ignore[arg-type]
            elif abs(v) > top:
                assert abs(s.value) == pytest.approx(top)  # type: ignore[arg-type]
            else:
                assert abs(s.value - v) <= step + 1e-6 * abs(v)  # type: ignore[operator]
    with pytest.raises(mo.FrameError):
        list(mo.parse(b"\x0d\x20\x00"))  # a float32 cut short
    with pytest.raises(mo.FrameError):
        list(mo.parse(b"\x01\x80\x80\x80\x80\x80"))  # a varuint beyond 5 bytes
