r"""Compumotor Gemini/6K-style ASCII dialect: the serial link to the drives, as a pure codec.

Both ends use this module: the virtual robot's serial server (``virtual_robot.serial_server``)
parses commands and formats replies, the host driver (``drivers.serial_arm``) does the reverse.
No ports, no clocks, no drive state: what a command *does* is the server's business (the
semantics are summarised here so the dialect is documented in one place).

Framing
-------
* Line based, 7-bit ASCII (a receiver decodes bytes as Latin-1, so no byte is ever an encoding
  error). Nominal 9600 baud 8N1; a pty ignores the baud rate and the emulator does not model
  byte time. For scale: one XTQ cycle of two requests and two replies is about 68 characters,
  i.e. about 70 ms at 9600 baud and about 272 000 baud at 400 Hz.
* A **command** is ``[n_][!]CMD[value]`` terminated by CR (``\r``). LF is accepted as a
  terminator too and empty lines are ignored, so a host that sends CR LF works. Spaces and tabs
  around the command are ignored; none are allowed inside it. At most :data:`MAX_LINE`
  characters.

  - ``n_``: unit address, decimal 0-255, for a multi-drop line (1 = shoulder DM1200-A,
    2 = elbow DM1015-B; the drive profile's ``unit_address``). Commands that read something
    (and ``XTQ``, ``DMTLIM``) need it. Without it, ``DRIVE0``/``DRIVE1``, ``DMODE2``, ``K`` and
    ``RESET`` go to every unit (broadcast) and ``ECHO`` is a property of the link.
  - ``!``: immediate command. Accepted and ignored: the emulated drive executes every command at
    once (a real Gemini would bypass its command buffer).
  - ``CMD``: ASCII letters, case-insensitive (normalised to upper case). The name is the longest
    run of letters; the value is what follows.
  - ``value``: an integer ``[+-]digits`` or a decimal ``[+-]digits[.digits]``, at most 32
    characters. Omitted on a command that supports a report form, it asks for the value.
    Ranges checked by the codec: ``DRIVE`` and ``ECHO`` 0..1, ``XTQ`` -32768..32767 (outside:
    INVALID_DATA_HIGH / INVALID_DATA_LOW); the server checks the others against the drive.

* A **reply** is ``*[n_]CMD[value]`` terminated by CR LF. A reply carries the unit prefix of
  its command, exactly (``1_TPE`` -> ``*1_TPE+123456``; ``DRIVE0`` -> ``*DRIVE0``), so replies on
  a multi-drop line are unambiguous. Every command gets exactly one reply line, except
  ``XTQ`` in lockstep (below) and empty lines (none). A setting command is answered with the value
  now in effect, the same text its report form gives (``1_DRIVE1`` -> ``*1_DRIVE1`` once the drive
  is enabled, ``*1_DRIVE0`` if it could not enable; a broadcast ``DRIVE1`` answers ``*DRIVE1``
  only if every unit is enabled). Real Gemini drives do not acknowledge settings; this dialect
  does, so the host can wait for completion.
* An **error reply** is ``*[n_]TOKEN`` CR LF, TOKEN one of

  ====================== ====================================================================
  ``UNDEFINED_LABEL``    not a command of this dialect (or no command name at all)
  ``INVALID_DATA``       malformed or missing value, value not allowed (``DMODE3``), unknown
                         unit, unit prefix missing where one is needed, line too long
  ``INVALID_DATA_HIGH``  numeric value above the accepted range
  ``INVALID_DATA_LOW``   numeric value below the accepted range
  ====================== ====================================================================

  The prefix is present when the command's own prefix could be parsed.

* ``ECHO1`` (power-on default, as on a Gemini): every received byte is sent back as it arrives,
  before the reply. ``ECHO0``: no echo. A host sends ``ECHO0`` first and takes the reply text
  after the last CR of the line it reads.

Commands (n = unit address; values as the drive reports them)
-------------------------------------------------------------

========== ================== ===============================================================
command    reply              meaning (CiA 402 objects of the emulated drive)
========== ================== ===============================================================
DRIVE1     ``*n_DRIVE1``      enable: 0x6071 := 0, 0x6060 := 10 (cyclic synchronous torque),
                              controlwords 0x06, 0x07, 0x0F (skipped if already enabled).
                              Replies ``DRIVE0`` if the drive did not reach OPERATION ENABLED
                              (e.g. in FAULT: send RESET first)
DRIVE0     ``*n_DRIVE0``      disable: 0x6071 := 0, controlword 0x00 (SWITCH ON DISABLED)
DRIVE      ``*n_DRIVE1|0``    report: 1 = OPERATION ENABLED
DMODE2     ``*n_DMODE2``      torque mode: 0x6060 := 10. Any other value: INVALID_DATA
DMODE      ``*n_DMODE2``      report (the emulated drive has torque modes only)
DMTLIMx    ``*n_DMTLIM150.000``  torque limit x Nm -> 0x6072 = round(x·1000/rated) per-mille,
                              accepted 1..32767 ‰ (else INVALID_DATA_LOW/HIGH). Reply in Nm,
                              3 decimals, of the per-mille now in effect
DMTLIM     same               report
TPE        ``*n_TPE+123456``  encoder position, counts (0x6064, INT32, always signed)
TVELA      ``*n_TVELA+1.2345`` velocity, rev/s like a Gemini, 4 decimals (0x606C / counts/rev)
TTRQ       ``*n_TTRQ-12.400`` torque actual, Nm, 3 decimals (0x6077 ‰ · rated / 1000)
TAS        ``*n_TAS0000_...`` axis status, 32 bits (table below)
ERROR      ``*n_ERROR0x8250`` error code 0x603F as 4 hex digits (0x0000: no error)
TREV       ``*n_TREV<text>``  revision (free text to the end of the line)
K          ``*n_K``           kill: 0x6071 := 0, controlword 0x00 (drive disabled, torque zero)
RESET      ``*n_RESET``       fault reset: 0x6071 := 0, controlword 0x80 then 0x00; the drive
                              ends in SWITCH ON DISABLED (not a reboot as on a Gemini)
ECHO0/1    ``*ECHO0``         echo off / on; ``ECHO`` reports
========== ================== ===============================================================

Vendor extension: ``XTQ`` torque streaming (NOT a Gemini command)
-----------------------------------------------------------------
Real drives of this family (the Dynaserv DM1200-A / DM1015-B of the CICESE arm) take the torque
command as an **analog ±10 V input**; the serial line only configures and supervises them.
The emulator adds one request/response per drive per cycle:

    ``n_XTQ<permille>`` -> ``*n_XTQ<counts>,<statusword>``
    e.g. ``1_XTQ+125`` -> ``*1_XTQ+123456,0x0637``

``permille`` sets the target torque 0x6071 in per-mille of the rated torque 0x6076 (integer,
INT16 range -32768..32767, else INVALID_DATA_LOW/HIGH; the drive clamps it to 0x6072). The reply
carries the encoder count (0x6064, signed decimal) and the CiA 402 statusword (0x6041, ``0x``
and 4 hex digits) sampled after the command took effect:

* lockstep: robot time stands still until *every* unit has received its XTQ for the current
  period; then the robot advances one period and samples, and each pending XTQ is answered, in
  the order received, with the fresh sample. So ``1_XTQa\r2_XTQb\r`` followed by reading two
  replies gives q(t_k+1) for torques applied at t_k. A second XTQ to the same unit within one
  period only replaces its torque (and gets its own reply after the step). A rejected XTQ does
  not count. Other commands are answered at once from the current sample, even while an XTQ
  waits, so a host that interleaves them must match replies by prefix and name.
* realtime: the torque applies on arrival (the plant is integrated up to that instant first)
  and the reply carries the counts sampled at that moment.

400 Hz streaming works on the emulated link only: a real serial drive can be configured and
supervised over this dialect (``DRIVE``, ``DMODE``, ``DMTLIM``, ``TPE``, ``TAS``, ``ERROR``, ...),
not streamed at 400 Hz, and has no ``XTQ``.

Supervision by the emulated drives: in realtime the drive's command watchdog faults (error
0x8250, TAS bit 14) when an enabled drive gets no XTQ for ``watchdog_s`` (0.5 s); in
lockstep the robot only moves on XTQ, and the server disables every drive if the host sends
nothing for the bench's timeout_s (2 s), or closes the port.

TAS bit map
-----------
32 characters ``0``/``1`` in groups of 4 separated by ``_``; the leftmost character is bit 1
(Gemini numbering). Bits 1-16 are Gemini-style flags, bits 17-32 carry the CiA 402 statusword
0x6041 verbatim, least significant bit first (bit 17 = statusword bit 0), so the host recovers
the exact statusword from a TAS (:func:`tas_to_statusword`).

===== ===============================================================================
bit   meaning when 1
===== ===============================================================================
1     moving: velocity actual 0x606C ≠ 0
2     direction negative: 0x606C < 0
3-8   0 (motion-profile flags of a Gemini; meaningless in torque mode)
9     in torque mode (0x6060 = 10 or 4; always 1 on the emulated drive)
10-11 0
12    torque limited: the target torque exceeds 0x6072 and is clamped (statusword bit 11)
13    drive shut down: not in OPERATION ENABLED (so **drive enabled ⇔ bit 13 = 0**)
14    drive faulted: CiA 402 FAULT (statusword bit 3); ``ERROR`` gives the code
15    quick stop active (CiA 402 QUICK STOP ACTIVE)
16    0
17-32 statusword bits 0..15 (17: ready to switch on, 18: switched on, 19: operation enabled,
      20: fault, 21: voltage enabled, 22: quick stop (1 = not active), 23: switch on disabled,
      24: warning, 25: manufacturer, 26: remote, 27: target reached, 28: internal limit, ...)
===== ===============================================================================

Example: enabled, at rest, not limited, statusword 0x0637 (OPERATION ENABLED, voltage enabled,
remote, target reached) -> ``*1_TAS0000_0000_1000_0000_1110_1100_0110_0000``.
"""

