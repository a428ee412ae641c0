"""CANopen server of the virtual robot (virtual_robot.can_server) driven by raw frames.

The host side here speaks CiA 301 by hand (python-can frames, the shared cia402 codec), the way a
host configures real drives: boot-up, SDO, PDO configuration, NMT start, CiA 402 enable by RPDO,
SYNC → TPDOs. Transports: python-can ``virtual`` (fast), slcan over a pty, socketcand over TCP,
and socketcan where the kernel has vcan0.
"""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Callable, Iterator

import can
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.protocol import cia402 as co
from profiles.bench import load_bench
from profiles.robot import load_robot
from virtual_robot.can_server import ERR_PARAMETER, ERR_PDO_LENGTH, CanDriveServer
from virtual_robot.robot import REALTIME, VirtualRobot
from virtual_robot.serve import serve

ROBOT = load_robot("cicese")
NODES = (1, 2)
TPDO_IDS = {co.TPDO1_BASE + n for n in NODES} | {co.TPDO2_BASE + n for n in NODES}


def frame(cob: int, data: bytes = b"", **kw: object) -> can.Message:
    return can.Message(arbitration_id=cob, data=data, is_extended_id=False, **kw)


class Host:
    """A CANopen master by hand on a python-can bus; every received frame is kept in ``log``."""

    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self.log: list[can.Message] = []

    def send(self, cob: int, data: bytes = b"") -> None:
        self.bus.send(frame(cob, data))

    def recv_until(self, pred: Callable[[can.Message], bool], timeout: float = 2.0) -> can.Message:
        while True:
            msg = self.bus.recv(timeout)
            assert msg is not None, "no answer from the virtual robot"
            self.log.append(msg)
            if pred(msg):
                return msg

    def frames(self, cob: int, since: int = 0) -> list[can.Message]:
        return [m for m in self.log[since:] if m.arbitration_id == cob]

    def sdo(self, node: int, request: bytes) -> bytes:
        self.send(co.SDO_RX_BASE + node, request)
        return bytes(self.recv_until(lambda m: m.arbitration_id == co.SDO_TX_BASE + node).data)

    def read(self, node: int, index: int, sub: int) -> int:
        data = co.decode_sdo_response(self.sdo(node, co.sdo_upload_request(index, sub)), index, sub)
        return co.OBJECT_MAP[(index, sub)].decode(data)

    def write(self, node: int, index: int, sub: int, value: int) -> None:
        raw = co.OBJECT_MAP[(index, sub)].encode(value)
        co.decode_sdo_response(self.sdo(node, co.sdo_download_request(index, sub, raw)), index, sub)

    def abort_code(self, node: int, request: bytes) -> int:
        reply = self.sdo(node, request)
        assert reply[0] == 0x80, f"expected an abort, got {reply.hex()}"
        return int.from_bytes(reply[4:8], "little")

    def barrier(self) -> None:
        """An SDO round trip: whatever the server sent before has arrived."""
        self.read(1, 0x1000, 0)

    def nmt(self, cs: int, node: int = 0) -> None:
        self.send(co.NMT_ID, bytes([cs, node]))

    def configure(self, node: int) -> None:
        """docs/design.md PDO layout, CiA 301 order: invalidate, unmap, map, count, validate."""
        for comm, mapping_index, base, entries in (
            (0x1400, 0x1600, co.RPDO1_BASE, co.RPDO1_MAP),
            (0x1800, 0x1A00, co.TPDO1_BASE, co.TPDO1_MAP),
            (0x1801, 0x1A01, co.TPDO2_BASE, co.TPDO2_MAP),
        ):
            self.write(node, comm, 1, 0x80000000 | (base + node))
            self.write(node, comm, 2, co.TRANSMISSION_SYNC)
            self.write(node, mapping_index, 0, 0)
            for k, entry in enumerate(entries, start=1):
                self.write(node, mapping_index, k, co.mapping_entry(*entry))
            self.write(node, mapping_index, 0, len(entries))
            self.write(node, comm, 1, base + node)

    def rpdo(self, node: int, controlword: int, torque: int = 0) -> None:
        self.send(co.RPDO1_BASE + node, co.pack_pdo(co.RPDO1_MAP, (controlword, torque)))

    def sync(self) -> dict[int, tuple[int, ...]]:
        """SYNC; the four TPDOs as {node: (statusword, position, velocity, torque)}."""
        start = len(self.log)
        self.send(co.SYNC_ID)
        got: dict[int, bytes] = {}
        while len(got) < 4:
            msg = self.recv_until(lambda m: m.arbitration_id in TPDO_IDS)
            got[msg.arbitration_id] = bytes(msg.data)
        order = [m.arbitration_id for m in self.log[start:] if m.arbitration_id in TPDO_IDS]
        assert order == [0x181, 0x281, 0x182, 0x282]
        return {
            n: co.unpack_pdo(co.TPDO1_MAP, got[co.TPDO1_BASE + n])
            + co.unpack_pdo(co.TPDO2_MAP, got[co.TPDO2_BASE + n])
            for n in NODES
        }

    def start_up(self) -> None:
        """Configure both nodes, NMT start, CST mode, enable by RPDO (6, 7, 15)."""
        for n in NODES:
            self.configure(n)
        self.nmt(co.NMT_START)
        for n in NODES:
            self.write(n, 0x6060, 0, co.MODE_CST)
        for cw in (co.CW_SHUTDOWN, co.CW_SWITCH_ON, co.CW_ENABLE_OPERATION):
            for n in NODES:
                self.rpdo(n, cw, 0)


