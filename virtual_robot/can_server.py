"""CANopen (CiA 301) slave stack for the virtual robot's CiA 402 drives, on any python-can bus.

:class:`CanDriveServer` decodes the frames a host sends and calls the transport-independent
:class:`~virtual_robot.robot.VirtualRobot`; it never touches the physics itself. The object map,
PDO layouts, SDO codec and COB-IDs come from :mod:`drivers.protocol.cia402` (shared with the host).

Services (CiA 301 predefined connection set, node id n):

* **NMT** 0x000 ``[cs, node]`` (node 0 = every node). Each node has its own NMT state. When the
  server starts, each node sends its boot-up message 0x700+n ``[0x00]`` and is PRE-OPERATIONAL.
  0x01 start → OPERATIONAL, 0x02 stop → STOPPED, 0x80 → PRE-OPERATIONAL, 0x81 reset node →
  :meth:`VirtualRobot.reset_node` (drive and object dictionary to power-on values, so the PDOs
  are unconfigured again) + boot-up + PRE-OPERATIONAL, 0x82 reset communication →
  :meth:`VirtualRobot.reset_communication` (the communication parameters 0x1000-0x1FFF: PDO
  COB-IDs, transmission types, mappings and 0x1017 to power-on values, the drive kept as it is)
  + boot-up + PRE-OPERATIONAL, as CiA 301 has it. Malformed NMT frames are ignored and logged.
* **SDO** server 0x600+n → 0x580+n, expedited transfers only, in PRE-OPERATIONAL and
  OPERATIONAL. Every failure is answered with an abort frame (CiA 301 codes from the codec, from
  :meth:`VirtualRobot.read`/``write``, or 0x06070010 when the data size does not match the
  object); an unexpected internal error aborts with 0x08000000. A client abort (ccs 4) gets no
  answer. An expedited download without size indication takes the object's size from the 4 bytes.
* **RPDO1** on the COB-ID configured in 0x1400:1, OPERATIONAL only, mapping 0x1600: each mapped
  object is written with :meth:`VirtualRobot.write`, and the plant is given them once, with
  the core's lock held throughout (a realtime period tick never sees half an RPDO).
* **SYNC** 0x080 (DLC 0, or 1 with a SYNC counter): :meth:`VirtualRobot.sync` (one period in
  lockstep), then for each OPERATIONAL node with valid COB-IDs, TPDO1 (0x1800/0x1A00) and TPDO2
  (0x1801/0x1A01), packed from :meth:`VirtualRobot.read` of each mapped object. Order: node 1
  TPDO1, TPDO2, node 2 TPDO1, TPDO2. The SYNC and the reads hold the core's lock together, so a
  realtime period tick cannot fall between them. The plant advances on every SYNC whatever the
  NMT state.
* **EMCY** 0x080+n, ``cia402.emcy_payload`` (error code, error register, 5 zero bytes): after
  every event (and on every loop pass, for the realtime period timer) the core's queued events
  are sent, after the event's own replies; nodes in STOPPED send none (CiA 301).
* **Heartbeat** 0x700+n ``[NMT state]`` every 0x1017 ms when 0x1017 > 0 (wall time).

EMCY error codes (the error register byte is the drive's 0x1001 or-ed with the bits shown):

====== ========================================================== =============================
code   meaning                                                    error register
====== ========================================================== =============================
0x8250 RPDO timeout: the drive's command watchdog (from the drive) 0x11 (from the drive)
0x8400 overspeed (from the drive)                                  0x21 (from the drive)
0x0000 error reset / no error (from the drive, after fault reset)  0x00
0x8210 RPDO not processed due to length error (server)             0x11 (generic, communication)
0x6320 RPDO value rejected by the drive: parameter error (server)  0x01 (generic)
====== ========================================================== =============================

Frames that are remote, error or extended-id frames, frames for other nodes and frames that the
present NMT state does not allow are ignored and counted in :attr:`CanDriveServer.ignored`.

Bus time: with a :class:`~virtual_robot.bus_pacing.BusPacer` (bench ``pace_bus = true``) the
frames read together are dispatched once the last of them has crossed the bus at its bitrate,
and the frames sent together are written once the last of them has (bus_pacing.py).

Cost: the routing table, the PDO codecs (precompiled structs) and the heartbeat periods are
derived from the object dictionary once per change of it (``VirtualRobot.config_version``). On a
bus with ``recv_frames``/``send_frames`` (:class:`~virtual_robot.slcan_device.SlcanPtyBus`) a
batch of frames (a lockstep cycle's RPDOs and SYNC) is read in one read and answered in one
write, before the periodic work (heartbeats, host-silence check).
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from collections.abc import Callable, Sequence

import can

from drivers.protocol import cia402 as co
from drivers.protocol.cia402 import SdoAbortError
from virtual_robot.bus_pacing import BusPacer, RawFrame
from virtual_robot.host_silence import HostSilence
from virtual_robot.robot import REALTIME, VirtualRobot

ERR_PDO_LENGTH = 0x8210  # CiA 301: PDO not processed due to length error
ERR_PARAMETER = 0x6320  # CiA 301: software, parameter error (a mapped value the drive rejected)
RECV_TIMEOUT_S = 0.05
RECV_TIMEOUT_REALTIME_S = 0.01  # realtime: watchdog EMCYs from the period timer go out sooner

_NMT_NEXT = {
    co.NMT_START: co.NMT_STATE_OPERATIONAL,
    co.NMT_STOP: co.NMT_STATE_STOPPED,
    co.NMT_PRE_OPERATIONAL: co.NMT_STATE_PRE_OPERATIONAL,
}
_TPDOS = ((0x1800, 0x1A00), (0x1801, 0x1A01))
_SDO, _RPDO = "sdo", "rpdo"

_logger = logging.getLogger(__name__)


def _index_of(data: bytes) -> tuple[int, int]:
    """(index, subindex) of an SDO frame as far as it has them, for an abort reply."""
    index = int.from_bytes(data[1:3], "little") if len(data) >= 3 else 0
    return index, data[3] if len(data) >= 4 else 0


def _raw(msg: can.Message) -> RawFrame:
    """A python-can Message as the pacer's (id, data, extended, remote); remote: DLC bytes."""
    data = bytes(msg.dlc) if msg.is_remote_frame else bytes(msg.data or b"")
    return msg.arbitration_id, data, msg.is_extended_id, msg.is_remote_frame


