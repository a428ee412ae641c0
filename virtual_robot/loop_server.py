"""What the CAN servers of drives with their own loop share (MIT mode: virtual_robot.mit_server;
ODrive CANSimple: virtual_robot.odrive_server): the receive loop, the frame filter, the
lockstep period, the host-silence check and the event log.

Lockstep (docs/design.md, "Time"): one host period h (``mit_substeps`` drive periods,
virtual_robot.stepping.Stepper) passes once every armed drive (motor mode, closed loop) has its
command of the period; a second command to a drive that already has one starts the next period
first. A host silent for ``idle_timeout_s`` of wall time makes every drive stop (torque 0).
Realtime: the drives' own period timer runs their loop and watchdog
(VirtualRobot.start_period_timer); a frame is applied when it arrives.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import can

from virtual_robot.host_silence import HostSilence
from virtual_robot.loop_drive import LoopDrive
from virtual_robot.robot import LOCKSTEP, REALTIME, VirtualRobot

RECV_TIMEOUT_S = 0.05

_logger = logging.getLogger(__name__)


class LoopDriveServer:
    """Base of the servers of ``core``'s drives on ``bus`` (module docstring). A subclass
    answers one standard data frame in :meth:`_frame` and sets itself up in :meth:`_setup`."""

    protocol = ""  # the drives' protocol (profiles.drive.PROTOCOLS)
    label = ""  # how the log names it

    def __init__(
        self,
        core: VirtualRobot,
        bus: can.BusABC,
        *,
        idle_timeout_s: float | None = None,
        log: Callable[[str], None] | None = None,
    ) -> None:
        if core.protocol != self.protocol:
            raise ValueError(f"robot {core.robot.name}: its drives do not speak {self.label}")
        self.core = core
        self.bus = bus
        self.idle_timeout_s = idle_timeout_s
        self._log = log or _logger.warning
        self.by_id: dict[int, int] = dict(core.by_node)
        self.drives: list[LoopDrive] = list(core.drives)  # type: ignore[arg-type]
        self._commanded: set[int] = set()  # lockstep: drives with a command this period
        self.frames_in = 0
        self.frames_out = 0
        self.ignored = 0
        self.errors = 0
        self._said: set[str] = set()
        self._silence = HostSilence(idle_timeout_s)
        if core.mode == LOCKSTEP and core.syncs == 0:
            core.stepper.sync()  # sample 0 at t = 0: every later step is one whole period
        self._setup()

    def _setup(self) -> None:
        """A subclass's own set-up from ``self.core`` (called last by ``__init__``)."""

    # ---- life cycle ---------------------------------------------------------------------------
    def serve_forever(self, stop: threading.Event) -> None:
        """Receive and answer frames until ``stop`` is set."""
        if self.core.mode == REALTIME:
            self.core.start_period_timer(stop)
        while not stop.is_set():
            try:
                msg = self.bus.recv(timeout=self.recv_timeout_s())
            except Exception as exc:  # a dead or flaky transport: say so once, keep trying
                self.errors += 1
                self._once(f"bus receive failed: {type(exc).__name__}: {exc}")
                stop.wait(RECV_TIMEOUT_S)
                continue
            if msg is not None:
                self.handle(msg)
            self.poll()

    def recv_timeout_s(self) -> float:
        return RECV_TIMEOUT_S

    # ---- one frame ----------------------------------------------------------------------------
    def handle(self, msg: can.Message) -> None:
        """Answer one received frame; never raises (errors are counted and logged)."""
        self.frames_in += 1
        self._silence.heard()
        if msg.is_error_frame or msg.is_extended_id or msg.is_fd:
            self.ignore(f"error, extended-id or CAN FD frames are ignored by {self.label} drives")
            return
        try:
            self._frame(msg)
        except Exception as exc:
            self.errors += 1
            self._log(
                f"frame 0x{msg.arbitration_id:03X} [{bytes(msg.data).hex()}]: "
                f"{type(exc).__name__}: {exc}"
            )
            return
        if self.core.mode == LOCKSTEP and self._period_complete():
            self._step()
        self._report_events()

    def _frame(self, msg: can.Message) -> None:
        raise NotImplementedError

    def ignore(self, why: str) -> None:
        """A frame left unanswered: counted, and ``why`` logged once."""
        self.ignored += 1
        self._once(why)

    def commanded(self, i: int) -> None:
        """Lockstep: drive ``i`` has its command of this period (call with the core's lock)."""
        if self.core.mode == LOCKSTEP:
            self._commanded.add(i)

    def next_period_if_commanded(self, i: int) -> None:
        """Lockstep: a second command to drive ``i`` starts the next period first."""
        if self.core.mode == LOCKSTEP and i in self._commanded:
            self._step()

    def _period_complete(self) -> bool:
        if not self._commanded:
            return False
        armed = {i for i, d in enumerate(self.drives) if d.armed}
        return armed <= self._commanded

    def _step(self) -> None:
        """Lockstep: one host period, the drives' loop run ``mit_substeps`` times."""
        with self.core.lock:
            self.core.step_host_period()
            self._commanded.clear()
        self.stepped()

    def stepped(self) -> None:
        """Lockstep: a host period has passed (a subclass may send what the drives send then)."""

    # ---- periodic -----------------------------------------------------------------------------
    def poll(self, now: float | None = None) -> None:
        """The host-silence check (lockstep) and the drives' events."""
        now = time.monotonic() if now is None else now
        if self._silence.expired(now):
            self.core.disable_all()
            self._log(f"host silent for {self.idle_timeout_s:g} s: every drive stopped, torque 0")
        self._report_events()

    def _report_events(self) -> None:
        for node, event in self.core.pop_emcy():
            i = self.by_id[node]
            self._log(f"drive 0x{node:03X}: {self.drives[i].last_error or event}")

    def _once(self, text: str) -> None:
        if text not in self._said:
            self._said.add(text)
            self._log(text)

    def send(self, arbitration_id: int, data: bytes) -> None:
        self.send_message(
            can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False)
        )

    def send_message(self, msg: can.Message) -> None:
        """Put ``msg`` on the bus; a failure is counted and said once, never raised."""
        try:
            self.bus.send(msg)
        except Exception as exc:
            self.errors += 1
            self._once(f"send failed: {type(exc).__name__}: {exc}")
        else:
            self.frames_out += 1


__all__ = ["RECV_TIMEOUT_S", "LoopDriveServer"]
