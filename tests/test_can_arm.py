"""CanArm (canopen set-up, raw PDO cycle) against CanDriveServer on a python-can virtual bus."""

from __future__ import annotations

import dataclasses
import math
import threading
import time
import uuid
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import can
import numpy as np
import pytest
from canopen.objectdictionary import ODRecord
from canopen.sdo import SdoAbortedError
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.arm import Fault, LinkError, SafetyLimits, SafetyStop
from drivers.can_arm import (
    CanArm,
    Frame,
    build_object_dictionary,
    frame_routes,
    parse_frame,
)
from drivers.protocol import cia402 as co
from drivers.recording import read_signals
from profiles.drive import load_drive
from profiles.effects import load_effects
from profiles.experiment import load_experiment
from profiles.robot import load_robot
from virtual_robot.can_server import CanDriveServer
from virtual_robot.drive import State
from virtual_robot.robot import REALTIME, VirtualRobot
from virtual_robot.simulate import simulate

H = 0.0025
LIMITS = SafetyLimits((200.0, 15.0), (12.0, 25.0), ((-3.2, 3.2), (-3.2, 3.2)))
TPDO_IDS = (0x181, 0x281, 0x182, 0x282)


@dataclasses.dataclass
class Rig:
    channel: str
    core: VirtualRobot
    server: CanDriveServer
    server_bus: can.BusABC
    arms: list[CanArm]
    extra_buses: list[can.BusABC]

    def arm(self, tmp_path: Path | None = None, **overrides) -> CanArm:
        robot = load_robot("cicese")
        kwargs = {
            "period_s": H,
            "mode": self.core.mode,
            "timeout_s": 0.5,
            "limits": LIMITS,
            "log_path": tmp_path / "bus.log" if tmp_path is not None else None,
        }
        drives = overrides.pop("drives", [load_drive(n) for n in robot.drives])
        kwargs.update(overrides)
        arm = CanArm(lambda: can.Bus(interface="virtual", channel=self.channel), drives, **kwargs)
        self.arms.append(arm)
        return arm

    def client(self) -> can.BusABC:
        """A second client on the bus (a sniffer, or a rogue SYNC producer)."""
        bus = can.Bus(interface="virtual", channel=self.channel)
        self.extra_buses.append(bus)
        return bus


def _make_rig(core: VirtualRobot) -> Iterator[Rig]:
    channel = f"test-can-arm-{uuid.uuid4().hex}"
    server_bus = can.Bus(interface="virtual", channel=channel)
    server = CanDriveServer(core, server_bus)
    server.start()
    rig = Rig(channel, core, server, server_bus, [], [])
    try:
        yield rig
    finally:
        for arm in rig.arms:
            arm.close()
        server.stop()
        server_bus.shutdown()
        for bus in rig.extra_buses:
            bus.shutdown()


@pytest.fixture
def rig() -> Iterator[Rig]:
    yield from _make_rig(VirtualRobot(load_robot("cicese"), period_s=H))


@pytest.fixture
def realtime_rig() -> Iterator[Rig]:
    core = VirtualRobot(load_robot("cicese"), mode=REALTIME, period_s=H, clock=time.monotonic)
    yield from _make_rig(core)


def _frames(bus: can.BusABC, duration_s: float) -> list[can.Message]:
    out, end = [], time.monotonic() + duration_s
    while (left := end - time.monotonic()) > 0:
        msg = bus.recv(left)
        if msg is not None:
            out.append(msg)
    return out


# ---- equivalence with the offline simulation ------------------------------------------------
def test_lockstep_run_is_bit_identical_to_offline_simulation(rig, tmp_path):
    n = 400
    robot = load_robot("cicese")
    experiment = load_experiment("reyes-kelly")
    assert experiment.period_s == H
    torques = experiment.torque_table(np.arange(n) * H)
    rows = []
    with rig.arm(tmp_path) as arm:
        arm.enable()
        s = arm.start()
        for k in range(n):
            nxt = arm.cycle(torques[k])
            # row k: q sampled at t_k (before command k), tau commanded at t_k
            rows.append((s.t, *s.q_rad, *nxt.tau_Nm))
            s = nxt
        assert arm.faults() == []
    got = np.array(rows)
    simulate(robot, experiment, tmp_path / "sim", duration_s=n * H, plot=False)
    ref = read_signals(tmp_path / "sim")
    assert len(ref) == n
    assert np.array_equal(got[:, 0], ref.t)
    assert np.array_equal(got[:, 1:3], ref.q)
    assert np.array_equal(got[:, 3:5], ref.tau)
    assert np.ptp(ref.q[:, 0]) > 0.05  # the arm really moved


