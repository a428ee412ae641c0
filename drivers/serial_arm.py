"""Host driver for drives on a serial line (Gemini-style dialect, ``drivers.protocol.gemini``).

One :class:`SerialArm` talks to every unit of a multi-drop line through pyserial: a USB serial
adapter on a real bench, the pty the virtual robot announces on a virtual one. Configuration and
supervision use the dialect's own commands (``ECHO0``, ``DMODE2``, ``TREV``, ``DRIVE1``, ``TAS``,
``ERROR``, ``RESET``); the cyclic torque uses the emulator's **vendor extension** ``XTQ`` (a real
drive of this family takes its torque as an analog ±10 V input and has no ``XTQ``).

A cycle:

* lockstep: both ``n_XTQ<‰>`` lines go out in one write, then both replies are read. The robot
  steps when every unit has its XTQ, so the replies carry q(t_k+1) for the torque held over
  [t_k, t_k+1); ``Sample.t`` = k·h and the timestamps equal it (nothing to time).
* realtime: the XTQ lines go out at once, so the torque applies as soon as it is computed (as a
  CAN RPDO would); then the driver waits for ``deadline`` and samples with a second XTQ of the
  same torque (which changes nothing but feeds the watchdog and returns the counts at that
  instant). Two request/response pairs per drive per period, on the emulated link only.
  ``Sample.t`` and ``received_at`` are the receive time, ``sent_at`` when the sampling request
  went out; all in seconds since :meth:`open` (:meth:`Arm.now`).

Every request and reply is appended to ``serial.log`` as ``<seconds since open> > 1_XTQ+10`` /
``<seconds since open> < *1_XTQ+123,0x0637`` (terminators stripped; ``!`` lines are the
driver's own errors: timeouts, dead port, unexpected replies), flushed every 100 lines, after an
error and on close.
"""

from __future__ import annotations

import contextlib
import math
import select
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TextIO, Unpack

import serial

from drivers.arm import LIVENESS_POLL_S, Arm, Fault, LinkError, LinkSettings, Sample
from drivers.protocol import gemini as gm
from drivers.protocol.cia402 import (
    ERR_OVERSPEED,
    ERR_RPDO_TIMEOUT,
    State,
    state_from_statusword,
)
from drivers.units import permille_to_torque, position_to_rad, torque_to_permille, unwrap_int32
from profiles.drive import DriveProfile

LOG_FLUSH_LINES = 100
DISABLE_TIMEOUT_S = 1.0  # disable() is best effort: it never waits longer than this per step
FAULT_TEXT = {
    ERR_RPDO_TIMEOUT: "command watchdog: no torque command for too many periods",
    ERR_OVERSPEED: "overspeed",
}

_Request = tuple[int | None, str, int | float | None]  # (unit, command, value)


