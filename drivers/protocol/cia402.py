"""CiA 402 subset over CiA 301 framing: the object map as data, PDO layouts, SDO frames.

Both ends use this module: the virtual robot's CAN server to decode what the host sends and
encode its answers, the host driver to do the reverse. docs/protocol.md is the prose version.

COB-IDs (CiA 301 predefined connection set), node id n:
    NMT 0x000, SYNC 0x080, EMCY 0x080+n, TPDO1 0x180+n, RPDO1 0x200+n, TPDO2 0x280+n,
    SDO server→client 0x580+n, client→server 0x600+n, heartbeat 0x700+n.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass

# ---- COB-IDs -------------------------------------------------------------------------------
NMT_ID = 0x000
SYNC_ID = 0x080
EMCY_BASE = 0x080
TPDO1_BASE = 0x180
RPDO1_BASE = 0x200
TPDO2_BASE = 0x280
SDO_TX_BASE = 0x580  # server (drive) -> client (host)
SDO_RX_BASE = 0x600  # client -> server
HEARTBEAT_BASE = 0x700

# Frames only a host (the NMT master, SYNC producer and SDO client) sends, by function code
# (COB-ID >> 7) of the CiA 301 predefined connection set: RPDO1-4 (0x200, 0x300, 0x400,
# 0x500 + n) and SDO client→server (0x600 + n); NMT and SYNC are bus-wide
_HOST_FUNCTIONS = {4: "RPDO1", 6: "RPDO2", 8: "RPDO3", 10: "RPDO4", 12: "SDO request"}


def host_frame_name(cob_id: int) -> str | None:
    """What a frame only a host sends is ("SYNC", "NMT", "SDO request to node 3", ...), or
    None for a frame a drive (or anyone) sends: TPDOs, SDO answers, EMCY, heartbeats."""
    if cob_id == NMT_ID:
        return "NMT"
    if cob_id == SYNC_ID:
        return "SYNC"
    node, what = cob_id & 0x7F, _HOST_FUNCTIONS.get(cob_id >> 7)
    return f"{what} to node {node}" if what is not None and node > 0 else None


# The host's heartbeat (CiA 302: an NMT master produces a heartbeat on 0x700 + its node-ID): how
# two hosts on one bus settle which of them is its host before either sends set-up. 8 bytes:
# its state (claiming: pre-operational; holding the bus: operational), the tag b"ddb" (a
# device's heartbeat is 1 byte) and a random nonce. Of two claims the lower (node-ID, nonce)
# wins; a holding host answers any claim with its own heartbeat.
HOST_HEARTBEAT_TAG = b"ddb"


def host_heartbeat(holding: bool, nonce: bytes) -> bytes:
    """The data of the host's heartbeat (``nonce``: 4 bytes)."""
    state = NMT_STATE_OPERATIONAL if holding else NMT_STATE_PRE_OPERATIONAL
    return bytes([state]) + HOST_HEARTBEAT_TAG + nonce


def parse_host_heartbeat(data: bytes) -> tuple[bool, bytes] | None:
    """(holding, nonce) of a host's heartbeat, or None for any other frame (a device's)."""
    if len(data) != 8 or bytes(data[1:4]) != HOST_HEARTBEAT_TAG:
        return None
    return data[0] == NMT_STATE_OPERATIONAL, bytes(data[4:8])


# NMT command specifiers (CiA 301)
NMT_START = 0x01
NMT_STOP = 0x02
NMT_PRE_OPERATIONAL = 0x80
NMT_RESET_NODE = 0x81
NMT_RESET_COMMUNICATION = 0x82

# NMT states as sent in the heartbeat byte
NMT_STATE_BOOTUP = 0x00
NMT_STATE_STOPPED = 0x04
NMT_STATE_OPERATIONAL = 0x05
NMT_STATE_PRE_OPERATIONAL = 0x7F

# ---- CiA 402 --------------------------------------------------------------------------------
MODE_TQ = 4  # 0x6060 profile torque
MODE_CST = 10  # 0x6060 cyclic synchronous torque

CW_SHUTDOWN = 0x0006
CW_SWITCH_ON = 0x0007
CW_ENABLE_OPERATION = 0x000F
CW_DISABLE_OPERATION = 0x0007
CW_DISABLE_VOLTAGE = 0x0000
CW_QUICK_STOP = 0x0002
CW_FAULT_RESET = 0x0080  # bit 7, rising edge
CW_HALT = 0x0100  # bit 8