def _pdo_struct(mapping: Sequence[tuple[int, int]]) -> struct.Struct:
    """One precompiled codec for a whole PDO: the same bytes as ``cia402.pack_pdo``."""
    return struct.Struct("<" + "".join(co.OBJECT_MAP[m].fmt[1:] for m in mapping))


class _Plan:
    """What the server derives from the drives' configuration, rebuilt when it changes.

    ``routes``: COB-ID → (service, node) for SDO requests and valid RPDO COB-IDs;
    ``rpdo``: node → (mapping, codec); ``tpdo``: node → [(COB-ID, codec, readers)] of its valid
    TPDOs in order; ``heartbeat_s``: node → producer heartbeat period in s (0: off).
    """

    def __init__(self, core: VirtualRobot, nodes: Sequence[int]) -> None:
        self.version = core.config_version
        self.routes: dict[int, tuple[str, int]] = {}
        self.rpdo: dict[int, tuple[tuple[tuple[int, int], ...], struct.Struct]] = {}
        self.tpdo: dict[int, list[tuple[int, struct.Struct, tuple[Callable[[], int], ...]]]] = {}
        self.heartbeat_s: dict[int, float] = {}
        for node in nodes:
            self.routes[co.SDO_RX_BASE + node] = (_SDO, node)
            rpdo_id = core.pdo_cob_id(node, 0x1400)
            if rpdo_id is not None:
                self.routes.setdefault(rpdo_id, (_RPDO, node))
            mapping = core.pdo_mapping(node, 0x1600)
            self.rpdo[node] = (mapping, _pdo_struct(mapping))
            entries = []
            for comm, mapping_index in _TPDOS:
                cob_id = core.pdo_cob_id(node, comm)
                if cob_id is None:
                    continue
                mapping = core.pdo_mapping(node, mapping_index)
                readers = tuple(core.reader(i, s, node=node) for i, s in mapping)
                entries.append((cob_id, _pdo_struct(mapping), readers))
            self.tpdo[node] = entries
            self.heartbeat_s[node] = core.read(0x1017, 0, node=node) / 1000.0


