"""Serial link: the Gemini-style codec, the virtual robot's pty server and the SerialArm driver."""

from __future__ import annotations

import contextlib
import os
import queue
import re
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.arm import LinkError, SafetyLimits, SafetyStop
from drivers.protocol import cia402 as co
from drivers.protocol import gemini as gm
from drivers.recording import RecordingWriter, read_signals
from drivers.serial_arm import SerialArm
from profiles.bench import load_bench
from profiles.drive import load_drive
from profiles.experiment import load_experiment
from profiles.robot import load_robot
from virtual_robot.robot import VirtualRobot
from virtual_robot.serial_server import SerialDriveServer, open_pty, serve_serial
from virtual_robot.simulate import simulate

H = 0.0025
ROBOT = load_robot("cicese")
BENCH = load_bench("virtual-serial")
DRIVES = [load_drive(n) for n in ROBOT.drives]
LIMITS = SafetyLimits(BENCH.torque_limit_Nm, BENCH.velocity_limit_rad_s, BENCH.position_limit_rad)
UNITS = (1, 2)


# ---- codec ------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("1_XTQ+125", gm.Command(1, False, "XTQ", 125)),
        ("2_XTQ-32768\r", gm.Command(2, False, "XTQ", -32768)),
        ("2_!DRIVE1", gm.Command(2, True, "DRIVE", 1)),
        ("drive0", gm.Command(None, False, "DRIVE", 0)),
        ("  1_tpe \t", gm.Command(1, False, "TPE", None)),
        ("1_DMTLIM150.5", gm.Command(1, False, "DMTLIM", 150.5)),
        ("1_DMTLIM.5", gm.Command(1, False, "DMTLIM", 0.5)),
        ("1_DMTLIM", gm.Command(1, False, "DMTLIM", None)),
        ("ECHO0", gm.Command(None, False, "ECHO", 0)),
        ("!K", gm.Command(None, True, "K", None)),
        ("2_RESET", gm.Command(2, False, "RESET", None)),
        ("DMODE2", gm.Command(None, False, "DMODE", 2)),
        ("255_TAS", gm.Command(255, False, "TAS", None)),
    ],
)
def test_parse_command(line, expected):
    assert gm.parse_command(line) == expected


@pytest.mark.parametrize(
    ("name", "value", "unit", "immediate"),
    [
        ("XTQ", 0, 1, False),
        ("XTQ", -32768, 2, False),
        ("XTQ", 32767, 2, True),
        ("DRIVE", 1, None, False),
        ("DRIVE", None, 1, False),
        ("DMODE", 2, 2, False),
        ("DMTLIM", 12.345, 2, False),
        ("TPE", None, 1, False),
        ("TVELA", None, 1, False),
        ("TTRQ", None, 2, False),
        ("TAS", None, 2, True),
        ("ERROR", None, 1, False),
        ("TREV", None, 1, False),
        ("K", None, None, True),
        ("RESET", None, 2, False),
        ("ECHO", 1, None, False),
    ],
)
def test_format_parse_command_round_trip(name, value, unit, immediate):
    text = gm.format_command(name, value, unit=unit, immediate=immediate)
    assert text.endswith("\r") and "\n" not in text
    cmd = gm.parse_command(text)
    assert cmd == gm.Command(unit, immediate, name, value)
    assert cmd.text() == text