def state_of(feedback: tuple[int, ...]) -> co.State | None:
    return co.state_from_statusword(feedback[0])


# ---- fixtures -----------------------------------------------------------------------------------
class Link:
    def __init__(self, core: VirtualRobot, server: CanDriveServer, host: Host, logs: list[str]):
        self.core, self.server, self.host, self.logs = core, server, host, logs


@pytest.fixture
def make_link() -> Iterator[Callable[..., Link]]:
    """A server on a fresh python-can virtual channel and a host bus on the same channel."""
    cleanup: list[Callable[[], None]] = []

    def make(core: VirtualRobot | None = None, **server_kw: object) -> Link:
        channel = f"ddbench-test-{uuid.uuid4().hex}"
        core = core or VirtualRobot(ROBOT)
        robot_bus = can.Bus(interface="virtual", channel=channel)
        host_bus = can.Bus(interface="virtual", channel=channel)
        cleanup.extend((robot_bus.shutdown, host_bus.shutdown))
        logs: list[str] = []
        server = CanDriveServer(core, robot_bus, log=logs.append, **server_kw)  # type: ignore[arg-type]
        server.start()
        cleanup.append(server.stop)
        return Link(core, server, Host(host_bus), logs)

    yield make
    for fn in reversed(cleanup):
        fn()


@pytest.fixture
def link(make_link: Callable[..., Link]) -> Link:
    return make_link()


# ---- start-up, PDOs, motion ---------------------------------------------------------------------
def test_full_start_up_by_raw_frames(link: Link) -> None:
    host = link.host
    for n in NODES:  # boot-up: 0x700+n [0x00], then PRE-OPERATIONAL
        boot = host.recv_until(lambda m, n=n: m.arbitration_id == co.HEARTBEAT_BASE + n)
        assert bytes(boot.data) == bytes([co.NMT_STATE_BOOTUP])
    assert link.server.nmt_state == dict.fromkeys(NODES, co.NMT_STATE_PRE_OPERATIONAL)
    assert host.read(1, 0x1018, 2) == 0x00001200
    assert host.read(2, 0x1018, 2) == 0x00001015

    # before PDO configuration a SYNC produces no TPDO, neither in PRE-OP nor in OPERATIONAL
    mark = len(host.log)
    host.send(co.SYNC_ID)
    host.nmt(co.NMT_START)
    host.send(co.SYNC_ID)
    host.barrier()
    assert not [m for m in host.log[mark:] if m.arbitration_id in TPDO_IDS]
    host.nmt(co.NMT_PRE_OPERATIONAL)

    host.start_up()
    assert host.read(1, 0x6061, 0) == co.MODE_CST
    fb = host.sync()
    assert all(state_of(fb[n]) is co.State.OPERATION_ENABLED for n in NODES)
    start = {n: fb[n][1] for n in NODES}

    torque = {1: 100, 2: 200}  # ‰: 20 Nm and 3 Nm, above the Coulomb levels 7.17 and 1.73 Nm
    for _ in range(40):  # 0.1 s
        for n in NODES:
            host.rpdo(n, co.CW_ENABLE_OPERATION, torque[n])
        fb = host.sync()
    assert all(state_of(fb[n]) is co.State.OPERATION_ENABLED for n in NODES)
    assert all(fb[n][3] == torque[n] for n in NODES)  # torque actual
    assert all(fb[n][1] > start[n] for n in NODES)  # encoders moved forward
    assert all(fb[n][2] > 0 for n in NODES)  # and the velocity is positive
    assert link.server.errors == 0


