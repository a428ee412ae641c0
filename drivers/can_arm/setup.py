"""Set-up of :class:`~drivers.can_arm.CanArm` through the canopen library, as a CANopen tool
does it: connect (one :class:`canopen.RemoteNode` per drive), confirm each drive against its
profile (device type, identity, rated torque, encoder resolution), configure the PDO map and
the mode by SDO, NMT start; close; and the SDO helpers with their one-line errors.

:class:`NodeSetup` is a mixin of :class:`~drivers.can_arm.CanArm`.

Imports: :mod:`drivers.can_arm.objects`, :mod:`drivers.can_arm.link`, :mod:`drivers.arm`,
:mod:`drivers.candump`, canopen.
"""

from __future__ import annotations

import contextlib
import secrets
import time
from pathlib import Path
from typing import Any

import can
import canopen
from canopen.nmt import NmtError
from canopen.objectdictionary import ODRecord
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from drivers.arm import LinkError
from drivers.can_arm.link import ArmNetwork, Receiver, channel_name
from drivers.can_arm.objects import PDO_LAYOUT, build_object_dictionary, one_line
from drivers.candump import CandumpWriter
from drivers.protocol import cia402 as co
from profiles.drive import DriveProfile

SHORT_SDO_TIMEOUT_S = 0.2  # disable() and fault queries: best effort, do not hang on a dead link
# Before it sends anything the host listens this long for another host's frames (NMT, SYNC,
# RPDOs and SDO requests to its drives): a host already cycling sends a SYNC every period
# (2.5 ms at 400 Hz; faster in lockstep) and one setting up an SDO request per answer, so
# 0.1 s sees dozens; they are another host's run, which NMT and SDO set-up would ruin. A host
# that starts together with another hears it during its own set-up instead (checked after
# every SDO transfer until open)
HOST_LISTEN_S = 0.1
# Then it claims the bus with its heartbeat and listens this long for a rival's (two hosts that
# started together both heard a silent bus): the lower claim wins, the other refuses before it
# has sent any set-up, and a host that holds the bus answers every claim (co.host_heartbeat).
# Longer than a heartbeat's round trip over any of the transports (a 1 Mbit/s frame takes
# 0.13 ms; an slcan adapter or a socketcand hop adds milliseconds).
HOST_CLAIM_S = 0.1


def profile_name(p: DriveProfile) -> str:
    return Path(p.source).stem if p.source else p.model


