"""The host's view of the drives' CANopen objects, pure (no bus, no threads): the canopen object
dictionary built from :data:`drivers.protocol.cia402.OBJECTS`, the PDO layout the host
configures, the precompiled PDO codecs of the cycle, and the decoding of received frames
(:func:`parse_frame`, fed random frames by the tests).

Imports: :mod:`drivers.protocol`, canopen.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from typing import NamedTuple

from canopen.objectdictionary import ObjectDictionary, ODRecord, ODVariable, datatypes

from drivers.protocol import cia402 as co

LOCKSTEP, REALTIME = "lockstep", "realtime"

FAULT_TEXT = {
    co.ERR_RPDO_TIMEOUT: "RPDO timeout (command watchdog)",
    co.ERR_OVERSPEED: "overspeed",
    co.ERR_COMMUNICATION: "communication error (a second SYNC producer on the bus?)",
}

_OD_TYPES = {
    "<B": datatypes.UNSIGNED8,
    "<H": datatypes.UNSIGNED16,
    "<I": datatypes.UNSIGNED32,
    "<b": datatypes.INTEGER8,
    "<h": datatypes.INTEGER16,
    "<i": datatypes.INTEGER32,
}

# (communication index, mapping index, COB-ID base, mapping) in configuration order
PDO_LAYOUT: tuple[tuple[int, int, int, tuple[tuple[int, int], ...]], ...] = (
    (0x1400, 0x1600, co.RPDO1_BASE, co.RPDO1_MAP),
    (0x1800, 0x1A00, co.TPDO1_BASE, co.TPDO1_MAP),
    (0x1801, 0x1A01, co.TPDO2_BASE, co.TPDO2_MAP),
)


# ---- object dictionary as data ------------------------------------------------------------------
def _od_variable(obj: co.Obj) -> ODVariable:
    var = ODVariable(obj.name, obj.index, obj.subindex)
    var.data_type = _OD_TYPES[obj.fmt]
    var.access_type = obj.access.value
    var.pdo_mappable = obj.pdo
    var.min, var.max = obj.limits()
    return var


def _record_name(objs: Sequence[co.Obj]) -> str:
    """The words the members' names share ("identity", "RPDO1 mapping"), else the index; the
    generic sub-index 0 ("highest sub-index supported") does not count."""
    named = [o for o in objs if o.subindex] or objs
    words = [o.name.split() for o in named]
    common: list[str] = []
    for column in zip(*words, strict=False):
        if any(w != column[0] for w in column):
            break
        common.append(column[0])
    return " ".join(common) or f"object 0x{objs[0].index:04X}"


def build_object_dictionary(objects: Sequence[co.Obj] = co.OBJECTS) -> ObjectDictionary:
    """A canopen ObjectDictionary from the drives' object map: variables and records."""
    od = ObjectDictionary()
    by_index: dict[int, list[co.Obj]] = {}
    for obj in objects:
        by_index.setdefault(obj.index, []).append(obj)
    for index, objs in sorted(by_index.items()):
        if len(objs) == 1 and objs[0].subindex == 0:
            od.add_object(_od_variable(objs[0]))
        else:
            record = ODRecord(_record_name(objs), index)
            for obj in objs:
                record.add_member(_od_variable(obj))
            od.add_object(record)
    return od


# ---- host-side frame parsing (pure; fed random frames by the tests) ------------------------------
class Frame(NamedTuple):
    """A frame of interest to the host, decoded."""

    kind: str  # "tpdo1" | "tpdo2" | "emcy" | "heartbeat"
    joint: int  # 0-based
    values: tuple[int, ...]  # tpdo1: (statusword, position counts); tpdo2: (velocity, torque ‰)
    # emcy: (error code, error register); heartbeat: (NMT state,)


TPDO1, TPDO2, EMCY, HEARTBEAT = "tpdo1", "tpdo2", "emcy", "heartbeat"


def frame_routes(node_ids: Sequence[int]) -> dict[int, tuple[str, int]]:
    """COB-ID → (kind, joint) for the frames the host consumes from these nodes."""
    routes: dict[int, tuple[str, int]] = {}
    for joint, n in enumerate(node_ids):
        routes[co.TPDO1_BASE + n] = (TPDO1, joint)
        routes[co.TPDO2_BASE + n] = (TPDO2, joint)
        routes[co.EMCY_BASE + n] = (EMCY, joint)
        routes[co.HEARTBEAT_BASE + n] = (HEARTBEAT, joint)
    return routes


def _pdo_codec(mapping: tuple[tuple[int, int], ...]) -> struct.Struct:
    """A whole PDO as one precompiled struct: the bytes of ``cia402.pack_pdo``/``unpack_pdo``."""
    return struct.Struct("<" + "".join(co.OBJECT_MAP[m].fmt[1:] for m in mapping))


RPDO1_CODEC = _pdo_codec(co.RPDO1_MAP)
TPDO_CODECS = {TPDO1: _pdo_codec(co.TPDO1_MAP), TPDO2: _pdo_codec(co.TPDO2_MAP)}


def parse_frame(
    routes: dict[int, tuple[str, int]],
    can_id: int,
    data: bytes | bytearray,
    *,
    is_extended_id: bool = False,
    is_remote_frame: bool = False,
    is_error_frame: bool = False,
) -> Frame | None:
    """Decode one received frame.

    Returns None for frames the host does not consume (other COB-IDs, extended ids, remote and
    error frames). Raises ValueError, and nothing else, for a consumed COB-ID whose payload does
    not fit (wrong PDO length, EMCY shorter than 3 bytes, empty heartbeat).
    """
    if is_extended_id or is_remote_frame or is_error_frame:
        return None
    route = routes.get(can_id)
    if route is None:
        return None
    kind, joint = route
    payload = bytes(data)
    codec = TPDO_CODECS.get(kind)
    if codec is not None:  # cia402.unpack_pdo with the mapping precompiled
        if len(payload) != codec.size:
            raise ValueError(f"PDO of {len(payload)} bytes, mapping needs {codec.size}")
        return Frame(kind, joint, codec.unpack(payload))
    if kind == EMCY:
        return Frame(kind, joint, co.decode_emcy(payload))
    if len(payload) < 1:
        raise ValueError("heartbeat of 0 bytes, need 1")
    return Frame(kind, joint, (payload[0] & 0x7F,))


def fault_text(code: int) -> str:
    return FAULT_TEXT.get(code, "drive fault")


def one_line(exc: BaseException) -> str:
    # python-can's socketcand puts the traceback into its error's text: keep the error
    text = " ".join(str(exc).split("Traceback (most recent call last)", 1)[0].split())
    return text or type(exc).__name__


__all__ = [
    "EMCY",
    "FAULT_TEXT",
    "HEARTBEAT",
    "LOCKSTEP",
    "PDO_LAYOUT",
    "REALTIME",
    "RPDO1_CODEC",
    "TPDO1",
    "TPDO2",
    "TPDO_CODECS",
    "Frame",
    "build_object_dictionary",
    "fault_text",
    "frame_routes",
    "one_line",
    "parse_frame",
]