@pytest.mark.parametrize(
    ("line", "error", "reply"),
    [
        ("FOO", gm.UndefinedLabelError, "*UNDEFINED_LABEL\r\n"),
        ("1_TPX", gm.UndefinedLabelError, "*1_UNDEFINED_LABEL\r\n"),
        ("123", gm.UndefinedLabelError, "*UNDEFINED_LABEL\r\n"),
        ("1_", gm.UndefinedLabelError, "*UNDEFINED_LABEL\r\n"),
        ("!1_K", gm.UndefinedLabelError, "*UNDEFINED_LABEL\r\n"),
        ("1_XTQ", gm.InvalidDataError, "*1_INVALID_DATA\r\n"),
        ("1_XTQ1.5", gm.InvalidDataError, "*1_INVALID_DATA\r\n"),
        ("1_XTQ 5", gm.InvalidDataError, "*1_INVALID_DATA\r\n"),
        ("1_XTQ٣", gm.InvalidDataError, "*1_INVALID_DATA\r\n"),  # no Unicode digits
        ("1_TPE5", gm.InvalidDataError, "*1_INVALID_DATA\r\n"),
        ("TPE", gm.InvalidDataError, "*INVALID_DATA\r\n"),  # reports need a unit
        ("XTQ5", gm.InvalidDataError, "*INVALID_DATA\r\n"),
        ("DMTLIM5", gm.InvalidDataError, "*INVALID_DATA\r\n"),
        ("256_TPE", gm.InvalidDataError, "*INVALID_DATA\r\n"),
        ("1_DMTLIM1e3", gm.InvalidDataError, "*1_INVALID_DATA\r\n"),
        ("1_XTQ" + "1" * 40, gm.InvalidDataError, "*1_INVALID_DATA\r\n"),
        ("1_TPE" + " " * 300 + "x", gm.InvalidDataError, "*INVALID_DATA\r\n"),
        ("1_XTQ32768", gm.InvalidDataHighError, "*1_INVALID_DATA_HIGH\r\n"),
        ("1_DRIVE2", gm.InvalidDataHighError, "*1_INVALID_DATA_HIGH\r\n"),
        ("2_XTQ-32769", gm.InvalidDataLowError, "*2_INVALID_DATA_LOW\r\n"),
        ("ECHO-1", gm.InvalidDataLowError, "*INVALID_DATA_LOW\r\n"),
    ],
)
def test_parse_command_errors(line, error, reply):
    with pytest.raises(error) as info:
        gm.parse_command(line)
    assert type(info.value) is error
    assert isinstance(info.value, gm.ProtocolError)
    assert info.value.reply == reply


def test_reply_round_trips():
    cases = [
        ("TPE", gm.fmt_signed(-123456), 1),
        ("TVELA", gm.fmt_fixed(1.23456, 4), 2),
        ("TTRQ", gm.fmt_fixed(-12.4, 3), 2),
        ("DMTLIM", gm.fmt_fixed(150.0, 3, signed=False), 1),
        ("TAS", gm.statusword_to_tas(0x0637), 1),
        ("ERROR", gm.fmt_hex16(0x8250), 1),
        ("TREV", "DM1200-A emulated, ddbench 0.1.0", 1),
        ("XTQ", gm.fmt_xtq(-(2**31), 0x0637), 2),
        ("DRIVE", "1", None),
        ("K", "", None),
        ("ECHO", "0", None),
    ]
    for name, value, unit in cases:
        line = gm.format_reply(name, value, unit)
        assert line.endswith("\r\n") and line.startswith("*")
        assert gm.parse_reply(line) == gm.Reply(unit, name, value)
        assert gm.parse_reply(line.rstrip("\r\n")) == gm.Reply(unit, name, value)
    assert gm.parse_reply("*1_TPE+123456\r\n").int_value() == 123456
    assert gm.parse_reply("*2_XTQ-5,0x0A37\r\n").xtq() == (-5, 0x0A37)
    assert gm.parse_reply("*1_ERROR0x8250").hex_value() == 0x8250
    assert gm.parse_reply("*1_TVELA-0.5000").float_value() == -0.5
    assert gm.parse_reply("*1_TREVDRIVE-X 1.0").value == "DRIVE-X 1.0"  # longest known name


@pytest.mark.parametrize("token", gm.ERROR_TOKENS)
@pytest.mark.parametrize("unit", [None, 1, 2])
def test_error_replies(token, unit):
    line = gm.format_error(token, unit)
    assert line == f"*{'' if unit is None else f'{unit}_'}{token}\r\n"
    with pytest.raises(gm.DriveReplyError) as info:
        gm.parse_reply(line)
    assert info.value.token == token and info.value.unit == unit
    assert isinstance(info.value, gm.ProtocolError)
    assert gm.ERROR_CLASSES[token]("x", unit).reply == line