class NodeSetup:
    """Open, confirm, configure, close; SDO reads and writes (a mixin of CanArm)."""

    # ---- link ------------------------------------------------------------------------------
    def open(self) -> None:
        """Connect, confirm each drive against its profile, configure PDOs by SDO, NMT start."""
        if self._is_open:
            return
        try:
            self._connect()
            self._claim_the_bus()
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
            raise LinkError(f"CAN link failed during set-up: {one_line(exc)}") from exc
        except BaseException:
            self.close()
            raise
        self._is_open = True

    def _connect(self) -> None:
        try:
            self.bus = self._bus_factory()
        except (can.CanError, OSError, ValueError) as exc:
            raise LinkError(f"cannot open the CAN bus: {one_line(exc)}") from exc
        if self.log_path is not None:
            self.log_path.parent.mkdir(parents=True, exist_ok=True)
            self._writer = CandumpWriter(self.log_path, channel=channel_name(self.bus))
        # the batch path of buses that have one (drivers.slcan.SelectSlcanBus)
        self._bus_send_frames = getattr(self.bus, "send_frames", None)
        self._bus_recv_frames = getattr(self.bus, "recv_frames", None)
        network = ArmNetwork(self, self.bus)
        nodes = []
        for p in self.drives:
            node = canopen.RemoteNode(p.node_id, build_object_dictionary())
            node.sdo.RESPONSE_TIMEOUT = self.timeout_s
            network.add_node(node)
            nodes.append(node)
        self.network, self.nodes = network, tuple(nodes)
        self._listeners = list(network.listeners)
        self._receiver = Receiver(self._read_frames, name="can-arm-receiver")
        network.notifier = self._receiver  # type: ignore[assignment]  # check() reads .exception

    def _claim_the_bus(self) -> None:
        """Listen :data:`HOST_LISTEN_S` before sending anything: another host's frames on the
        bus mean it is driving (or setting up) these drives (CiA 301: one NMT master, one SYNC
        producer per bus): refuse in one line rather than reset its drives under it. Then claim
        the bus with the host's heartbeat (a random node-ID no drive has, a random nonce) and
        listen :data:`HOST_CLAIM_S` for a rival's: on a bus without a hub, of two hosts that
        start together exactly one keeps it (``BusLink._host_heartbeat``)."""
        self._listen(HOST_LISTEN_S)
        free = [k for k in range(1, 128) if k not in self.node_ids]
        with self._claim_lock:  # a heartbeat heard before this line wins; after, values decide
            lost = bool(self._claim_lost)
            if not lost:
                self._claim = (secrets.choice(free), secrets.token_bytes(4))
        if lost:
            self._refuse_beside_another_host()  # lost unclaimed: our heartbeat must not follow
        self._send_heartbeat()
        self._listen(HOST_CLAIM_S)
        self._holding = True

    def _listen(self, seconds: float) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline and not self._another_host():
            time.sleep(0.005)
        self._refuse_beside_another_host()

    def _confirm(self, j: int) -> None:
        """Presence (0x1000), identity (0x1018), rated torque (0x6076), encoder (0x608F:1)."""
        p, n, name = self.drives[j], self.node_ids[j], profile_name(self.drives[j])
        try:
            device_type = self._sdo_read(j, 0x1000, 0)
        except LinkError:
            self._refuse_beside_another_host()  # no answer for us: another host's doing
            # not there yet (or we missed its boot-up): wait for a boot-up, then ask once more
            with contextlib.suppress(NmtError):
                if n not in self._booted:
                    self.nodes[j].nmt.wait_for_bootup(self.timeout_s)
            try:
                device_type = self._sdo_read(j, 0x1000, 0)
            except LinkError as exc:
                self._refuse_beside_another_host()
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
        """PDO map by SDO (docs/design.md), synchronous; mode 10 (cyclic synchronous torque)."""
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
        self._is_open = self._holding = False
        self._claim, self._claim_lost = None, ""
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

    # ---- SDO helpers -------------------------------------------------------------------------
    def _sdo_var(self, j: int, index: int, sub: int) -> Any:
        entry = self.nodes[j].sdo[index]
        return entry[sub] if isinstance(entry.od, ODRecord) else entry

    def _sdo_read(self, j: int, index: int, sub: int) -> int:
        self._threaded_receive()
        try:
            value = int(self._sdo_var(j, index, sub).raw)
        except Exception as exc:
            self._refuse_while_opening()
            raise self._sdo_error(j, "read", index, sub, exc) from exc
        self._refuse_while_opening()
        return value

    def _sdo_write(self, j: int, index: int, sub: int, value: int) -> None:
        self._threaded_receive()
        try:
            self._sdo_var(j, index, sub).raw = value
        except Exception as exc:
            self._refuse_while_opening()
            raise self._sdo_error(j, "write", index, sub, exc) from exc
        self._refuse_while_opening()

    def _sdo_error(self, j: int, op: str, index: int, sub: int, exc: Exception) -> LinkError:
        n = self.node_ids[j]
        obj = co.OBJECT_MAP.get((index, sub))
        what = f"0x{index:04X}:{sub}" + (f" ({obj.name})" if obj else "")
        if isinstance(exc, SdoAbortedError):
            text = co.ABORT_TEXT.get(exc.code) or str(exc)
            reason = f"aborted 0x{exc.code:08X}: {text}"
        elif isinstance(exc, SdoCommunicationError):
            reason = f"no answer ({one_line(exc)})"
        else:
            reason = f"failed: {type(exc).__name__}: {one_line(exc)}"
        message = f"node {n}: SDO {op} {what} {reason}"
        self._note_error(message)
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

    def _require_open(self) -> None:
        if not self._is_open:
            raise LinkError("CAN link is not open")


__all__ = ["NodeSetup", "profile_name"]