SW_INTERNAL_LIMIT = 0x0800  # bit 11: torque command clamped
SW_TARGET_REACHED = 0x0400  # bit 10
SW_FAULT = 0x0008  # bit 3

# error codes (0x603F and EMCY)
ERR_NONE = 0x0000
ERR_RPDO_TIMEOUT = 0x8250  # CiA 301: RPDO timeout (the command watchdog)
ERR_OVERSPEED = 0x8400  # CiA 402: velocity / speed controller
ERR_COMMUNICATION = 0x8100  # CiA 301: communication, generic (here: a second SYNC producer)

# 0x1001 error register bits (CiA 301)
ERREG_GENERIC = 0x01
ERREG_COMMUNICATION = 0x10
ERREG_DEVICE_PROFILE = 0x20

# SDO abort codes (CiA 301)
ABORT_TOGGLE = 0x05030000
ABORT_TIMEOUT = 0x05040000
ABORT_COMMAND = 0x05040001  # client/server command specifier not valid or unknown
ABORT_UNSUPPORTED_ACCESS = 0x06010000
ABORT_READ_ONLY = 0x06010002  # attempt to write a read-only object
ABORT_WRITE_ONLY = 0x06010001
ABORT_NO_OBJECT = 0x06020000  # object does not exist in the object dictionary
ABORT_NOT_MAPPABLE = 0x06040041
ABORT_PDO_LENGTH = 0x06040042
ABORT_LENGTH = 0x06070010  # data type does not match, length of service parameter does not match
ABORT_NO_SUBINDEX = 0x06090011
ABORT_VALUE_RANGE = 0x06090030
ABORT_VALUE_TOO_HIGH = 0x06090031
ABORT_VALUE_TOO_LOW = 0x06090032
ABORT_GENERAL = 0x08000000
ABORT_NOT_IN_STATE = 0x08000022  # cannot be transferred because of the present device state

ABORT_TEXT = {
    ABORT_TOGGLE: "toggle bit not alternated",
    ABORT_TIMEOUT: "SDO protocol timed out",
    ABORT_COMMAND: "command specifier not valid or unknown",
    ABORT_UNSUPPORTED_ACCESS: "unsupported access to an object",
    ABORT_READ_ONLY: "attempt to write a read only object",
    ABORT_WRITE_ONLY: "attempt to read a write only object",
    ABORT_NO_OBJECT: "object does not exist in the object dictionary",
    ABORT_NOT_MAPPABLE: "object cannot be mapped to the PDO",
    ABORT_PDO_LENGTH: "number and length of mapped objects would exceed PDO length",
    ABORT_LENGTH: "data type does not match, length of service parameter does not match",
    ABORT_NO_SUBINDEX: "sub-index does not exist",
    ABORT_VALUE_RANGE: "invalid value for parameter",
    ABORT_VALUE_TOO_HIGH: "value of parameter written too high",
    ABORT_VALUE_TOO_LOW: "value of parameter written too low",
    ABORT_GENERAL: "general error",
    ABORT_NOT_IN_STATE: "data cannot be transferred because of the present device state",
}


class State(enum.Enum):
    """CiA 402 power drive system state machine."""

    NOT_READY_TO_SWITCH_ON = enum.auto()
    SWITCH_ON_DISABLED = enum.auto()
    READY_TO_SWITCH_ON = enum.auto()
    SWITCHED_ON = enum.auto()
    OPERATION_ENABLED = enum.auto()
    QUICK_STOP_ACTIVE = enum.auto()
    FAULT_REACTION_ACTIVE = enum.auto()
    FAULT = enum.auto()


# CiA 402 statusword patterns: (mask, value) per state, bits 0-3, 5, 6.
SW_PATTERNS: tuple[tuple[int, int, State], ...] = (
    (0x4F, 0x00, State.NOT_READY_TO_SWITCH_ON),
    (0x4F, 0x40, State.SWITCH_ON_DISABLED),
    (0x6F, 0x21, State.READY_TO_SWITCH_ON),
    (0x6F, 0x23, State.SWITCHED_ON),
    (0x6F, 0x27, State.OPERATION_ENABLED),
    (0x6F, 0x07, State.QUICK_STOP_ACTIVE),
    (0x4F, 0x0F, State.FAULT_REACTION_ACTIVE),
    (0x4F, 0x08, State.FAULT),
)