@pytest.mark.parametrize(
    "line",
    ["", "TPE+1", "*", "*1_", "*FOO", "*1_TPE\x00", "*1234_TPE+1", "*1_TPÉ", "1_XTQ+1,0x0637"],
)
def test_parse_reply_rejects_garbage(line):
    with pytest.raises(gm.MalformedReplyError):
        gm.parse_reply(line)


def test_reply_value_errors_are_protocol_errors():
    for text, method in [
        ("*1_TPE+1.5", "int_value"),
        ("*1_XTQ+1", "xtq"),
        ("*1_XTQ1,0x0637", "xtq"),
        ("*1_TAS0000", "statusword"),
        ("*1_ERROR8250", "hex_value"),
        ("*1_TTRQabc", "float_value"),
    ]:
        with pytest.raises(gm.MalformedReplyError):
            getattr(gm.parse_reply(text), method)()


def test_tas_bit_map():
    enabled = gm.statusword_to_tas(0x0637)
    assert enabled == "0000_0000_1000_0000_1110_1100_0110_0000"  # the docstring's example
    assert gm.tas_bit(enabled, gm.TAS_TORQUE_MODE)
    assert not gm.tas_bit(enabled, gm.TAS_DRIVE_SHUT_DOWN)
    assert not gm.tas_bit(enabled, gm.TAS_DRIVE_FAULTED)
    limited = gm.statusword_to_tas(0x0A37, velocity_counts_s=-10)
    assert gm.tas_bit(limited, gm.TAS_TORQUE_LIMITED)
    assert gm.tas_bit(limited, gm.TAS_MOVING) and gm.tas_bit(limited, gm.TAS_DIRECTION_NEGATIVE)
    fault = gm.statusword_to_tas(0x0218)
    assert gm.tas_bit(fault, gm.TAS_DRIVE_FAULTED) and gm.tas_bit(fault, gm.TAS_DRIVE_SHUT_DOWN)
    quick = gm.statusword_to_tas(0x0217)
    assert gm.tas_bit(quick, gm.TAS_QUICK_STOP) and gm.tas_bit(quick, gm.TAS_DRIVE_SHUT_DOWN)
    disabled = gm.statusword_to_tas(0x0240)
    assert gm.tas_bit(disabled, gm.TAS_DRIVE_SHUT_DOWN)
    assert not gm.tas_bit(disabled, gm.TAS_DRIVE_FAULTED)
    for sw in range(0x10000):  # bits 17-32 carry the statusword losslessly
        assert gm.tas_to_statusword(gm.statusword_to_tas(sw)) == sw


def test_value_formats():
    assert gm.fmt_signed(0) == "+0" and gm.fmt_signed(-3) == "-3"
    assert gm.fmt_fixed(-0.00001, 4) == "+0.0000"  # never "-0.0000"
    assert gm.fmt_fixed(0.0, 3, signed=False) == "0.000"
    assert gm.fmt_hex16(0) == "0x0000"
    with pytest.raises(ValueError):
        gm.fmt_hex16(0x10000)
    with pytest.raises(ValueError):
        gm.format_command("NOPE")


# ---- server: request -> reply ----------------------------------------------------------------
@pytest.fixture
def server() -> SerialDriveServer:
    return SerialDriveServer(VirtualRobot(ROBOT))


def states(core: VirtualRobot) -> list[co.State | None]:
    return [co.state_from_statusword(core.read(0x6041, 0, unit=u)) for u in UNITS]


def test_server_samples_t0_at_start(server):
    assert server.core.syncs == 1 and server.core.t == 0.0
    assert server.handle_line("1_TPE") == "*1_TPE+0\r\n"
    assert server.handle_line("2_TREV").startswith("*2_TREVDM1015-B")