# ---- traffic log ----------------------------------------------------------------------------
def test_traffic_log_holds_every_frame_and_reads_back(rig, tmp_path):
    n = 60
    with rig.arm(tmp_path) as arm:
        arm.enable()
        arm.start()
        for _ in range(n):
            arm.cycle((3.0, 0.3))
        stats = arm.stats
        assert arm.traffic_log() == str(tmp_path / "bus.log")
    messages = list(can.LogReader(tmp_path / "bus.log"))
    sent = Counter(m.arbitration_id for m in messages if not m.is_rx)
    received = Counter(m.arbitration_id for m in messages if m.is_rx)
    assert sent[co.SYNC_ID] == n + 1  # start() + n cycles
    for cob_id in TPDO_IDS:
        assert received[cob_id] == n + 1
    # 3 enable steps, 1 keep-alive in start(), n cycles, 1 in disable() on exit
    assert sent[0x201] == sent[0x202] == 3 + 1 + n + 1
    assert sent[0x601] > 10 and received[0x581] == sent[0x601]  # SDO set-up
    assert sent[co.NMT_ID] >= 2
    assert sum(sent.values()) == stats.frames_sent
    assert sum(received.values()) == stats.frames_received
    stamps = [m.timestamp for m in messages]
    assert stamps == sorted(stamps)


def test_traffic_log_is_flushed_while_running(rig, tmp_path):
    with rig.arm(tmp_path) as arm:
        arm.enable()
        arm.start()
        for _ in range(30):
            arm.cycle((0.0, 0.0))
        on_disk = (tmp_path / "bus.log").read_text().splitlines()
        assert len(on_disk) >= 100  # a crash now would leave this much behind


# ---- set-up by SDO --------------------------------------------------------------------------
def test_pdos_are_configured_by_sdo_at_open(rig):
    sniffer = rig.client()
    sniffer.send(
        can.Message(arbitration_id=co.NMT_ID, data=[co.NMT_START, 0], is_extended_id=False)
    )
    sniffer.send(can.Message(arbitration_id=co.SYNC_ID, data=b"", is_extended_id=False))
    before = _frames(sniffer, 0.1)
    assert not [m for m in before if m.arbitration_id in TPDO_IDS]  # unconfigured: no TPDO
    assert rig.core.pdo_cob_id(1, 0x1800) is None

    arm = rig.arm()
    arm.open()
    for node in (1, 2):
        assert rig.core.pdo_mapping(node, 0x1600) == co.RPDO1_MAP
        assert rig.core.pdo_mapping(node, 0x1A00) == co.TPDO1_MAP
        assert rig.core.pdo_mapping(node, 0x1A01) == co.TPDO2_MAP
        assert rig.core.pdo_cob_id(node, 0x1400) == 0x200 + node
        assert rig.core.read(0x6060, 0, node=node) == co.MODE_CST
    _frames(sniffer, 0.05)  # drain the set-up traffic
    sniffer.send(can.Message(arbitration_id=co.SYNC_ID, data=b"", is_extended_id=False))
    after = [m for m in _frames(sniffer, 0.1) if m.arbitration_id in TPDO_IDS]
    assert [m.arbitration_id for m in after] == [0x181, 0x281, 0x182, 0x282]
    assert [len(m.data) for m in after] == [6, 6, 6, 6]


def test_object_dictionary_is_built_from_the_object_map():
    od = build_object_dictionary()
    for obj in co.OBJECTS:
        entry = od[obj.index]
        var = entry[obj.subindex] if isinstance(entry, ODRecord) else entry
        assert (var.index, var.subindex) == (obj.index, obj.subindex)
        assert len(var) == obj.size * 8
        assert var.access_type == obj.access.value
        assert var.pdo_mappable == obj.pdo
    assert od[0x1018].name == "identity"