def state_from_statusword(sw: int) -> State | None:
    """Decode a 0x6041 statusword into its CiA 402 state, or None if no pattern matches."""
    for mask, value, state in SW_PATTERNS:
        if sw & mask == value:
            return state
    return None


# ---- object dictionary as data ----------------------------------------------------------------
class Access(enum.Enum):
    RO = "ro"
    RW = "rw"
    WO = "wo"


@dataclass(frozen=True)
class Obj:
    """One object (index, subindex) of the drives' dictionary."""

    index: int
    subindex: int
    name: str
    fmt: str  # struct format, little-endian: "<H" UINT16, "<h" INT16, "<i" INT32, "<I", "<B"
    access: Access
    pdo: bool = False  # mappable

    @property
    def size(self) -> int:
        return struct.calcsize(self.fmt)

    def encode(self, value: int) -> bytes:
        return struct.pack(self.fmt, value)

    def decode(self, data: bytes) -> int:
        return struct.unpack(self.fmt, data)[0]

    def limits(self) -> tuple[int, int]:
        bits = self.size * 8
        if self.fmt[-1].islower():  # signed
            return -(2 ** (bits - 1)), 2 ** (bits - 1) - 1
        return 0, 2**bits - 1


RO, RW = Access.RO, Access.RW
# The objects as declared; OBJECTS below adds sub-index 0 of the records that do not declare it.
_DECLARED: tuple[Obj, ...] = (
    Obj(0x1000, 0, "device type", "<I", RO),
    Obj(0x1001, 0, "error register", "<B", RO),
    Obj(0x1017, 0, "producer heartbeat time ms", "<H", RW),
    Obj(0x1018, 1, "identity vendor id", "<I", RO),
    Obj(0x1018, 2, "identity product code", "<I", RO),
    Obj(0x1018, 3, "identity revision", "<I", RO),
    # PDO communication parameters: sub 1 COB-ID (bit 31 = invalid), sub 2 transmission type
    Obj(0x1400, 1, "RPDO1 COB-ID", "<I", RW),
    Obj(0x1400, 2, "RPDO1 transmission type", "<B", RW),
    Obj(0x1800, 1, "TPDO1 COB-ID", "<I", RW),
    Obj(0x1800, 2, "TPDO1 transmission type", "<B", RW),
    Obj(0x1801, 1, "TPDO2 COB-ID", "<I", RW),
    Obj(0x1801, 2, "TPDO2 transmission type", "<B", RW),
    # PDO mapping: sub 0 = number of entries, sub 1.. = (index << 16 | sub << 8 | bit length)
    *(Obj(0x1600, s, f"RPDO1 mapping {s}", "<B" if s == 0 else "<I", RW) for s in range(3)),
    *(Obj(0x1A00, s, f"TPDO1 mapping {s}", "<B" if s == 0 else "<I", RW) for s in range(3)),
    *(Obj(0x1A01, s, f"TPDO2 mapping {s}", "<B" if s == 0 else "<I", RW) for s in range(3)),
    Obj(0x603F, 0, "error code", "<H", RO),
    Obj(0x6040, 0, "controlword", "<H", RW, pdo=True),
    Obj(0x6041, 0, "statusword", "<H", RO, pdo=True),
    Obj(0x6060, 0, "modes of operation", "<b", RW),
    Obj(0x6061, 0, "modes of operation display", "<b", RO),
    Obj(0x6064, 0, "position actual value (counts)", "<i", RO, pdo=True),
    Obj(0x606C, 0, "velocity actual value (counts/s)", "<i", RO, pdo=True),
    Obj(0x6071, 0, "target torque (per mille of 0x6076)", "<h", RW, pdo=True),
    Obj(0x6072, 0, "max torque (per mille)", "<H", RW),
    Obj(0x6076, 0, "motor rated torque (mNm)", "<I", RO),
    Obj(0x6077, 0, "torque actual value (per mille)", "<h", RO, pdo=True),
    Obj(0x608F, 1, "position encoder increments", "<I", RO),
    Obj(0x608F, 2, "position encoder motor revolutions", "<I", RO),
)


def _record_entries(objects: tuple[Obj, ...]) -> dict[int, int]:
    """Index -> highest sub-index, of every record (an index with sub-indices above 0) that does
    not declare its sub-index 0. CiA 301: sub-index 0 of a record is its number of entries, a
    read-only UNSIGNED8 every device serves."""
    declared = {(o.index, o.subindex) for o in objects}
    highest: dict[int, int] = {}
    for o in objects:
        if o.subindex and (o.index, 0) not in declared:
            highest[o.index] = max(highest.get(o.index, 0), o.subindex)
    return highest


