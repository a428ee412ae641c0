"""Host driver for mjbots moteus controllers over the register protocol
(:mod:`drivers.protocol.moteus`) on one CAN-FD bus (an fdcanusb: :mod:`drivers.fdcanusb`): the same
:class:`~drivers.arm.Arm` as CiA 402, MIT mode and ODrive, so ``hil run`` drives them.

Torque control is position mode with no gain: position NaN, velocity 0, kp_scale = kd_scale = 0,
feedforward_torque τ (float32). A period k:

    cycle(τ_k):  τ_k to every controller (no reply asked)
                 lockstep: the robot steps once every controller has its command
                 realtime: wait for the deadline t_{k+1}
                 then a query to every controller → mode, position, velocity, torque at t_{k+1}

so τ_k is held over [t_k, t_{k+1}) and the sample is taken at t_{k+1}, the recording's
convention. q = 2π · position (revolutions of the output), the torque recorded the float32 sent.
``start`` queries q(t_0). The host's CAN id (source) is 0.

Enable: a stop (mode 0, clears a fault or TIMEOUT), then position mode without torque (bringing a
controller up takes no time in lockstep). Status: a controller in position mode is reported
OPERATION ENABLED (statusword 0x0637), any other mode as FAULT (0x0008; the fault register's
code, or the mode). Safe stop (every exit path): a stop to every controller, each on its own.
"""

from __future__ import annotations

import math
import time
from typing import Any

import can

from drivers.arm import Fault, LinkError, Sample
from drivers.bus_arm import BusArm
from drivers.protocol import moteus as mo

SW_ENABLED = 0x0637  # CiA 402 statusword OPERATION ENABLED (what the loop checks)
SW_FAULT = 0x0008
TWO_PI = 2.0 * math.pi
HOST_ID = 0

QUERY = (
    mo.pack_read(mo.MODE, mo.INT8, 1)
    + mo.pack_read(mo.POSITION, mo.F32, 3)
    + mo.pack_read(mo.FAULT, mo.INT8, 1)
)
STOP = mo.pack_registers(mo.WRITE_BASE, mo.MODE, mo.INT8, [mo.STOPPED])


def torque_frame(tau_Nm: float) -> bytes:
    """Position mode, position NaN, velocity 0, feed-forward τ, kp_scale = kd_scale = 0."""
    return mo.pack_registers(mo.WRITE_BASE, mo.MODE, mo.INT8, [mo.POSITION_MODE]) + (
        mo.pack_registers(mo.WRITE_BASE, mo.CMD_POSITION, mo.F32, [math.nan, 0.0, tau_Nm, 0.0, 0.0])
    )


class MoteusArm(BusArm):
    """N moteus controllers on one CAN-FD bus; joint j is ``drives[j]`` at id ``node_id``."""

    table = "moteus"
    label = "moteus"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._modes = [mo.STOPPED] * self.n_joints

    def _send(self, j: int, data: bytes, *, reply: bool) -> None:
        arb = (0x8000 if reply else 0) | HOST_ID << 8 | self.ids[j]
        self._bus().send(
            can.Message(arbitration_id=arb, data=data, is_extended_id=True, is_fd=True)
        )
        self.stats.frames_sent += 1

    def _exchange(self, j: int, data: bytes) -> dict[int, float | int]:
        """``data`` to controller j with a reply asked; its reply registers. A write error
        (the controller refused a command) is a LinkError."""
        self._send(j, data, reply=True)
        bus, want = self._bus(), mo.reply_id(self.ids[j], HOST_ID)
        end = time.monotonic() + self.feedback_timeout_s
        while (left := end - time.monotonic()) > 0:
            msg = bus.recv(min(left, 0.005))
            if msg is None:
                if self.peer_gone():
                    raise LinkError("moteus arm: the virtual robot is gone")
                continue
            self.stats.frames_received += 1
            if msg.arbitration_id & 0x7FFF != want:
                continue
            try:
                subs = list(mo.parse(bytes(msg.data)))
            except mo.FrameError as exc:
                raise LinkError(f"moteus controller {self.ids[j]}: bad reply ({exc})") from None
            values = {s.register: s.value for s in subs if s.kind == mo.REPLY_BASE}
            if mo.MODE in values:
                self._modes[j] = int(values[mo.MODE])  # type: ignore[arg-type]
            if mo.FAULT in values:
                self._errors[j] = int(values[mo.FAULT])  # type: ignore[arg-type]
            if any(s.kind == mo.WRITE_ERROR for s in subs):
                raise LinkError(
                    f"moteus controller {self.ids[j]}: command refused in mode {self._modes[j]}"
                )
            return values  # type: ignore[return-value]
        self.stats.timeouts += 1
        raise LinkError(
            f"moteus controller {self.ids[j]}: no reply within {self.feedback_timeout_s} s"
        )

    # ---- power --------------------------------------------------------------------------------
    def enable(self) -> None:
        """Stop, then position mode without torque, on every controller."""
        for j in range(self.n_joints):
            self._exchange(j, STOP + QUERY)
            got = self._exchange(j, torque_frame(0.0) + QUERY)
            if got.get(mo.MODE) != mo.POSITION_MODE:
                raise LinkError(
                    f"moteus controller {self.ids[j]}: mode {got.get(mo.MODE)} after a "
                    "position command, not 10"
                )

    def disable(self) -> None:
        """A stop to every controller; the first failure is raised after all were tried."""
        self._stop_each(lambda j: (lambda: self._exchange(j, STOP + QUERY),))

    def faults(self) -> list[Fault]:
        return [
            Fault(j, self._errors[j] or m, f"moteus mode {m}, fault {self._errors[j]}")
            for j, m in enumerate(self._modes)
            if m in (mo.FAULT_MODE, mo.TIMEOUT_MODE)
        ]

    def clear_faults(self) -> None:
        for j, m in enumerate(self._modes):
            if m in (mo.FAULT_MODE, mo.TIMEOUT_MODE):
                self._exchange(j, STOP + QUERY)
                self._errors[j] = 0

    # ---- cycle --------------------------------------------------------------------------------
    def _sample(self, t: float, tau: tuple[float, ...], sent_at: float, dl: float) -> Sample:
        q, dq = [], []
        for j in range(self.n_joints):
            got = self._exchange(j, QUERY)
            q.append(TWO_PI * float(got[mo.POSITION]))
            dq.append(TWO_PI * float(got[mo.VELOCITY]))
        received = self.now()
        self.stats.waited(received - sent_at, self.period_s)
        self._check_limits(q, dq)
        status = tuple(SW_ENABLED if m == mo.POSITION_MODE else SW_FAULT for m in self._modes)
        return Sample(t, tuple(q), status, tau, sent_at, received, dl)

    def start(self) -> Sample:
        """q(t_0): a query to every controller."""
        now = self.now()
        self._started = True
        return self._sample(now, (), now, now)

    def cycle(self, tau_Nm: Any, deadline: float | None = None) -> Sample:
        tau = tuple(mo.f32(t) for t in self._command(tau_Nm, self._started))
        sent_at = self.now()
        for j, t in enumerate(tau):
            self._send(j, torque_frame(t), reply=False)
        self.stats.cycles += 1
        if deadline is None:
            deadline = sent_at + self.period_s
        if self.mode == "realtime":
            self.wait_for_deadline(deadline)
        return self._sample(self.now(), tau, sent_at, deadline)


__all__ = ["MoteusArm", "torque_frame"]
