"""ODrive CANSimple (firmware 0.6.x): the frames an emulated axis and a host exchange, as data.

docs/protocol.md ("CAN: ODrive CANSimple") is the prose version. Sources: the ODrive
documentation "CAN Protocol" (CANSimple, docs.odriverobotics.com/v/latest/manual/can-protocol)
and the DBC file the odrive-can client ships (odrive-cansimple-0.6.10.dbc); both agree on every
layout used here. Standard 11-bit identifiers: ``can_id = node_id << 5 | cmd_id`` (node id 6
bits, command 5 bits). All fields little-endian; floats IEEE-754 single precision.

* 0x01 Heartbeat (axis → host, cyclic): ``Axis_Error u32 | Axis_State u8 |
  Procedure_Result u8 | Trajectory_Done_Flag (bit 0) u8 | reserved u8``;
* 0x02 Estop (host → axis, 0 bytes): axis to IDLE with the error ESTOP_REQUESTED;
* 0x07 Set_Axis_State: ``Axis_Requested_State u32``;
* 0x09 Get_Encoder_Estimates (axis → host, cyclic or on an RTR request):
  ``Pos_Estimate f32 (rev) | Vel_Estimate f32 (rev/s)``;
* 0x0B Set_Controller_Mode: ``Control_Mode u32 | Input_Mode u32``;
* 0x0E Set_Input_Torque: ``Input_Torque f32 (Nm)``;
* 0x16 Reboot: ``Action u8`` (0 reboot; 0.6.10's DBC, 1 byte);
* 0x18 Clear_Errors: ``Identify u8``.

Pure functions and data: no bus, no clock.
"""

from __future__ import annotations

import struct

# command ids (the low 5 bits of the CAN id)
HEARTBEAT = 0x01
ESTOP = 0x02
GET_ERROR = 0x03
SET_AXIS_STATE = 0x07
GET_ENCODER_ESTIMATES = 0x09
SET_CONTROLLER_MODE = 0x0B
SET_INPUT_POS = 0x0C
SET_INPUT_VEL = 0x0D
SET_INPUT_TORQUE = 0x0E
REBOOT = 0x16
CLEAR_ERRORS = 0x18

# Axis_State (ODrive enums AxisState)
IDLE = 1
CLOSED_LOOP_CONTROL = 8
# Control_Mode / Input_Mode (ControlMode, InputMode)
TORQUE_CONTROL = 1
POSITION_CONTROL = 3
PASSTHROUGH = 1
# Axis_Error bits (ODriveError, firmware 0.6)
ERROR_NONE = 0
SYSTEM_LEVEL = 0x02
BAD_CONFIG = 0x10
WATCHDOG_TIMER_EXPIRED = 0x0100_0000
ESTOP_REQUESTED = 0x0200_0000
# Procedure_Result
SUCCESS = 0
INVALID_STATE = 13

NODE_BITS = 6
CMD_BITS = 5


def can_id(node_id: int, cmd_id: int) -> int:
    """``node_id << 5 | cmd_id`` (CANSimple's arbitration id)."""
    if not (0 <= node_id < 1 << NODE_BITS and 0 <= cmd_id < 1 << CMD_BITS):
        raise ValueError(f"node id {node_id} or command {cmd_id} out of range (6 and 5 bits)")
    return node_id << CMD_BITS | cmd_id


def split_id(arbitration_id: int) -> tuple[int, int]:
    """(node_id, cmd_id) of an 11-bit arbitration id."""
    return arbitration_id >> CMD_BITS, arbitration_id & ((1 << CMD_BITS) - 1)


def pack_heartbeat(
    axis_error: int, axis_state: int, procedure_result: int = SUCCESS, traj_done: bool = True
) -> bytes:
    return struct.pack("<IBBBx", axis_error, axis_state, procedure_result, int(traj_done))


def unpack_heartbeat(data: bytes) -> tuple[int, int, int, bool]:
    error, state, result, flags = struct.unpack("<IBBBx", data)
    return error, state, result, bool(flags & 1)


def pack_encoder_estimates(pos_rev: float, vel_rev_s: float) -> bytes:
    return struct.pack("<ff", pos_rev, vel_rev_s)


def unpack_encoder_estimates(data: bytes) -> tuple[float, float]:
    pos, vel = struct.unpack("<ff", data)
    return pos, vel


def pack_u32(value: int) -> bytes:
    """Set_Axis_State's payload (the u32 in the first 4 of 8 bytes)."""
    return struct.pack("<I4x", value)


def unpack_u32(data: bytes) -> int:
    return struct.unpack_from("<I", data)[0]


def pack_controller_mode(control_mode: int, input_mode: int) -> bytes:
    return struct.pack("<II", control_mode, input_mode)


def unpack_controller_mode(data: bytes) -> tuple[int, int]:
    control, inp = struct.unpack("<II", data)
    return control, inp


def pack_input_torque(torque_Nm: float) -> bytes:
    return struct.pack("<f4x", torque_Nm)


def unpack_input_torque(data: bytes) -> float:
    return struct.unpack_from("<f", data)[0]


def f32(x: float) -> float:
    """``x`` rounded to the float32 the frames carry."""
    return struct.unpack("<f", struct.pack("<f", x))[0]


# the payload length each host → axis command must have (the DBC's; Estop has none)
COMMAND_LENGTH = {
    ESTOP: 0,
    SET_AXIS_STATE: 8,
    SET_CONTROLLER_MODE: 8,
    SET_INPUT_TORQUE: 8,
    REBOOT: 1,
    CLEAR_ERRORS: 1,
}

__all__ = [
    "BAD_CONFIG",
    "CLEAR_ERRORS",
    "CLOSED_LOOP_CONTROL",
    "COMMAND_LENGTH",
    "ERROR_NONE",
    "ESTOP",
    "ESTOP_REQUESTED",
    "GET_ENCODER_ESTIMATES",
    "GET_ERROR",
    "HEARTBEAT",
    "IDLE",
    "INVALID_STATE",
    "PASSTHROUGH",
    "POSITION_CONTROL",
    "REBOOT",
    "SET_AXIS_STATE",
    "SET_CONTROLLER_MODE",
    "SET_INPUT_POS",
    "SET_INPUT_TORQUE",
    "SET_INPUT_VEL",
    "SUCCESS",
    "SYSTEM_LEVEL",
    "TORQUE_CONTROL",
    "WATCHDOG_TIMER_EXPIRED",
    "can_id",
    "f32",
    "pack_controller_mode",
    "pack_encoder_estimates",
    "pack_heartbeat",
    "pack_input_torque",
    "pack_u32",
    "split_id",
    "unpack_controller_mode",
    "unpack_encoder_estimates",
    "unpack_heartbeat",
    "unpack_input_torque",
    "unpack_u32",
]