from __future__ import annotations

import enum
import math
import re
from dataclasses import dataclass

MAX_LINE = 256  # characters of one command, terminator excluded
MAX_VALUE = 32  # characters of one value
UNIT_MAX = 255
COMMAND_END = "\r"
REPLY_END = "\r\n"

UNDEFINED_LABEL = "UNDEFINED_LABEL"
INVALID_DATA = "INVALID_DATA"
INVALID_DATA_HIGH = "INVALID_DATA_HIGH"
INVALID_DATA_LOW = "INVALID_DATA_LOW"
ERROR_TOKENS = (UNDEFINED_LABEL, INVALID_DATA, INVALID_DATA_HIGH, INVALID_DATA_LOW)

INT16_MIN, INT16_MAX = -(2**15), 2**15 - 1


# ---- errors ----------------------------------------------------------------------------------
class ProtocolError(ValueError):
    """Base of every error of this codec.

    ``token`` is the dialect's error token (``INVALID_DATA`` ...) or None for a host-side
    problem with no token (garbage reply); ``unit`` the unit prefix, if known; ``reply`` the
    complete reply line a drive sends for it (``""`` when there is no token).
    """

    token: str | None = None

    def __init__(self, detail: str, unit: int | None = None) -> None:
        super().__init__(detail)
        self.detail = detail
        self.unit = unit

    @property
    def reply(self) -> str:
        return format_error(self.token, self.unit) if self.token else ""


