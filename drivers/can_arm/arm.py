"""The :class:`CanArm`: N CiA 402 drives on one CAN bus, composed of its capabilities (set-up,
power states, cycle, bus link; the package docstring says what each does).

Imports: the modules of :mod:`drivers.can_arm`, :mod:`drivers.arm`.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Unpack

import can
import canopen

from drivers.arm import Arm, Fault, LinkSettings
from drivers.can_arm.cycle import SyncCycle
from drivers.can_arm.link import BusLink, Receiver
from drivers.can_arm.objects import frame_routes
from drivers.can_arm.power import PowerStates
from drivers.can_arm.setup import NodeSetup
from drivers.candump import CandumpWriter
from drivers.protocol import cia402 as co
from profiles.drive import DriveProfile


class CanArm(NodeSetup, PowerStates, SyncCycle, BusLink, Arm):
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
        log_path: str | Path | None = None,
        **link: Unpack[LinkSettings],
    ) -> None:
        self._init_link(drives, **link)
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
        self._receiver: Receiver | None = None
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
        # host frames received (NMT, SYNC; RPDOs and SDO requests to our drives): never our own
        # (a CAN controller does not receive its own frames), so each is another host's
        # (CiA 301: one NMT master, one SYNC producer per bus); COB-ID -> what it is
        self._host_ids = {
            cob: name
            for n in (0, *self.node_ids)
            for cob in range(n, 0x680, 0x80)
            if (name := co.host_frame_name(cob)) is not None
        }
        self._foreign_syncs = 0
        self._foreign_host_frames = 0
        self._foreign_host_first = ""  # what the first of them was ("SYNC", "SDO request ...")
        # the host's heartbeat (co.host_heartbeat): 0x700 + a node-ID no drive here has; our
        # claim (node-ID, nonce) once sent, whether we hold the bus, and why another host's
        # heartbeat won it (drivers.can_arm.setup: NodeSetup._claim_the_bus)
        self._heartbeat_ids = frozenset(
            co.HEARTBEAT_BASE + k for k in range(1, 128) if k not in self.node_ids
        )
        self._claim: tuple[int, bytes] | None = None
        self._claim_lock = threading.Lock()  # a claim is set, or lost unclaimed, not both
        self._holding = False
        self._claim_lost = ""
        self._booted: set[int] = set()
        self._counts: list[int] = [0] * self.n_joints
        self._k = 0
        self._started = False


__all__ = ["CanArm"]
