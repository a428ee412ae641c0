"""MIT-mode (Mini Cheetah protocol) drive server for the virtual robot, on any python-can bus.

:class:`MitDriveServer` decodes the frames a host sends to the robot's MIT-mode drives
(virtual_robot.mit_drive) and answers them; the codec is :mod:`drivers.protocol.mit` (shared
with the host). The drives' CAN ids are their profiles' ``node_id`` (``ak80-6@k``).

Every 8-byte data frame addressed to a drive is answered with one reply (id :data:`MASTER_ID`,
6 or 8 bytes as the profile says: the drive's id, p, v, τ), as the firmware does:

* ``FF FF FF FF FF FF FF FC``: enter motor mode; ``…FD``: exit motor mode; ``…FE``: set zero;
* anything else: a p/v/kp/kd/τ command (every bit pattern is a valid command: the fields span
  the firmware's ranges, so an out-of-range value cannot arrive; the host saturates it). The
  PD torque is saturated at ±t_max by the drive.

Ignored, counted in :attr:`MitDriveServer.ignored` and logged once per kind: remote, error,
extended-id and CAN FD frames, frames for ids that are no drive, and frames of another length
than 8 (no reply: the firmware answers none either).

Time (DESIGN.md "Time"), with the robot's drive period the PD loop's, ``h / mit_substeps``:

* **lockstep**: a command is answered with the state sampled at t_k, then held. One host
  period h (``mit_substeps`` drive periods, virtual_robot.stepping.Stepper) passes once every
  drive in motor mode has its command of the period (a second command to a drive that already
  has one starts the next period first), so a client that commands its motors one after the
  other, each waiting for its reply (both client libraries do), runs in lockstep with the
  robot: its recording is the in-process stepping of the same commands, count for count
  (tests/test_mit.py). Special commands take no time. A host silent for ``idle_timeout_s`` of
  wall time makes every drive leave motor mode.
* **realtime**: the drives' own period timer runs the PD loop and the watchdog
  (VirtualRobot.start_period_timer); a frame is applied when it arrives.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import can

from drivers.protocol import mit
from virtual_robot.mit_drive import MitDrive
from virtual_robot.robot import LOCKSTEP, REALTIME, VirtualRobot

RECV_TIMEOUT_S = 0.05

_logger = logging.getLogger(__name__)


class MitDriveServer:
    """Serves the MIT-mode drives of ``core`` on ``bus`` (module docstring)."""

    def __init__(
        self,
        core: VirtualRobot,
        bus: can.BusABC,
        *,
        idle_timeout_s: float | None = None,
        log: Callable[[str], None] | None = None,
    ) -> None:
        if core.protocol != "mit":
            raise ValueError(f"robot {core.robot.name}: its drives do not speak MIT mode")
        self.core = core
        self.bus = bus
        self.idle_timeout_s = idle_timeout_s
        self._log = log or _logger.warning
        self.by_id: dict[int, int] = dict(core.by_node)
        self.drives: list[MitDrive] = list(core.drives)  # type: ignore[arg-type]
        self.ranges = [mit.MitRanges.of(p.mit) for p in core.profiles]  # type: ignore[arg-type]
        self.reply_length = [p.mit.reply_length for p in core.profiles]  # type: ignore[union-attr]
        self._commanded: set[int] = set()  # lockstep: drives with a command this period
        self.frames_in = 0
        self.frames_out = 0
        self.ignored = 0
        self.errors = 0
        self._said: set[str] = set()
        self._last_rx: float | None = None
        self._idle_fired = False
        if core.mode == LOCKSTEP and core.syncs == 0:
            core.stepper.sync()  # sample 0 at t = 0: every later step is one whole period

    # ---- life cycle ---------------------------------------------------------------------------
    def serve_forever(self, stop: threading.Event) -> None:
        """Receive and answer frames until ``stop`` is set."""
        if self.core.mode == REALTIME:
            self.core.start_period_timer(stop)
        while not stop.is_set():
            try:
                msg = self.bus.recv(timeout=RECV_TIMEOUT_S)
            except Exception as exc:  # a dead or flaky transport: say so once, keep trying
                self.errors += 1
                self._once(f"bus receive failed: {type(exc).__name__}: {exc}")
                stop.wait(RECV_TIMEOUT_S)
                continue
            if msg is not None:
                self.handle(msg)
            self.poll()

    # ---- one frame ----------------------------------------------------------------------------
    def handle(self, msg: can.Message) -> None:
        """Answer one received frame; never raises (errors are counted and logged)."""
        self.frames_in += 1
        self._last_rx = time.monotonic()
        self._idle_fired = False
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id or msg.is_fd:
            self.ignored += 1
            self._once("remote, error, extended-id or CAN FD frames are ignored in MIT mode")
            return
        i = self.by_id.get(msg.arbitration_id)
        if i is None:
            self.ignored += 1
            self._once(f"frame for CAN id 0x{msg.arbitration_id:03X}: no drive there, ignored")
            return
        data = bytes(msg.data)
        if len(data) != 8:
            self.ignored += 1
            self._once(
                f"frame of {len(data)} bytes for drive 0x{msg.arbitration_id:03X} ignored "
                "(MIT mode frames have 8)"
            )
            return
        try:
            reply = self._dispatch(i, data)
        except Exception as exc:
            self.errors += 1
            self._log(
                f"frame 0x{msg.arbitration_id:03X} [{data.hex()}]: {type(exc).__name__}: {exc}"
            )
            return
        self._send(reply)
        if self.core.mode == LOCKSTEP and self._period_complete():
            self._step()
        self._report_events()

    def _dispatch(self, i: int, data: bytes) -> bytes:
        core, d = self.core, self.drives[i]
        special = mit.SPECIAL.get(data)
        with core.lock:
            if special is None and self.core.mode == LOCKSTEP and i in self._commanded:
                self._step()  # this drive's next period: the others were not commanded
            now = core.now() if core.mode == LOCKSTEP else core.catch_up()
            if special == "enter":
                d.enter_motor_mode(now)
            elif special == "exit":
                d.exit_motor_mode(now)
            elif special == "zero":
                d.set_zero(now)
            else:
                d.write_command(mit.unpack_command(data, self.ranges[i]), now)
                if core.mode == LOCKSTEP:
                    self._commanded.add(i)
            core.apply_now(now)
            return self._reply(i)

    def _reply(self, i: int) -> bytes:
        d, profile = self.drives[i], self.core.profiles[i]
        return mit.pack_reply(
            profile.node_id,
            d.position_rad,
            d.velocity_rad_s,
            d.drive_torque_Nm,
            self.ranges[i],
            length=self.reply_length[i],
        )

    def _period_complete(self) -> bool:
        if not self._commanded:
            return False
        in_motor_mode = {i for i, d in enumerate(self.drives) if d.motor_mode}
        return in_motor_mode <= self._commanded

    def _step(self) -> None:
        """Lockstep: one host period, the drives' PD loop run ``mit_substeps`` times."""
        with self.core.lock:
            for _ in range(self.core.mit_substeps):
                self.core.stepper.sync()
            self._commanded.clear()

    # ---- periodic -----------------------------------------------------------------------------
    def poll(self, now: float | None = None) -> None:
        """The host-silence check (lockstep) and the drives' events."""
        now = time.monotonic() if now is None else now
        if (
            self.idle_timeout_s is not None
            and self._last_rx is not None
            and not self._idle_fired
            and now - self._last_rx > self.idle_timeout_s
        ):
            self._idle_fired = True
            self.core.disable_all()
            self._log(f"host silent for {self.idle_timeout_s:g} s: motor mode left on every drive")
        self._report_events()

    def _report_events(self) -> None:
        for node, event in self.core.pop_emcy():
            i = self.by_id[node]
            self._log(f"drive 0x{node:03X}: {self.drives[i].last_error or event}")

    def _once(self, text: str) -> None:
        if text not in self._said:
            self._said.add(text)
            self._log(text)

    def _send(self, data: bytes) -> None:
        msg = can.Message(arbitration_id=mit.MASTER_ID, data=data, is_extended_id=False)
        try:
            self.bus.send(msg)
        except Exception as exc:
            self.errors += 1
            self._once(f"send failed: {type(exc).__name__}: {exc}")
        else:
            self.frames_out += 1


__all__ = ["MitDriveServer"]
