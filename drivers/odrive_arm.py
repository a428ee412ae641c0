"""Host driver for ODrive axes over CANSimple (``drivers.protocol.odrive``) on one CAN bus: the
same :class:`~drivers.arm.Arm` as CiA 402, serial and MIT mode, so ``hil run`` drives them.

A period k:

    cycle(τ_k):  Set_Input_Torque τ_k to every axis (held by the axis until the next)
                 lockstep: the robot steps once every axis has its torque and sends each
                           axis' Get_Encoder_Estimates, the state at t_{k+1}
                 realtime: wait for the deadline t_{k+1}, then request the estimates (RTR) and
                           take the first of each axis that arrives after the request

so τ_k is held over [t_k, t_{k+1}) and the sample is taken at t_{k+1}, the recording's
convention. ``start`` requests the estimates at t_0 (an RTR takes no time in lockstep).
q = 2π · Pos_Estimate (turns of the axis: the profile's direct drive), the torque recorded is
the float32 the frame carries (after the host's clamp).

Status from the heartbeat: an axis in CLOSED_LOOP_CONTROL without an axis error is reported
OPERATION ENABLED (statusword 0x0637), one with an error as FAULT (0x0008, the error bits).

Enable: Clear_Errors, Set_Controller_Mode (TORQUE_CONTROL, PASSTHROUGH), Set_Input_Torque 0,
Set_Axis_State CLOSED_LOOP_CONTROL, and wait until every heartbeat says so. Safe stop (every exit
path): Set_Input_Torque 0, then Set_Axis_State IDLE, to every axis.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import can

from drivers.arm import Fault, LinkError, Sample
from drivers.bus_arm import BusArm
from drivers.protocol import odrive as od

SW_ENABLED = 0x0637  # CiA 402 statusword OPERATION ENABLED (what the loop checks)
SW_FAULT = 0x0008
TWO_PI = 2.0 * math.pi


class OdriveArm(BusArm):
    """N ODrive axes on one CAN bus; joint j is ``drives[j]`` at node id ``node_id``."""

    table = "odrive"
    label = "ODrive"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._index = {node: j for j, node in enumerate(self.ids)}
        self._states = [0] * self.n_joints

    def _send(self, j: int, cmd: int, data: bytes = b"", *, rtr: bool = False) -> None:
        msg = can.Message(
            arbitration_id=od.can_id(self.ids[j], cmd),
            data=data,
            is_extended_id=False,
            is_remote_frame=rtr,
            dlc=8 if rtr else len(data),
        )
        self._bus().send(msg)
        self.stats.frames_sent += 1

    def _receive(
        self, until: Callable[[dict[int, tuple[float, float]]], bool], what: str
    ) -> dict[int, tuple[float, float]]:
        """Frames until ``until(estimates)`` holds: heartbeats update the axes' state and
        errors; the estimates of each axis (the last one) are returned."""
        bus = self._bus()
        got: dict[int, tuple[float, float]] = {}
        end = time.monotonic() + self.feedback_timeout_s
        while not until(got):
            left = end - time.monotonic()
            if left <= 0:
                self.stats.timeouts += 1
                raise LinkError(f"ODrive arm: {what} within {self.feedback_timeout_s} s")
            msg = bus.recv(min(left, 0.005))
            if msg is None:
                if self.peer_gone():
                    raise LinkError("ODrive arm: the virtual robot is gone")
                continue
            self.stats.frames_received += 1
            if msg.is_remote_frame or msg.is_extended_id or len(msg.data) != 8:
                continue
            node, cmd = od.split_id(msg.arbitration_id)
            j = self._index.get(node)
            if j is None:
                continue
            if cmd == od.HEARTBEAT:
                error, state, _, _ = od.unpack_heartbeat(bytes(msg.data))
                self._errors[j], self._states[j] = error, state
            elif cmd == od.GET_ENCODER_ESTIMATES:
                got[j] = od.unpack_encoder_estimates(bytes(msg.data))
        return got

    def _drain(self) -> None:
        bus = self._bus()
        while (msg := bus.recv(0)) is not None:
            self.stats.frames_received += 1
            node, cmd = od.split_id(msg.arbitration_id)
            j = self._index.get(node)
            if j is not None and cmd == od.HEARTBEAT and len(msg.data) == 8:
                error, state, _, _ = od.unpack_heartbeat(bytes(msg.data))
                self._errors[j], self._states[j] = error, state

    # ---- power --------------------------------------------------------------------------------
    def enable(self) -> None:
        """Every axis to closed loop in torque control (torque 0); waits for the heartbeats."""
        for j in range(self.n_joints):
            self._send(j, od.CLEAR_ERRORS, b"\x00")
            self._send(j, od.SET_CONTROLLER_MODE, od.pack_controller_mode(1, 1))
            self._send(j, od.SET_AXIS_STATE, od.pack_u32(od.CLOSED_LOOP_CONTROL))
        self._states = [0] * self.n_joints
        self._receive(
            lambda _: all(s == od.CLOSED_LOOP_CONTROL for s in self._states) or any(self._errors),
            "no heartbeat in closed loop",
        )
        if any(self._errors):
            raise LinkError(
                "ODrive arm: closed loop refused, axis errors "
                + ", ".join(f"0x{e:08X}" for e in self._errors)
            )

    def disable(self) -> None:
        """Torque 0, then IDLE, on every axis; the first failure is raised after all were tried."""
        self._stop_each(
            lambda j: (
                lambda: self._send(j, od.SET_INPUT_TORQUE, od.pack_input_torque(0.0)),
                lambda: self._send(j, od.SET_AXIS_STATE, od.pack_u32(od.IDLE)),
            )
        )

    def faults(self) -> list[Fault]:
        return [Fault(j, e, f"axis error 0x{e:08X}") for j, e in enumerate(self._errors) if e]

    def clear_faults(self) -> None:
        for j, e in enumerate(self._errors):
            if e:
                self._send(j, od.CLEAR_ERRORS, b"\x00")
                self._errors[j] = 0

    # ---- cycle --------------------------------------------------------------------------------
    def _estimates(self) -> dict[int, tuple[float, float]]:
        return self._receive(lambda got: len(got) == self.n_joints, "no encoder estimates")

    def _request(self) -> dict[int, tuple[float, float]]:
        self._drain()
        for j in range(self.n_joints):
            self._send(j, od.GET_ENCODER_ESTIMATES, rtr=True)
        return self._estimates()

    def _sample(
        self, got: dict[int, tuple[float, float]], t: float, tau: tuple, sent_at: float, dl: float
    ) -> Sample:
        q = [TWO_PI * got[j][0] for j in range(self.n_joints)]
        dq = [TWO_PI * got[j][1] for j in range(self.n_joints)]
        received = self.now()
        self.stats.waited(received - sent_at, self.period_s)
        self._check_limits(q, dq)
        status = tuple(SW_FAULT if e else SW_ENABLED for e in self._errors)
        return Sample(t, tuple(q), status, tau, sent_at, received, dl)

    def start(self) -> Sample:
        """q(t_0): the estimates on request."""
        now = self.now()
        self._started = True
        return self._sample(self._request(), now, (), now, now)

    def cycle(self, tau_Nm: Sequence[float], deadline: float | None = None) -> Sample:
        tau = tuple(od.f32(t) for t in self._command(tau_Nm, self._started))
        sent_at = self.now()
        if self.mode == "lockstep":
            self._drain()
        for j, t in enumerate(tau):
            self._send(j, od.SET_INPUT_TORQUE, od.pack_input_torque(t))
        self.stats.cycles += 1
        if deadline is None:
            deadline = sent_at + self.period_s
        if self.mode == "lockstep":
            got = self._estimates()
        else:
            self.wait_for_deadline(deadline)
            got = self._request()
        return self._sample(got, self.now(), tau, sent_at, deadline)


__all__ = ["OdriveArm"]
