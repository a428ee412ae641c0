"""CiA 402 drives over CAN: the :class:`~drivers.arm.Arm` of the host on any python-can bus.

Set-up uses the ``canopen`` library the way a CANopen tool would: a :class:`canopen.Network` on
the bus, one :class:`canopen.RemoteNode` per drive with an object dictionary built from
:data:`drivers.protocol.cia402.OBJECTS`, NMT through ``node.nmt`` and every configuration
object (identity, rated torque, encoder resolution, the PDO map, the mode) by SDO.

The cyclic path packs PDOs directly (precompiled structs, not canopen's PdoMap): per period one
RPDO1 per drive (controlword + target torque), then SYNC, then TPDO1 (statusword + position)
and TPDO2 (velocity + torque actual) from every drive. Frames go out through the bus's
``send_frames`` where it has one (:class:`drivers.slcan.SelectSlcanBus`: one write for all),
else one ``send`` each.

Who reads the bus: a receive thread (python-can's Notifier's job) reads every frame and feeds
canopen and the feedback collector. In lockstep the cycle sends RPDOs and SYNC in one write
and reads the feedback in its own thread: the receive thread is paused from :meth:`start` on,
which saves a thread hand-over per cycle, and gets the bus back as soon as canopen sends
anything (the SDO of faults(), disable(), ...; from another thread, after the cycle in
progress). Realtime keeps the receive thread: RPDOs go out at once, the SYNC at the deadline.

Measured with ``tests/benchmarks/bench_can_cycle.py`` (python-can ``virtual`` bus, lockstep
virtual robot + CanDriveServer in threads of the same process, 2 drives, traffic log off; 8
alternating blocks of 250 cycles, medians of two runs on the 2-core machine, quiet; µs per
cycle):

    path                                          wall       host CPU (main + receive thread)
    raw (CanArm.cycle, incl. clamp, units,        305-312    124-134  (124-134 + 0)
      limit checks; reads the bus itself)
    canopen PDO machinery (PdoMap vars,           390-394    198-209  (150-162 + 46-48)
      transmit(), sync.transmit(), callbacks)

The server thread costs another 185-190 µs per cycle either way. The raw path costs the host
about 35 % less CPU and the cycle about 80 µs less wall time, and it also does more (clamp,
limits). The cycle uses the raw path; canopen does NMT, SDO and the 402 set-up. Over slcan to
the virtual robot process see README.md (Numbers).

Time: ``Sample`` times are host seconds since :meth:`open` connected (``Arm.now()``). Lockstep:
``t`` = k·h and ``sent_at`` = ``received_at`` = ``deadline`` = ``t`` (the link's clock);
realtime: RPDOs go out at once (the drive applies them on arrival), SYNC at ``deadline``,
``t`` = SYNC send time; feedback later than one period is a timing event
(``stats.late_feedback``), later than ``feedback_budget_s`` (bench profile) a dead link; a
receive error (closed pty or socket) or a dead robot process ends the wait at once.

Log: every frame sent and received goes to ``log_path`` in ``candump -L`` format, the lines
python-can's :class:`can.CanutilsLogWriter` writes (:class:`drivers.candump.CandumpWriter`,
readable with :class:`can.LogReader`), flushed every 50 frames and on close. Sent frames are
marked ``T`` (``is_rx = False``), received ones ``R``, stamped when sent or read. In lockstep a
cycle's lines are written just after the next write to the bus, while the drives work on it.
"""

from __future__ import annotations

import contextlib
import logging
import math
import re
import struct
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import can
import canopen
from canopen.nmt import NmtError
from canopen.objectdictionary import ObjectDictionary, ODRecord, ODVariable, datatypes
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from drivers.arm import LIVENESS_POLL_S, Arm, Fault, LinkError, SafetyLimits, SafetyStop, Sample
from drivers.candump import CandumpWriter
from drivers.protocol import cia402 as co
from drivers.units import (
    counts_to_rad,
    permille_to_torque,
    position_to_rad,
    torque_to_permille,
    unwrap_int32,
)
from profiles.drive import DriveProfile

LOCKSTEP, REALTIME = "lockstep", "realtime"
LOG_FLUSH_EVERY = 50  # frames
MAX_DEADLINE_AHEAD_S = 1.0  # a deadline further ahead than this (+10 periods) is a caller bug
SHORT_SDO_TIMEOUT_S = 0.2  # disable() and fault queries: best effort, do not hang on a dead link
MAX_ERRORS_KEPT = 100
RECEIVER_POLL_S = 0.01  # receive thread wake-up: bounds close() and pausing it
LOCKSTEP_LIVENESS_POLL_S = 0.05  # a lockstep wait checks this often whether the robot is gone
PAUSE_TIMEOUT_S = 1.0  # the receive thread did not stop reading: keep it (threaded cycle)

_logger = logging.getLogger(__name__)

FAULT_TEXT = {
    co.ERR_RPDO_TIMEOUT: "RPDO timeout (command watchdog)",
    co.ERR_OVERSPEED: "overspeed",
    co.ERR_COMMUNICATION: "communication error (a second SYNC producer on the bus?)",
}

_OD_TYPES = {
    "<B": datatypes.UNSIGNED8,
    "<H": datatypes.UNSIGNED16,
    "<I": datatypes.UNSIGNED32,
    "<b": datatypes.INTEGER8,
    "<h": datatypes.INTEGER16,
    "<i": datatypes.INTEGER32,
}

# (communication index, mapping index, COB-ID base, mapping) in configuration order
PDO_LAYOUT: tuple[tuple[int, int, int, tuple[tuple[int, int], ...]], ...] = (
    (0x1400, 0x1600, co.RPDO1_BASE, co.RPDO1_MAP),
    (0x1800, 0x1A00, co.TPDO1_BASE, co.TPDO1_MAP),
    (0x1801, 0x1A01, co.TPDO2_BASE, co.TPDO2_MAP),
)


