"""Serial server: the Gemini-style ASCII dialect (``drivers.protocol.gemini``) on a pty.

The virtual robot opens a pseudo-terminal, puts its slave side in raw mode (no echo, no CR/LF
translation) and announces the slave path; the host opens that path with pyserial as if it were
a USB serial adapter. Each received line is decoded by the codec and mapped onto the drive
objects of :class:`~virtual_robot.robot.VirtualRobot` (``core.write``/``core.read`` with
``unit=n``); the command table and reply formats are in the codec's docstring.

Time (docs/design.md "Time"):

* lockstep: the server calls ``core.sync()`` once at start-up (sample at t = 0). An ``n_XTQ``
  writes the target torque at the current robot time; when every unit has received its XTQ for
  the current period, ``core.sync()`` advances one period and samples, and every pending XTQ is
  answered, in the order received, with its unit's fresh counts and statusword. Other commands
  answer at once from the current sample. If nothing arrives for ``host_timeout_s`` (the bench's
  ``timeout_s``; 5 s by default) after
  the first command, every drive is disabled (``core.disable_all()``) and one line goes to stderr.
* realtime: the drives' period timer runs (``core.start_period_timer``, the command watchdog);
  an XTQ applies at arrival (``core.write`` integrates the plant up to the clock first) and its
  reply carries the counts sampled at that moment (``core.sync()`` samples without counting a
  watchdog period).

No byte-time model: a pty ignores the baud rate, so replies are as fast as the process is. The
bench's ``baudrate`` is only reported. The server closes its own slave descriptor after setting
it raw, so a host that closes the port is seen as EIO on the master (no data): the partial line
and any pending XTQ are dropped, and a host that opens the path again starts clean.
"""

from __future__ import annotations

import errno
import os
import select
import sys
import threading
import time
from collections.abc import Callable
from typing import IO, TextIO

from drivers.protocol import cia402 as co
from drivers.protocol import gemini as gm
from drivers.protocol.cia402 import SdoAbortError, State
from drivers.units import INT16_MAX, permille_to_torque, torque_to_permille
from profiles.bench import BenchProfile
from virtual_robot import __version__
from virtual_robot.raw_pty import open_raw_pty
from virtual_robot.robot import LOCKSTEP, VirtualRobot

HOST_TIMEOUT_S = 5.0
WRITE_STALL_S = 1.0  # a host that does not read its replies for this long loses them
_TORQUE_MODES = (co.MODE_CST, co.MODE_TQ)

_ABORT_ERRORS: dict[int, type[gm.CommandError]] = {
    co.ABORT_VALUE_TOO_HIGH: gm.InvalidDataHighError,
    co.ABORT_VALUE_TOO_LOW: gm.InvalidDataLowError,
}


