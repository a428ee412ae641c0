"""mjbots moteus register protocol (docs/reference.md of github.com/mjbots/moteus, "A. Protocol"
and "A.2b Registers") and the fdcanusb's serial line protocol
(docs/reference.md "fdcanusb"): pure functions, no port, no bus.

CAN-FD arbitration id (reference "A.1 CAN"): ``0x8000`` if a reply is wanted, source id in bits
8..14, destination id in bits 0..6 (0x7F broadcast); a reply's id is the drive's id << 8 | the
host's source id. The payload is a list of multiplex subframes (reference "A.1 Subframes"):

* write ``0x00 | type << 2 | n`` (n = 0: a varuint count follows), start register (varuint),
  n values of ``type`` (int8, int16, int32 little endian, float32);
* read ``0x10 | type << 2 | n``, start register; the reply ``0x20 | type << 2 | n``, start
  register, n values; ``0x30``/``0x31`` write/read error: register, error code (varuints);
* ``0x50``: nop (padding of a CAN-FD frame to its DLC).

Integer encodings are scaled per register (reference "A.2a Register Types" and the register
table): the most negative integer of each width is NaN.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator
from dataclasses import dataclass

from drivers.protocol.odrive import f32  # the one float32 rounding (F32 registers carry it)

INT8, INT16, INT32, F32 = 0, 1, 2, 3
WRITE_BASE, READ_BASE, REPLY_BASE = 0x00, 0x10, 0x20
WRITE_ERROR, READ_ERROR, NOP = 0x30, 0x31, 0x50
_FMT = ("<b", "<h", "<i", "<f")
_SIZE = (1, 2, 4, 4)
_NAN_INT = (-128, -32768, -2147483648)

# registers (reference "A.2b")
MODE = 0x000
POSITION = 0x001
VELOCITY = 0x002
TORQUE = 0x003
TRAJECTORY_COMPLETE = 0x00B
VOLTAGE = 0x00D
TEMPERATURE = 0x00E
FAULT = 0x00F
CMD_POSITION = 0x020
CMD_VELOCITY = 0x021
CMD_FEEDFORWARD = 0x022
CMD_KP_SCALE = 0x023
CMD_KD_SCALE = 0x024
CMD_MAX_TORQUE = 0x025
CMD_STOP_POSITION = 0x026
CMD_WATCHDOG = 0x027
CMD_VELOCITY_LIMIT = 0x028
CMD_ACCEL_LIMIT = 0x029
CMD_FIXED_VOLTAGE = 0x02A
CMD_ILIMIT_SCALE = 0x02B
CMD_FIXED_CURRENT = 0x02C
CMD_IGNORE_BOUNDS = 0x02D

# modes (register 0x000; reference "A.2b", register 0x000)
STOPPED, FAULT_MODE, POSITION_MODE, TIMEOUT_MODE = 0, 1, 10, 11
CURRENT_MODE, ZERO_VELOCITY_MODE, STAY_WITHIN_MODE, BRAKE_MODE = 9, 12, 13, 15
MODE_NAMES = (
    "stopped",
    "fault",
    "enabling",
    "calibrating",
    "calibration complete",
    "pwm",
    "voltage",
    "voltage foc",
    "voltage dq",
    "current",
    "position",
    "timeout",
    "zero velocity",
    "stay within",
    "measure inductance",
    "brake",
)

FAULT_NONE = 0  # register 0x00f: the emulation models no fault (docs/protocol.md)

# int8, int16, int32 scale of each kind of register (reference "A.2b", the mapping column)
_POS = (0.01, 0.0001, 0.00001)
_VEL = (0.1, 0.00025, 0.00001)
_TQ = (0.5, 0.01, 0.001)
_PWM = (1 / 127, 1 / 32767, 1 / 2147483647)
_VOLT = (0.5, 0.1, 0.001)
_TEMP = (1.0, 0.1, 0.001)
_TIME = (0.01, 0.001, 0.000001)
_ACCEL = (0.05, 0.001, 0.00001)
_CURRENT = (1.0, 0.1, 0.001)
_UNIT = (1.0, 1.0, 1.0)
SCALES: dict[int, tuple[float, float, float]] = {
    MODE: _UNIT,
    POSITION: _POS,
    VELOCITY: _VEL,
    TORQUE: _TQ,
    TRAJECTORY_COMPLETE: _UNIT,
    VOLTAGE: _VOLT,
    TEMPERATURE: _TEMP,
    FAULT: _UNIT,
    CMD_POSITION: _POS,
    CMD_VELOCITY: _VEL,
    CMD_FEEDFORWARD: _TQ,
    CMD_KP_SCALE: _PWM,
    CMD_KD_SCALE: _PWM,
    CMD_MAX_TORQUE: _TQ,
    CMD_STOP_POSITION: _POS,
    CMD_WATCHDOG: _TIME,
    CMD_VELOCITY_LIMIT: _VEL,
    CMD_ACCEL_LIMIT: _ACCEL,
    CMD_FIXED_VOLTAGE: _VOLT,
    CMD_ILIMIT_SCALE: _PWM,
    CMD_FIXED_CURRENT: _CURRENT,
    CMD_IGNORE_BOUNDS: _UNIT,
}
INTEGER_REGISTERS = frozenset({MODE, TRAJECTORY_COMPLETE, FAULT, CMD_IGNORE_BOUNDS})


class FrameError(ValueError):
    """A payload that is no valid multiplex frame."""


@dataclass(frozen=True)
class Subframe:
    kind: int  # WRITE_BASE, READ_BASE, REPLY_BASE, WRITE_ERROR or READ_ERROR
    register: int
    resolution: int
    value: float | int | None  # scaled (None for a read; an error's code)


# ---- CAN ids ---------------------------------------------------------------------------------
def split_id(arbitration_id: int) -> tuple[int, int, bool]:
    """(source, destination, reply wanted) of a host → drive arbitration id."""
    return (arbitration_id >> 8) & 0x7F, arbitration_id & 0x7F, bool(arbitration_id & 0x8000)


def reply_id(drive_id: int, host_id: int) -> int:
    return (drive_id & 0x7F) << 8 | (host_id & 0x7F)


# ---- values ------------------------------------------------------------------------------------
def _varuint(data: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    for k in range(5):
        if i + k >= len(data):
            raise FrameError("varuint runs past the end of the frame")
        b = data[i + k]
        value |= (b & 0x7F) << shift
        shift += 7
        if not b & 0x80:
            return value, i + k + 1
    raise FrameError("varuint longer than 5 bytes")


def _put_varuint(value: int) -> bytes:
    out = bytearray()
    while True:
        b = value & 0x7F
        value >>= 7
        out.append(b | (0x80 if value else 0))
        if not value:
            return bytes(out)


def scale_in(register: int, resolution: int, raw: float | int) -> float | int:
    """A register's wire value → its physical value (int NaN code → NaN)."""
    if resolution == F32:
        return float(raw)
    if register in INTEGER_REGISTERS:
        return int(raw)
    if raw == _NAN_INT[resolution]:
        return math.nan
    return raw * SCALES.get(register, _UNIT)[resolution]