def test_wrong_counts_per_rev_is_refused_with_one_line(rig):
    wrong = dataclasses.replace(load_drive("dm1200a"), counts_per_rev=655360)
    arm = rig.arm(drives=[wrong, load_drive("dm1015b")])
    with pytest.raises(LinkError) as err:
        arm.open()
    assert str(err.value) == "node 1 reports 1024000 counts/rev, profile dm1200a says 655360"
    assert arm.bus is None  # closed again


def test_wrong_drive_on_node_1_is_refused(rig):
    wrong = dataclasses.replace(load_drive("dm1015b"), node_id=1)
    arm = rig.arm(drives=[wrong, load_drive("dm1015b")])
    with pytest.raises(LinkError) as err:
        arm.open()
    message = str(err.value)
    assert message == "node 1 reports product code 0x00001200, profile dm1015b says 0x00001015"
    assert "\n" not in message


def test_wrong_rated_torque_is_refused(rig):
    wrong = dataclasses.replace(load_drive("dm1015b"), rated_torque_Nm=20.0)
    arm = rig.arm(drives=[load_drive("dm1200a"), wrong])
    with pytest.raises(LinkError, match="node 2 reports rated torque 15000 mNm"):
        arm.open()


def test_missing_node_is_a_link_error(rig):
    ghost = dataclasses.replace(load_drive("dm1015b"), node_id=5)
    arm = rig.arm(drives=[load_drive("dm1200a"), ghost], timeout_s=0.1)
    with pytest.raises(LinkError, match=r"node 5 .* does not answer"):
        arm.open()


def test_sdo_abort_names_node_object_and_text(rig):
    arm = rig.arm()
    arm.open()
    with pytest.raises(LinkError) as err:
        arm._sdo_write(0, 0x6041, 0, 1)
    assert str(err.value) == (
        "node 1: SDO write 0x6041:0 (statusword) aborted 0x06010002: "
        "attempt to write a read only object"
    )


def test_canopen_reads_the_number_of_entries_and_cannot_write_it(rig):
    """Sub-index 0 of a record by the canopen library, as any CANopen master reads it."""
    arm = rig.arm()
    arm.open()
    for node in arm.nodes:
        assert node.sdo[0x1018][0].raw == 3  # vendor id, product code, revision
        assert node.sdo[0x1800][0].raw == 2  # COB-ID, transmission type
        assert len(node.sdo[0x1018]) == 3  # canopen sizes a record by its sub-index 0
        with pytest.raises(SdoAbortedError) as err:
            node.sdo.download(0x1018, 0, b"\x05")
        assert err.value.code == co.ABORT_READ_ONLY == 0x06010002
        assert node.sdo[0x1018][0].raw == 3


def test_canopen_nmt_reset_communication_restores_the_communication_parameters(rig):
    """CiA 301: NMT reset communication (0x82) sets the communication profile area (0x1000 to
    0x1FFF: PDO COB-IDs, transmission types, mappings, 0x1017) back to power-on values and boots
    the node again; the application (the CiA 402 drive) is left as it was. By the canopen
    library, as a master sends it."""
    arm = rig.arm()
    arm.open()  # PDOs configured
    arm.enable()
    node = arm.nodes[0]
    node.sdo[0x1017].raw = 50  # a producer heartbeat, ms
    assert not node.sdo[0x1800][1].raw & 0x80000000  # TPDO1 valid
    assert node.sdo[0x1A00][0].raw > 0
    node.nmt.send_command(co.NMT_RESET_COMMUNICATION)
    node.nmt.wait_for_bootup(2.0)
    power_on = co.power_on_objects(1, 0, 0, 200.0, 1)
    for index in (0x1400, 0x1800, 0x1801):
        for sub in (1, 2):
            assert node.sdo[index][sub].raw == power_on[(index, sub)], (hex(index), sub)
    for index in (0x1600, 0x1A00, 0x1A01):
        assert node.sdo[index][0].raw == 0
        assert node.sdo[index][1].raw == 0
    assert node.sdo[0x1017].raw == 0
    assert rig.core.drives[0].state is State.OPERATION_ENABLED  # the application is kept
    assert rig.server.nmt_state[1] == co.NMT_STATE_PRE_OPERATIONAL
    assert not arm.nodes[1].sdo[0x1800][1].raw & 0x80000000  # node 2 untouched