def test_tpdo_follows_any_configured_mapping(link: Link) -> None:
    host = link.host
    host.write(1, 0x1800, 1, 0x80000181)
    host.write(1, 0x1A00, 1, co.mapping_entry(0x6077, 0))
    host.write(1, 0x1A00, 0, 1)
    host.write(1, 0x1800, 1, 0x181)
    host.nmt(co.NMT_START, 1)
    mark = len(host.log)
    host.send(co.SYNC_ID)
    msg = host.recv_until(lambda m: m.arbitration_id == 0x181)
    assert bytes(msg.data) == b"\0\0"  # torque actual only, 2 bytes
    host.barrier()
    assert [m.arbitration_id for m in host.log[mark:] if m.arbitration_id in TPDO_IDS] == [0x181]


# ---- SDO ----------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("request_frame", "code"),
    [
        (co.sdo_upload_request(0x2000, 0), co.ABORT_NO_OBJECT),
        (co.sdo_upload_request(0x6041, 5), co.ABORT_NO_SUBINDEX),
        (co.sdo_download_request(0x6041, 0, b"\x06\x00"), co.ABORT_READ_ONLY),
        (co.sdo_download_request(0x1018, 0, b"\x03"), co.ABORT_READ_ONLY),  # number of entries
        (co.sdo_download_request(0x1018, 4, b"\x00\x00\x00\x00"), co.ABORT_NO_SUBINDEX),
        (co.sdo_download_request(0x6060, 0, b"\x03"), co.ABORT_VALUE_RANGE),
        (co.sdo_download_request(0x6040, 0, b"\x06\x00\x00\x00"), co.ABORT_LENGTH),  # 4 for 2
        (co.sdo_download_request(0x6060, 0, b"\x0a\x00"), co.ABORT_LENGTH),  # 2 for 1
        (co.sdo_upload_request(0x6041, 0)[:7], co.ABORT_LENGTH),  # DLC 7
        (bytes([0xE0]) + co.sdo_upload_request(0x6041, 0)[1:], co.ABORT_COMMAND),
        (bytes([0x60]) + co.sdo_upload_request(0x6041, 0)[1:], co.ABORT_COMMAND),  # no segment
        (bytes([0x21]) + co.sdo_upload_request(0x6040, 0)[1:], co.ABORT_UNSUPPORTED_ACCESS),
        (co.sdo_download_request(0x1A00, 0, b"\x03"), co.ABORT_VALUE_TOO_HIGH),
        (co.sdo_download_request(0x1800, 2, b"\xff"), co.ABORT_VALUE_RANGE),
    ],
    ids=lambda v: v.hex() if isinstance(v, bytes) else f"0x{v:08X}",
)
def test_sdo_errors_are_abort_frames(link: Link, request_frame: bytes, code: int) -> None:
    assert link.host.abort_code(1, request_frame) == code
    reply = link.host.frames(co.SDO_TX_BASE + 1)[-1]
    assert len(reply.data) == 8
    assert link.server.errors == 0
    assert link.host.read(1, 0x6041, 0)  # still serving