def test_drive1_enables_both_units(server):
    core = server.core
    assert states(core) == [co.State.SWITCH_ON_DISABLED] * 2
    assert server.handle_line("DRIVE1") == "*DRIVE1\r\n"
    assert states(core) == [co.State.OPERATION_ENABLED] * 2
    assert [core.read(0x6060, 0, unit=u) for u in UNITS] == [co.MODE_CST] * 2
    assert server.handle_line("1_DRIVE") == "*1_DRIVE1\r\n"
    tas = gm.parse_reply(server.handle_line("2_TAS"))
    assert tas.statusword() == core.read(0x6041, 0, unit=2)
    assert not gm.tas_bit(tas.value, gm.TAS_DRIVE_SHUT_DOWN)
    assert server.handle_line("2_DRIVE0") == "*2_DRIVE0\r\n"
    assert states(core) == [co.State.OPERATION_ENABLED, co.State.SWITCH_ON_DISABLED]
    assert server.handle_line("1_DMODE") == "*1_DMODE2\r\n"


def test_xtq_steps_once_every_unit_has_its_torque(server):
    core = server.core
    server.handle_line("DRIVE1")
    assert server.handle_line("1_XTQ+100") == ""
    assert server.handle_line("1_XTQ+250") == ""  # same unit again: overwrites, no step
    assert core.syncs == 1 and core.t == 0.0 and server.pending_xtq == (1, 1)
    assert server.handle_line("1_TTRQ") == "*1_TTRQ+50.000\r\n"  # 250 ‰ of 200 Nm, at once
    assert server.handle_line("1_TPE") == "*1_TPE+0\r\n"  # answered now, from the t = 0 sample
    out = server.handle_line("2_XTQ-10")
    assert core.syncs == 2 and core.t == H and server.pending_xtq == ()
    replies = [gm.parse_reply(line) for line in out.splitlines()]
    assert [(r.unit, r.name) for r in replies] == [(1, "XTQ"), (1, "XTQ"), (2, "XTQ")]
    for r in replies:
        counts, sw = r.xtq()
        assert counts == core.read(0x6064, 0, unit=r.unit)
        assert sw == core.read(0x6041, 0, unit=r.unit)
    assert replies[0].xtq()[0] > 0 and replies[2].xtq()[0] < 0  # moved with the torques
    assert server.handle_line("2_TTRQ") == "*2_TTRQ-0.150\r\n"
    assert server.handle_line("2_XTQ+0") == ""  # the next period starts with unit 2 this time
    assert len(server.handle_line("1_XTQ+0").splitlines()) == 2 and core.syncs == 3


def test_undefined_label_and_invalid_data(server):
    assert server.handle_line("FOO") == "*UNDEFINED_LABEL\r\n"
    assert server.handle_line("1_TPX") == "*1_UNDEFINED_LABEL\r\n"
    assert server.handle_line("1_DMODE3") == "*1_INVALID_DATA\r\n"
    assert server.handle_line("DMODE4") == "*INVALID_DATA\r\n"
    assert server.handle_line("5_TPE") == "*5_INVALID_DATA\r\n"  # no drive at unit 5
    assert server.handle_line("1_TPE7") == "*1_INVALID_DATA\r\n"
    assert server.handle_line("1_XTQ+abc") == "*1_INVALID_DATA\r\n"
    assert server.handle_line("1_XTQabc") == "*1_UNDEFINED_LABEL\r\n"  # name = all the letters
    assert server.handle_line("1_XTQ40000") == "*1_INVALID_DATA_HIGH\r\n"
    assert server.handle_line("1_DMTLIM0") == "*1_INVALID_DATA_LOW\r\n"
    assert server.handle_line("1_DMTLIM-3") == "*1_INVALID_DATA_LOW\r\n"
    assert server.handle_line("1_DMTLIM7000") == "*1_INVALID_DATA_HIGH\r\n"  # > 32767 ‰
    assert server.handle_line("1_DMTLIM150") == "*1_DMTLIM150.000\r\n"
    assert server.core.read(0x6072, 0, unit=1) == 750
    assert server.handle_line("2_DMTLIM10.01") == "*2_DMTLIM10.005\r\n"  # nearest 0.015 Nm step
    assert server.handle_line("") == "" and server.handle_line("  ") == ""
    assert server.core.syncs == 1  # nothing stepped