# ---- object dictionary as data ------------------------------------------------------------------
def _od_variable(obj: co.Obj) -> ODVariable:
    var = ODVariable(obj.name, obj.index, obj.subindex)
    var.data_type = _OD_TYPES[obj.fmt]
    var.access_type = obj.access.value
    var.pdo_mappable = obj.pdo
    var.min, var.max = obj.limits()
    return var


def _record_name(objs: Sequence[co.Obj]) -> str:
    """The words the members' names share ("identity", "RPDO1 mapping"), else the index; the
    generic sub-index 0 ("highest sub-index supported") does not count."""
    named = [o for o in objs if o.subindex] or objs
    words = [o.name.split() for o in named]
    common: list[str] = []
    for column in zip(*words, strict=False):
        if any(w != column[0] for w in column):
            break
        common.append(column[0])
    return " ".join(common) or f"object 0x{objs[0].index:04X}"


def build_object_dictionary(objects: Sequence[co.Obj] = co.OBJECTS) -> ObjectDictionary:
    """A canopen ObjectDictionary from the drives' object map: variables and records."""
    od = ObjectDictionary()
    by_index: dict[int, list[co.Obj]] = {}
    for obj in objects:
        by_index.setdefault(obj.index, []).append(obj)
    for index, objs in sorted(by_index.items()):
        if len(objs) == 1 and objs[0].subindex == 0:
            od.add_object(_od_variable(objs[0]))
        else:
            record = ODRecord(_record_name(objs), index)
            for obj in objs:
                record.add_member(_od_variable(obj))
            od.add_object(record)
    return od


# ---- host-side frame parsing (pure; fed random frames by the tests) ------------------------------
class Frame(NamedTuple):
    """A frame of interest to the host, decoded."""

    kind: str  # "tpdo1" | "tpdo2" | "emcy" | "heartbeat"
    joint: int  # 0-based
    values: tuple[int, ...]  # tpdo1: (statusword, position counts); tpdo2: (velocity, torque ‰)
    # emcy: (error code, error register); heartbeat: (NMT state,)


TPDO1, TPDO2, EMCY, HEARTBEAT = "tpdo1", "tpdo2", "emcy", "heartbeat"


def frame_routes(node_ids: Sequence[int]) -> dict[int, tuple[str, int]]:
    """COB-ID → (kind, joint) for the frames the host consumes from these nodes."""
    routes: dict[int, tuple[str, int]] = {}
    for joint, n in enumerate(node_ids):
        routes[co.TPDO1_BASE + n] = (TPDO1, joint)
        routes[co.TPDO2_BASE + n] = (TPDO2, joint)
        routes[co.EMCY_BASE + n] = (EMCY, joint)
        routes[co.HEARTBEAT_BASE + n] = (HEARTBEAT, joint)
    return routes


def _pdo_codec(mapping: tuple[tuple[int, int], ...]) -> struct.Struct:
    """A whole PDO as one precompiled struct: the bytes of ``cia402.pack_pdo``/``unpack_pdo``."""
    return struct.Struct("<" + "".join(co.OBJECT_MAP[m].fmt[1:] for m in mapping))


_RPDO1 = _pdo_codec(co.RPDO1_MAP)
_TPDO_CODECS = {TPDO1: _pdo_codec(co.TPDO1_MAP), TPDO2: _pdo_codec(co.TPDO2_MAP)}


def parse_frame(
    routes: dict[int, tuple[str, int]],
    can_id: int,
    data: bytes | bytearray,
    *,
    is_extended_id: bool = False,
    is_remote_frame: bool = False,
    is_error_frame: bool = False,
) -> Frame | None:
    """Decode one received frame.

    Returns None for frames the host does not consume (other COB-IDs, extended ids, remote and
    error frames). Raises ValueError, and nothing else, for a consumed COB-ID whose payload does
    not fit (wrong PDO length, EMCY shorter than 3 bytes, empty heartbeat).
    """
    if is_extended_id or is_remote_frame or is_error_frame:
        return None
    route = routes.get(can_id)
    if route is None:
        return None
    kind, joint = route
    payload = bytes(data)
    codec = _TPDO_CODECS.get(kind)
    if codec is not None:  # cia402.unpack_pdo with the mapping precompiled
        if len(payload) != codec.size:
            raise ValueError(f"PDO of {len(payload)} bytes, mapping needs {codec.size}")
        return Frame(kind, joint, codec.unpack(payload))
    if kind == EMCY:
        return Frame(kind, joint, co.decode_emcy(payload))
    if len(payload) < 1:
        raise ValueError("heartbeat of 0 bytes, need 1")
    return Frame(kind, joint, (payload[0] & 0x7F,))


def fault_text(code: int) -> str:
    return FAULT_TEXT.get(code, "drive fault")


def _profile_name(p: DriveProfile) -> str:
    return Path(p.source).stem if p.source else p.model


def _channel_name(bus: can.BusABC) -> str:
    """A whitespace-free channel name for the log (candump -L has one token there)."""
    for attr in ("channel_id", "channel", "_channel"):
        value = getattr(bus, attr, None)
        if isinstance(value, str | int) and str(value):
            name = re.sub(r"[^A-Za-z0-9_.:/-]", "_", str(value))
            return f"can{name}" if name.isdigit() else name
    return "can0"


class _Network(canopen.Network):
    """canopen Network whose sends go through the arm (traffic log, counters)."""

    def __init__(self, arm: CanArm, bus: can.BusABC) -> None:
        super().__init__(bus)
        self._arm = arm

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        if not self.bus:
            raise RuntimeError("Not connected to CAN bus")
        self._arm._threaded_receive()  # canopen expects its answers from the receive thread
        msg = can.Message(
            arbitration_id=can_id,
            is_extended_id=can_id > 0x7FF,
            data=data,
            is_remote_frame=remote,
            is_rx=False,
        )
        with self.send_lock:
            self._arm._send(msg)
        self.check()


