"""moteus register-protocol server for the virtual robot, on any python-can bus that carries
CAN-FD frames (the fdcanusb pty of virtual_robot.fdcanusb_device, or python-can's ``virtual``).

:class:`MoteusServer` decodes the frames a host sends to the robot's moteus controllers
(virtual_robot.moteus_drive) and answers them; the codec is :mod:`drivers.protocol.moteus`. A
controller's id is its profile's ``node_id`` (``qdd100@k``). A frame's subframes are handled in
order: writes of the mode register (0 stop, 10 position with the position-mode command
registers 0x020..0x027 written in the same frame, the rest taking the firmware's defaults; 12 zero
velocity with its kd_scale, 0x024, default 1), then the
reads, answered in one reply (id = controller id << 8 | the host's source id, padded with nop
subframes to a CAN-FD length) when the id asks for one (bit 15).

Refused with a write-error subframe (0x30, register 0x000, after the reply's registers; logged
once, with why): other modes
(PWM, voltage, current, stay-within, brake, …; write error 3, the firmware's answer to a mode it
does not have), the position-mode registers the emulation does not
run (stop_position, velocity_limit, accel_limit, fixed voltage or current, ilimit_scale) when
finite, a non-finite feed-forward torque or kp/kd scale, a position or zero-velocity command in
TIMEOUT;
command registers written without a mode. The controller keeps its present command and mode.
Reads of registers the emulation does not keep get a read-error subframe (0x31).

Ignored, counted in :attr:`MoteusServer.ignored` and logged once per kind: error and remote
frames, frames for ids that are no controller (and broadcasts, 0x7F) or with a CAN prefix
(bits 16-28, ``id.can_prefix``: the emulated controllers' is 0), frames that are no valid
multiplex payload (truncated values, unknown subframes: nothing of such a frame is applied).

Time (virtual_robot.loop_server): in lockstep a command is answered with the state sampled at
t_k; a host period passes once every controller in position mode has its command of the period
(a command that brings a controller into position mode is not a period's command: bringing a
controller up takes no time, as MIT mode's "enter motor mode"), so a client that brings its
controllers up, then commands them with ``query=True`` and waits for the replies, runs in
lockstep with the robot: its replies are the offline stepping of the same commands
(virtual_robot.moteus_simulate.run_commands, tests/test_moteus.py).
"""

from __future__ import annotations

import math
import time

import can

from drivers.protocol import moteus as mo
from virtual_robot.loop_server import LoopDriveServer
from virtual_robot.moteus_drive import MoteusDrive, PositionCommand
from virtual_robot.robot import LOCKSTEP

# command register → PositionCommand field (the rest refused when finite: not emulated)
_FIELDS = {
    mo.CMD_POSITION: "position_rev",
    mo.CMD_VELOCITY: "velocity_rev_s",
    mo.CMD_FEEDFORWARD: "feedforward_Nm",
    mo.CMD_KP_SCALE: "kp_scale",
    mo.CMD_KD_SCALE: "kd_scale",
    mo.CMD_MAX_TORQUE: "maximum_torque_Nm",
    mo.CMD_WATCHDOG: "watchdog_s",
}
_NOT_RUN = {
    mo.CMD_STOP_POSITION: "stop_position",
    mo.CMD_VELOCITY_LIMIT: "velocity_limit",
    mo.CMD_ACCEL_LIMIT: "accel_limit",
    mo.CMD_FIXED_VOLTAGE: "fixed_voltage_override",
    mo.CMD_ILIMIT_SCALE: "ilimit_scale",
    mo.CMD_FIXED_CURRENT: "fixed_current_override",
}
# write-error codes (moteus fw/moteus_controller.cc, Write): 1 unknown register, 3 a mode the
# firmware does not have; the emulation refuses what it does not run with 3 as well
ERR_REFUSED = 3
ERR_UNKNOWN = 1
# the modes a host may write that the emulation does not run, and why (docs/protocol.md)
_ELECTRICAL = "it drives the motor's phases directly: no electrical motor model here"
_MODES_NOT_RUN = {
    **dict.fromkeys((5, 6, 7, 8, 9, 14), _ELECTRICAL),
    mo.STAY_WITHIN_MODE: "stay-within is not emulated",
    mo.BRAKE_MODE: (
        "brake shorts the phases: its damping (back-EMF constant over phase resistance) is not "
        "in the drive profile"
    ),
}