def test_torque_limit_shows_in_tas(server):
    server.handle_line("DRIVE1")
    server.handle_line("1_DMTLIM100")
    server.handle_line("1_XTQ+900")  # 180 Nm asked, 100 Nm allowed
    tas = gm.parse_reply(server.handle_line("1_TAS")).value
    assert gm.tas_bit(tas, gm.TAS_TORQUE_LIMITED)
    assert server.handle_line("1_TTRQ") == "*1_TTRQ+100.000\r\n"


def test_kill_disables_and_zeroes_torque(server):
    core = server.core
    server.handle_line("DRIVE1")
    server.handle_line("1_XTQ+300")
    server.handle_line("2_XTQ+300")
    assert server.handle_line("!K") == "*K\r\n"
    assert states(core) == [co.State.SWITCH_ON_DISABLED] * 2
    assert [d.torque_Nm for d in core.drives] == [0.0, 0.0]
    assert server.handle_line("1_TTRQ") == "*1_TTRQ+0.000\r\n"
    assert server.handle_line("2_DRIVE") == "*2_DRIVE0\r\n"
    server.handle_line("DRIVE1")
    assert core.read(0x6071, 0, unit=1) == 0  # re-enabled onto zero torque, not the old 300 ‰
    assert server.handle_line("2_K") == "*2_K\r\n"
    assert states(core) == [co.State.OPERATION_ENABLED, co.State.SWITCH_ON_DISABLED]


def test_fault_error_and_reset(server):
    core = server.core
    server.handle_line("DRIVE1")
    for _ in range(DRIVES[0].watchdog_periods(H)):  # periods pass without a torque command
        core.sync()
    assert states(core) == [co.State.FAULT] * 2
    assert server.handle_line("1_ERROR") == "*1_ERROR0x8250\r\n"
    tas = gm.parse_reply(server.handle_line("1_TAS")).value
    assert gm.tas_bit(tas, gm.TAS_DRIVE_FAULTED)
    assert server.handle_line("1_DRIVE1") == "*1_DRIVE0\r\n"  # cannot enable in FAULT
    assert server.handle_line("1_RESET") == "*1_RESET\r\n"
    assert server.handle_line("1_ERROR") == "*1_ERROR0x0000\r\n"
    assert states(core) == [co.State.SWITCH_ON_DISABLED, co.State.FAULT]
    assert server.handle_line("RESET") == "*RESET\r\n"
    assert states(core) == [co.State.SWITCH_ON_DISABLED] * 2
    assert server.handle_line("DRIVE1") == "*DRIVE1\r\n"


def test_feed_frames_lines_and_echoes(server):
    assert server.echo  # ECHO1 at power-on, as a Gemini
    assert server.feed(b"1_TPE\r") == b"1_TPE\r*1_TPE+0\r\n"
    assert server.feed(b"ECHO0\r1_TPE\r") == b"ECHO0\r*ECHO0\r\n*1_TPE+0\r\n"
    assert server.feed(b"1_T") == b""  # partial line kept
    assert server.feed(b"PE\r\n2_TPE\n") == b"*1_TPE+0\r\n*2_TPE+0\r\n"  # LF and CR LF too
    assert server.feed(b"x" * 400) == b""
    assert server.feed(b"\r") == b"*INVALID_DATA\r\n"  # overlong line: one error, then clean
    assert server.feed(b"1_TPE\r") == b"*1_TPE+0\r\n"
    assert server.feed(b"\xff\xfe\r") == b"*UNDEFINED_LABEL\r\n"