def scale_out(register: int, resolution: int, value: float | int) -> float | int:
    """A physical value → the wire value of ``resolution`` (saturated; NaN → the NaN code)."""
    if resolution == F32:
        return float(value)
    if register in INTEGER_REGISTERS:
        return int(value)
    if not math.isfinite(value):
        return _NAN_INT[resolution]
    top = (127, 32767, 2147483647)[resolution]
    return int(max(-top, min(top, value / SCALES.get(register, _UNIT)[resolution])))


# ---- frames ------------------------------------------------------------------------------------
def parse(data: bytes) -> Iterator[Subframe]:
    """The register and error subframes of a payload; raises :class:`FrameError` on a
    truncated or unknown subframe (the firmware drops the rest of such a frame)."""
    i = 0
    while i < len(data):
        cmd = data[i]
        i += 1
        if cmd == NOP:
            continue
        if cmd in (WRITE_ERROR, READ_ERROR):
            register, i = _varuint(data, i)
            code, i = _varuint(data, i)
            yield Subframe(cmd, register, INT8, code)
            continue
        upper, res, n = cmd & 0xF0, (cmd >> 2) & 3, cmd & 3
        if upper not in (WRITE_BASE, READ_BASE, REPLY_BASE):
            raise FrameError(f"subframe 0x{cmd:02X} not handled")
        if n == 0:
            n, i = _varuint(data, i)
        register, i = _varuint(data, i)
        for k in range(n):
            if upper == READ_BASE:
                yield Subframe(READ_BASE, register + k, res, None)
                continue
            size = _SIZE[res]
            if i + size > len(data):
                raise FrameError(f"register 0x{register + k:03X}: value runs past the frame")
            (raw,) = struct.unpack_from(_FMT[res], data, i)
            i += size
            yield Subframe(upper, register + k, res, scale_in(register + k, res, raw))