class SerialArm(Arm):
    """The drives of one arm on a serial line (see the module docstring)."""

    def __init__(
        self,
        port: str,
        drives: Sequence[DriveProfile],
        *,
        log_path: str | Path | None = None,
        baudrate: int = 9600,
        **link: Unpack[LinkSettings],
    ) -> None:
        self._init_link(drives, **link)
        self.port = port
        self.units = tuple(d.unit_address for d in self.drives)
        self.baudrate = baudrate
        self.log_path = Path(log_path) if log_path is not None else None
        self.revisions: tuple[str, ...] = ()
        self._ser: serial.Serial | None = None
        self._log: TextIO | None = None
        self._log_lines = 0
        self._rx = bytearray()
        # a wait for replies checks the peer this often (a dead robot stops it at once)
        self._poll_s = LIVENESS_POLL_S if self.mode == "realtime" else 0.05
        self._k: int | None = None  # cycles since start()
        self._counts = [0] * self.n_joints  # unwrapped encoder counts
        self._q_prev: tuple[float, ...] = ()
        self._t_prev = 0.0
        self._sent_prev = 0.0  # host time of the previous sample's request

    # ---- Arm API ---------------------------------------------------------------------------
    def open(self) -> None:
        if self._ser is not None:
            return
        try:
            self._ser = serial.Serial(
                self.port, baudrate=self.baudrate, timeout=0, write_timeout=self.timeout_s
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LinkError(f"cannot open serial port {self.port}: {exc}") from None
        self.opened_at = time.monotonic()
        self._rx.clear()
        try:
            if self.log_path is not None:
                self.log_path.parent.mkdir(parents=True, exist_ok=True)
                self._log = open(self.log_path, "a")  # noqa: SIM115 (closed in close())
            self._ser.reset_input_buffer()
            self._echo_off()
            for reply in self._transact([(u, "DMODE", 2) for u in self.units], self.timeout_s):
                if reply.value != "2":
                    raise LinkError(f"unit {reply.unit} on {self.port} refused torque mode")
            replies = self._transact([(u, "TREV", None) for u in self.units], self.timeout_s)
            self.revisions = tuple(r.value for r in replies)
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        ser, self._ser = self._ser, None
        if ser is not None:
            with contextlib.suppress(Exception):
                ser.close()
        log, self._log = self._log, None
        if log is not None:
            with contextlib.suppress(Exception):
                log.close()

    def enable(self) -> None:
        self._transact([(u, "DRIVE", 1) for u in self.units], self.timeout_s)
        replies = self._transact([(u, "TAS", None) for u in self.units], self.timeout_s)
        for j, reply in enumerate(replies):
            state = state_from_statusword(self._statusword(reply))
            if state is not State.OPERATION_ENABLED:
                code = self._transact([(self.units[j], "ERROR", None)], self.timeout_s)[0]
                raise LinkError(
                    f"drive {self.drives[j].model} (unit {self.units[j]}) on {self.port} did not "
                    f"enable: state {state.name if state else 'unknown'}, error {code.value}"
                )

    def disable(self) -> None:
        """XTQ0 then DRIVE0 on every unit; both steps are tried, LinkError if either failed."""
        if self._ser is None:
            return
        timeout = min(self.timeout_s, DISABLE_TIMEOUT_S)
        failures: list[str] = []
        for cmd, value in (("XTQ", 0), ("DRIVE", 0)):
            try:
                self._transact([(u, cmd, value) for u in self.units], timeout, skip_stale=True)
            except LinkError as exc:
                failures.append(str(exc))
        if failures:
            raise LinkError("; ".join(failures))

    def start(self) -> Sample:
        sent = self.now()
        requests: list[_Request] = []
        for u in self.units:
            requests += [(u, "TPE", None), (u, "TAS", None)]
        replies = self._transact(requests, self.timeout_s)
        received = self.now()
        raw = [self._int(replies[2 * j]) for j in range(self.n_joints)]
        status = tuple(self._statusword(replies[2 * j + 1]) for j in range(self.n_joints))
        self._counts = list(raw)
        q = self._q()
        self._k = 0
        t = 0.0 if self.mode == "lockstep" else sent
        self._q_prev, self._t_prev = q, t
        self._sent_prev = sent
        self._check_limits(q, None)
        zeros = (0.0,) * self.n_joints
        if self.mode == "lockstep":
            return Sample(t, q, status, zeros, t, t, t)
        return Sample(t, q, status, zeros, sent, received, math.nan)

    def cycle(self, tau_Nm: Sequence[float], deadline: float | None = None) -> Sample:
        tau = self._command(tau_Nm, self._k is not None)
        permille = [
            torque_to_permille(t, d.rated_torque_Nm) for t, d in zip(tau, self.drives, strict=True)
        ]
        applied = tuple(
            permille_to_torque(p, d.rated_torque_Nm)
            for p, d in zip(permille, self.drives, strict=True)
        )
        requests: list[_Request] = [
            (u, "XTQ", p) for u, p in zip(self.units, permille, strict=True)
        ]
        timeout = self.feedback_timeout_s
        if self.mode == "realtime":
            asked = self.now()
            self._transact(requests, timeout)  # apply now; the sample comes at the deadline
            self.stats.waited(self.now() - asked, self.period_s)  # a late reply is late too
            if deadline is not None:
                self.wait_for_deadline(deadline)
        sent = self.now()
        replies = self._transact(requests, timeout)
        received = self.now()
        if self.mode == "realtime":
            self.stats.waited(received - sent, self.period_s)
        feedback = [self._xtq(r) for r in replies]
        for j, (raw, _) in enumerate(feedback):
            self._counts[j] = unwrap_int32(self._counts[j], raw)
        q = self._q()
        status = tuple(sw for _, sw in feedback)
        self._k += 1
        self.stats.cycles += 1
        # realtime: the robot samples when the request arrives, so the send time is the sample's
        # time; receive times jitter with the host's read scheduling and would corrupt dq below
        t = self._k * self.period_s if self.mode == "lockstep" else sent
        dt = t - self._t_prev
        if self.mode == "realtime":
            # the robot samples when it reads the request, somewhere between our send and its
            # reply (later if it was not scheduled), so the interval since the previous sample
            # is anywhere up to this reply's time minus the previous send. The velocity check
            # takes that longest interval: a robot that read one request late must not read
            # as overspeed. It reads up to latency/period low; the drives' own overspeed
            # check is exact.
            dt = max(dt, received - self._sent_prev)
        dq = tuple((a - b) / dt for a, b in zip(q, self._q_prev, strict=True)) if dt > 0 else None
        self._q_prev, self._t_prev = q, t
        self._sent_prev = sent
        self._check_limits(q, dq)
        if self.mode == "lockstep":
            return Sample(t, q, status, applied, t, t, t)
        return Sample(
            t, q, status, applied, sent, received, math.nan if deadline is None else deadline
        )

    def faults(self) -> list[Fault]:
        replies = self._transact([(u, "ERROR", None) for u in self.units], self.timeout_s)
        out = []
        for j, reply in enumerate(replies):
            code = self._hex(reply)
            if code:
                out.append(Fault(j, code, FAULT_TEXT.get(code, f"drive error 0x{code:04X}")))
        return out

    def clear_faults(self) -> None:
        faulted = [self.units[f.joint] for f in self.faults()]
        if faulted:
            self._transact([(u, "RESET", None) for u in faulted], self.timeout_s)

    def traffic_log(self) -> str | None:
        return str(self.log_path) if self.log_path is not None else None

    # ---- helpers ---------------------------------------------------------------------------
    def request(self, unit: int | None, command: str, value: int | float | None = None) -> str:
        """One command, its reply value (text); LinkError on error replies or no reply.

        For supervision tools and tests (``arm.request(1, "TTRQ")`` -> ``"+12.400"``).
        """
        return self._transact([(unit, command, value)], self.timeout_s)[0].value

    def _q(self) -> tuple[float, ...]:
        return tuple(
            position_to_rad(c, d.counts_per_rev)
            for c, d in zip(self._counts, self.drives, strict=True)
        )

    def _echo_off(self) -> None:
        """ECHO0, tolerating the echo of this very line and junk left on the line before it."""
        self._write("\r" + gm.format_command("ECHO", 0), ["ECHO0"])
        deadline = time.monotonic() + self.timeout_s
        while True:
            line = self._read_line(deadline, self.timeout_s, "ECHO0")
            with contextlib.suppress(gm.ProtocolError):
                if gm.parse_reply(line).name == "ECHO":
                    return

    def _transact(
        self, requests: Sequence[_Request], timeout: float, *, skip_stale: bool = False
    ) -> list[gm.Reply]:
        """Send every request in one write, then read one reply per request, in order."""
        if self._ser is None:
            raise LinkError(f"serial port {self.port} is not open")
        lines = [gm.format_command(name, value, unit=unit) for unit, name, value in requests]
        self._write("".join(lines), [ln.rstrip("\r") for ln in lines])
        deadline = time.monotonic() + timeout
        replies = []
        for (unit, name, _), line in zip(requests, lines, strict=True):
            while True:
                text = self._read_line(deadline, timeout, line.rstrip("\r"))
                try:
                    reply = gm.parse_reply(text)
                except gm.ProtocolError as exc:
                    if skip_stale:
                        continue
                    raise self._error(
                        f"{line.rstrip()!r} answered {text!r} on {self.port}: {exc}"
                    ) from None
                if reply.unit == unit and reply.name == name:
                    replies.append(reply)
                    break
                if not skip_stale:
                    raise self._error(
                        f"unexpected reply {text!r} to {line.rstrip()!r} on {self.port}"
                    )
        return replies

    def _write(self, data: str, logged: Sequence[str]) -> None:
        assert self._ser is not None
        for text in logged:
            self._log_line(">", text)
        try:
            self._ser.write(data.encode("ascii"))
        except (serial.SerialException, OSError) as exc:
            raise self._error(
                f"link to the virtual robot/drive on {self.port} lost on write ({exc})"
            ) from None
        self.stats.frames_sent += len(logged)

    def _read_line(self, deadline: float, timeout: float, waiting_for: str) -> str:
        """The next non-empty reply line (terminators stripped, echoed input dropped)."""
        assert self._ser is not None
        while True:
            end = self._rx.find(b"\n")
            if end >= 0:
                text = bytes(self._rx[: end + 1]).decode("latin-1").rstrip("\r\n")
                del self._rx[: end + 1]
                text = text.rsplit("\r", 1)[-1]  # echo (ECHO1): the reply follows the last CR
                if not text:
                    continue
                self.stats.frames_received += 1
                self._log_line("<", text)
                return text
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self.stats.timeouts += 1
                raise self._error(
                    f"virtual robot/drive not responding on {self.port} after "
                    f"{timeout:.3g} s (no reply to {waiting_for}): stalled or gone"
                )
            # waited a poll slice already and the other end is dead: say so now, not at the end
            if timeout - remaining > self._poll_s and self.peer_gone():
                raise self._error(f"the virtual robot process on {self.port} is gone")
            try:
                ready, _, _ = select.select(
                    [self._ser.fileno()], [], [], min(remaining, self._poll_s)
                )
                if ready:
                    self._rx += self._ser.read(max(1, self._ser.in_waiting))
            except (serial.SerialException, OSError, ValueError) as exc:
                raise self._error(
                    f"link to the virtual robot/drive on {self.port} lost on read ({exc})"
                ) from None

    def _error(self, message: str) -> LinkError:
        """The LinkError to raise for ``message``, kept as the link's errors are."""
        self._note_error(message)
        return LinkError(message)

    def _note_error(self, text: str) -> None:
        """Kept in the stats and written to serial.log as a ``!`` line (flushed: the run may
        end with it)."""
        super()._note_error(text)
        if self._log is not None:
            self._log_line("!", text)
            with contextlib.suppress(Exception):
                self._log.flush()

    def _log_line(self, arrow: str, text: str) -> None:
        if self._log is None:
            return
        t = time.monotonic() - (self.opened_at or 0.0)
        self._log.write(f"{t:.6f} {arrow} {text}\n")
        self._log_lines += 1
        if self._log_lines % LOG_FLUSH_LINES == 0:
            self._log.flush()

    # reply decoding with LinkError instead of the codec's errors
    def _decode(self, reply: gm.Reply, fn: str) -> int | tuple[int, int]:
        try:
            return getattr(reply, fn)()
        except gm.ProtocolError as exc:
            raise self._error(f"bad {reply.name} reply on {self.port}: {exc}") from None

    def _int(self, reply: gm.Reply) -> int:
        return self._decode(reply, "int_value")  # type: ignore[return-value]

    def _hex(self, reply: gm.Reply) -> int:
        return self._decode(reply, "hex_value")  # type: ignore[return-value]

    def _statusword(self, reply: gm.Reply) -> int:
        return self._decode(reply, "statusword")  # type: ignore[return-value]

    def _xtq(self, reply: gm.Reply) -> tuple[int, int]:
        return self._decode(reply, "xtq")  # type: ignore[return-value]