class CommandError(ProtocolError):
    """A command the drive refuses; :attr:`reply` is the error reply to send."""

    token: str = INVALID_DATA


class UndefinedLabelError(CommandError):
    token = UNDEFINED_LABEL


class InvalidDataError(CommandError):
    token = INVALID_DATA


class InvalidDataHighError(InvalidDataError):
    token = INVALID_DATA_HIGH


class InvalidDataLowError(InvalidDataError):
    token = INVALID_DATA_LOW


class MalformedReplyError(ProtocolError):
    """Host side: a reply line that is not a reply of this dialect (garbage, wrong format)."""


class DriveReplyError(ProtocolError):
    """Host side: the drive answered with an error token (``*1_INVALID_DATA_HIGH``)."""

    def __init__(self, token: str, unit: int | None, line: str) -> None:
        self.token = token
        self.line = line
        prefix = f"unit {unit}: " if unit is not None else ""
        super().__init__(f"{prefix}drive replied {token}", unit)


ERROR_CLASSES: dict[str, type[CommandError]] = {
    UNDEFINED_LABEL: UndefinedLabelError,
    INVALID_DATA: InvalidDataError,
    INVALID_DATA_HIGH: InvalidDataHighError,
    INVALID_DATA_LOW: InvalidDataLowError,
}


