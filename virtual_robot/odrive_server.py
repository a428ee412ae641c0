"""ODrive CANSimple server for the virtual robot, on any python-can bus.

:class:`OdriveServer` decodes the frames a host sends to the robot's ODrive axes
(virtual_robot.odrive_drive) and sends what the axes send; the codec is
:mod:`drivers.protocol.odrive`. An axis' node id is its profile's ``node_id``
(``odrive-s1-d6374@k``); its frames are ``node_id << 5 | cmd_id``.

Handled (host → axis): Set_Axis_State (IDLE, CLOSED_LOOP_CONTROL), Set_Controller_Mode,
Set_Input_Torque, Clear_Errors, Estop, Reboot, and RTR requests for the Heartbeat and
Get_Encoder_Estimates (answered at once). Sent (axis → host): the Heartbeat every
``heartbeat_period_s`` of wall time (it reports a state, not a sample), and
Get_Encoder_Estimates: in lockstep once per host period, right after the period (the state at
t_{k+1}); in realtime every ``encoder_period_s``.

Ignored, counted in :attr:`OdriveServer.ignored` and logged once per kind: error, extended-id and
CAN FD frames, frames for node ids that are no axis, axis → host command ids, commands shorter
than their layout, the commands not emulated (Set_Input_Pos/Vel, Set_Limits, gains, SDO, …),
remote frames for anything but the heartbeat and the estimates, and a non-finite
Set_Input_Torque (the axis keeps its last setpoint). A torque beyond ±torque_lim is clamped by
the axis.

Time (virtual_robot.loop_server): in lockstep a host period passes once every axis in closed
loop has its Set_Input_Torque of the period, so a client that sends its torques and waits for
the next encoder estimates runs in lockstep with the robot: its estimates are the offline
stepping of the same torques (virtual_robot.odrive_simulate.run_torques, tests/test_odrive.py).
"""

from __future__ import annotations

import math
import time

import can

from drivers.protocol import odrive as od
from virtual_robot.loop_server import RECV_TIMEOUT_S, LoopDriveServer
from virtual_robot.odrive_drive import OdriveAxis
from virtual_robot.robot import LOCKSTEP, REALTIME

_NOT_EMULATED = {
    od.SET_INPUT_POS: "Set_Input_Pos",
    od.SET_INPUT_VEL: "Set_Input_Vel",
}


class OdriveServer(LoopDriveServer):
    """Serves the ODrive axes of ``core`` on ``bus`` (module docstring)."""

    protocol = "odrive"
    label = "ODrive CANSimple"

    drives: list[OdriveAxis]  # type: ignore[assignment]

    def _setup(self) -> None:
        tables = [p.odrive for p in self.core.profiles]
        self.heartbeat_period_s = min(t.heartbeat_period_s for t in tables)  # type: ignore[union-attr]
        self.encoder_period_s = min(t.encoder_period_s for t in tables)  # type: ignore[union-attr]
        self._next_heartbeat = 0.0
        self._next_encoder = 0.0

    def recv_timeout_s(self) -> float:
        if self.core.mode == REALTIME and self.encoder_period_s > 0:
            return min(RECV_TIMEOUT_S, self.encoder_period_s / 2)
        return min(RECV_TIMEOUT_S, self.heartbeat_period_s / 2)

    # ---- one frame ----------------------------------------------------------------------------
    def _frame(self, msg: can.Message) -> None:
        node, cmd = od.split_id(msg.arbitration_id)
        i = self.by_id.get(node)
        if i is None:
            self.ignore(f"frame 0x{msg.arbitration_id:03X}: no axis at node id {node}, ignored")
            return
        if msg.is_remote_frame:
            if cmd == od.HEARTBEAT:
                self._heartbeat(i)
            elif cmd == od.GET_ENCODER_ESTIMATES:
                self._estimates(i)
            else:
                self.ignore(f"remote request for command 0x{cmd:02X}: not emulated, ignored")
            return
        data = bytes(msg.data)
        need = od.COMMAND_LENGTH.get(cmd)
        if need is None:
            name = _NOT_EMULATED.get(cmd, f"command 0x{cmd:02X}")
            self.ignore(f"{name}: not emulated (torque control only), ignored")
            return
        if len(data) < need:
            self.ignore(
                f"command 0x{cmd:02X} for node {node}: {len(data)} bytes, needs {need}; ignored"
            )
            return
        d, core = self.drives[i], self.core
        with core.lock:
            if cmd == od.SET_INPUT_TORQUE:
                torque = od.unpack_input_torque(data)
                if not math.isfinite(torque):
                    self.ignore(f"node {node}: non-finite Set_Input_Torque ignored")
                    return
                self.next_period_if_commanded(i)
            now = core.now() if core.mode == LOCKSTEP else core.catch_up()
            if cmd == od.SET_INPUT_TORQUE:
                d.set_input_torque(torque)
                self.commanded(i)
            elif cmd == od.SET_AXIS_STATE:
                why = d.request_state(od.unpack_u32(data), now)
                if why:
                    self._log(f"node {node}: {why}")
            elif cmd == od.SET_CONTROLLER_MODE:
                control, inp = od.unpack_controller_mode(data)
                d.set_controller_mode(control, inp)
                if (control, inp) != (od.TORQUE_CONTROL, od.PASSTHROUGH):
                    self._once(
                        f"node {node}: control mode {control}, input mode {inp}: only "
                        "TORQUE_CONTROL with PASSTHROUGH is emulated (closed loop will be refused)"
                    )
            elif cmd == od.CLEAR_ERRORS:
                d.clear_errors()
            elif cmd == od.ESTOP:
                d.estop(now)
            elif cmd == od.REBOOT:
                d.reboot(now)
            core.apply_now(now)

    # ---- what the axes send ----------------------------------------------------------------------
    def _heartbeat(self, i: int) -> None:
        d = self.drives[i]
        with self.core.lock:
            data = od.pack_heartbeat(d.axis_error, d.state, d.procedure_result)
        self.send(od.can_id(self.core.profiles[i].node_id, od.HEARTBEAT), data)

    def _estimates(self, i: int) -> None:
        d = self.drives[i]
        with self.core.lock:
            if self.core.mode == REALTIME:
                self.core.catch_up()
            data = od.pack_encoder_estimates(d.pos_estimate_rev, d.vel_estimate_rev_s)
        self.send(od.can_id(self.core.profiles[i].node_id, od.GET_ENCODER_ESTIMATES), data)

    def stepped(self) -> None:
        for i in range(len(self.drives)):
            self._estimates(i)

    def poll(self, now: float | None = None) -> None:
        """The cyclic heartbeat (and in realtime the encoder estimates), then the base's checks."""
        wall = time.monotonic() if now is None else now
        if wall >= self._next_heartbeat:
            self._next_heartbeat = wall + self.heartbeat_period_s
            for i in range(len(self.drives)):
                self._heartbeat(i)
        if self.core.mode == REALTIME and self.encoder_period_s > 0 and wall >= self._next_encoder:
            self._next_encoder = wall + self.encoder_period_s
            self.stepped()
        super().poll(now)


__all__ = ["OdriveServer"]