RECORD_ENTRIES: dict[int, int] = _record_entries(_DECLARED)  # 0x1018: 3, 0x1800: 2, ...
OBJECTS: tuple[Obj, ...] = tuple(
    sorted(
        (*_DECLARED, *(Obj(i, 0, "highest sub-index supported", "<B", RO) for i in RECORD_ENTRIES)),
        key=lambda o: (o.index, o.subindex),
    )
)
OBJECT_MAP: dict[tuple[int, int], Obj] = {(o.index, o.subindex): o for o in OBJECTS}
INDICES = frozenset(o.index for o in OBJECTS)


def lookup(index: int, subindex: int) -> Obj:
    """The object at (index, subindex); raises SdoAbortError if there is none."""
    obj = OBJECT_MAP.get((index, subindex))
    if obj is None:
        raise SdoAbortError(
            index, subindex, ABORT_NO_SUBINDEX if index in INDICES else ABORT_NO_OBJECT
        )
    return obj


def mapping_entry(index: int, subindex: int) -> int:
    """A PDO mapping entry value: index << 16 | subindex << 8 | length in bits."""
    return index << 16 | subindex << 8 | OBJECT_MAP[(index, subindex)].size * 8


# The PDO layout the host configures by SDO at start-up (docs/design.md), synchronous (type 1).
RPDO1_MAP = ((0x6040, 0), (0x6071, 0))  # controlword, target torque: 4 bytes
TPDO1_MAP = ((0x6041, 0), (0x6064, 0))  # statusword, position actual: 6 bytes
TPDO2_MAP = ((0x606C, 0), (0x6077, 0))  # velocity actual, torque actual: 6 bytes
TRANSMISSION_SYNC = 1  # synchronous, every SYNC

DEVICE_TYPE_SERVO = 0x00020192  # 0x1000: CiA 402 servo drive
IDENTITY_REVISION = 0x00010000  # 0x1018:3


def power_on_objects(
    node_id: int, vendor_id: int, product_code: int, rated_torque_Nm: float, counts_per_rev: int
) -> dict[tuple[int, int], int]:
    """A drive's stored objects at power-on (the EDS default values). PDOs start invalid and
    unmapped: the host must configure them."""
    store = {
        (0x1000, 0): DEVICE_TYPE_SERVO,
        (0x1017, 0): 0,
        (0x1018, 1): vendor_id,
        (0x1018, 2): product_code,
        (0x1018, 3): IDENTITY_REVISION,
        (0x1400, 1): 0x80000000 | (RPDO1_BASE + node_id),
        (0x1400, 2): TRANSMISSION_SYNC,
        (0x1800, 1): 0x80000000 | (TPDO1_BASE + node_id),
        (0x1800, 2): TRANSMISSION_SYNC,
        (0x1801, 1): 0x80000000 | (TPDO2_BASE + node_id),
        (0x1801, 2): TRANSMISSION_SYNC,
        (0x6076, 0): round(rated_torque_Nm * 1000),  # mNm
        (0x608F, 1): counts_per_rev,
        (0x608F, 2): 1,
    }
    for index, entries in RECORD_ENTRIES.items():  # constants, read-only
        store[(index, 0)] = entries
    for m in (0x1600, 0x1A00, 0x1A01):
        store[(m, 0)] = 0
        store[(m, 1)] = 0
        store[(m, 2)] = 0
    return store


def pack_pdo(mapping: tuple[tuple[int, int], ...], values: tuple[int, ...]) -> bytes:
    return b"".join(OBJECT_MAP[m].encode(v) for m, v in zip(mapping, values, strict=True))


def unpack_pdo(mapping: tuple[tuple[int, int], ...], data: bytes) -> tuple[int, ...]:
    """Values of a PDO; raises ValueError if the length does not match the mapping."""
    size = sum(OBJECT_MAP[m].size for m in mapping)
    if len(data) != size:
        raise ValueError(f"PDO of {len(data)} bytes, mapping needs {size}")
    out, offset = [], 0
    for m in mapping:
        obj = OBJECT_MAP[m]
        out.append(obj.decode(bytes(data[offset : offset + obj.size])))
        offset += obj.size
    return tuple(out)