class SerialDriveServer:
    """The drives of ``core`` behind one serial line.

    :meth:`handle_line` is the pure request -> reply map (no I/O); :meth:`feed` adds line
    framing and echo to it (bytes in -> bytes out); :meth:`serve` is the I/O loop on
    ``fd_or_file`` (an fd or an object with ``fileno()``, e.g. a pty master), None for tests
    that only call :meth:`handle_line`/:meth:`feed`.
    """

    def __init__(
        self,
        core: VirtualRobot,
        fd_or_file: int | IO[bytes] | None = None,
        *,
        host_timeout_s: float = HOST_TIMEOUT_S,
        log: TextIO | None = None,
    ) -> None:
        self.core = core
        if fd_or_file is None or isinstance(fd_or_file, int):
            self.fd: int | None = fd_or_file
        else:
            self.fd = fd_or_file.fileno()
        self.host_timeout_s = host_timeout_s
        self.log = log
        self.units = tuple(sorted(core.by_unit))
        self.profiles = {p.unit_address: p for p in core.profiles}
        self.echo = True  # ECHO1 is the power-on default of a Gemini
        self.lockstep = core.mode == LOCKSTEP
        self._pending: list[int] = []  # lockstep: units whose XTQ waits for the step
        self.dropped_xtq = 0  # robot-side timing fault: torques lost
        self._buffer = bytearray()
        self._overflow = False
        self._last_rx: float | None = None
        self._host_lost = False
        self._connected = False
        self.lines = 0
        if self.lockstep and core.syncs == 0:
            core.sync()  # sample at t = 0: every later sync advances one period

    # ---- request -> reply ---------------------------------------------------------------
    def handle_line(self, line: str) -> str:
        """The reply text for one command line (terminator optional).

        Normally one reply line (``*...`` CR LF). Exceptions: ``""`` for a blank line and, in
        lockstep, for an XTQ that waits for the other units; the XTQ that completes the period
        returns the replies of every pending XTQ, in order. Never raises for bad input.
        """
        if not line.strip(" \t\r\n"):
            return ""
        self.lines += 1
        try:
            cmd = gm.parse_command(line)
        except gm.CommandError as exc:
            return exc.reply
        try:
            return self._execute(cmd)
        except gm.CommandError as exc:
            exc.unit = cmd.unit
            return exc.reply
        except SdoAbortError as exc:
            return gm.format_error(_ABORT_ERRORS.get(exc.code, gm.InvalidDataError).token, cmd.unit)

    def _execute(self, cmd: gm.Command) -> str:
        name, value = cmd.name, cmd.value
        if name == "ECHO":
            if value is not None:
                self.echo = bool(value)
            return gm.format_reply(name, str(int(self.echo)), cmd.unit)
        if cmd.unit is not None and cmd.unit not in self.profiles:
            raise gm.InvalidDataError(f"no drive at unit {cmd.unit}")
        units = (cmd.unit,) if cmd.unit is not None else self.units
        if name == "XTQ":
            assert cmd.unit is not None and isinstance(value, int)
            return self._xtq(cmd.unit, value)
        if cmd.is_report:
            assert cmd.unit is not None  # the codec requires a unit for reports
            return gm.format_reply(name, self._report(name, cmd.unit), cmd.unit)
        for u in units:
            self._set(name, u, value)
        if name in ("K", "RESET"):
            text = ""
        elif cmd.unit is not None:
            text = self._report(name, cmd.unit)
        else:  # broadcast DRIVE/DMODE: 1 only if every unit is enabled
            texts = {self._report(name, u) for u in units}
            text = texts.pop() if len(texts) == 1 else "0"
        return gm.format_reply(name, text, cmd.unit)

    def _set(self, name: str, u: int, value: int | float | None) -> None:
        w = self.core.write
        if name == "DRIVE":
            if value:
                if self._state(u) is not State.OPERATION_ENABLED:
                    w(0x6071, 0, 0, unit=u)  # never enable onto a stale torque
                    w(0x6060, 0, co.MODE_CST, unit=u)
                    for cw in (co.CW_SHUTDOWN, co.CW_SWITCH_ON, co.CW_ENABLE_OPERATION):
                        w(0x6040, 0, cw, unit=u)
            else:
                w(0x6071, 0, 0, unit=u)
                w(0x6040, 0, co.CW_DISABLE_VOLTAGE, unit=u)
        elif name == "DMODE":
            if value != 2:
                raise gm.InvalidDataError(f"DMODE{value}: only 2 (torque) is supported")
            w(0x6060, 0, co.MODE_CST, unit=u)
        elif name == "DMTLIM":
            assert isinstance(value, float)
            rated = self.profiles[u].rated_torque_Nm
            if value * 1000.0 / rated >= INT16_MAX + 0.5:
                raise gm.InvalidDataHighError(f"DMTLIM{value} above {INT16_MAX} per-mille")
            w(0x6072, 0, torque_to_permille(value, rated), unit=u)  # 0 or less: too low
        elif name == "K":
            w(0x6071, 0, 0, unit=u)
            w(0x6040, 0, co.CW_DISABLE_VOLTAGE, unit=u)
        elif name == "RESET":
            w(0x6071, 0, 0, unit=u)
            w(0x6040, 0, co.CW_FAULT_RESET, unit=u)
            w(0x6040, 0, co.CW_DISABLE_VOLTAGE, unit=u)
        else:  # a report-only command given a value is refused by the codec
            raise gm.InvalidDataError(f"{name} cannot be set")

    def _report(self, name: str, u: int) -> str:
        r = self._read
        p = self.profiles[u]
        if name == "DRIVE":
            return "1" if self._state(u) is State.OPERATION_ENABLED else "0"
        if name == "DMODE":
            mode = r(0x6060, u)
            return "2" if mode in _TORQUE_MODES else str(mode)
        if name == "DMTLIM":
            return gm.fmt_fixed(permille_to_torque(r(0x6072, u), p.rated_torque_Nm), 3, False)
        if name == "TPE":
            return gm.fmt_signed(r(0x6064, u))
        if name == "TVELA":
            return gm.fmt_fixed(r(0x606C, u) / p.counts_per_rev, 4)
        if name == "TTRQ":
            return gm.fmt_fixed(permille_to_torque(r(0x6077, u), p.rated_torque_Nm), 3)
        if name == "TAS":
            return gm.statusword_to_tas(
                r(0x6041, u), r(0x606C, u), torque_mode=r(0x6060, u) in _TORQUE_MODES
            )
        if name == "ERROR":
            return gm.fmt_hex16(r(0x603F, u))
        if name == "TREV":
            return f"{p.model} emulated, ddbench virtual_robot {__version__}"
        raise gm.InvalidDataError(f"{name} has no report form")

    @property
    def pending_xtq(self) -> tuple[int, ...]:
        """Lockstep: units whose XTQ of the current period waits for the other units."""
        return tuple(self._pending)

    def _xtq(self, u: int, permille: int) -> str:
        if self.core.drop_command():  # an injected timing fault: the torque is lost, the
            self.dropped_xtq += 1  # request still samples and is answered
        else:
            self.core.write(0x6071, 0, permille, unit=u)
        if not self.lockstep:
            self.core.sync()  # realtime: samples now, no watchdog period
            delay = self.core.feedback_delay_s()
            if delay > 0:  # an injected timing fault: the reply leaves late
                time.sleep(delay)
            return self._xtq_reply(u)
        self._pending.append(u)
        if not set(self.units) <= set(self._pending):
            return ""
        self.core.sync()  # every unit has its torque: advance one period, sample
        pending, self._pending = self._pending, []
        return "".join(self._xtq_reply(p) for p in pending)

    def _xtq_reply(self, u: int) -> str:
        return gm.format_reply("XTQ", gm.fmt_xtq(self._read(0x6064, u), self._read(0x6041, u)), u)

    def _read(self, index: int, u: int) -> int:
        return self.core.read(index, 0, unit=u)

    def _state(self, u: int) -> State | None:
        return co.state_from_statusword(self._read(0x6041, u))

    # ---- bytes in -> bytes out -------------------------------------------------------------
    def feed(self, data: bytes) -> bytes:
        """Frame received bytes into lines (CR or LF), echo them if ECHO1, answer each line."""
        now = time.monotonic()
        self._last_rx, self._host_lost, self._connected = now, False, True
        out = bytearray()
        start = 0
        while start < len(data):
            ends = [i for i in (data.find(b"\r", start), data.find(b"\n", start)) if i >= 0]
            end = min(ends) if ends else len(data)
            segment = data[start : end + 1] if ends else data[start:]
            if self.echo:
                out += segment  # echo follows ECHO0/ECHO1 line by line, as typed
            if not ends:
                self._buffer += segment
                if len(self._buffer) > gm.MAX_LINE + 64:
                    self._buffer.clear()
                    self._overflow = True
                break
            self._buffer += data[start:end]
            line, overflow = bytes(self._buffer), self._overflow
            self._buffer.clear()
            self._overflow = False
            if overflow:
                out += gm.format_error(gm.INVALID_DATA).encode("ascii")
            else:
                out += self._answer(line.decode("latin-1"))
            start = end + 1
        return bytes(out)

    def _answer(self, line: str) -> bytes:
        try:
            return self.handle_line(line).encode("ascii")
        except Exception as exc:  # a bug must not kill the drives' link: say so and go on
            self._say(f"internal error on {line[:40]!r}: {type(exc).__name__}: {exc}")
            return gm.format_error(gm.INVALID_DATA).encode("ascii")

    def host_gone(self) -> None:
        """The host closed the port: drop the partial line and any XTQ waiting for its step."""
        self._buffer.clear()
        self._overflow = False
        self._pending.clear()
        self._connected = False
        self.core.disable_all()  # nobody commands them any more: zero torque, disabled
        self._say("host closed the port; drives disabled")

    def check_host(self, now: float | None = None) -> bool:
        """Lockstep: disable every drive once if the host went quiet. True if it did now."""
        if not self.lockstep or self._last_rx is None or self._host_lost:
            return False
        now = time.monotonic() if now is None else now
        if now - self._last_rx < self.host_timeout_s:
            return False
        self._host_lost = True
        self._pending.clear()
        self.core.disable_all()
        self._say(f"no command from the host for {self.host_timeout_s:g} s; drives disabled")
        return True

    def _say(self, text: str) -> None:
        print(f"virtual-robot: serial: {text}", file=self.log or sys.stderr, flush=True)

    # ---- I/O loop --------------------------------------------------------------------------
    def serve(self, stop: threading.Event, poll_s: float = 0.05) -> None:
        """Serve until ``stop`` is set (or the fd is closed under us)."""
        if self.fd is None:
            raise ValueError("SerialDriveServer without a file descriptor cannot serve")
        fd = self.fd
        while not stop.is_set():
            try:
                readable, _, _ = select.select([fd], [], [], poll_s)
            except (OSError, ValueError):
                return  # closed under us
            if not readable:
                self.check_host()
                continue
            try:
                data = os.read(fd, 4096)
            except BlockingIOError:
                continue
            except OSError as exc:
                if exc.errno != errno.EIO:
                    return  # EBADF & co: the master is gone
                data = b""
            if not data:  # EIO on a pty master: no host has the slave open
                if self._connected:
                    self.host_gone()
                self.check_host()
                stop.wait(0.01)
                continue
            out = self.feed(data)
            if out:
                self._write(fd, out)

    def _write(self, fd: int, data: bytes) -> None:
        view = memoryview(data)
        give_up = time.monotonic() + WRITE_STALL_S
        while view:
            try:
                n = os.write(fd, view)
                view = view[n:]
            except BlockingIOError:
                if time.monotonic() > give_up:
                    self._say(f"host does not read; {len(view)} bytes of replies dropped")
                    return
                select.select([], [fd], [], 0.05)
            except OSError:
                return  # host gone (EIO) or fd closed: nobody to answer