# ---- state machine, faults ------------------------------------------------------------------
def test_enable_disable_and_context_manager_exit(rig):
    with rig.arm() as arm:
        arm.enable()
        assert [d.state for d in rig.core.drives] == [State.OPERATION_ENABLED] * 2
        s = arm.start()
        assert [co.state_from_statusword(w) for w in s.status] == [State.OPERATION_ENABLED] * 2
        assert s.t == s.sent_at == s.received_at == s.deadline == 0.0  # lockstep: the link clock
        assert s.tau_Nm == (0.0, 0.0)
        s = arm.cycle((1000.0, -1000.0))  # clamped to the host limits
        assert s.tau_Nm == (200.0, -15.0)
        assert s.t == s.sent_at == s.deadline == H
        arm.disable()
        assert [d.state for d in rig.core.drives] == [State.SWITCH_ON_DISABLED] * 2
        arm.enable()
    assert [d.state for d in rig.core.drives] == [State.SWITCH_ON_DISABLED] * 2  # exit
    assert arm.bus is None
    arm.close()  # idempotent


def test_watchdog_fault_is_reported_and_cleared(rig, tmp_path):
    rogue = rig.client()
    with rig.arm(tmp_path) as arm:
        arm.enable()
        for _ in range(load_drive("dm1200a").watchdog_periods(H) + 1):  # SYNCs, no torque: trips
            rogue.send(can.Message(arbitration_id=co.SYNC_ID, data=b"", is_extended_id=False))
            time.sleep(0.002)
        deadline = time.monotonic() + 1.0
        while len(arm.faults()) < 2 and time.monotonic() < deadline:
            time.sleep(0.002)
        faults = arm.faults()
        assert [(f.joint, f.error_code) for f in faults] == [(0, 0x8250), (1, 0x8250)]
        assert all(isinstance(f, Fault) and "watchdog" in f.text for f in faults)
        with pytest.raises(LinkError, match=r"node 1 in FAULT, error code 0x8250"):
            arm.enable()
        arm.clear_faults()
        assert arm.faults() == []
        arm.enable()
        s = arm.start()
        s = arm.cycle((1.0, 0.1))
        assert [co.state_from_statusword(w) for w in s.status] == [State.OPERATION_ENABLED] * 2
    emcy = Counter(m.arbitration_id for m in can.LogReader(tmp_path / "bus.log") if m.is_rx)
    assert emcy[0x081] >= 2 and emcy[0x082] >= 2  # fault, then error reset


def test_server_gone_mid_run_is_a_link_error(rig):
    arm = rig.arm(timeout_s=0.3)
    with arm:
        arm.enable()
        arm.start()
        for _ in range(5):
            arm.cycle((2.0, 0.2))
        rig.server.stop()
        started = time.monotonic()
        with pytest.raises(LinkError, match=r"no feedback from node 1 within 300 ms"):
            arm.cycle((2.0, 0.2))
        assert time.monotonic() - started < 0.5
        assert arm.stats.timeouts == 1
        arm.safe_stop()  # must not raise on a dead link
    assert arm.bus is None


def test_position_limit_trips_a_safety_stop(rig):
    tight = SafetyLimits((200.0, 15.0), (12.0, 25.0), ((-0.02, 0.02), (-3.2, 3.2)))
    torques = load_experiment("reyes-kelly").torque_table(np.arange(400) * H)
    with rig.arm(limits=tight) as arm:
        arm.enable()
        arm.start()
        with pytest.raises(SafetyStop, match=r"joint 1 position .* outside \[-0.02, 0.02\]"):
            for tau in torques:
                arm.cycle(tau)
        assert [d.state for d in rig.core.drives] == [State.SWITCH_ON_DISABLED] * 2
        assert rig.core.drives[0].torque_Nm == 0.0