def test_lockstep_lost_host_disables(server):
    core = server.core
    server.feed(b"DRIVE1\r")
    assert not server.check_host(time.monotonic() + 1.0)
    assert server.check_host(time.monotonic() + 5.1)  # no command for > 5 s
    assert states(core) == [co.State.SWITCH_ON_DISABLED] * 2
    assert not server.check_host(time.monotonic() + 10.0)  # once


def test_realtime_xtq_replies_at_once():
    core = VirtualRobot(ROBOT, mode="realtime", clock=time.monotonic)
    srv = SerialDriveServer(core)
    assert srv.handle_line("DRIVE1") == "*DRIVE1\r\n"
    reply = gm.parse_reply(srv.handle_line("1_XTQ+100"))
    assert reply.unit == 1 and reply.xtq()[1] == core.read(0x6041, 0, unit=1)
    assert srv.pending_xtq == ()


# ---- fuzz --------------------------------------------------------------------------------------
_NOT_EOL = st.characters(blacklist_characters="\r\n")
_commandish = st.builds(
    lambda unit, bang, name, value: f"{unit}{bang}{name}{value}",
    st.sampled_from(["", "1_", "2_", "3_", "0_", "256_", "01_"]),
    st.sampled_from(["", "!"]),
    st.sampled_from([*gm.COMMANDS, "xtq", "drive", "TP", "K1"]),
    st.one_of(
        st.just(""),
        st.integers(-70_000, 70_000).map(lambda v: f"{v:+d}"),
        st.integers(-3, 3).map(str),
        st.floats(-1e6, 1e6).map(repr),
        st.text(_NOT_EOL, max_size=6),
    ),
)
_lines = st.one_of(
    st.text(_NOT_EOL, max_size=80),
    st.binary(max_size=80).map(lambda b: b.decode("latin-1").replace("\r", "").replace("\n", "")),
    _commandish,
)


@settings(max_examples=300, deadline=None)
@given(st.lists(_lines, min_size=1, max_size=12))
def test_fuzz_handle_line(lines):
    srv = SerialDriveServer(VirtualRobot(ROBOT))
    for line in lines:
        out = srv.handle_line(line)
        assert isinstance(out, str)
        if out == "":  # only a blank line or an XTQ waiting for the other unit
            assert not line.strip(" \t") or srv.pending_xtq
        else:
            assert out.startswith("*") and out.endswith("\r\n")
            assert all(part.startswith("*") for part in out.split("\r\n")[:-1])
        for i, u in enumerate(UNITS):
            sw = srv.core.read(0x6041, 0, unit=u)
            state = co.state_from_statusword(sw)
            assert isinstance(state, co.State) and state is srv.core.drives[i].state
            assert gm.tas_to_statusword(gm.statusword_to_tas(sw)) == sw


_reply_lines = st.one_of(
    st.text(max_size=80),
    st.binary(max_size=80).map(lambda b: b.decode("latin-1")),
    st.builds(lambda a, b: "*" + a + b, st.sampled_from(["", "1_", "12_", "999_"]), st.text()),
    st.builds(
        lambda name, v: f"*1_{name}{v}",
        st.sampled_from([*gm.COMMANDS, *gm.ERROR_TOKENS]),
        st.text(max_size=40),
    ),
)


@settings(max_examples=300, deadline=None)
@given(_reply_lines)
def test_fuzz_parse_reply(line):
    try:
        reply = gm.parse_reply(line)
    except gm.ProtocolError:
        return
    assert isinstance(reply, gm.Reply) and reply.name in gm.COMMANDS
    for method in ("int_value", "float_value", "hex_value", "xtq", "statusword"):
        with contextlib.suppress(gm.ProtocolError):
            getattr(reply, method)()