# ---- SDO (expedited transfers only: every object here is <= 4 bytes) -------------------------
class SdoAbortError(Exception):
    """An SDO transfer aborted with a CiA 301 abort code."""

    def __init__(self, index: int, subindex: int, code: int) -> None:
        self.index, self.subindex, self.code = index, subindex, code
        text = ABORT_TEXT.get(code, "unknown abort code")
        super().__init__(f"SDO abort 0x{code:08X} on 0x{index:04X}:{subindex}: {text}")


@dataclass(frozen=True)
class SdoRequest:
    """A decoded client→server SDO frame: an upload (read) or an expedited download (write)."""

    write: bool
    index: int
    subindex: int
    data: bytes = b""


def sdo_upload_request(index: int, subindex: int) -> bytes:
    return struct.pack("<BHB4x", 0x40, index, subindex)


def sdo_download_request(index: int, subindex: int, data: bytes) -> bytes:
    """Expedited download with size indicated (CiA 301 ccs = 1, e = 1, s = 1)."""
    if not 1 <= len(data) <= 4:
        raise ValueError("expedited SDO carries 1 to 4 bytes")
    cmd = 0x23 | (4 - len(data)) << 2
    return struct.pack("<BHB", cmd, index, subindex) + data.ljust(4, b"\0")


def decode_sdo_request(frame: bytes) -> SdoRequest:
    """Decode a client request; raises SdoAbortError (ABORT_COMMAND, ABORT_LENGTH) if malformed."""
    if len(frame) != 8:
        index, sub = _index_of(frame)
        raise SdoAbortError(index, sub, ABORT_LENGTH)
    cmd = frame[0]
    index, subindex = struct.unpack_from("<HB", frame, 1)
    ccs = cmd >> 5
    if ccs == 2:  # initiate upload
        return SdoRequest(False, index, subindex)
    if ccs == 1:  # initiate download
        expedited, size_given = bool(cmd & 0x02), bool(cmd & 0x01)
        if not expedited:
            raise SdoAbortError(index, subindex, ABORT_UNSUPPORTED_ACCESS)  # no segmented transfers
        n = 4 - (cmd >> 2 & 0x03) if size_given else 4
        return SdoRequest(True, index, subindex, bytes(frame[4 : 4 + n]))
    if ccs == 4:  # client abort
        raise SdoAbortError(index, subindex, struct.unpack_from("<I", frame, 4)[0])
    raise SdoAbortError(index, subindex, ABORT_COMMAND)


def _index_of(frame: bytes) -> tuple[int, int]:
    if len(frame) >= 4:
        return struct.unpack_from("<HB", frame, 1)
    return 0, 0


def sdo_upload_response(index: int, subindex: int, data: bytes) -> bytes:
    cmd = 0x43 | (4 - len(data)) << 2
    return struct.pack("<BHB", cmd, index, subindex) + data.ljust(4, b"\0")


def sdo_download_response(index: int, subindex: int) -> bytes:
    return struct.pack("<BHB4x", 0x60, index, subindex)


def sdo_abort(index: int, subindex: int, code: int) -> bytes:
    return struct.pack("<BHBI", 0x80, index, subindex, code)


def decode_sdo_response(frame: bytes, index: int, subindex: int) -> bytes:
    """Data of the server response to a request on (index, subindex); SdoAbortError on abort."""
    if len(frame) != 8:
        raise SdoAbortError(index, subindex, ABORT_LENGTH)
    cmd = frame[0]
    r_index, r_sub = struct.unpack_from("<HB", frame, 1)
    if cmd == 0x80:
        raise SdoAbortError(r_index, r_sub, struct.unpack_from("<I", frame, 4)[0])
    if (r_index, r_sub) != (index, subindex):
        raise SdoAbortError(index, subindex, ABORT_GENERAL)
    if cmd == 0x60:
        return b""
    if cmd >> 5 == 2 and cmd & 0x02:
        n = 4 - (cmd >> 2 & 0x03) if cmd & 0x01 else 4
        return bytes(frame[4 : 4 + n])
    raise SdoAbortError(index, subindex, ABORT_COMMAND)


# ---- EMCY, heartbeat ------------------------------------------------------------------------
def emcy_payload(error_code: int, error_register: int) -> bytes:
    """EMCY: error code (UINT16), error register (UINT8), 5 manufacturer bytes."""
    return struct.pack("<HB5x", error_code, error_register)


def decode_emcy(data: bytes) -> tuple[int, int]:
    if len(data) < 3:
        raise ValueError(f"EMCY of {len(data)} bytes, need at least 3")
    return struct.unpack_from("<HB", data, 0)