def test_non_finite_torque_is_a_safety_stop(rig):
    with rig.arm() as arm:
        arm.enable()
        arm.start()
        with pytest.raises(SafetyStop, match="not 2 finite values"):
            arm.cycle((math.nan, 0.0))
        assert [d.state for d in rig.core.drives] == [State.SWITCH_ON_DISABLED] * 2
        assert arm.stats.errors[-1].startswith("safety stop: torque command (nan, 0.0)")


def test_cycle_before_start_is_refused(rig):
    with rig.arm() as arm, pytest.raises(RuntimeError, match=r"CanArm.cycle\(\) before start"):
        arm.cycle((0.0, 0.0))


# ---- realtime -------------------------------------------------------------------------------
def test_realtime_cycles_on_deadlines_and_notices_a_dead_robot(realtime_rig):
    with realtime_rig.arm(mode="realtime") as arm:
        arm.enable()
        s0 = arm.start()
        assert math.isnan(s0.deadline) and s0.t == s0.sent_at <= arm.now()
        with pytest.raises(ValueError, match="not host seconds since open"):
            arm.cycle((0.0, 0.0), deadline=time.monotonic())  # wrong clock: refused, not slept
        samples = []
        for k in range(1, 41):
            samples.append(arm.cycle((5.0, 0.5), deadline=s0.sent_at + k * H))
        assert arm.faults() == []
        late = [s.sent_at - s.deadline for s in samples]
        assert min(late) >= 0.0
        assert all(s.t == s.sent_at and s.received_at >= s.sent_at for s in samples)
        realtime_rig.server.stop()  # silent, not provably dead: the feedback budget runs out
        deadline = samples[-1].deadline + H
        with pytest.raises(LinkError, match=r"no feedback from node 1 within 250 ms"):
            arm.cycle((0.0, 0.0), deadline=deadline)
        noticed = arm.now() - deadline
        assert arm.feedback_budget_s - 0.001 < noticed < arm.feedback_budget_s + 0.05
        arm.peer_alive = lambda: False  # known dead: the next wait stops at once
        deadline = arm.now() + H
        with pytest.raises(LinkError, match=r"virtual robot process is gone"):
            arm.cycle((0.0, 0.0), deadline=deadline)
        assert arm.now() - deadline < arm.feedback_budget_s / 2


# ---- parsing: random frames -----------------------------------------------------------------
ROUTES = frame_routes((1, 2))


@settings(max_examples=200, deadline=None)
@given(
    can_id=st.one_of(st.sampled_from(sorted(ROUTES)), st.integers(0, 0x1FFFFFFF)),
    data=st.binary(max_size=64),
    extended=st.booleans(),
    remote=st.booleans(),
    error=st.booleans(),
)
def test_parse_frame_returns_a_frame_none_or_value_error(can_id, data, extended, remote, error):
    try:
        frame = parse_frame(
            ROUTES,
            can_id,
            data,
            is_extended_id=extended,
            is_remote_frame=remote,
            is_error_frame=error,
        )
    except ValueError:
        assert can_id in ROUTES and not (extended or remote or error)
        return
    if frame is not None:
        assert isinstance(frame, Frame)
        assert frame.joint in (0, 1)
        assert can_id in ROUTES


@settings(max_examples=200, deadline=None)
@given(
    frames=st.lists(
        st.tuples(
            st.one_of(st.sampled_from(sorted(ROUTES)), st.integers(0, 0x7FF)),
            st.binary(max_size=8),
        ),
        max_size=20,
    )
)
def test_listener_never_raises_on_random_frames(frames):
    """Neither receive path (a Message at a time, or a batch of standard frames) raises on
    any frame, and both keep the same errors for the same frames."""

    def listening() -> CanArm:
        arm = CanArm(
            lambda: can.Bus(interface="virtual", channel="unused"),
            [load_drive("dm1200a"), load_drive("dm1015b")],
            period_s=H,
            mode="lockstep",
            timeout_s=0.1,
            limits=LIMITS,
        )
        arm._collect_since = 0.0  # as if a SYNC were in flight
        arm._missing = 4
        return arm

    one, batch = listening(), listening()
    for can_id, data in frames:
        one._on_frame(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))
    batch._on_standard_frames(frames, time.time(), time.monotonic())
    assert one.stats.frames_received == batch.stats.frames_received == len(frames)
    assert len(one.stats.errors) <= 101
    assert one.stats.errors == batch.stats.errors