# ---- over a real pty ---------------------------------------------------------------------------
@contextlib.contextmanager
def serving(core: VirtualRobot) -> Iterator[tuple[str, threading.Event, threading.Thread]]:
    """serve_serial in a thread; yields (slave path, stop event, thread); always stopped."""
    stop = threading.Event()
    announced: queue.Queue[dict] = queue.Queue()
    thread = threading.Thread(
        target=serve_serial,
        args=(core, BENCH),
        kwargs={"announce": announced.put, "stop": stop},
        daemon=True,
    )
    thread.start()
    try:
        info = announced.get(timeout=5)
        assert info == {
            "event": "ready",
            "protocol": "serial",
            "transport": "serial",
            "channel": info["channel"],
        }
        yield info["channel"], stop, thread
    finally:
        stop.set()
        thread.join(timeout=5)
        assert not thread.is_alive()


def make_arm(port: str, mode: str = "lockstep", **kw) -> SerialArm:
    kw.setdefault("timeout_s", 2.0)
    kw.setdefault("limits", LIMITS)
    return SerialArm(port, DRIVES, period_s=H, mode=mode, **kw)


def test_end_to_end_equals_offline_simulation(tmp_path):
    n = 200
    experiment = load_experiment("reyes-kelly")
    torques = experiment.torque_table(np.arange(n) * H).tolist()
    log = tmp_path / "hil" / "serial.log"
    with serving(VirtualRobot(ROBOT)) as (port, _, _):
        arm = make_arm(port, log_path=log)
        with arm, RecordingWriter(tmp_path / "hil", {"kind": "test"}) as rec:
            assert arm.revisions[0].startswith("DM1200-A")
            arm.enable()
            sample = arm.start()
            assert sample.t == 0.0
            for k in range(n):
                nxt = arm.cycle(torques[k])
                assert nxt.t == (k + 1) * H and nxt.status == (0x0637, 0x0637)
                rec.write((k * H, *sample.q_rad, *nxt.tau_Nm))
                sample = nxt
            assert arm.faults() == []
        assert arm.stats.cycles == n and arm.stats.timeouts == 0 and not arm.stats.errors
        assert arm.stats.frames_sent == arm.stats.frames_received
        assert arm.traffic_log() == str(log)

        again = make_arm(port)  # the host closes and reopens the port: a clean session
        with again:
            again.enable()
            assert again.start().t == 0.0
            again.cycle((0.0, 0.0))

    simulate(ROBOT, experiment, tmp_path / "sim", duration_s=n * H, plot=False)
    hil, sim = read_signals(tmp_path / "hil"), read_signals(tmp_path / "sim")
    assert len(hil) == len(sim) == n
    assert np.array_equal(hil.t, sim.t)
    assert np.array_equal(hil.q, sim.q)  # bit-identical, not just close
    assert np.array_equal(hil.tau, sim.tau)

    lines = log.read_text().splitlines()
    assert re.fullmatch(r"\d+\.\d{6} > ECHO0", lines[0])
    assert any(re.fullmatch(r"\d+\.\d{6} > 1_XTQ[+-]\d+", ln) for ln in lines)
    assert any(re.fullmatch(r"\d+\.\d{6} < \*2_XTQ[+-]\d+,0x0637", ln) for ln in lines)
    assert lines[-1].endswith("< *2_DRIVE0")  # the context manager's safe stop


def test_safety_stop_disables_the_drives():
    core = VirtualRobot(ROBOT)
    tight = SafetyLimits((200.0, 15.0), (12.0, 25.0), ((-0.001, 0.001), (-3.2, 3.2)))
    with serving(core) as (port, _, _), make_arm(port, limits=tight) as arm:
        arm.enable()
        arm.start()
        with pytest.raises(SafetyStop, match="joint 1 position"):
            for _ in range(50):
                arm.cycle((100.0, 0.0))
        assert states(core) == [co.State.SWITCH_ON_DISABLED] * 2
        assert arm.stats.errors[-1].startswith("safety stop: joint 1 position")
        with pytest.raises(SafetyStop, match="finite"):
            arm.cycle((float("nan"), 0.0))
        assert arm.stats.errors[-1].startswith("safety stop: torque command (nan, 0.0)")