def pack_registers(base: int, start: int, resolution: int, values: list[float | int]) -> bytes:
    """One write (``WRITE_BASE``) or reply (``REPLY_BASE``) subframe of consecutive registers."""
    n = len(values)
    head = bytes([base | resolution << 2 | (n if n <= 3 else 0)])
    if n > 3:
        head += _put_varuint(n)
    body = b"".join(
        struct.pack(_FMT[resolution], scale_out(start + k, resolution, v))
        for k, v in enumerate(values)
    )
    return head + _put_varuint(start) + body


def pack_read(start: int, resolution: int, n: int) -> bytes:
    head = bytes([READ_BASE | resolution << 2 | (n if n <= 3 else 0)])
    return head + (_put_varuint(n) if n > 3 else b"") + _put_varuint(start)


def pack_error(read: bool, register: int, code: int) -> bytes:
    return (
        bytes([READ_ERROR if read else WRITE_ERROR]) + _put_varuint(register) + _put_varuint(code)
    )


# ---- fdcanusb line protocol ----------------------------------------------------------------------
_CRC8 = (
    0x00,
    0x97,
    0xB9,
    0x2E,
    0xE5,
    0x72,
    0x5C,
    0xCB,
    0x5D,
    0xCA,
    0xE4,
    0x73,
    0xB8,
    0x2F,
    0x01,
    0x96,
)
FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


def crc8(data: bytes) -> int:
    """CRC-8, polynomial 0x97, a nybble at a time (the fdcanusb / moteus UART line checksum)."""
    crc = 0
    for b in data:
        crc = _CRC8[((crc >> 4) ^ (b >> 4)) & 0xF] ^ ((crc << 4) & 0xFF)
        crc = _CRC8[((crc >> 4) ^ (b & 0xF)) & 0xF] ^ ((crc << 4) & 0xFF)
    return crc


def strip_checksum(line: bytes) -> tuple[bytes, bool | None]:
    """(line without a trailing `` *XX``, whether it was right; None when there was none)."""
    star = line.rfind(b"*")
    if star < 0 or star + 3 != len(line):
        return line, None
    try:
        claimed = int(line[star + 1 :], 16)
    except ValueError:
        return line, None
    return line[:star].rstrip(b" "), crc8(line[:star]) == claimed


def add_checksum(line: bytes) -> bytes:
    return line + b" *" + f"{crc8(line + b' '):02X}".encode()


@dataclass(frozen=True)
class FdLine:
    arbitration_id: int
    data: bytes
    brs: bool
    fd: bool


def parse_can_send(fields: list[bytes]) -> FdLine:
    """``can send <hex id> <hex data> [flags]`` (fields after ``can send``)."""
    if len(fields) < 2:
        raise FrameError("can send needs an id and data")
    try:
        arb = int(fields[0], 16)
        data = bytes.fromhex(fields[1].decode("ascii"))
    except ValueError as exc:
        raise FrameError(f"can send: {exc}") from None
    if arb > 0x1FFFFFFF or len(data) > 64:
        raise FrameError("can send: id beyond 29 bits or more than 64 bytes")
    flags = b"".join(fields[2:])
    return FdLine(arb, data, b"B" in flags, b"F" in flags or len(data) > 8)


def format_rcv(arbitration_id: int, data: bytes) -> bytes:
    """``rcv <id> <data> E B F`` (extended id, bit rate switch, FD: what moteus replies carry)."""
    return f"rcv {arbitration_id:x} {data.hex().upper()} E B F".encode()


def pad_fd(data: bytes) -> bytes:
    """Pad to the next CAN-FD length with nop subframes (0x50), as the firmware does."""
    size = next(n for n in FD_LENGTHS if n >= len(data))
    return data + bytes([NOP]) * (size - len(data))


__all__ = [
    "F32",
    "FD_LENGTHS",
    "INT8",
    "INT16",
    "INT32",
    "FdLine",
    "FrameError",
    "Subframe",
    "add_checksum",
    "crc8",
    "f32",
    "format_rcv",
    "pack_error",
    "pack_read",
    "pack_registers",
    "pad_fd",
    "parse",
    "parse_can_send",
    "reply_id",
    "scale_in",
    "scale_out",
    "split_id",
    "strip_checksum",
]