class MoteusServer(LoopDriveServer):
    """Serves the moteus controllers of ``core`` on ``bus`` (module docstring)."""

    protocol = "moteus"
    label = "moteus"

    # ---- one frame ----------------------------------------------------------------------------
    def handle(self, msg: can.Message) -> None:
        """CAN-FD and extended ids are moteus' own: only error and remote frames are dropped
        here; the rest is the base's (one frame, lockstep period, events)."""
        if msg.is_error_frame or msg.is_remote_frame:
            self.frames_in += 1
            self._last_rx = time.monotonic()
            self.ignore("error and remote frames are ignored by moteus controllers")
            return
        if msg.is_fd or msg.is_extended_id:  # the base drops them for the classic-CAN drives
            msg = can.Message(
                arbitration_id=msg.arbitration_id,
                data=msg.data,
                is_extended_id=False,
                timestamp=msg.timestamp,
            )
        super().handle(msg)

    def _frame(self, msg: can.Message) -> None:
        if msg.arbitration_id >> 16:  # id.can_prefix: the emulated controllers' is 0
            self.ignore(f"frame 0x{msg.arbitration_id:X}: CAN prefix not 0 (id.can_prefix)")
            return
        source, dest, want_reply = mo.split_id(msg.arbitration_id)
        i = self.by_id.get(dest)
        if i is None:
            self.ignore(f"frame 0x{msg.arbitration_id:04X}: no moteus controller at id {dest}")
            return
        try:
            subframes = list(mo.parse(bytes(msg.data)))
        except mo.FrameError as exc:
            self.ignore(f"controller {dest}: invalid multiplex frame ignored ({exc})")
            return
        writes = {s.register: s.value for s in subframes if s.kind == mo.WRITE_BASE}
        reads = [s for s in subframes if s.kind == mo.READ_BASE]
        d, core = self.drives[i], self.core
        assert isinstance(d, MoteusDrive)
        out = refused = b""
        with core.lock:
            if writes:
                why = self._check(writes)
                if not why and writes.get(mo.MODE) == mo.POSITION_MODE:
                    cmd = _command(writes)
                    why = d.refuses(cmd)
                    if not why:
                        self.next_period_if_commanded(i)
                        now = core.now() if core.mode == LOCKSTEP else core.catch_up()
                        entering = d.mode != mo.POSITION_MODE
                        d.position(cmd)
                        if not entering:  # bringing a controller up takes no time
                            self.commanded(i)
                        core.apply_now(now)
                elif not why and writes[mo.MODE] == mo.ZERO_VELOCITY_MODE:
                    kd = writes.get(mo.CMD_KD_SCALE)
                    kd_scale = 1.0 if kd is None else float(kd)
                    why = d.refuses_zero_velocity(kd_scale)
                    if not why:  # takes no time, as a stop: no period's command
                        now = core.now() if core.mode == LOCKSTEP else core.catch_up()
                        d.zero_velocity(kd_scale)
                        core.apply_now(now)
                elif not why:  # mode 0
                    now = core.now() if core.mode == LOCKSTEP else core.catch_up()
                    d.stop()
                    core.apply_now(now)
                if why:
                    self._once(f"controller {dest}: {why}")
                    refused = mo.pack_error(False, mo.MODE, ERR_REFUSED)
            if reads:
                if core.mode != LOCKSTEP:
                    core.catch_up()
                out += self._reply(d, reads)
        # the registers first: the library takes a reply that starts with a reply or read-error
        # subframe (moteus.Controller's reply filter), the write error after them
        out += refused
        if want_reply and out:
            self.send_fd(mo.reply_id(dest, source), mo.pad_fd(out))

    @staticmethod
    def _check(writes: dict[int, float | int | None]) -> str:
        if mo.MODE not in writes:
            return "command registers written without a mode: not applied"
        mode = writes[mo.MODE]
        if mode not in (mo.STOPPED, mo.POSITION_MODE, mo.ZERO_VELOCITY_MODE):
            if not isinstance(mode, int) or not 0 <= mode < len(mo.MODE_NAMES):
                return f"mode {mode}: no such mode (the firmware's write error 3)"
            why = _MODES_NOT_RUN.get(mode, "the controller enters it itself")
            return (
                f"mode {mode} ({mo.MODE_NAMES[mode]}) is not emulated: {why} "
                "(stop 0, position 10 and zero velocity 12 are)"
            )
        if mode == mo.ZERO_VELOCITY_MODE:
            extra = [r for r in writes if r not in (mo.MODE, mo.CMD_KD_SCALE)]
            if extra:
                return f"register 0x{extra[0]:03X} is no zero-velocity register: command refused"
            return ""
        for reg, name in _NOT_RUN.items():
            v = writes.get(reg)
            if v is not None and not (isinstance(v, float) and math.isnan(v)):
                return f"{name} is not emulated: command refused"
        unknown = [r for r in writes if r != mo.MODE and r not in _FIELDS and r not in _NOT_RUN]
        if unknown and mode == mo.POSITION_MODE:
            return f"register 0x{unknown[0]:03X} is not emulated: command refused"
        return ""

    def _reply(self, d: MoteusDrive, reads: list[mo.Subframe]) -> bytes:
        """Reply subframes for the reads, one per run of consecutive registers of one type."""
        values = {
            mo.MODE: d.mode,
            mo.POSITION: d.position_rev,
            mo.VELOCITY: d.velocity_rev_s,
            mo.TORQUE: d.drive_torque_Nm,
            mo.TRAJECTORY_COMPLETE: 0,
            mo.VOLTAGE: 24.0,  # a bench supply: the emulation models no bus voltage
            mo.TEMPERATURE: 25.0,  # nor a board temperature
            mo.FAULT: d.fault,
        }
        out = b""
        run: list[mo.Subframe] = []

        def flush() -> bytes:
            if not run:
                return b""
            return mo.pack_registers(
                mo.REPLY_BASE, run[0].register, run[0].resolution, [values[s.register] for s in run]
            )

        for s in reads:
            if s.register not in values:
                out += flush()
                run = []
                out += mo.pack_error(True, s.register, ERR_UNKNOWN)
                continue
            if run and (s.resolution != run[-1].resolution or s.register != run[-1].register + 1):
                out += flush()
                run = []
            run.append(s)
        return out + flush()

    def send_fd(self, arbitration_id: int, data: bytes) -> None:
        self.send_message(
            can.Message(
                arbitration_id=arbitration_id,
                data=data,
                is_extended_id=arbitration_id > 0x7FF,
                is_fd=True,
                bitrate_switch=True,
            )
        )


def _command(writes: dict[int, float | int | None]) -> PositionCommand:
    kw: dict[str, float] = {}
    for reg, name in _FIELDS.items():
        v = writes.get(reg)
        if v is not None:
            kw[name] = float(v)
    return PositionCommand(**kw)


__all__ = ["MoteusServer"]
