"""The control cycle of :class:`~drivers.can_arm.CanArm`: RPDOs and SYNC (one write in
lockstep, the SYNC at the deadline in realtime), the wait for every drive's TPDO1 + TPDO2
within the feedback budget (a dead link or robot ends it at once), counts to rad, and the
safety limits (:meth:`drivers.arm.Arm._check_limits`: a safety stop on a violation).

:class:`SyncCycle` is a mixin of :class:`~drivers.can_arm.CanArm`.

Imports: :mod:`drivers.can_arm.objects`, :mod:`drivers.arm`, :mod:`drivers.units`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence

import can

from drivers.arm import LIVENESS_POLL_S, LinkError, Sample
from drivers.can_arm.objects import LOCKSTEP, REALTIME, one_line
from drivers.protocol import cia402 as co
from drivers.units import (
    counts_to_rad,
    permille_to_torque,
    position_to_rad,
    torque_to_permille,
    unwrap_int32,
)

MAX_DEADLINE_AHEAD_S = 1.0  # a deadline further ahead than this (+10 periods) is a caller bug
LOCKSTEP_LIVENESS_POLL_S = 0.05  # a lockstep wait checks this often whether the robot is gone


class SyncCycle:
    """start() and cycle(): SYNC, feedback, limits (a mixin of CanArm)."""

    # ---- cycle --------------------------------------------------------------------------------
    def _sleep_until(self, deadline: float) -> None:
        """Wait until host time ``deadline`` (s since open): :meth:`Arm.wait_for_deadline`."""
        self.wait_for_deadline(deadline)

    def _sync(
        self, rpdos: list[tuple[int, bytes]] | None = None
    ) -> tuple[float, float, list[tuple[int, ...]], list[tuple[int, ...]]]:
        """SYNC, then wait for TPDO1 + TPDO2 of every drive; (sent_at, received_at, fb1, fb2).

        ``rpdos``: frames to send just before the SYNC, in the same write (lockstep).
        """
        timeout = self.feedback_timeout_s
        with self._fb_lock:
            self._fb1 = [None] * self.n_joints
            self._fb2 = [None] * self.n_joints
            self._missing = 2 * self.n_joints
            self._fb_event.clear()
            sent = time.monotonic()
            self._collect_since = sent
        try:
            self._send_frames([*(rpdos or ()), (co.SYNC_ID, b"")])
        except (can.CanError, RuntimeError) as exc:
            with self._fb_lock:
                self._collect_since = None
            what = "RPDO + SYNC" if rpdos else "SYNC"
            raise LinkError(f"cannot send {what}: {one_line(exc)}") from exc
        if self._direct:
            arrived = self._read_feedback(sent + timeout)
            if self._direct_refused:
                self._threaded_receive()
        else:
            arrived = self._wait_feedback(sent, timeout)
        if not arrived:
            with self._fb_lock:
                self._collect_since = None
                fb1, fb2 = list(self._fb1), list(self._fb2)
            if fb1.count(None) + fb2.count(None) > 0:
                self.stats.timeouts += 1
                j = next(j for j in range(self.n_joints) if fb1[j] is None or fb2[j] is None)
                message = (
                    self._gone_reason()
                    or self._fault_reason(j)
                    or (
                        f"no feedback from node {self.node_ids[j]} within {timeout * 1000:g} "
                        "ms (the feedback budget): virtual robot, drive or bus stalled or gone"
                    )
                )
                self._note_error(message)
                raise LinkError(message)
        with self._fb_lock:
            fb1 = list(self._fb1)
            fb2 = list(self._fb2)
            received = self._fb_last_at
        if self.mode == REALTIME:
            self.stats.waited(received - sent, self.period_s)
        return sent - self._t0, received - self._t0, fb1, fb2  # type: ignore[return-value]

    def _wait_feedback(self, sent: float, timeout: float) -> bool:
        """Threaded receive: wait for the feedback event until ``sent + timeout``. Past one
        period (late), poll every few ms whether the receive thread died (closed pty, reset
        socket) or the peer process is gone, and stop at once if so."""
        event = self._fb_event
        if event.wait(min(timeout, self.period_s)):
            return True
        until = sent + timeout
        while True:
            if self._gone_reason():
                return event.is_set()
            left = until - time.monotonic()
            if left <= 0:
                return event.is_set()
            if event.wait(min(left, LIVENESS_POLL_S)):
                return True

    def _fault_reason(self, j: int) -> str | None:
        """Why feedback stopped when a drive said so first (an EMCY fault), or None."""
        faults = dict(self._emcy)
        if not faults:
            return None
        others = self._foreign_syncs
        described = "; ".join(
            f"node {self.node_ids[f.joint]} FAULT 0x{f.error_code:04X} ({f.text})"
            for f in sorted(faults.values(), key=lambda f: f.joint)
        )
        seen = f"; {others} SYNC frames of another producer seen" if others else ""
        return (
            f"no feedback from node {self.node_ids[j]}: the drives faulted ({described}{seen}); "
            "clear it with hil run --clear-faults once the cause is gone"
        )

    def _gone_reason(self) -> str | None:
        """Why the other end is certainly gone (not merely late), or None."""
        receiver = self._receiver
        if self._link_lost is not None:
            return self._link_lost
        if receiver is not None and receiver.exception is not None:
            return f"CAN link lost: {one_line(receiver.exception)}"
        if self.peer_gone():
            return "the virtual robot process is gone"
        return None

    def _read_feedback(self, until: float) -> bool:
        """Direct receive: read and dispatch frames until every TPDO is in or ``until``."""
        event = self._fb_event
        check_peer_after = time.monotonic() + LOCKSTEP_LIVENESS_POLL_S  # not on the fast path
        while not event.is_set():
            now = time.monotonic()
            left = until - now
            if left <= 0 or (now > check_peer_after and self.peer_gone()):
                return False
            try:
                self._read_frames(min(left, LOCKSTEP_LIVENESS_POLL_S))
            except (can.CanError, OSError, RuntimeError) as exc:
                self._link_lost = f"CAN link lost: {one_line(exc)}"
                self._note_error(f"CAN receive failed: {one_line(exc)}")
                return False
        return True

    def _feedback(
        self, fb1: list[tuple[int, ...]], fb2: list[tuple[int, ...]]
    ) -> tuple[tuple[float, ...], tuple[float, ...], tuple[int, ...]]:
        q, dq, status = [], [], []
        for j in range(self.n_joints):
            sw, raw = fb1[j]
            velocity, _torque = fb2[j]
            counts = raw if not self._started else unwrap_int32(self._counts[j], raw)
            self._counts[j] = counts
            q.append(position_to_rad(counts, self._cpr[j]))
            dq.append(counts_to_rad(velocity, self._cpr[j]))
            status.append(sw)
        self._started = True
        return tuple(q), tuple(dq), tuple(status)

    def start(self) -> Sample:
        """First feedback q(t_0): keep-alive RPDO (torque 0), SYNC, TPDOs of every drive."""
        self._require_open()
        self._started = False
        self._k = 0
        keep_alive = self._rpdo_frames(co.CW_ENABLE_OPERATION, (0,) * self.n_joints)
        if self.mode == LOCKSTEP:
            self._direct_receive()
            sent_at, received_at, fb1, fb2 = self._sync(keep_alive)
        else:
            try:
                # feeds the command watchdog between enable() and the first cycle
                self._send_frames(keep_alive)
            except (can.CanError, RuntimeError) as exc:
                raise LinkError(f"cannot send RPDO: {one_line(exc)}") from exc
            sent_at, received_at, fb1, fb2 = self._sync()
        q, dq, status = self._feedback(fb1, fb2)
        self._check_limits(q, dq)
        zeros = (0.0,) * self.n_joints
        if self.mode == LOCKSTEP:  # the link's clock: host times equal t (Sample docstring)
            return Sample(0.0, q, status, zeros, 0.0, 0.0, 0.0)
        return Sample(sent_at, q, status, zeros, sent_at, received_at, math.nan)

    def cycle(self, tau_Nm: Sequence[float], deadline: float | None = None) -> Sample:
        """Command ``tau_Nm`` (clamped, quantized) for one period; the feedback at its end."""
        tau = self._command(tau_Nm, self._started)
        if self.mode == REALTIME and deadline is not None:
            ahead = deadline - self.now()
            if not ahead <= MAX_DEADLINE_AHEAD_S + 10 * self.period_s:
                raise ValueError(
                    f"deadline {deadline!r} is {ahead:.3f} s ahead: not host seconds since "
                    "open() (Arm.now())"
                )
        permille = tuple(torque_to_permille(t, r) for t, r in zip(tau, self._rated, strict=True))
        rpdos = self._rpdo_frames(co.CW_ENABLE_OPERATION, permille)
        if self.mode == LOCKSTEP:  # RPDOs and SYNC in one write; the robot steps on the SYNC
            self._direct_receive()
            sent_at, received_at, fb1, fb2 = self._sync(rpdos)
        else:  # RPDOs now (the drive applies them on arrival), SYNC at the deadline
            try:
                self._send_frames(rpdos)
            except (can.CanError, RuntimeError) as exc:
                raise LinkError(f"cannot send RPDO: {one_line(exc)}") from exc
            if deadline is not None:
                self._sleep_until(deadline)
            sent_at, received_at, fb1, fb2 = self._sync()
        self._k += 1
        self.stats.cycles += 1
        q, dq, status = self._feedback(fb1, fb2)
        self._check_limits(q, dq)
        applied = tuple(
            permille_to_torque(p, r) for p, r in zip(permille, self._rated, strict=True)
        )
        if self.mode == LOCKSTEP:
            t = self._k * self.period_s
            return Sample(t, q, status, applied, t, t, t)
        due = math.nan if deadline is None else float(deadline)
        return Sample(sent_at, q, status, applied, sent_at, received_at, due)


__all__ = ["SyncCycle"]