def test_sub_index_0_of_every_record_is_its_number_of_entries(link: Link) -> None:
    """CiA 301: sub-index 0 of a record is served, read-only; its value is the record's highest
    sub-index in the one object map, also after an NMT reset node."""
    host = link.host
    highest: dict[int, int] = {}
    for index, sub in co.OBJECT_MAP:
        highest[index] = max(highest.get(index, 0), sub)
    records = {i: n for i, n in highest.items() if n > 0 and i not in (0x1600, 0x1A00, 0x1A01)}
    assert records == co.RECORD_ENTRIES
    assert records == {0x1018: 3, 0x1400: 2, 0x1800: 2, 0x1801: 2, 0x608F: 2}
    for n in NODES:
        for index, entries in records.items():
            assert host.read(n, index, 0) == entries
            write = co.sdo_download_request(index, 0, bytes([entries]))
            assert host.abort_code(n, write) == co.ABORT_READ_ONLY
    host.nmt(co.NMT_RESET_NODE, 1)
    assert host.read(1, 0x1018, 0) == 3
    assert link.server.errors == 0


def test_sdo_download_without_size_indication_and_client_abort(link: Link) -> None:
    host = link.host
    reply = host.sdo(1, bytes([0x22, 0x60, 0x60, 0x00, 0x04, 0xAA, 0xBB, 0xCC]))  # e=1, s=0
    assert reply[0] == 0x60
    assert host.read(1, 0x6060, 0) == co.MODE_TQ
    mark = len(host.log)
    host.send(0x601, co.sdo_abort(0x6060, 0, co.ABORT_TIMEOUT))  # client abort: no answer
    host.barrier()
    assert len(host.frames(0x581, mark)) == 1  # only the barrier's answer


# ---- NMT, heartbeat -----------------------------------------------------------------------------
def test_nmt_states_per_node(link: Link) -> None:
    host = link.host
    host.configure(1)
    host.configure(2)
    host.nmt(co.NMT_START, 2)
    host.nmt(co.NMT_STOP, 1)
    mark = len(host.log)
    host.send(0x601, co.sdo_upload_request(0x1000, 0))  # STOPPED: no SDO
    host.send(co.SYNC_ID)  # only node 2 is OPERATIONAL
    host.read(2, 0x1000, 0)
    assert not host.frames(0x581, mark)
    assert [m.arbitration_id for m in host.log[mark:] if m.arbitration_id in TPDO_IDS] == [
        0x182,
        0x282,
    ]
    assert link.server.nmt_state == {1: co.NMT_STATE_STOPPED, 2: co.NMT_STATE_OPERATIONAL}
    for bad in (b"\x01", b"\x01\x00\x00", b"\x55\x00"):  # malformed: ignored, logged
        host.send(co.NMT_ID, bad)
    host.nmt(co.NMT_START, 7)  # another node's
    host.read(2, 0x1000, 0)
    assert link.server.nmt_state == {1: co.NMT_STATE_STOPPED, 2: co.NMT_STATE_OPERATIONAL}
    assert sum("NMT" in line for line in link.logs) == 3

    mark = len(host.log)
    host.nmt(co.NMT_RESET_NODE, 2)  # boot-up, PRE-OP, PDO configuration gone
    boot = host.recv_until(lambda m: m.arbitration_id == 0x702)
    assert bytes(boot.data) == b"\x00"
    assert host.read(2, 0x1800, 1) & 0x80000000
    host.nmt(co.NMT_RESET_COMMUNICATION, 1)
    host.recv_until(lambda m: m.arbitration_id == 0x701)
    assert link.server.nmt_state == dict.fromkeys(NODES, co.NMT_STATE_PRE_OPERATIONAL)


def test_heartbeat_producer(link: Link) -> None:
    host = link.host
    host.write(2, 0x1017, 0, 20)  # ms
    beats = [host.recv_until(lambda m: m.arbitration_id == 0x702 and m.data[0] != 0)]
    host.nmt(co.NMT_START, 2)
    beats.append(
        host.recv_until(lambda m: m.arbitration_id == 0x702 and m.data[0] == 0x05, timeout=1.0)
    )
    assert beats[0].data[0] == co.NMT_STATE_PRE_OPERATIONAL
    assert not host.frames(0x701)[1:]  # node 1: boot-up only, 0x1017 = 0