def test_cycle_before_start_is_refused():
    core = VirtualRobot(ROBOT)
    with (
        serving(core) as (port, _, _),
        make_arm(port) as arm,
        pytest.raises(RuntimeError, match=r"SerialArm.cycle\(\) before start"),
    ):
        arm.cycle((0.0, 0.0))


def test_realtime_watchdog_faults_when_the_host_stops_streaming():
    core = VirtualRobot(ROBOT, mode="realtime", clock=time.monotonic, period_s=H)
    with serving(core) as (port, _, _), make_arm(port, mode="realtime") as arm:
        arm.enable()
        s0 = arm.start()
        s1 = arm.cycle((10.0, 1.0), deadline=arm.now() + H)
        assert s1.t > s0.t and s1.sent_at >= s1.deadline - 1e-9
        last_command = time.monotonic()
        # no XTQ from now on: the drives fault once watchdog_s has passed on their own timer
        # (which a loaded machine may starve: wait for it, but never see it early)
        deadline = last_command + DRIVES[0].watchdog_s + 10.0
        while not gm.tas_bit(tas := arm.request(1, "TAS"), gm.TAS_DRIVE_FAULTED):
            assert time.monotonic() < deadline, "the watchdog never fired"
            time.sleep(0.01)
        assert time.monotonic() - last_command >= DRIVES[0].watchdog_s - 2 * H
        assert co.state_from_statusword(gm.tas_to_statusword(tas)) is co.State.FAULT
        assert arm.request(2, "ERROR") == "0x8250"
        faults = arm.faults()
        assert [(f.joint, f.error_code) for f in faults] == [(0, 0x8250), (1, 0x8250)]
        assert "watchdog" in faults[0].text
        arm.clear_faults()
        assert arm.faults() == []
        assert states(core) == [co.State.SWITCH_ON_DISABLED] * 2


def test_killed_server_gives_link_error_and_safe_stop_is_quiet():
    with serving(VirtualRobot(ROBOT)) as (port, stop, thread):
        arm = make_arm(port, timeout_s=1.0)
        try:
            arm.open()
            arm.enable()
            arm.start()
            for _ in range(5):
                arm.cycle((1.0, 0.1))
            stop.set()  # the virtual robot goes away: its master fd is closed
            thread.join(timeout=5)
            started = time.monotonic()
            with pytest.raises(LinkError, match=re.escape(port)):
                arm.cycle((1.0, 0.1))
            assert time.monotonic() - started < 1.0
            arm.safe_stop()  # must not raise
            assert arm.stats.errors
        finally:
            arm.close()


def test_silent_server_times_out():
    core = VirtualRobot(ROBOT)
    master, port = open_pty()
    stop = threading.Event()
    srv = SerialDriveServer(core, master)
    thread = threading.Thread(target=srv.serve, args=(stop,), daemon=True)
    thread.start()
    arm = make_arm(port, timeout_s=0.3)
    try:
        arm.open()
        arm.enable()
        arm.start()
        arm.cycle((0.0, 0.0))
        stop.set()  # still there, but nobody answers any more
        thread.join(timeout=5)
        started = time.monotonic()
        with pytest.raises(LinkError, match=r"not responding on .* after 0\.3 s"):
            arm.cycle((0.0, 0.0))
        assert 0.25 < time.monotonic() - started < 1.0
        assert arm.stats.timeouts == 1
        started = time.monotonic()
        arm.safe_stop()
        assert time.monotonic() - started < 1.5
    finally:
        arm.close()
        os.close(master)


def test_open_fails_with_link_error(tmp_path):
    arm = make_arm(str(tmp_path / "no-such-port"))
    with pytest.raises(LinkError, match="cannot open serial port"):
        arm.open()
    master, port = open_pty()  # a port where nothing answers: open() says so and closes
    try:
        arm = make_arm(port, timeout_s=0.2)
        with pytest.raises(LinkError, match="not responding"):
            arm.open()
    finally:
        os.close(master)