# ---- command table -----------------------------------------------------------------------------
class Kind(enum.Enum):
    NONE = "none"  # no value allowed
    INT = "int"
    DECIMAL = "decimal"


@dataclass(frozen=True)
class CommandSpec:
    name: str
    kind: Kind
    report: bool = False  # the value may be omitted: report form
    required: bool = False  # the value must be given
    lo: int | None = None  # integer range checked by the codec (else the server checks)
    hi: int | None = None
    broadcast: bool = False  # the setting form may omit the unit (goes to every unit)
    link: bool = False  # a property of the link: the unit is optional and ignored
    action: bool = False  # no value, does something (K, RESET); other no-value commands report
    vendor: bool = False  # not a Gemini command: vendor extension
    summary: str = ""


COMMANDS: dict[str, CommandSpec] = {
    s.name: s
    for s in (
        CommandSpec("DRIVE", Kind.INT, report=True, lo=0, hi=1, broadcast=True,
                    summary="enable (1) / disable (0) / report"),
        CommandSpec("DMODE", Kind.INT, report=True, broadcast=True,
                    summary="drive mode: 2 = torque"),
        CommandSpec("DMTLIM", Kind.DECIMAL, report=True, summary="torque limit, Nm"),
        CommandSpec("TPE", Kind.NONE, summary="encoder position, counts"),
        CommandSpec("TVELA", Kind.NONE, summary="velocity actual, rev/s"),
        CommandSpec("TTRQ", Kind.NONE, summary="torque actual, Nm"),
        CommandSpec("TAS", Kind.NONE, summary="axis status bits"),
        CommandSpec("ERROR", Kind.NONE, summary="error code (CiA 402), hex"),
        CommandSpec("TREV", Kind.NONE, summary="revision"),
        CommandSpec("K", Kind.NONE, broadcast=True, action=True,
                    summary="kill: disable, torque zero"),
        CommandSpec("RESET", Kind.NONE, broadcast=True, action=True,
                    summary="fault reset, back to disabled"),
        CommandSpec("ECHO", Kind.INT, report=True, lo=0, hi=1, link=True,
                    summary="echo received characters (1) or not (0)"),
        CommandSpec("XTQ", Kind.INT, required=True, lo=INT16_MIN, hi=INT16_MAX, vendor=True,
                    summary="vendor extension: torque per-mille, replies counts,statusword"),
    )
}  # fmt: skip
_NAMES_LONGEST_FIRST = tuple(sorted(COMMANDS, key=len, reverse=True))

_COMMAND_RE = re.compile(r"(?:([0-9]+)_)?(!)?([A-Za-z]+)(.*)", re.DOTALL)
_INT_RE = re.compile(r"[+-]?[0-9]+")
_DECIMAL_RE = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)")
_UNIT_RE = re.compile(r"([0-9]{1,3})_")
_PRINTABLE_RE = re.compile(r"[\x20-\x7e]*")


