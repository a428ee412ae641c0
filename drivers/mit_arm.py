"""Host driver for MIT-mode drives (T-Motor/CubeMars AK series, ``drivers.protocol.mit``) on
one CAN bus: the same :class:`~drivers.arm.Arm` as CiA 402 and serial, so ``hil run`` drives
them as it drives the others.

MIT mode has no sample without a command: a drive answers each frame with its state when the
frame arrived. A period k is therefore two exchanges per drive (as the serial XTQ cycle):

    cycle(τ_k):  send τ_k to every drive now (applied at once; the replies are not kept)
                 wait for the deadline t_{k+1}
                 send τ_k again (the held command: nothing changes) → replies q(t_{k+1})

so τ_k is held over [t_k, t_{k+1}) and the sample is taken at t_{k+1}, the recording's convention.
On real drives the re-sent command is the one they hold. This needs the drives' own clock:
**realtime only**. In lockstep the virtual robot counts one period per full set of commands
(what the client libraries need, docs/protocol.md), so a re-sent command would be a period of
its own; a lockstep bench refuses this arm with a one-line error.

Joint frame: q = axis_direction · p, τ_drive = axis_direction · τ (the drive profile's [mit]).
The torque a drive applies is the 12-bit τ_ff field (kp = kd = 0: the drive's PD is off),
rounded toward zero so that it never exceeds the host's clamp.
Status: MIT mode reports none; a drive that answers is reported OPERATION ENABLED
(statusword 0x0637), one whose 8-byte reply carries an error code as FAULT (0x0008).

Safe stop (every exit path, ``Arm.__exit__``): a zero command, then "exit motor mode", to every
drive, each on its own (one that does not answer does not keep the others in motor mode).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import can

from drivers.arm import Fault, LinkError, Sample
from drivers.bus_arm import BusArm
from drivers.protocol import mit

SW_ENABLED = 0x0637  # CiA 402 statusword OPERATION ENABLED (what the loop checks)
SW_FAULT = 0x0008


class MitArm(BusArm):
    """N MIT-mode drives on one CAN bus; joint j is ``drives[j]`` at CAN id ``node_id``."""

    table = "mit"
    label = "MIT"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        if kwargs.get("mode") != "realtime":
            raise ValueError(
                "MIT mode runs the host realtime only (--mode realtime): in lockstep the "
                "virtual robot counts a period per set of commands (docs/protocol.md)"
            )
        super().__init__(*args, **kwargs)
        self.ranges = tuple(mit.MitRanges.of(p.mit) for p in self.drives)  # type: ignore[arg-type]
        self.direction = tuple(p.mit.axis_direction for p in self.drives)  # type: ignore[union-attr]
        self._held = [mit.MitCommand(0.0, 0.0, 0.0, 0.0, 0.0)] * self.n_joints
        zeros = [mit.pack_command(mit.MitCommand(0.0, 0.0, 0.0, 0.0, 0.0), r) for r in self.ranges]
        self._zero_pv = [mit.unpack_command_raw(z)[:2] for z in zeros]  # p = v = 0, packed

    # ---- link ---------------------------------------------------------------------------------
    def _exchange(self, j: int, data: bytes) -> tuple[float, float, float]:
        """Send ``data`` to drive j and wait for its reply: (p, v, τ) in the joint's frame."""
        bus = self._bus()
        drive_id = self.ids[j]
        bus.send(can.Message(arbitration_id=drive_id, data=data, is_extended_id=False))
        self.stats.frames_sent += 1
        end = time.monotonic() + self.feedback_timeout_s
        while (left := end - time.monotonic()) > 0:
            msg = bus.recv(min(left, 0.005))
            if msg is None:
                if self.peer_gone():
                    raise LinkError("MIT arm: the virtual robot is gone")
                continue
            self.stats.frames_received += 1
            data_in = bytes(msg.data)
            if msg.arbitration_id != mit.MASTER_ID or len(data_in) not in (6, 8):
                continue
            if data_in[0] != drive_id:
                continue
            if len(data_in) == 8:
                self._errors[j] = data_in[7]
            _, p, v, t = mit.unpack_reply(data_in, self.ranges[j])
            d = self.direction[j]
            return d * p, d * v, d * t
        self.stats.timeouts += 1
        raise LinkError(f"MIT drive 0x{drive_id:03X}: no reply within {self.feedback_timeout_s} s")

    # ---- power --------------------------------------------------------------------------------
    def enable(self) -> None:
        """Enter motor mode on every drive (its held command: all zero)."""
        for j in range(self.n_joints):
            self._held[j] = mit.MitCommand(0.0, 0.0, 0.0, 0.0, 0.0)
            self._exchange(j, mit.pack_command(self._held[j], self.ranges[j]))
            self._exchange(j, mit.ENTER_MOTOR_MODE)

    def disable(self) -> None:
        """Zero command, then exit motor mode, on every drive; the first failure is raised
        after every drive was tried."""
        zero = mit.MitCommand(0.0, 0.0, 0.0, 0.0, 0.0)
        self._stop_each(
            lambda j: (
                lambda: self._exchange(j, mit.pack_command(zero, self.ranges[j])),
                lambda: self._exchange(j, mit.EXIT_MOTOR_MODE),
            )
        )

    def faults(self) -> list[Fault]:
        return [
            Fault(j, e, mit.ERROR_CODES.get(e, "unknown")) for j, e in enumerate(self._errors) if e
        ]

    def clear_faults(self) -> None:
        """Exit and enter motor mode again on every drive with an error code."""
        for j, e in enumerate(self._errors):
            if e:
                self._exchange(j, mit.EXIT_MOTOR_MODE)
                self._errors[j] = 0
                self._exchange(j, mit.ENTER_MOTOR_MODE)

    # ---- cycle --------------------------------------------------------------------------------
    def _sample(self, t: float, tau: tuple[float, ...], sent_at: float, deadline: float) -> Sample:
        q, dq = [], []
        for j in range(self.n_joints):
            p, v, _ = self._exchange(j, mit.pack_command(self._held[j], self.ranges[j]))
            q.append(p)
            dq.append(v)
        received = self.now()
        self.stats.waited(received - sent_at, self.period_s)
        self._check_limits(q, dq)
        status = tuple(SW_FAULT if e else SW_ENABLED for e in self._errors)
        return Sample(t, tuple(q), status, tau, sent_at, received, deadline)

    def start(self) -> Sample:
        """q(t_0): the replies to the held (zero) command."""
        now = self.now()
        self._started = True
        return self._sample(now, (), now, now)

    def cycle(self, tau_Nm: Sequence[float], deadline: float | None = None) -> Sample:
        tau = self._command(tau_Nm, self._started)
        quantized = []
        for j, t in enumerate(tau):
            r = self.ranges[j]
            p, v = self._zero_pv[j]
            u = mit.torque_toward_zero(self.direction[j] * t, r)  # never beyond the limit
            frame = mit.pack_command_raw(p, v, 0, 0, u)
            self._held[j] = mit.unpack_command(frame, r)
            quantized.append(self.direction[j] * self._held[j].t_ff)
            self._exchange(j, frame)
        self.stats.cycles += 1
        if deadline is None:
            deadline = self.now() + self.period_s
        self.wait_for_deadline(deadline)
        return self._sample(self.now(), tuple(quantized), self.now(), deadline)


__all__ = ["MitArm"]
