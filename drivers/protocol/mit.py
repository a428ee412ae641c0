"""MIT mode ("Mini Cheetah" protocol) of T-Motor/CubeMars AK actuators: the CAN frames as data.

Both ends use this module: the virtual robot's MIT server to decode commands and encode its
replies, a host to do the reverse. docs/protocol.md ("CAN: MIT mode") is the prose version.

The protocol is Ben Katz's Mini Cheetah motor controller firmware (MIT Biomimetic Robotics Lab,
``CAN_com.cpp``), which T-Motor/CubeMars ship on the AK series as "MIT mode" (AK80-6 manual,
"MIT Mini Cheetah" mode). Standard 11-bit identifiers, 1 Mbit/s, big-endian bit fields:

* host → drive, id = the drive's CAN id, 8 bytes:
  ``p[15:8] | p[7:0] | v[11:4] | v[3:0] kp[11:8] | kp[7:0] | kd[11:4] | kd[3:0] t[11:8] | t[7:0]``
  with p 16 bits over [P_MIN, P_MAX], v 12 bits over [V_MIN, V_MAX], kp 12 bits over
  [0, KP_MAX], kd 12 bits over [0, KD_MAX] and the feed-forward torque t 12 bits over
  [T_MIN, T_MAX];
* the special commands, 8 bytes ``FF FF FF FF FF FF FF xx``: ``FC`` enter motor mode,
  ``FD`` exit motor mode, ``FE`` set the present position as zero;
* drive → host, id = the master id (0 on the Mini Cheetah firmware), 6 bytes:
  ``id | p[15:8] | p[7:0] | v[11:4] | v[3:0] t[11:8] | t[7:0]`` (newer CubeMars firmware sends
  8 bytes: the same 6 plus the MOSFET temperature in °C and an error code).

The firmware's scaling (``math_ops.c``): ``float_to_uint(x) = int((x - min) · (2^bits − 1) /
span)`` and ``uint_to_float(u) = u · span / (2^bits − 1) + min``. Every drive reply to any frame
addressed to it (a command, a special command) carries its state at that moment.

Pure functions and data: no bus, no clock.
"""

from __future__ import annotations

from dataclasses import dataclass

from profiles.drive import MitProfile

ENTER_MOTOR_MODE = bytes.fromhex("FFFFFFFFFFFFFFFC")
EXIT_MOTOR_MODE = bytes.fromhex("FFFFFFFFFFFFFFFD")
SET_ZERO = bytes.fromhex("FFFFFFFFFFFFFFFE")
SPECIAL = {ENTER_MOTOR_MODE: "enter", EXIT_MOTOR_MODE: "exit", SET_ZERO: "zero"}
MASTER_ID = 0x000  # the id a Mini Cheetah firmware replies with (CAN_MASTER)

# error byte of the 8-byte CubeMars reply (TMotorCANControl's table of the CubeMars manual)
ERROR_NONE = 0
ERROR_CODES = {
    0: "no error",
    1: "over temperature",
    2: "over current",
    3: "over voltage",
    4: "under voltage",
    5: "encoder fault",
    6: "phase current unbalance",
}


@dataclass(frozen=True)
class MitRanges:
    """The ranges the packed fields span; fixed in the drive's firmware, and the host must use
    the same (AK80-6 firmware V1.1: p ±12.5 rad, v ±22.5 rad/s, kp 0..500, kd 0..5, t ±12 Nm)."""

    p_max: float
    v_max: float
    kp_max: float
    kd_max: float
    t_max: float

    @classmethod
    def of(cls, mit: MitProfile) -> MitRanges:
        """The ranges of a drive profile's [mit] table."""
        return cls(mit.p_max, mit.v_max, mit.kp_max, mit.kd_max, mit.t_max)


@dataclass(frozen=True)
class MitCommand:
    """One decoded command, in the drive's units (rad, rad/s, Nm/rad, Nm s/rad, Nm)."""

    p_des: float
    v_des: float
    kp: float
    kd: float
    t_ff: float


def float_to_uint(x: float, lo: float, hi: float, bits: int) -> int:
    """The firmware's ``float_to_uint`` (math_ops.c), clamped to the field: a value outside
    [lo, hi] saturates instead of wrapping."""
    top = (1 << bits) - 1
    u = int((x - lo) * top / (hi - lo))
    return 0 if u < 0 else top if u > top else u


def uint_to_float(u: int, lo: float, hi: float, bits: int) -> float:
    """The firmware's ``uint_to_float`` (math_ops.c)."""
    return u * (hi - lo) / ((1 << bits) - 1) + lo