class _Receiver:
    """The host's receive thread (python-can's Notifier's job), which a cycle can pause.

    It calls ``read(timeout)`` (read what arrives, dispatch it) until stopped. While paused it
    does not touch the bus, so the caller's own thread may read it. As with can.Notifier, an
    exception from ``read`` ends the thread and is kept in :attr:`exception` (canopen's
    ``Network.check()`` raises it on the next send).
    """

    def __init__(self, read: Callable[[float], None], name: str) -> None:
        self._read = read
        self.exception: Exception | None = None
        self._running = threading.Event()
        self._running.set()
        self._idle = threading.Event()
        self._stopped = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stopped:
            if not self._running.is_set():
                self._idle.set()
                self._running.wait()
                continue
            self._idle.clear()
            if not self._running.is_set():  # paused meanwhile: the pauser may have seen idle
                continue
            try:
                self._read(RECEIVER_POLL_S)
            except Exception as exc:
                self.exception = exc
                _logger.debug("receive thread ended: %s", exc)
                break
        self._idle.set()

    def pause(self, timeout: float = PAUSE_TIMEOUT_S) -> bool:
        """Stop reading; True once the thread is no longer inside ``read``."""
        self._running.clear()
        return self._idle.wait(timeout)

    def resume(self) -> None:
        self._running.set()

    def stop(self, timeout: float) -> None:
        self._stopped = True
        self._running.set()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout)