def open_pty() -> tuple[int, str]:
    """A new pty: (master fd, non-blocking; slave path). The slave is raw and left closed, so a
    host closing the port shows as EIO on the master."""
    master, _, path = open_raw_pty(keep_slave_open=False)
    return master, path


def serve_serial(
    core: VirtualRobot,
    bench: BenchProfile,
    *,
    announce: Callable[[dict], None],
    stop: threading.Event,
) -> int:
    """Serve ``core`` on a new pty until ``stop`` is set; announce the slave path. Returns 0."""
    master, path = open_pty()
    done = threading.Event()
    timer: threading.Thread | None = None
    try:
        # lockstep: a host silent for the bench's timeout_s (what the host waits for us) is gone
        server = SerialDriveServer(core, master, host_timeout_s=bench.timeout_s)
        timer = core.start_period_timer(done)  # realtime only (None in lockstep)
        print(
            f"virtual-robot: serial drives on {path} ({core.mode}, h = {core.period_s * 1e3:g} ms;"
            f" {bench.baudrate} baud nominal, byte time not modelled)",
            file=sys.stderr,
            flush=True,
        )
        announce({"event": "ready", "protocol": "serial", "transport": "serial", "channel": path})
        server.serve(stop)
    finally:
        done.set()
        os.close(master)
    if timer is not None:
        timer.join(timeout=1.0)
    return 0