def pack_command(cmd: MitCommand, r: MitRanges) -> bytes:
    """The 8-byte command frame of ``cmd`` (each field saturated to its range)."""
    return pack_command_raw(
        float_to_uint(cmd.p_des, -r.p_max, r.p_max, 16),
        float_to_uint(cmd.v_des, -r.v_max, r.v_max, 12),
        float_to_uint(cmd.kp, 0.0, r.kp_max, 12),
        float_to_uint(cmd.kd, 0.0, r.kd_max, 12),
        float_to_uint(cmd.t_ff, -r.t_max, r.t_max, 12),
    )


def torque_toward_zero(t_ff: float, r: MitRanges) -> int:
    """The 12-bit τ field nearest ``t_ff`` on the side of zero: the firmware's scaling floors,
    which for a negative torque lands up to one step beyond it (a host limit would be
    exceeded); this takes the step back."""
    u = float_to_uint(t_ff, -r.t_max, r.t_max, 12)
    if t_ff < 0 and uint_to_float(u, -r.t_max, r.t_max, 12) < t_ff and u < 4095:
        u += 1
    return u


def pack_command_raw(p: int, v: int, kp: int, kd: int, t: int) -> bytes:
    """The 8-byte command frame of the unsigned fields (p 16 bits, the others 12)."""
    fields = (p >> 8, p & 0xFF, v >> 4, (v & 0xF) << 4 | kp >> 8, kp & 0xFF, kd >> 4)
    return bytes((*fields, (kd & 0xF) << 4 | t >> 8, t & 0xFF))


def unpack_command_raw(data: bytes) -> tuple[int, int, int, int, int]:
    """The five unsigned fields (p, v, kp, kd, t) of an 8-byte command frame."""
    if len(data) != 8:
        raise ValueError(f"an MIT command has 8 bytes, got {len(data)}")
    p = data[0] << 8 | data[1]
    v = data[2] << 4 | data[3] >> 4
    kp = (data[3] & 0xF) << 8 | data[4]
    kd = data[5] << 4 | data[6] >> 4
    t = (data[6] & 0xF) << 8 | data[7]
    return p, v, kp, kd, t


def unpack_command(data: bytes, r: MitRanges) -> MitCommand:
    """The command an 8-byte frame carries, scaled as the firmware does (CAN_com.cpp
    ``unpack_cmd``)."""
    p, v, kp, kd, t = unpack_command_raw(data)
    return MitCommand(
        uint_to_float(p, -r.p_max, r.p_max, 16),
        uint_to_float(v, -r.v_max, r.v_max, 12),
        uint_to_float(kp, 0.0, r.kp_max, 12),
        uint_to_float(kd, 0.0, r.kd_max, 12),
        uint_to_float(t, -r.t_max, r.t_max, 12),
    )


def pack_reply(
    drive_id: int,
    p: float,
    v: float,
    t: float,
    r: MitRanges,
    *,
    length: int = 6,
    temperature_C: int = 25,
    error: int = ERROR_NONE,
) -> bytes:
    """The drive's reply: id, p (16 bits), v (12), t (12); ``length`` 8 adds the CubeMars
    temperature and error bytes. Fields saturate at their range's ends."""
    pu = float_to_uint(p, -r.p_max, r.p_max, 16)
    vu = float_to_uint(v, -r.v_max, r.v_max, 12)
    tu = float_to_uint(t, -r.t_max, r.t_max, 12)
    head = bytes(
        (drive_id & 0xFF, pu >> 8, pu & 0xFF, vu >> 4, (vu & 0xF) << 4 | tu >> 8, tu & 0xFF)
    )
    if length == 6:
        return head
    if length != 8:
        raise ValueError(f"an MIT reply has 6 or 8 bytes, not {length}")
    return head + bytes((max(0, min(255, temperature_C)), error & 0xFF))


def unpack_reply(data: bytes, r: MitRanges) -> tuple[int, float, float, float]:
    """(drive id, p, v, t) of a 6- or 8-byte reply."""
    if len(data) not in (6, 8):
        raise ValueError(f"an MIT reply has 6 or 8 bytes, got {len(data)}")
    pu = data[1] << 8 | data[2]
    vu = data[3] << 4 | data[4] >> 4
    tu = (data[4] & 0xF) << 8 | data[5]
    return (
        data[0],
        uint_to_float(pu, -r.p_max, r.p_max, 16),
        uint_to_float(vu, -r.v_max, r.v_max, 12),
        uint_to_float(tu, -r.t_max, r.t_max, 12),
    )


__all__ = [
    "ENTER_MOTOR_MODE",
    "ERROR_CODES",
    "ERROR_NONE",
    "EXIT_MOTOR_MODE",
    "MASTER_ID",
    "SET_ZERO",
    "SPECIAL",
    "MitCommand",
    "MitRanges",
    "float_to_uint",
    "pack_command",
    "pack_command_raw",
    "pack_reply",
    "torque_toward_zero",
    "uint_to_float",
    "unpack_command",
    "unpack_command_raw",
    "unpack_reply",
]