class CanArm(Arm):
    """N CiA 402 drives on one CAN bus; joint j is ``drives[j]`` at node ``drives[j].node_id``.

    ``bus_factory`` builds the python-can bus at :meth:`open` (the arm owns and shuts it down).
    ``mode``: "lockstep" (the robot advances one period per SYNC; ``Sample.t`` = k·h; feedback
    timeout ``timeout_s``) or "realtime" (SYNC at the host's deadline; ``Sample.t`` = SYNC send
    time; feedback later than a period is counted, later than ``feedback_budget_s`` ends the
    run, a closed bus at once). ``log_path``:
    file for the traffic log (an existing directory gets ``bus.log`` inside it); None: no log.
    """

    def __init__(
        self,
        bus_factory: Callable[[], can.BusABC],
        drives: Sequence[DriveProfile],
        *,
        period_s: float,
        mode: str,
        timeout_s: float,
        limits: SafetyLimits,
        log_path: str | Path | None = None,
        feedback_budget_s: float | None = None,
        feedback_timeout_periods: int | None = None,
    ) -> None:
        self._init_link(
            drives,
            period_s=period_s,
            mode=mode,
            timeout_s=timeout_s,
            limits=limits,
            feedback_budget_s=feedback_budget_s,
            feedback_timeout_periods=feedback_timeout_periods,
        )
        self._bus_factory = bus_factory
        self.node_ids = tuple(p.node_id for p in self.drives)
        if len(set(self.node_ids)) != len(self.node_ids):
            raise ValueError(f"node ids must differ, got {self.node_ids}")
        if log_path is not None:
            log_path = Path(log_path)
            if log_path.is_dir():
                log_path = log_path / "bus.log"
        self.log_path: Path | None = log_path

        self.bus: can.BusABC | None = None
        self.network: canopen.Network | None = None
        self.nodes: tuple[canopen.RemoteNode, ...] = ()
        self._receiver: _Receiver | None = None
        self._direct = False  # the cycle reads the bus in the caller's thread (lockstep)
        self._direct_owner = 0  # that thread's ident
        self._direct_refused = False  # set for good once canopen runs in another thread meanwhile
        self._listeners: list[can.Listener] = []  # canopen's, fed every received Message
        self._bus_send_frames: Callable[[list[tuple[int, bytes]]], None] | None = None
        self._bus_recv_frames: Callable[[float], list[Any]] | None = None
        self._writer: CandumpWriter | None = None
        self._log_queue: list[tuple[float, list[tuple[int, bytes]], bool]] = []
        self._log_lock = threading.Lock()
        self._send_lock = threading.Lock()  # raw sends, canopen's sends, the enable keep-alive
        self._log_frames = 0
        self._is_open = False
        self._t0 = 0.0

        self._routes = frame_routes(self.node_ids)
        self._rpdo_ids = tuple(co.RPDO1_BASE + n for n in self.node_ids)
        self._cpr = tuple(p.counts_per_rev for p in self.drives)
        self._rated = tuple(p.rated_torque_Nm for p in self.drives)

        # feedback of the SYNC in flight (guarded by _fb_lock)
        self._fb_lock = threading.Lock()
        self._fb_event = threading.Event()
        self._collect_since: float | None = None
        self._fb1: list[tuple[int, ...] | None] = [None] * self.n_joints
        self._fb2: list[tuple[int, ...] | None] = [None] * self.n_joints
        self._missing = 0
        self._fb_last_at = math.nan
        self._link_lost: str | None = None  # a receive error in the cycle's own thread

        self._emcy: dict[int, Fault] = {}  # joint → last active fault from EMCY
        self._booted: set[int] = set()
        self._counts: list[int] = [0] * self.n_joints
        self._k = 0
        self._started = False

    # ---- link ------------------------------------------------------------------------------
    def open(self) -> None:
        """Connect, confirm each drive against its profile, configure PDOs by SDO, NMT start."""
        if self._is_open:
            return
        try:
            self._connect()
            self.opened_at = self._t0 = time.monotonic()  # the clock of Sample times, deadlines
            for j in range(self.n_joints):
                self._confirm(j)
            for j in range(self.n_joints):
                self._configure(j)
            for node in self.nodes:
                node.nmt.send_command(co.NMT_START)
        except LinkError:
            self.close()
            raise
        except (can.CanError, RuntimeError, OSError) as exc:
            self.close()
            raise LinkError(f"CAN link failed during set-up: {_one_line(exc)}") from exc
        except BaseException:
            self.close()
            raise
        self._is_open = True

    def _connect(self) -> None:
        try:
            self.bus = self._bus_factory()
        except (can.CanError, OSError, ValueError) as exc:
            raise LinkError(f"cannot open the CAN bus: {_one_line(exc)}") from exc
        if self.log_path is not None:
            self.log_path.parent.mkdir(parents=True, exist_ok=True)
            self._writer = CandumpWriter(self.log_path, channel=_channel_name(self.bus))
        # the batch path of buses that have one (drivers.slcan.SelectSlcanBus)
        self._bus_send_frames = getattr(self.bus, "send_frames", None)
        self._bus_recv_frames = getattr(self.bus, "recv_frames", None)
        network = _Network(self, self.bus)
        nodes = []
        for p in self.drives:
            node = canopen.RemoteNode(p.node_id, build_object_dictionary())
            node.sdo.RESPONSE_TIMEOUT = self.timeout_s
            network.add_node(node)
            nodes.append(node)
        self.network, self.nodes = network, tuple(nodes)
        self._listeners = list(network.listeners)
        self._receiver = _Receiver(self._read_frames, name="can-arm-receiver")
        network.notifier = self._receiver  # type: ignore[assignment]  # check() reads .exception

    def _confirm(self, j: int) -> None:
        """Presence (0x1000), identity (0x1018), rated torque (0x6076), encoder (0x608F:1)."""
        p, n, name = self.drives[j], self.node_ids[j], _profile_name(self.drives[j])
        try:
            device_type = self._sdo_read(j, 0x1000, 0)
        except LinkError:
            # not there yet (or we missed its boot-up): wait for a boot-up, then ask once more
            with contextlib.suppress(NmtError):
                if n not in self._booted:
                    self.nodes[j].nmt.wait_for_bootup(self.timeout_s)
            try:
                device_type = self._sdo_read(j, 0x1000, 0)
            except LinkError as exc:
                raise LinkError(f"node {n} ({name}) does not answer: {exc}") from None
        if device_type & 0xFFFF != 402:
            raise LinkError(
                f"node {n} is not a CiA 402 drive (device type 0x{device_type:08X}), "
                f"profile {name} expects one"
            )
        checks = (
            (0x1018, 1, p.vendor_id, "vendor id"),
            (0x1018, 2, p.product_code, "product code"),
        )
        for index, sub, expected, what in checks:
            if expected:  # 0: the profile does not say
                got = self._sdo_read(j, index, sub)
                if got != expected:
                    raise LinkError(
                        f"node {n} reports {what} 0x{got:08X}, profile {name} says 0x{expected:08X}"
                    )
        rated_mNm = self._sdo_read(j, 0x6076, 0)
        if rated_mNm != round(p.rated_torque_Nm * 1000):
            raise LinkError(
                f"node {n} reports rated torque {rated_mNm} mNm, "
                f"profile {name} says {round(p.rated_torque_Nm * 1000)}"
            )
        cpr = self._sdo_read(j, 0x608F, 1)
        if cpr != p.counts_per_rev:
            raise LinkError(
                f"node {n} reports {cpr} counts/rev, profile {name} says {p.counts_per_rev}"
            )

    def _configure(self, j: int) -> None:
        """PDO map by SDO (DESIGN.md), synchronous; mode 10 (cyclic synchronous torque)."""
        n = self.node_ids[j]
        self.nodes[j].nmt.send_command(co.NMT_PRE_OPERATIONAL)
        for comm, mapping_index, base, mapping in PDO_LAYOUT:
            cob_id = base + n
            self._sdo_write(j, comm, 1, 0x80000000 | cob_id)  # invalidate while mapping
            self._sdo_write(j, comm, 2, co.TRANSMISSION_SYNC)
            self._sdo_write(j, mapping_index, 0, 0)
            for s, (index, sub) in enumerate(mapping, start=1):
                self._sdo_write(j, mapping_index, s, co.mapping_entry(index, sub))
            self._sdo_write(j, mapping_index, 0, len(mapping))
            self._sdo_write(j, comm, 1, cob_id)
        self._sdo_write(j, 0x6060, 0, co.MODE_CST)
        mode = self._sdo_read(j, 0x6061, 0)
        if mode != co.MODE_CST:
            raise LinkError(f"node {n} reports mode {mode} after 0x6060 = {co.MODE_CST}")

    def close(self) -> None:
        """Stop the receive thread, shut the bus down, close the log. Idempotent; commands
        nothing."""
        self._is_open = False
        self._direct = self._direct_refused = False
        receiver, self._receiver = self._receiver, None
        if receiver is not None:
            with contextlib.suppress(Exception):
                receiver.stop(timeout=1.0)
        if self.network is not None:
            for node in self.nodes:
                with contextlib.suppress(Exception):
                    del self.network[node.id]
            self.network.bus = None
            self.network.notifier = None
        bus, self.bus = self.bus, None
        if bus is not None:
            with contextlib.suppress(Exception):
                bus.shutdown()
        with self._log_lock:
            with contextlib.suppress(Exception):
                self._drain_log()
            writer, self._writer = self._writer, None
            if writer is not None:
                with contextlib.suppress(Exception):
                    writer.stop()

    def traffic_log(self) -> str | None:
        return str(self.log_path) if self.log_path is not None else None

    # ---- frames ----------------------------------------------------------------------------
    def _send(self, msg: can.Message) -> None:
        """Send one frame; log it first (direction T). Raises can.CanError / RuntimeError."""
        bus = self.bus
        if bus is None:
            raise RuntimeError("CAN bus is closed")
        with self._send_lock:
            msg.timestamp = time.time()
            msg.is_rx = False
            self._log(msg)
            bus.send(msg)
            self.stats.frames_sent += 1

    def _send_frames(self, frames: list[tuple[int, bytes]]) -> None:
        """Send standard data frames ``(id, data)`` in order, in one write where the bus can.

        Logged with the time of sending (direction T): first, as :meth:`_send` does; in direct
        receive, just after the write, while the drives work on the frames.
        Raises can.CanError / RuntimeError.
        """
        bus = self.bus
        if bus is None:
            raise RuntimeError("CAN bus is closed")
        with self._send_lock:
            stamp = time.time()
            if self._writer is not None:
                self._log_frames_of(stamp, frames, rx=False)
            try:
                if self._bus_send_frames is not None:
                    self._bus_send_frames(frames)
                else:
                    for cob_id, data in frames:
                        bus.send(
                            can.Message(
                                timestamp=stamp,
                                arbitration_id=cob_id,
                                data=data,
                                is_extended_id=False,
                                is_rx=False,
                            )
                        )
            finally:
                if self._log_queue:
                    with self._log_lock:
                        self._drain_log()
            self.stats.frames_sent += len(frames)

    def _log(self, msg: can.Message) -> None:
        if self._writer is None:
            return
        with self._log_lock:
            writer = self._writer
            if writer is None:
                return
            self._drain_log()  # frames logged earlier go first
            writer.write_message(msg)
            self._log_frames += 1
            if self._log_frames % LOG_FLUSH_EVERY == 0:
                writer.flush()

    def _log_frames_of(self, stamp: float, frames: list[tuple[int, bytes]], rx: bool) -> None:
        """Log standard data frames seen at ``stamp``; in direct receive the lines are queued
        and written by the next :meth:`_send_frames` after its write (off the critical path)."""
        with self._log_lock:
            self._log_queue.append((stamp, frames, rx))
            if not self._direct:
                self._drain_log()

    def _drain_log(self) -> None:
        """Write the queued log lines (hold ``_log_lock``); flush every LOG_FLUSH_EVERY frames."""
        writer, queue = self._writer, self._log_queue
        if writer is None:
            queue.clear()
            return
        before = count = self._log_frames
        for stamp, frames, rx in queue:
            writer.write_frames(stamp, frames, rx)
            count += len(frames)
        queue.clear()
        self._log_frames = count
        if before // LOG_FLUSH_EVERY != count // LOG_FLUSH_EVERY:
            writer.flush()

    def _read_frames(self, timeout: float) -> None:
        """Wait up to ``timeout`` for frames, then dispatch every frame that has arrived.

        The receive thread's loop, and the cycle's own in lockstep. Raises what the bus raises.
        """
        bus = self.bus
        if bus is None:
            raise RuntimeError("CAN bus is closed")
        if self._bus_recv_frames is None:
            msg = bus.recv(timeout)
            if msg is not None:
                for listener in self._listeners:
                    listener.on_message_received(msg)
                self._on_frame(msg)
            return
        batch = self._bus_recv_frames(timeout)
        if not batch:
            return
        stamp, now = time.time(), time.monotonic()
        run: list[tuple[int, bytes]] = []  # standard data frames, dispatched a run at a time
        for item in batch:
            if type(item) is tuple:
                run.append(item)
                continue
            if run:
                self._on_standard_frames(run, stamp, now)
                run = []
            for listener in self._listeners:  # an extended, remote, error or FD frame
                listener.on_message_received(item)
            self._on_frame(item)
        if run:
            self._on_standard_frames(run, stamp, now)

    def _on_standard_frames(
        self, frames: list[tuple[int, bytes]], stamp: float, now: float
    ) -> None:
        """Received standard data frames: log, canopen, counters, feedback, EMCY (in order)."""
        if self._writer is not None:
            self._log_frames_of(stamp, frames, rx=True)
        self.stats.frames_received += len(frames)
        network = self.network
        notify = network.notify if network is not None else None
        routes = self._routes
        for cob_id, data in frames:
            if notify is not None:
                try:  # what canopen's MessageListener does with a Message
                    notify(cob_id, bytearray(data), stamp)
                except Exception as exc:
                    _logger.error(str(exc))
            route = routes.get(cob_id)
            if route is None:
                continue
            try:
                codec = _TPDO_CODECS.get(route[0])
                if codec is not None and len(data) == codec.size:  # feedback: the cyclic case
                    self._collect(route[0], route[1], codec.unpack(data), now)
                    continue
                frame = parse_frame(routes, cob_id, data)
                if frame is not None:
                    self._handle(frame, now)
            except ValueError as exc:
                self._error(f"0x{cob_id:03X}: {exc}")
            except Exception as exc:  # never kill the receive thread
                self._error(f"listener: {type(exc).__name__}: {exc}")

    def _on_frame(self, msg: can.Message) -> None:
        """Receive-side callback for a Message: log, count, collect feedback, record EMCY."""
        now = time.monotonic()
        try:
            self.stats.frames_received += 1
            self._log(msg)
            frame = parse_frame(
                self._routes,
                msg.arbitration_id,
                msg.data,
                is_extended_id=msg.is_extended_id,
                is_remote_frame=msg.is_remote_frame,
                is_error_frame=msg.is_error_frame,
            )
            if frame is not None:
                self._handle(frame, now)
        except ValueError as exc:
            self._error(f"0x{msg.arbitration_id:03X}: {exc}")
        except Exception as exc:  # never kill the receive thread
            self._error(f"listener: {type(exc).__name__}: {exc}")

    def _handle(self, frame: Frame, now: float) -> None:
        kind, j, values = frame
        if kind in (TPDO1, TPDO2):
            self._collect(kind, j, values, now)
        elif kind == EMCY:
            code, _register = values
            if code == co.ERR_NONE:
                self._emcy.pop(j, None)  # error reset
            else:
                self._emcy[j] = Fault(j, code, fault_text(code))
        elif values[0] == co.NMT_STATE_BOOTUP:
            self._booted.add(self.node_ids[j])

    def _collect(self, kind: str, j: int, values: tuple[int, ...], now: float) -> None:
        """A TPDO of drive ``j``: keep it if a SYNC of ours is waiting for it."""
        with self._fb_lock:
            since = self._collect_since
            if since is None or now < since:
                return  # not waiting, or stale (from before our SYNC)
            slots = self._fb1 if kind == TPDO1 else self._fb2
            if slots[j] is not None:
                return  # a duplicate for this SYNC (another SYNC producer on the bus)
            slots[j] = values
            self._missing -= 1
            if self._missing == 0:
                self._fb_last_at = now
                self._collect_since = None
                self._fb_event.set()

    def _error(self, text: str) -> None:
        errors = self.stats.errors
        if len(errors) < MAX_ERRORS_KEPT:
            errors.append(text)
        elif len(errors) == MAX_ERRORS_KEPT:
            errors.append("(further errors not kept)")

    # ---- SDO helpers -------------------------------------------------------------------------
    def _sdo_var(self, j: int, index: int, sub: int) -> Any:
        entry = self.nodes[j].sdo[index]
        return entry[sub] if isinstance(entry.od, ODRecord) else entry

    def _sdo_read(self, j: int, index: int, sub: int) -> int:
        self._threaded_receive()
        try:
            return int(self._sdo_var(j, index, sub).raw)
        except Exception as exc:
            raise self._sdo_error(j, "read", index, sub, exc) from exc

    def _sdo_write(self, j: int, index: int, sub: int, value: int) -> None:
        self._threaded_receive()
        try:
            self._sdo_var(j, index, sub).raw = value
        except Exception as exc:
            raise self._sdo_error(j, "write", index, sub, exc) from exc

    def _sdo_error(self, j: int, op: str, index: int, sub: int, exc: Exception) -> LinkError:
        n = self.node_ids[j]
        obj = co.OBJECT_MAP.get((index, sub))
        what = f"0x{index:04X}:{sub}" + (f" ({obj.name})" if obj else "")
        if isinstance(exc, SdoAbortedError):
            text = co.ABORT_TEXT.get(exc.code) or str(exc)
            reason = f"aborted 0x{exc.code:08X}: {text}"
        elif isinstance(exc, SdoCommunicationError):
            reason = f"no answer ({_one_line(exc)})"
        else:
            reason = f"failed: {type(exc).__name__}: {_one_line(exc)}"
        message = f"node {n}: SDO {op} {what} {reason}"
        self._error(message)
        return LinkError(message)

    @contextlib.contextmanager
    def _short_sdo_timeouts(self) -> Any:
        saved = [node.sdo.RESPONSE_TIMEOUT for node in self.nodes]
        for node in self.nodes:
            node.sdo.RESPONSE_TIMEOUT = min(SHORT_SDO_TIMEOUT_S, self.timeout_s)
        try:
            yield
        finally:
            for node, value in zip(self.nodes, saved, strict=True):
                node.sdo.RESPONSE_TIMEOUT = value

    # ---- who reads the bus ---------------------------------------------------------------------
    def _threaded_receive(self) -> None:
        """The receive thread reads the bus (canopen's SDO and NMT need it).

        From another thread while a cycle reads the bus itself, it only asks: the cycle gives
        the bus back when it ends, and later cycles leave it to the thread.
        """
        if not self._direct:
            return
        if threading.get_ident() != self._direct_owner:
            self._direct_refused = True
            return
        self._direct = False
        with self._log_lock:
            self._drain_log()
        if self._receiver is not None:
            self._receiver.resume()

    def _direct_receive(self) -> None:
        """Lockstep cycles: the caller's thread reads the bus itself, with no hand-over between
        threads per cycle. Anything canopen sends (SDO for faults(), disable(), ...) gives the
        bus back to the receive thread."""
        if self._direct or self.mode != LOCKSTEP or self._receiver is None:
            return
        if self._direct_refused:  # canopen was used from another thread during a cycle
            return
        if self._receiver.pause():
            self._direct_owner = threading.get_ident()
            self._direct = True
        else:
            self._receiver.resume()  # still busy in a callback: stay threaded

    # ---- drive state -------------------------------------------------------------------------
    def _require_open(self) -> None:
        if not self._is_open:
            raise LinkError("CAN link is not open")

    def _rpdo_frames(self, controlword: int, permille: Sequence[int]) -> list[tuple[int, bytes]]:
        pack = _RPDO1.pack  # cia402.pack_pdo(RPDO1_MAP, ...), precompiled
        return [
            (cob_id, pack(controlword, value))
            for cob_id, value in zip(self._rpdo_ids, permille, strict=True)
        ]

    def _send_rpdos(self, controlword: int, permille: Sequence[int]) -> None:
        self._send_frames(self._rpdo_frames(controlword, permille))

    def enable(self) -> None:
        """Shutdown, switch on, enable operation (RPDO, torque 0); each confirmed by SDO 0x6041.

        Realtime: the drives' command watchdog runs on their own period timer from the moment
        they are enabled, and an SDO round trip may outlast its periods (socketcand,
        a busy adapter); so while the last step is being confirmed, a keep-alive thread sends
        RPDO (enable operation, torque 0) every period. It stops before enable() returns.
        """
        self._require_open()
        zero = (0,) * self.n_joints
        steps = (
            (co.CW_SHUTDOWN, co.State.READY_TO_SWITCH_ON),
            (co.CW_SWITCH_ON, co.State.SWITCHED_ON),
            (co.CW_ENABLE_OPERATION, co.State.OPERATION_ENABLED),
        )
        for controlword, state in steps:
            try:
                self._send_rpdos(controlword, zero)
            except (can.CanError, RuntimeError) as exc:
                raise LinkError(f"cannot send RPDO: {_one_line(exc)}") from exc
            if state is co.State.OPERATION_ENABLED and self.mode == REALTIME:
                with self._keep_alive():
                    self._wait_state(state)
            else:
                self._wait_state(state)

    @contextlib.contextmanager
    def _keep_alive(self) -> Iterator[None]:
        """RPDO enable operation + torque 0 to every drive once a period, in a thread."""
        stop = threading.Event()
        zero = (0,) * self.n_joints

        def run() -> None:
            while not stop.wait(self.period_s):
                try:
                    self._send_rpdos(co.CW_ENABLE_OPERATION, zero)
                except Exception as exc:  # the main thread's SDO will fail and say why
                    self._error(f"keep-alive RPDO: {_one_line(exc)}")
                    return

        thread = threading.Thread(target=run, name="can-arm-keep-alive", daemon=True)
        thread.start()
        try:
            yield
        finally:
            stop.set()
            thread.join()

    def _wait_state(self, wanted: co.State) -> None:
        deadline = time.monotonic() + self.timeout_s
        pending = set(range(self.n_joints))
        while True:
            for j in sorted(pending):
                sw = self._sdo_read(j, 0x6041, 0)
                state = co.state_from_statusword(sw)
                if state is wanted:
                    pending.discard(j)
                elif state in (co.State.FAULT, co.State.FAULT_REACTION_ACTIVE):
                    code = self._sdo_read(j, 0x603F, 0)
                    raise LinkError(
                        f"node {self.node_ids[j]} in FAULT, error code 0x{code:04X} "
                        f"({fault_text(code)}): clear_faults() first"
                    )
            if not pending:
                return
            if time.monotonic() > deadline:
                j = min(pending)
                sw = self._sdo_read(j, 0x6041, 0)
                state = co.state_from_statusword(sw)
                raise LinkError(
                    f"node {self.node_ids[j]} not {wanted.name} within {self.timeout_s:g} s "
                    f"(statusword 0x{sw:04X}, {state.name if state else 'unknown state'})"
                )
            time.sleep(0.001)

    def disable(self) -> None:
        """RPDO torque 0 + controlword 0, then SDO 0x6040 = 0 per drive (short timeouts)."""
        if self.bus is None:
            raise LinkError("CAN link is not open")
        failures: list[str] = []
        try:
            self._send_rpdos(co.CW_DISABLE_VOLTAGE, (0,) * self.n_joints)
        except (can.CanError, RuntimeError) as exc:
            failures.append(f"RPDO: {_one_line(exc)}")
        with self._short_sdo_timeouts():
            for j in range(self.n_joints):
                try:
                    self._sdo_write(j, 0x6040, 0, co.CW_DISABLE_VOLTAGE)
                except LinkError as exc:
                    failures.append(str(exc))
        if failures:
            raise LinkError("disable incomplete: " + "; ".join(failures))

    def faults(self) -> list[Fault]:
        """Active faults: 0x603F of every drive by SDO; EMCY records where SDO fails."""
        self._require_open()
        out: list[Fault] = []
        with self._short_sdo_timeouts():
            for j in range(self.n_joints):
                try:
                    code = self._sdo_read(j, 0x603F, 0)
                except LinkError:
                    fault = self._emcy.get(j)
                    if fault is not None:
                        out.append(fault)
                    continue
                if code != co.ERR_NONE:
                    out.append(Fault(j, code, fault_text(code)))
        return out

    def clear_faults(self) -> None:
        """Fault reset (controlword 0x80 then 0x00, by SDO) on every drive in FAULT."""
        self._require_open()
        for j in range(self.n_joints):
            sw = self._sdo_read(j, 0x6041, 0)
            state = co.state_from_statusword(sw)
            if state in (co.State.FAULT, co.State.FAULT_REACTION_ACTIVE) or j in self._emcy:
                self._sdo_write(j, 0x6040, 0, co.CW_FAULT_RESET)
                self._sdo_write(j, 0x6040, 0, co.CW_DISABLE_VOLTAGE)
                self._emcy.pop(j, None)

    # ---- cycle --------------------------------------------------------------------------------
    def _sleep_until(self, deadline: float) -> None:
        """Wait until host time ``deadline`` (s since open): :meth:`Arm.wait_for_deadline`."""
        self.wait_for_deadline(deadline)

    def _sync(
        self, rpdos: list[tuple[int, bytes]] | None = None
    ) -> tuple[float, float, list[tuple[int, ...]], list[tuple[int, ...]]]:
        """SYNC, then wait for TPDO1 + TPDO2 of every drive; (sent_at, received_at, fb1, fb2).

        ``rpdos``: frames to send just before the SYNC, in the same write (lockstep).
        """
        timeout = self.feedback_timeout_s
        with self._fb_lock:
            self._fb1 = [None] * self.n_joints
            self._fb2 = [None] * self.n_joints
            self._missing = 2 * self.n_joints
            self._fb_event.clear()
            sent = time.monotonic()
            self._collect_since = sent
        try:
            self._send_frames([*(rpdos or ()), (co.SYNC_ID, b"")])
        except (can.CanError, RuntimeError) as exc:
            with self._fb_lock:
                self._collect_since = None
            what = "RPDO + SYNC" if rpdos else "SYNC"
            raise LinkError(f"cannot send {what}: {_one_line(exc)}") from exc
        if self._direct:
            arrived = self._read_feedback(sent + timeout)
            if self._direct_refused:
                self._threaded_receive()
        else:
            arrived = self._wait_feedback(sent, timeout)
        if not arrived:
            with self._fb_lock:
                self._collect_since = None
                fb1, fb2 = list(self._fb1), list(self._fb2)
            if fb1.count(None) + fb2.count(None) > 0:
                self.stats.timeouts += 1
                j = next(j for j in range(self.n_joints) if fb1[j] is None or fb2[j] is None)
                message = self._gone_reason() or (
                    f"no feedback from node {self.node_ids[j]} within {timeout * 1000:g} ms "
                    "(the feedback budget): virtual robot, drive or bus stalled or gone"
                )
                self._error(message)
                raise LinkError(message)
        with self._fb_lock:
            fb1 = list(self._fb1)
            fb2 = list(self._fb2)
            received = self._fb_last_at
        if self.mode == REALTIME:
            self.stats.waited(received - sent, self.period_s)
        return sent - self._t0, received - self._t0, fb1, fb2  # type: ignore[return-value]

    def _wait_feedback(self, sent: float, timeout: float) -> bool:
        """Threaded receive: wait for the feedback event until ``sent + timeout``. Past one
        period (late), poll every few ms whether the receive thread died (closed pty, reset
        socket) or the peer process is gone, and stop at once if so."""
        event = self._fb_event
        if event.wait(min(timeout, self.period_s)):
            return True
        until = sent + timeout
        while True:
            if self._gone_reason():
                return event.is_set()
            left = until - time.monotonic()
            if left <= 0:
                return event.is_set()
            if event.wait(min(left, LIVENESS_POLL_S)):
                return True

    def _gone_reason(self) -> str | None:
        """Why the other end is certainly gone (not merely late), or None."""
        receiver = self._receiver
        if self._link_lost is not None:
            return self._link_lost
        if receiver is not None and receiver.exception is not None:
            return f"CAN link lost: {_one_line(receiver.exception)}"
        if self.peer_gone():
            return "the virtual robot process is gone"
        return None

    def _read_feedback(self, until: float) -> bool:
        """Direct receive: read and dispatch frames until every TPDO is in or ``until``."""
        event = self._fb_event
        check_peer_after = time.monotonic() + LOCKSTEP_LIVENESS_POLL_S  # not on the fast path
        while not event.is_set():
            now = time.monotonic()
            left = until - now
            if left <= 0 or (now > check_peer_after and self.peer_gone()):
                return False
            try:
                self._read_frames(min(left, LOCKSTEP_LIVENESS_POLL_S))
            except (can.CanError, OSError, RuntimeError) as exc:
                self._link_lost = f"CAN link lost: {_one_line(exc)}"
                self._error(f"CAN receive failed: {_one_line(exc)}")
                return False
        return True

    def _feedback(
        self, fb1: list[tuple[int, ...]], fb2: list[tuple[int, ...]]
    ) -> tuple[tuple[float, ...], tuple[float, ...], tuple[int, ...]]:
        q, dq, status = [], [], []
        for j in range(self.n_joints):
            sw, raw = fb1[j]
            velocity, _torque = fb2[j]
            counts = raw if not self._started else unwrap_int32(self._counts[j], raw)
            self._counts[j] = counts
            q.append(position_to_rad(counts, self._cpr[j]))
            dq.append(counts_to_rad(velocity, self._cpr[j]))
            status.append(sw)
        self._started = True
        return tuple(q), tuple(dq), tuple(status)

    def _check_limits(self, q: tuple[float, ...], dq: tuple[float, ...]) -> None:
        reason = self.limits.check(q, dq)
        if reason is not None:
            self.safe_stop()
            self._error(f"safety stop: {reason}")
            raise SafetyStop(reason)

    def start(self) -> Sample:
        """First feedback q(t_0): keep-alive RPDO (torque 0), SYNC, TPDOs of every drive."""
        self._require_open()
        self._started = False
        self._k = 0
        keep_alive = self._rpdo_frames(co.CW_ENABLE_OPERATION, (0,) * self.n_joints)
        if self.mode == LOCKSTEP:
            self._direct_receive()
            sent_at, received_at, fb1, fb2 = self._sync(keep_alive)
        else:
            try:
                # feeds the command watchdog between enable() and the first cycle
                self._send_frames(keep_alive)
            except (can.CanError, RuntimeError) as exc:
                raise LinkError(f"cannot send RPDO: {_one_line(exc)}") from exc
            sent_at, received_at, fb1, fb2 = self._sync()
        q, dq, status = self._feedback(fb1, fb2)
        self._check_limits(q, dq)
        zeros = (0.0,) * self.n_joints
        if self.mode == LOCKSTEP:  # the link's clock: host times equal t (Sample docstring)
            return Sample(0.0, q, status, zeros, 0.0, 0.0, 0.0)
        return Sample(sent_at, q, status, zeros, sent_at, received_at, math.nan)

    def cycle(self, tau_Nm: Sequence[float], deadline: float | None = None) -> Sample:
        """Command ``tau_Nm`` (clamped, quantized) for one period; the feedback at its end."""
        if not self._started:
            raise LinkError("cycle() before start()")
        if len(tau_Nm) != self.n_joints or not all(math.isfinite(float(t)) for t in tau_Nm):
            self.safe_stop()
            raise SafetyStop(f"torque command {tuple(tau_Nm)} is not {self.n_joints} finite values")
        if self.mode == REALTIME and deadline is not None:
            ahead = deadline - self.now()
            if not ahead <= MAX_DEADLINE_AHEAD_S + 10 * self.period_s:
                raise ValueError(
                    f"deadline {deadline!r} is {ahead:.3f} s ahead: not host seconds since "
                    "open() (Arm.now())"
                )
        tau = self.limits.clamp_torque(tau_Nm)
        permille = tuple(torque_to_permille(t, r) for t, r in zip(tau, self._rated, strict=True))
        rpdos = self._rpdo_frames(co.CW_ENABLE_OPERATION, permille)
        if self.mode == LOCKSTEP:  # RPDOs and SYNC in one write; the robot steps on the SYNC
            self._direct_receive()
            sent_at, received_at, fb1, fb2 = self._sync(rpdos)
        else:  # RPDOs now (the drive applies them on arrival), SYNC at the deadline
            try:
                self._send_frames(rpdos)
            except (can.CanError, RuntimeError) as exc:
                raise LinkError(f"cannot send RPDO: {_one_line(exc)}") from exc
            if deadline is not None:
                self._sleep_until(deadline)
            sent_at, received_at, fb1, fb2 = self._sync()
        self._k += 1
        self.stats.cycles += 1
        q, dq, status = self._feedback(fb1, fb2)
        self._check_limits(q, dq)
        applied = tuple(
            permille_to_torque(p, r) for p, r in zip(permille, self._rated, strict=True)
        )
        if self.mode == LOCKSTEP:
            t = self._k * self.period_s
            return Sample(t, q, status, applied, t, t, t)
        due = math.nan if deadline is None else float(deadline)
        return Sample(sent_at, q, status, applied, sent_at, received_at, due)


def _one_line(exc: BaseException) -> str:
    # python-can's socketcand puts the traceback into its error's text: keep the error
    text = " ".join(str(exc).split("Traceback (most recent call last)", 1)[0].split())
    return text or type(exc).__name__


__all__ = [
    "EMCY",
    "HEARTBEAT",
    "PDO_LAYOUT",
    "TPDO1",
    "TPDO2",
    "CanArm",
    "Frame",
    "build_object_dictionary",
    "fault_text",
    "frame_routes",
    "parse_frame",
]