class CanDriveServer:
    """Serve a :class:`VirtualRobot`'s drives as CANopen nodes on a python-can bus.

    Outgoing frames of one received frame (or, on a bus with ``recv_frames``/``send_frames`` such
    as :class:`~virtual_robot.slcan_device.SlcanPtyBus`, of one batch of received frames) are
    sent together, in the order they were produced.
    """

    def __init__(
        self,
        core: VirtualRobot,
        bus: can.BusABC,
        *,
        idle_timeout_s: float | None = None,
        log: Callable[[str], None] | None = None,
        pacer: BusPacer | None = None,
    ) -> None:
        self.core = core
        self.bus = bus
        self.pacer = pacer  # frames take their bit time on the bus (bus_pacing.py), or None
        self.idle_timeout_s = idle_timeout_s
        self._log = log or _logger.info
        self.nodes: tuple[int, ...] = tuple(sorted(core.by_node))
        self.nmt_state: dict[int, int] = dict.fromkeys(self.nodes, co.NMT_STATE_PRE_OPERATIONAL)
        self.frames_in = 0
        self.frames_out = 0
        self.ignored = 0
        self.errors = 0
        self.dropped_rpdos = 0  # robot-side timing fault: command frames lost
        self._hold_until: float | None = None  # robot-side timing fault: late feedback
        self._last_heartbeat: dict[int, float] = {}
        self._silence = HostSilence(idle_timeout_s)
        self._last_recv_error = ""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._plan: _Plan | None = None
        self._outbox: list[tuple[int, bytes]] = []
        self._send_frames = getattr(bus, "send_frames", None)

    # ---- life cycle ---------------------------------------------------------------------
    def start(self) -> None:
        """Serve in a daemon thread until :meth:`stop`."""
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(
            target=self.serve_forever, args=(self._stop,), name="can-drive-server", daemon=True
        )
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread started by :meth:`start` and wait for it (idempotent)."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join()

    def serve_forever(self, stop: threading.Event) -> None:
        """Boot-up messages, then receive and dispatch frames until ``stop`` is set."""
        for node in self.nodes:
            self._boot_up(node)
        self._flush()
        if self.core.mode == REALTIME:
            self.core.start_period_timer(stop)
        timeout = RECV_TIMEOUT_REALTIME_S if self.core.mode == REALTIME else RECV_TIMEOUT_S
        recv_frames = getattr(self.bus, "recv_frames", None)
        pacer = self.pacer
        while not stop.is_set():
            try:
                if recv_frames is not None:  # a batch: raw (id, data, extended, remote) tuples
                    batch = recv_frames(timeout)
                    if pacer is not None and batch:
                        pacer.pace(batch)  # the drives see them once they crossed the bus
                    for can_id, data, extended, remote in batch:
                        self._handle(can_id, data, extended, remote)
                else:
                    msg = self.bus.recv(timeout=timeout)
                    if msg is not None:
                        if pacer is not None and not (msg.is_error_frame or msg.is_fd):
                            pacer.pace([_raw(msg)])
                        self._handle_message(msg)
            except Exception as exc:  # a dead or flaky transport: say so once, keep trying
                self.errors += 1
                text = f"{type(exc).__name__}: {exc}"
                if text != self._last_recv_error:
                    self._log(f"bus receive failed: {text}")
                    self._last_recv_error = text
                stop.wait(RECV_TIMEOUT_S)
            else:
                self._last_recv_error = ""
            self._flush()  # the answers first: the periodic work is off the host's critical path
            self._poll(None)
            if self._outbox:
                self._flush()
        if pacer is not None:
            load = pacer.load()
            self._log(
                f"paced bus at {pacer.bitrate} bit/s: {load['frames']} frames, "
                f"{load['bits']} bits in {load['elapsed_s']:.1f} s: load {load['load_pct']:.1f} %"
            )

    # ---- one frame ----------------------------------------------------------------------
    def handle(self, msg: can.Message) -> None:
        """Dispatch one received frame and send its replies; never raises (errors are counted
        and logged)."""
        self._handle_message(msg)
        self._flush()

    def _handle_message(self, msg: can.Message) -> None:
        if msg.is_error_frame or msg.is_fd:
            self.frames_in += 1
            self._silence.heard()
            self.ignored += 1
            self._send_emcys()
            return
        self._handle(
            msg.arbitration_id, bytes(msg.data or b""), msg.is_extended_id, msg.is_remote_frame
        )

    def _handle(self, can_id: int, data: bytes, extended: bool, remote: bool) -> None:
        self.frames_in += 1
        self._silence.heard()
        try:
            if remote or extended:
                self.ignored += 1
                return
            if not self._dispatch(can_id, data):
                self.ignored += 1
        except Exception as exc:
            self.errors += 1
            self._log(f"frame 0x{can_id:03X} [{bytes(data).hex()}]: {type(exc).__name__}: {exc}")
        finally:
            self._send_emcys()

    def _current_plan(self) -> _Plan:
        plan = self._plan
        if plan is None or plan.version != self.core.config_version:
            with self.core.lock:
                plan = self._plan = _Plan(self.core, self.nodes)
        return plan

    def _dispatch(self, cob_id: int, data: bytes) -> bool:
        """Handle a standard data frame; False if nothing here was addressed by it."""
        if cob_id == co.NMT_ID:
            return self._nmt(data)
        if cob_id == co.SYNC_ID:
            return self._sync(data)
        route = self._current_plan().routes.get(cob_id)
        if route is None:
            return False
        service, node = route
        state = self.nmt_state[node]
        if service == _SDO:
            if state == co.NMT_STATE_STOPPED:
                return False
            self._sdo(node, data)
            return True
        if state == co.NMT_STATE_OPERATIONAL:
            self._rpdo(node, data)
            return True
        return False

    # ---- NMT ----------------------------------------------------------------------------
    def _nmt(self, data: bytes) -> bool:
        if len(data) != 2:
            self._log(f"NMT frame of {len(data)} bytes ignored (needs 2)")
            return False
        cs, target = data
        if target != 0 and target not in self.nmt_state:
            return False  # another node's
        nodes = self.nodes if target == 0 else (target,)
        if cs in _NMT_NEXT:
            for node in nodes:
                self.nmt_state[node] = _NMT_NEXT[cs]
        elif cs in (co.NMT_RESET_NODE, co.NMT_RESET_COMMUNICATION):
            for node in nodes:
                if cs == co.NMT_RESET_NODE:
                    self.core.reset_node(node)
                else:
                    self.core.reset_communication(node)
                self._boot_up(node)
        else:
            self._log(f"NMT command specifier 0x{cs:02X} unknown, ignored")
            return False
        return True

    def _boot_up(self, node: int) -> None:
        self._send(co.HEARTBEAT_BASE + node, bytes([co.NMT_STATE_BOOTUP]))
        self.nmt_state[node] = co.NMT_STATE_PRE_OPERATIONAL
        self._last_heartbeat[node] = time.monotonic()

    # ---- SDO ----------------------------------------------------------------------------
    def _sdo(self, node: int, data: bytes) -> None:
        if len(data) == 8 and data[0] >> 5 == 4:
            return  # client abort: no transfer in progress, nothing to answer
        try:
            reply = self._sdo_reply(node, data)
        except SdoAbortError as exc:
            reply = co.sdo_abort(exc.index, exc.subindex, exc.code)
        except Exception as exc:  # an internal error: abort the transfer, keep serving
            self.errors += 1
            self._log(f"SDO on node {node} [{data.hex()}]: {type(exc).__name__}: {exc}")
            index, sub = _index_of(data)
            reply = co.sdo_abort(index, sub, co.ABORT_GENERAL)
        self._send(co.SDO_TX_BASE + node, reply)

    def _sdo_reply(self, node: int, data: bytes) -> bytes:
        req = co.decode_sdo_request(data)
        index, sub = req.index, req.subindex
        obj = co.lookup(index, sub)
        if not req.write:
            if obj.access is co.Access.WO:
                raise SdoAbortError(index, sub, co.ABORT_WRITE_ONLY)
            value = self.core.read(index, sub, node=node)
            return co.sdo_upload_response(index, sub, obj.encode(value))
        if obj.access is co.Access.RO:
            raise SdoAbortError(index, sub, co.ABORT_READ_ONLY)
        payload = req.data if data[0] & 0x01 else req.data[: obj.size]  # s = 0: size not given
        if len(payload) != obj.size:
            raise SdoAbortError(index, sub, co.ABORT_LENGTH)
        self.core.write(index, sub, obj.decode(payload), node=node)
        return co.sdo_download_response(index, sub)

    # ---- PDO, SYNC ----------------------------------------------------------------------
    def _rpdo(self, node: int, data: bytes) -> None:
        if self.core.drop_command():  # an injected timing fault: the frame never arrived
            self.dropped_rpdos += 1
            return
        mapping, codec = self._current_plan().rpdo[node]
        if len(data) != codec.size:
            register = self.core.read(0x1001, 0, node=node)
            register |= co.ERREG_GENERIC | co.ERREG_COMMUNICATION
            self._send(co.EMCY_BASE + node, co.emcy_payload(ERR_PDO_LENGTH, register))
            return
        # The mapped objects arrived together: written and applied together, under the core's
        # lock, so a realtime period tick cannot fall between them (it would apply the command
        # before the event log says it took effect, and `hil replay` could not reproduce it).
        with self.core.lock:
            try:
                for (index, sub), value in zip(mapping, codec.unpack(data), strict=True):
                    try:
                        self.core.write(index, sub, value, node=node, apply=False)
                    except SdoAbortError as exc:
                        register = self.core.read(0x1001, 0, node=node) | co.ERREG_GENERIC
                        self._send(co.EMCY_BASE + node, co.emcy_payload(ERR_PARAMETER, register))
                        self._log(f"RPDO1 of node {node}: {exc}")
            finally:
                self.core.apply_commands()

    def _sync(self, data: bytes) -> bool:
        if len(data) > 1:
            self._log(f"SYNC of {len(data)} bytes ignored (0, or 1 with a counter)")
            return False
        tpdo = self._current_plan().tpdo
        outbox = self._outbox
        with self.core.lock:  # sample and read the feedback as one step
            self.core.sync_sample()
            for node in self.nodes:
                if self.nmt_state[node] != co.NMT_STATE_OPERATIONAL:
                    continue
                for cob_id, codec, readers in tpdo[node]:
                    outbox.append((cob_id, codec.pack(*[read() for read in readers])))
        delay = self.core.feedback_delay_s()
        if delay > 0:  # an injected timing fault: this feedback leaves late
            self._hold_until = time.monotonic() + delay
        return True

    # ---- periodic -----------------------------------------------------------------------
    def poll(self, now: float | None = None) -> None:
        """Heartbeats, the host-silence check and queued EMCYs; called on every loop pass."""
        self._poll(now)
        self._flush()

    def _poll(self, now: float | None) -> None:
        now = time.monotonic() if now is None else now
        try:
            heartbeat_s = self._current_plan().heartbeat_s
            for node in self.nodes:
                period_s = heartbeat_s[node]
                if period_s <= 0:
                    self._last_heartbeat.pop(node, None)
                    continue
                last = self._last_heartbeat.setdefault(node, now)
                if now - last >= period_s:
                    self._send(co.HEARTBEAT_BASE + node, bytes([self.nmt_state[node]]))
                    # keep the beat on its grid unless we fell more than a period behind
                    behind = now - last >= 2 * period_s
                    self._last_heartbeat[node] = now if behind else last + period_s
            if self._silence.expired(now):
                self.core.disable_all()
                self._log(f"host silent for {self.idle_timeout_s:g} s: drives disabled")
        except Exception as exc:
            self.errors += 1
            self._log(f"periodic work failed: {type(exc).__name__}: {exc}")
        self._send_emcys()

    # ---- output -------------------------------------------------------------------------
    def _send_emcys(self) -> None:
        try:
            events = self.core.pop_emcy()
        except Exception as exc:
            self.errors += 1
            self._log(f"EMCY queue failed: {type(exc).__name__}: {exc}")
            return
        for node, event in events:
            if self.nmt_state.get(node) == co.NMT_STATE_STOPPED:
                continue
            payload = co.emcy_payload(event.error_code, event.error_register)
            self._send(co.EMCY_BASE + node, payload)

    def _send(self, cob_id: int, data: bytes) -> None:
        """Queue a frame; :meth:`_flush` sends the queue."""
        self._outbox.append((cob_id, data))

    def _flush(self) -> None:
        """Send the queued frames in order: one ``send_frames`` call where the bus has it."""
        frames, self._outbox = self._outbox, []
        if self._hold_until is not None:  # injected late feedback (see _sync)
            hold, self._hold_until = self._hold_until, None
            while (left := hold - time.monotonic()) > 0:
                time.sleep(left - 2e-4 if left > 4e-4 else 0)
        if self.pacer is not None and frames:  # written once the last has crossed the bus
            self.pacer.pace([(cob_id, data, False, False) for cob_id, data in frames])
        if self._send_frames is not None:
            try:
                self._send_frames(frames)
            except Exception as exc:
                self.errors += 1
                ids = ", ".join(f"0x{cob_id:03X}" for cob_id, _ in frames)
                self._log(f"send {ids} failed: {type(exc).__name__}: {exc}")
            else:
                self.frames_out += len(frames)
            return
        for cob_id, data in frames:
            msg = can.Message(arbitration_id=cob_id, data=data, is_extended_id=False)
            try:
                self.bus.send(msg)
            except Exception as exc:
                self.errors += 1
                self._log(f"send 0x{cob_id:03X} failed: {type(exc).__name__}: {exc}")
            else:
                self.frames_out += 1