# ---- RPDO, EMCY, watchdog -----------------------------------------------------------------------
def test_rpdo_length_error_and_rejected_value(link: Link, monkeypatch: pytest.MonkeyPatch) -> None:
    host = link.host
    host.start_up()
    host.sync()
    host.send(0x201, b"\x0f\x00\x64")  # 3 bytes for a 4-byte mapping
    emcy = host.recv_until(lambda m: m.arbitration_id == 0x81)
    assert co.decode_emcy(bytes(emcy.data)) == (ERR_PDO_LENGTH, 0x11)
    assert link.core.read(0x6071, 0, node=1) == 0  # nothing written

    def reject(index: int, sub: int, value: int, **kw: object) -> None:
        raise co.SdoAbortError(index, sub, co.ABORT_VALUE_RANGE)

    monkeypatch.setattr(link.core, "write", reject)
    host.rpdo(2, co.CW_ENABLE_OPERATION, 5)
    emcy = host.recv_until(lambda m: m.arbitration_id == 0x82)
    assert co.decode_emcy(bytes(emcy.data)) == (ERR_PARAMETER, 0x01)
    assert link.server.errors == 0


def test_an_rpdo_is_written_and_applied_under_the_core_lock(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """No realtime period tick (another thread) can fall between an RPDO's writes and their
    application: the server holds the core's lock from the first write to apply_commands."""
    core, server, _ = _configured_server()
    held: list[bool] = []

    def lock_held_elsewhere() -> bool:
        free = core.lock.acquire(blocking=False)
        if free:
            core.lock.release()
        return not free

    def probe(name: str) -> None:
        original = getattr(core, name)

        def wrapped(*args: object, **kw: object) -> object:
            other = threading.Thread(target=lambda: held.append(lock_held_elsewhere()))
            other.start()
            other.join()
            return original(*args, **kw)

        monkeypatch.setattr(core, name, wrapped)

    probe("write")
    probe("apply_commands")
    server.handle(frame(0x201, co.pack_pdo(co.RPDO1_MAP, (co.CW_ENABLE_OPERATION, 100))))
    assert held == [True, True, True]  # controlword, target torque, their application
    assert core.read(0x6071, 0, node=1) == 100


def test_watchdog_over_the_bus(link: Link) -> None:
    host = link.host
    host.start_up()
    periods = link.core.drives[0].watchdog_periods
    for k in range(1, periods + 1):
        fb = host.sync()  # no RPDO: the command watchdog counts
        expected = co.State.FAULT if k == periods else co.State.OPERATION_ENABLED
        assert all(state_of(fb[n]) is expected for n in NODES), k
    for n in NODES:
        emcy = host.recv_until(lambda m, n=n: m.arbitration_id == co.EMCY_BASE + n)
        code, register = co.decode_emcy(bytes(emcy.data))
        assert code == co.ERR_RPDO_TIMEOUT
        assert register & co.ERREG_COMMUNICATION
    assert all(fb[n][0] & co.SW_FAULT for n in NODES)
    assert host.read(1, 0x603F, 0) == co.ERR_RPDO_TIMEOUT
    assert len(host.frames(0x81)) == len(host.frames(0x82)) == 1  # one EMCY each

    for n in NODES:  # fault reset (rising edge of bit 7) by RPDO
        host.rpdo(n, co.CW_FAULT_RESET, 0)
    for n in NODES:
        emcy = host.recv_until(lambda m, n=n: m.arbitration_id == co.EMCY_BASE + n)
        assert co.decode_emcy(bytes(emcy.data)) == (0x0000, 0)  # error reset
    fb = host.sync()
    assert all(state_of(fb[n]) is co.State.SWITCH_ON_DISABLED for n in NODES)
    assert host.read(2, 0x603F, 0) == 0


def test_realtime_period_timer_runs_the_watchdog(make_link: Callable[..., Link]) -> None:
    link = make_link(VirtualRobot(ROBOT, mode=REALTIME, period_s=0.002, clock=time.monotonic))
    host = link.host
    host.start_up()
    # no SYNC and no further RPDO: the drives' own timer faults them within a few periods
    for n in NODES:
        emcy = host.recv_until(lambda m, n=n: m.arbitration_id == co.EMCY_BASE + n, timeout=1.0)
        assert co.decode_emcy(bytes(emcy.data))[0] == co.ERR_RPDO_TIMEOUT


def test_idle_host_disables_the_drives(make_link: Callable[..., Link]) -> None:
    link = make_link(idle_timeout_s=0.1)
    host = link.host
    host.start_up()
    host.barrier()
    assert link.core.drives[0].state is co.State.OPERATION_ENABLED
    done = threading.Event()
    for _ in range(100):
        if any("host silent" in line for line in link.logs):
            done.set()
            break
        done.wait(0.02)
    assert done.is_set()
    assert [line for line in link.logs if "host silent" in line] == [
        "host silent for 0.1 s: drives disabled"
    ]
    assert all(d.state is co.State.SWITCH_ON_DISABLED for d in link.core.drives)


def test_ignored_frames_are_counted(link: Link) -> None:
    host = link.host
    host.bus.send(can.Message(arbitration_id=0x601, is_remote_frame=True, is_extended_id=False))
    host.bus.send(can.Message(arbitration_id=0x601, data=bytes(8), is_extended_id=True))
    host.send(0x123, b"\x01")
    host.barrier()
    assert link.server.ignored >= 3
    assert link.server.frames_in >= 4
    assert link.server.frames_out >= 3  # 2 boot-ups, the barrier's answer


# ---- fuzz ---------------------------------------------------------------------------------------
class ListBus(can.BusABC):
    def __init__(self) -> None:
        self.sent: list[can.Message] = []
        super().__init__(channel="list")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.sent.append(msg)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return None, False


SPECIAL_IDS = [0x000, 0x080, 0x081, 0x082, 0x181, 0x182, 0x201, 0x202, 0x281, 0x282]
SPECIAL_IDS += [0x581, 0x582, 0x601, 0x602, 0x701, 0x702]


def _sdo_frame(cob: int, cmd: int, key: tuple[int, int], tail: bytes) -> can.Message:
    index, sub = key
    return frame(cob, bytes([cmd]) + index.to_bytes(2, "little") + bytes([sub]) + tail)


def _odd_frame(flag: str, cob: int, data: bytes) -> can.Message:
    if flag == "remote":
        return can.Message(arbitration_id=cob, is_remote_frame=True, dlc=len(data))
    if flag == "error":
        return can.Message(arbitration_id=cob, is_error_frame=True, data=data)
    return can.Message(arbitration_id=cob | 0x10000, is_extended_id=True, data=data)


_IDS = st.sampled_from(SPECIAL_IDS) | st.integers(0, 0x7FF)
_DATA = st.binary(max_size=8)
_SDO = st.builds(
    _sdo_frame,
    st.sampled_from([0x601, 0x602]),
    st.sampled_from([0x40, 0x2B, 0x2F, 0x27, 0x23, 0x22, 0x21, 0x60, 0x80, 0xE0]),
    st.sampled_from(sorted(co.OBJECT_MAP)) | st.tuples(st.integers(0, 0xFFFF), st.integers(0, 255)),
    st.binary(min_size=4, max_size=4),
)
_NMT = st.builds(
    lambda cs, node: frame(co.NMT_ID, bytes([cs, node])),
    st.sampled_from([1, 2, 0x80, 0x81, 0x82]) | st.integers(0, 255),
    st.sampled_from([0, 1, 2, 3]),
)
_RPDO = st.builds(
    lambda cob, cw, torque: frame(cob, co.pack_pdo(co.RPDO1_MAP, (cw, torque))),
    st.sampled_from([0x201, 0x202]),
    st.sampled_from([0, 2, 6, 7, 15, 0x80, 0x10F]) | st.integers(0, 0xFFFF),
    st.integers(-32768, 32767),
)
_RPDO_ANY = st.builds(frame, st.sampled_from([0x201, 0x202]), _DATA)
_SYNC = st.builds(frame, st.just(co.SYNC_ID), st.binary(max_size=1))
_RAW = st.builds(frame, _IDS, _DATA)
_ODD = st.builds(_odd_frame, st.sampled_from(["remote", "error", "extended"]), _IDS, _DATA)
random_frames = st.one_of(_RAW, _SDO, _NMT, _RPDO, _RPDO_ANY, _SYNC, _ODD)


def _configured_server(bus: ListBus | None = None) -> tuple[VirtualRobot, CanDriveServer, ListBus]:
    core, bus = VirtualRobot(ROBOT), bus or ListBus()
    server = CanDriveServer(core, bus, log=lambda line: None)
    for n in NODES:
        for comm, mapping_index, base, entries in (
            (0x1400, 0x1600, co.RPDO1_BASE, co.RPDO1_MAP),
            (0x1800, 0x1A00, co.TPDO1_BASE, co.TPDO1_MAP),
            (0x1801, 0x1A01, co.TPDO2_BASE, co.TPDO2_MAP),
        ):
            for k, entry in enumerate(entries, start=1):
                request = co.sdo_download_request(
                    mapping_index, k, co.mapping_entry(*entry).to_bytes(4, "little")
                )
                server.handle(frame(0x600 + n, request))
            server.handle(frame(0x600 + n, co.sdo_download_request(mapping_index, 0, b"\x02")))
            cob = (base + n).to_bytes(4, "little")
            server.handle(frame(0x600 + n, co.sdo_download_request(comm, 1, cob)))
    server.handle(frame(0, bytes([co.NMT_START, 0])))
    for cw in (6, 7, 15):
        for n in NODES:
            server.handle(frame(0x200 + n, co.pack_pdo(co.RPDO1_MAP, (cw, 0))))
    assert all(d.state is co.State.OPERATION_ENABLED for d in core.drives)
    assert server.errors == 0
    return core, server, bus


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(configured=st.booleans(), frames=st.lists(random_frames, max_size=20))
def test_fuzz_random_frames_never_break_the_server(
    configured: bool, frames: list[can.Message]
) -> None:
    if configured:
        core, server, bus = _configured_server()
    else:
        core, bus = VirtualRobot(ROBOT), ListBus()
        server = CanDriveServer(core, bus, log=lambda line: None)
    bus.shutdown()  # ListBus keeps working; this only silences python-can's __del__ warning
    for msg in frames:
        server.handle(msg)
        for d in core.drives:
            assert isinstance(d.state, co.State)
            assert co.state_from_statusword(d.statusword) is d.state
            assert abs(d.torque_actual_permille) <= d.max_torque_permille
            limit = d.max_torque_permille * d.profile.rated_torque_Nm / 1000.0
            assert abs(d.torque_Nm) <= limit + 1e-9
    assert server.errors == 0  # every protocol error is an abort, an EMCY or ignored
    for out in bus.sent:
        assert not out.is_extended_id and 0 <= out.arbitration_id <= 0x7FF and out.dlc <= 8


# ---- other transports ---------------------------------------------------------------------------
@pytest.fixture
def served() -> Iterator[Callable[[can.BusABC], CanDriveServer]]:
    servers: list[CanDriveServer] = []

    def start(bus: can.BusABC) -> CanDriveServer:
        server = CanDriveServer(VirtualRobot(ROBOT), bus, log=lambda line: None)
        server.start()
        servers.append(server)
        return server

    yield start
    for server in servers:
        server.stop()


def test_slcan_end_to_end(served: Callable[[can.BusABC], CanDriveServer]) -> None:
    from virtual_robot.slcan_device import SlcanPtyBus

    device = SlcanPtyBus()
    try:
        served(device)
        for _ in range(2):  # the host may close the port and open it again
            host_bus = can.Bus(
                interface="slcan",
                channel=device.channel_path,
                bitrate=1_000_000,
                sleep_after_open=0,
            )
            try:
                host = Host(host_bus)
                assert host.read(1, 0x1018, 2) == 0x1200
                host.start_up()
                fb = host.sync()
                assert all(state_of(fb[n]) is co.State.OPERATION_ENABLED for n in NODES)
                host.nmt(co.NMT_RESET_NODE)
                host.barrier()
            finally:
                host_bus.shutdown()
        assert device.device.bitrate == 1_000_000
        assert device.device.malformed == 0
    finally:
        device.shutdown()


def test_socketcand_end_to_end_with_a_sniffer(
    served: Callable[[can.BusABC], CanDriveServer],
) -> None:
    from virtual_robot.socketcand_hub import SocketcandHub

    with SocketcandHub() as hub:
        robot_bus = hub.robot_bus()
        clients: list[can.BusABC] = []
        try:
            served(robot_bus)
            for _ in range(2):
                clients.append(
                    can.Bus(interface="socketcand", host="127.0.0.1", port=hub.port, channel="can0")
                )
            host, sniffer = Host(clients[0]), Host(clients[1])
            host.start_up()
            fb = host.sync()
            assert all(state_of(fb[n]) is co.State.OPERATION_ENABLED for n in NODES)
            # the sniffer saw the host's SYNC and then the drives' four TPDOs
            sniffer.recv_until(lambda m: m.arbitration_id == co.SYNC_ID)
            seen = [sniffer.recv_until(lambda m: m.arbitration_id in TPDO_IDS) for _ in range(4)]
            assert [m.arbitration_id for m in seen] == [0x181, 0x281, 0x182, 0x282]
            assert [bytes(m.data) for m in seen] == [
                bytes(m.data) for m in host.log if m.arbitration_id in TPDO_IDS
            ][-4:]
            assert any(m.arbitration_id == 0x601 for m in sniffer.log)  # the host's SDO too
            assert not [m for m in host.log if m.arbitration_id in (0x601, 0x080)]  # no echo
        finally:
            for bus in clients:
                bus.shutdown()
            robot_bus.shutdown()


@pytest.mark.vcan
def test_socketcan_vcan0(served: Callable[[can.BusABC], CanDriveServer]) -> None:
    try:
        robot_bus = can.Bus(interface="socketcan", channel="vcan0")
    except Exception as exc:
        pytest.skip(f"socketcan vcan0 not available here: {type(exc).__name__}: {exc}")
    host_bus = can.Bus(interface="socketcan", channel="vcan0")
    try:
        served(robot_bus)
        host = Host(host_bus)
        assert host.read(2, 0x1018, 2) == 0x1015
    finally:
        host_bus.shutdown()
        robot_bus.shutdown()


# ---- serve() ------------------------------------------------------------------------------------
def test_serve_announces_and_stops() -> None:
    bench = load_bench("virtual-socketcand")
    stop = threading.Event()
    announced: list[dict] = []
    ready = threading.Event()

    def announce(info: dict) -> None:
        announced.append(info)
        ready.set()

    result: list[int] = []
    thread = threading.Thread(
        target=lambda: result.append(
            serve(bench, effects=None, mode=None, seed=7, announce=announce, stop=stop, log=print)
        )
    )
    thread.start()
    try:
        assert ready.wait(5.0)
        info = announced[0]
        assert info["event"] == "ready" and info["protocol"] == "can"
        assert info["transport"] == "socketcand" and info["interface_channel"] == "can0"
        assert info["channel"] == f"127.0.0.1:{info['port']}" and info["seed"] == 7
        bus = can.Bus(interface="socketcand", host="127.0.0.1", port=info["port"], channel="can0")
        try:
            assert Host(bus).read(1, 0x1018, 2) == 0x1200
        finally:
            bus.shutdown()
    finally:
        stop.set()
        thread.join(5.0)
    assert result == [0]


class BatchListBus(ListBus):
    """A bus with the batch path (``send_frames``), as SlcanPtyBus has."""

    def __init__(self) -> None:
        super().__init__()
        self.batches: list[list[tuple[int, bytes]]] = []

    def send_frames(self, frames: list[tuple[int, bytes]]) -> None:
        self.batches.append(list(frames))


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(configured=st.booleans(), frames=st.lists(random_frames, max_size=20))
def test_batched_output_equals_frame_by_frame(configured: bool, frames: list[can.Message]) -> None:
    """The same frames in the same order, sent one by one or per batch: the cached routing, PDO
    codecs and heartbeat periods follow every change of the configuration."""
    if configured:
        _, server, bus = _configured_server()
        _, batched, batch_bus = _configured_server(BatchListBus())
    else:
        bus, batch_bus = ListBus(), BatchListBus()
        server = CanDriveServer(VirtualRobot(ROBOT), bus, log=lambda line: None)
        batched = CanDriveServer(VirtualRobot(ROBOT), batch_bus, log=lambda line: None)
    for b in (bus, batch_bus):
        b.shutdown()  # ListBus keeps working; this only silences python-can's __del__ warning
    bus.sent.clear()
    batch_bus.batches.clear()
    for msg in frames:
        server.handle(msg)
        batched.handle(msg)
    one_by_one = [(m.arbitration_id, bytes(m.data)) for m in bus.sent]
    assert [frame for batch in batch_bus.batches for frame in batch] == one_by_one
    assert batched.frames_out == server.frames_out
    assert server.errors == batched.errors == 0