@dataclass(frozen=True)
class Command:
    """One parsed command. ``value`` is an int (Kind.INT), a float (Kind.DECIMAL) or None."""

    unit: int | None
    immediate: bool
    name: str
    value: int | float | None = None

    @property
    def spec(self) -> CommandSpec:
        return COMMANDS[self.name]

    @property
    def is_report(self) -> bool:
        """Asks for a value (``1_TPE``, ``1_DRIVE``) rather than setting or doing something."""
        return self.value is None and not self.spec.action

    def text(self) -> str:
        """The command line, terminator included (:func:`format_command`)."""
        return format_command(self.name, self.value, unit=self.unit, immediate=self.immediate)


def parse_command(line: str) -> Command:
    """Parse one command line (terminator optional). Raises a :class:`CommandError` subclass
    whose :attr:`~ProtocolError.reply` is the error reply for malformed input."""
    text = line.rstrip("\r\n").strip(" \t")
    if len(text) > MAX_LINE:
        raise InvalidDataError(f"line longer than {MAX_LINE} characters")
    m = _COMMAND_RE.fullmatch(text)
    if m is None:
        raise UndefinedLabelError(f"no command name in {text[:40]!r}")
    unit_text, bang, name, value_text = m.groups()
    unit: int | None = None
    if unit_text is not None:
        if len(unit_text) > 3 or int(unit_text) > UNIT_MAX:
            raise InvalidDataError(f"unit address {unit_text[:8]} not in 0..{UNIT_MAX}")
        unit = int(unit_text)
    name = name.upper()
    spec = COMMANDS.get(name)
    if spec is None:
        raise UndefinedLabelError(f"unknown command {name[:20]}", unit)
    value = _parse_value(spec, value_text, unit)
    # without a unit, only setting forms (DRIVE1, DMODE2) and actions (K, RESET) go to every unit
    broadcast = spec.broadcast and (value is not None or spec.action)
    if unit is None and not spec.link and not broadcast:
        raise InvalidDataError(f"{name} needs a unit address (n_{name})")
    return Command(unit, bang is not None, name, value)


def _parse_value(spec: CommandSpec, text: str, unit: int | None) -> int | float | None:
    if text == "":
        if spec.required or (spec.kind is not Kind.NONE and not spec.report):
            raise InvalidDataError(f"{spec.name} needs a value", unit)
        return None
    if spec.kind is Kind.NONE:
        raise InvalidDataError(f"{spec.name} takes no value", unit)
    if len(text) > MAX_VALUE:
        raise InvalidDataError(f"value longer than {MAX_VALUE} characters", unit)
    if spec.kind is Kind.INT:
        if not _INT_RE.fullmatch(text):
            raise InvalidDataError(f"{spec.name}: {text!r} is not an integer", unit)
        value = int(text)
        if spec.hi is not None and value > spec.hi:
            raise InvalidDataHighError(f"{spec.name}: {value} > {spec.hi}", unit)
        if spec.lo is not None and value < spec.lo:
            raise InvalidDataLowError(f"{spec.name}: {value} < {spec.lo}", unit)
        return value
    if not _DECIMAL_RE.fullmatch(text):
        raise InvalidDataError(f"{spec.name}: {text!r} is not a number", unit)
    return float(text)


def format_command(
    name: str, value: int | float | None = None, *, unit: int | None = None, immediate: bool = False
) -> str:
    """A command line with its CR: ``format_command("XTQ", -5, unit=1)`` -> ``"1_XTQ-5\\r"``."""
    if name not in COMMANDS:
        raise ValueError(f"unknown command {name!r}")
    if unit is not None and not 0 <= unit <= UNIT_MAX:
        raise ValueError(f"unit address {unit} not in 0..{UNIT_MAX}")
    prefix = f"{unit}_" if unit is not None else ""
    if value is None:
        v = ""
    elif isinstance(value, int):
        v = f"{value:+d}" if name == "XTQ" else str(value)
    else:
        if not math.isfinite(value):
            raise ValueError(f"value must be finite, got {value}")
        v = f"{value:.3f}"
    return f"{prefix}{'!' if immediate else ''}{name}{v}{COMMAND_END}"