def test_parse_frame_decodes_feedback_and_emcy():
    tpdo1 = co.pack_pdo(co.TPDO1_MAP, (0x0637, -5))
    assert parse_frame(ROUTES, 0x182, tpdo1) == Frame("tpdo1", 1, (0x0637, -5))
    tpdo2 = co.pack_pdo(co.TPDO2_MAP, (1234, -7))
    assert parse_frame(ROUTES, 0x281, tpdo2) == Frame("tpdo2", 0, (1234, -7))
    assert parse_frame(ROUTES, 0x081, co.emcy_payload(0x8250, 0x11)) == Frame(
        "emcy", 0, (0x8250, 0x11)
    )
    assert parse_frame(ROUTES, 0x701, b"\x00") == Frame("heartbeat", 0, (0,))
    assert parse_frame(ROUTES, 0x183, tpdo1) is None
    with pytest.raises(ValueError):
        parse_frame(ROUTES, 0x181, tpdo1[:5])


# ---- lockstep details -------------------------------------------------------------------------
@pytest.mark.parametrize("effects", ["amplifier-lag", "stribeck"])
def test_lockstep_with_effects_is_bit_identical_to_offline_simulation(effects, tmp_path):
    """Transport delay and amplifier lag make the plant sensitive to when a command is applied:
    the RPDOs' commands, applied at the next SYNC, are the simulation's commands at t_k."""
    n = 200
    robot, experiment = load_robot("cicese"), load_experiment("reyes-kelly")
    world = load_effects(effects)
    rig_gen = _make_rig(VirtualRobot(robot, world, period_s=H))
    rig = next(rig_gen)
    try:
        torques = experiment.torque_table(np.arange(n) * H)
        rows = []
        with rig.arm() as arm:
            arm.enable()
            s = arm.start()
            for k in range(n):
                nxt = arm.cycle(torques[k])
                rows.append((*s.q_rad, *nxt.tau_Nm))
                s = nxt
    finally:
        rig_gen.close()
    simulate(robot, experiment, tmp_path / "sim", effects=world, duration_s=n * H, plot=False)
    ref = read_signals(tmp_path / "sim")
    got = np.array(rows)
    assert np.array_equal(got[:, :2], ref.q)
    assert np.array_equal(got[:, 2:], ref.tau)


def test_cycles_read_the_bus_themselves_and_give_it_back_for_sdo(rig):
    with rig.arm() as arm:
        arm.enable()
        arm.start()
        assert arm._direct  # lockstep: the cycle reads the bus in this thread
        arm.cycle((1.0, 0.1))
        assert arm.faults() == []  # SDO: the receive thread reads again
        assert not arm._direct
        assert arm.nodes[0].sdo[0x1000].raw & 0xFFFF == 402  # canopen used directly works too
        for _ in range(3):
            s = arm.cycle((1.0, 0.1))
        assert arm._direct
        assert s.t == pytest.approx(4 * H)  # start() + 4 cycles


def test_sdo_from_another_thread_during_cycles_is_answered(rig):
    with rig.arm() as arm:
        arm.enable()
        arm.start()
        got: list[int] = []
        reader = threading.Thread(target=lambda: got.append(arm.nodes[1].sdo[0x6041].raw))
        reader.start()
        for _ in range(40):
            arm.cycle((1.0, 0.1))
            if got:
                break
        reader.join(2.0)
        assert got and co.state_from_statusword(got[0]) is State.OPERATION_ENABLED
        for _ in range(5):  # the receive thread keeps the bus from now on; cycles go on
            s = arm.cycle((1.0, 0.1))
        assert not arm._direct
        assert [co.state_from_statusword(w) for w in s.status] == [State.OPERATION_ENABLED] * 2
