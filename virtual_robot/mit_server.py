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

Time (docs/design.md, "Time"; the receive loop, lockstep period and host-silence check are
virtual_robot.loop_server's, shared with the ODrive server), with the robot's drive period the
PD loop's, ``h / mit_substeps``:

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

import can

from drivers.protocol import mit
from virtual_robot.loop_server import RECV_TIMEOUT_S, LoopDriveServer
from virtual_robot.mit_drive import MitDrive
from virtual_robot.robot import LOCKSTEP


class MitDriveServer(LoopDriveServer):
    """Serves the MIT-mode drives of ``core`` on ``bus`` (module docstring)."""

    protocol = "mit"
    label = "MIT mode"

    drives: list[MitDrive]  # type: ignore[assignment]

    def _setup(self) -> None:
        core = self.core
        self.ranges = [mit.MitRanges.of(p.mit) for p in core.profiles]  # type: ignore[arg-type]
        self.reply_length = [p.mit.reply_length for p in core.profiles]  # type: ignore[union-attr]

    def _frame(self, msg: can.Message) -> None:
        if msg.is_remote_frame:
            self.ignore("remote frames are ignored in MIT mode")
            return
        i = self.by_id.get(msg.arbitration_id)
        if i is None:
            self.ignore(f"frame for CAN id 0x{msg.arbitration_id:03X}: no drive there, ignored")
            return
        data = bytes(msg.data)
        if len(data) != 8:
            self.ignore(
                f"frame of {len(data)} bytes for drive 0x{msg.arbitration_id:03X} ignored "
                "(MIT mode frames have 8)"
            )
            return
        self.send(mit.MASTER_ID, self._dispatch(i, data))

    def _dispatch(self, i: int, data: bytes) -> bytes:
        core, d = self.core, self.drives[i]
        special = mit.SPECIAL.get(data)
        with core.lock:
            if special is None:
                self.next_period_if_commanded(i)  # this drive's next period: others uncommanded
            now = core.now() if core.mode == LOCKSTEP else core.catch_up()
            if special == "enter":
                d.enter_motor_mode(now)
            elif special == "exit":
                d.exit_motor_mode(now)
            elif special == "zero":
                d.set_zero(now)
            else:
                d.write_command(mit.unpack_command(data, self.ranges[i]), now)
                self.commanded(i)
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


__all__ = ["RECV_TIMEOUT_S", "MitDriveServer"]