# ---- replies -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Reply:
    """One parsed (non-error) reply: ``*[unit_]name[value]``; value is the raw text."""

    unit: int | None
    name: str
    value: str = ""

    def int_value(self) -> int:
        if not _INT_RE.fullmatch(self.value):
            raise MalformedReplyError(
                f"{self.name} reply {self.value!r} is not an integer", self.unit
            )
        return int(self.value)

    def float_value(self) -> float:
        if not _DECIMAL_RE.fullmatch(self.value):
            raise MalformedReplyError(
                f"{self.name} reply {self.value!r} is not a number", self.unit
            )
        return float(self.value)

    def hex_value(self) -> int:
        return parse_hex16(self.value)

    def xtq(self) -> tuple[int, int]:
        """(counts, statusword) of an XTQ reply."""
        return parse_xtq_value(self.value)

    def statusword(self) -> int:
        """The CiA 402 statusword carried by a TAS reply (bits 17-32)."""
        return tas_to_statusword(self.value)


def format_reply(name: str, value: str = "", unit: int | None = None) -> str:
    """``*[unit_]NAMEvalue`` CR LF; ``value`` is already formatted (see the fmt_ helpers)."""
    prefix = f"{unit}_" if unit is not None else ""
    return f"*{prefix}{name}{value}{REPLY_END}"


def format_error(token: str, unit: int | None = None) -> str:
    if token not in ERROR_TOKENS:
        raise ValueError(f"unknown error token {token!r}")
    return format_reply(token, "", unit)


def parse_reply(line: str) -> Reply:
    """Parse one reply line (CR LF optional).

    Raises :class:`DriveReplyError` for an error reply and :class:`MalformedReplyError` for
    anything that is not a reply of this dialect; both are :class:`ProtocolError`.
    """
    text = line[:-2] if line.endswith(REPLY_END) else line.rstrip("\r\n")
    if not text.startswith("*"):
        raise MalformedReplyError(f"reply does not start with '*': {text[:40]!r}")
    if len(text) > MAX_LINE + 8 or not _PRINTABLE_RE.fullmatch(text):
        raise MalformedReplyError(f"reply too long or not printable ASCII: {text[:40]!r}")
    rest = text[1:]
    unit: int | None = None
    m = _UNIT_RE.match(rest)
    if m is not None:
        unit = int(m.group(1))
        if unit > UNIT_MAX:
            raise MalformedReplyError(f"unit address {unit} not in 0..{UNIT_MAX}: {text[:40]!r}")
        rest = rest[m.end() :]
    if rest in ERROR_TOKENS:
        raise DriveReplyError(rest, unit, text)
    for name in _NAMES_LONGEST_FIRST:
        if rest.startswith(name):
            return Reply(unit, name, rest[len(name) :])
    raise MalformedReplyError(f"not a reply of this dialect: {text[:40]!r}", unit)


# ---- value formats ---------------------------------------------------------------------------
def fmt_signed(value: int) -> str:
    """Integer with an explicit sign: ``+123``, ``-5``, ``+0`` (TPE, XTQ)."""
    return f"{int(value):+d}"


def fmt_fixed(value: float, decimals: int, signed: bool = True) -> str:
    """Fixed point: ``+1.2345`` (TVELA, 4), ``-12.400`` (TTRQ, 3), ``150.000`` (DMTLIM)."""
    if not math.isfinite(value):
        raise ValueError(f"value must be finite, got {value}")
    text = f"{value:+.{decimals}f}" if signed else f"{value:.{decimals}f}"
    if float(text) == 0.0:  # no "-0.0000"
        text = f"{0.0:+.{decimals}f}" if signed else f"{0.0:.{decimals}f}"
    return text


def fmt_hex16(value: int) -> str:
    """``0x8250``: ERROR codes and statuswords."""
    if not 0 <= value <= 0xFFFF:
        raise ValueError(f"{value} is not a 16-bit value")
    return f"0x{value:04X}"


_HEX16_RE = re.compile(r"0x[0-9A-Fa-f]{4}")


def parse_hex16(text: str) -> int:
    if not _HEX16_RE.fullmatch(text):
        raise MalformedReplyError(f"{text[:40]!r} is not 0x and 4 hex digits")
    return int(text[2:], 16)


def fmt_xtq(counts: int, statusword: int) -> str:
    """XTQ reply value: ``+123456,0x0637``."""
    return f"{fmt_signed(counts)},{fmt_hex16(statusword)}"


_XTQ_RE = re.compile(r"([+-][0-9]{1,10}),(0x[0-9A-Fa-f]{4})")


def parse_xtq_value(text: str) -> tuple[int, int]:
    m = _XTQ_RE.fullmatch(text)
    if m is None:
        raise MalformedReplyError(f"XTQ reply {text[:40]!r} is not <counts>,0x<statusword>")
    return int(m.group(1)), int(m.group(2)[2:], 16)


# TAS bit numbers (Gemini numbering, 1 = leftmost)
TAS_MOVING = 1
TAS_DIRECTION_NEGATIVE = 2
TAS_TORQUE_MODE = 9
TAS_TORQUE_LIMITED = 12
TAS_DRIVE_SHUT_DOWN = 13
TAS_DRIVE_FAULTED = 14
TAS_QUICK_STOP = 15
TAS_STATUSWORD_FIRST = 17  # bits 17..32: statusword bits 0..15

_TAS_RE = re.compile(r"[01]{4}(?:_[01]{4}){7}")


def statusword_to_tas(statusword: int, velocity_counts_s: int = 0, torque_mode: bool = True) -> str:
    """Render the TAS value (``0000_0000_..._0000``) of a drive (bit map in the module doc)."""
    if not 0 <= statusword <= 0xFFFF:
        raise ValueError(f"statusword {statusword} is not a 16-bit value")
    bits = [False] * 33  # index 1..32
    bits[TAS_MOVING] = velocity_counts_s != 0
    bits[TAS_DIRECTION_NEGATIVE] = velocity_counts_s < 0
    bits[TAS_TORQUE_MODE] = torque_mode
    bits[TAS_TORQUE_LIMITED] = bool(statusword & 0x0800)
    bits[TAS_DRIVE_SHUT_DOWN] = statusword & 0x6F != 0x27  # not OPERATION ENABLED
    bits[TAS_DRIVE_FAULTED] = statusword & 0x4F == 0x08  # FAULT
    bits[TAS_QUICK_STOP] = statusword & 0x6F == 0x07  # QUICK STOP ACTIVE
    for b in range(16):
        bits[TAS_STATUSWORD_FIRST + b] = bool(statusword >> b & 1)
    chars = "".join("1" if bits[i] else "0" for i in range(1, 33))
    return "_".join(chars[i : i + 4] for i in range(0, 32, 4))


def tas_bits(text: str) -> tuple[bool, ...]:
    """The 32 TAS bits, index 0 = bit 1; MalformedReplyError if ``text`` is not a TAS value."""
    if not _TAS_RE.fullmatch(text):
        raise MalformedReplyError(f"TAS value {text[:48]!r} is not 32 bits in groups of 4")
    return tuple(c == "1" for c in text.replace("_", ""))


def tas_bit(text: str, bit: int) -> bool:
    """One TAS bit by its Gemini number (1..32)."""
    if not 1 <= bit <= 32:
        raise ValueError(f"TAS bit {bit} not in 1..32")
    return tas_bits(text)[bit - 1]


def tas_to_statusword(text: str) -> int:
    """The CiA 402 statusword carried in TAS bits 17-32."""
    bits = tas_bits(text)
    return sum(1 << b for b in range(16) if bits[TAS_STATUSWORD_FIRST - 1 + b])
