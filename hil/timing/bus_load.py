"""CAN bus load of a run from its traffic log, the way ``canbusload`` (can-utils) reports it.

``bus.log`` (``candump -L`` lines, :mod:`drivers.candump`) holds every frame the host sent
(``T``) and received (``R``); with the host and the drives the only nodes, that is every frame on
the bus, once. Each frame's length on the wire is exact (stuffing of its own bits,
:func:`drivers.protocol.can_bits.frame_bits`); load = bits per interval / (interval × bitrate).
The window is the cyclic phase, whole cycles only: from the first SYNC (0x080) to the last, so
the set-up (NMT, SDO) and the shutdown do not dilute it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from drivers.protocol.can_bits import bus_load, frame_bits

SYNC_ID = 0x080
CAN_ERR_FLAG = 0x20000000


def read_candump(path: str | Path) -> tuple[list[float], list[int], list[int]]:
    """(timestamps, bits on the wire, CAN ids) of the classical data and remote frames of a
    ``candump -L`` file; error frames, CAN FD frames and malformed lines are skipped."""
    stamps: list[float] = []
    bits: list[int] = []
    ids: list[int] = []
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            parts = line.split()
            if len(parts) < 3 or not parts[0].startswith("("):
                continue
            id_text, sep, body = parts[2].partition("#")
            if not sep or body.startswith("#"):  # not a frame, or CAN FD
                continue
            try:
                stamp = float(parts[0][1:-1])
                can_id = int(id_text, 16)
                extended = len(id_text) > 3
                if can_id & CAN_ERR_FLAG:
                    continue
                if body[:1] in ("R", "r"):
                    dlc = int(body[1:]) if len(body) > 1 else 0
                    n_bits = frame_bits(can_id, b"", extended=extended, remote=True, dlc=dlc)
                else:
                    n_bits = frame_bits(can_id, bytes.fromhex(body), extended=extended)
            except ValueError:
                continue
            stamps.append(stamp)
            bits.append(n_bits)
            ids.append(can_id)
    return stamps, bits, ids


def cyclic_bus_load(
    path: str | Path, bitrate: int, period_s: float, interval_s: float = 1.0
) -> dict[str, Any]:
    """Bus load during the cyclic phase of a run: the cycles from the first SYNC to the last."""
    stamps, bits, ids = read_candump(path)
    syncs = [t for t, i in zip(stamps, ids, strict=True) if i == SYNC_ID]
    if len(syncs) < 2:
        return {"bitrate": bitrate, "frames": 0, "note": "fewer than 2 SYNCs: no cyclic phase"}
    lo, hi = min(syncs), max(syncs)
    kept = [(t, b) for t, b in zip(stamps, bits, strict=True) if lo <= t < hi]
    load = bus_load([t for t, _ in kept], [b for _, b in kept], bitrate, interval_s)
    cycles = len(syncs) - 1
    load["frames_per_cycle"] = len(kept) / cycles
    load["bits_per_cycle"] = sum(b for _, b in kept) / cycles
    # what the cycle's frames need of one period at this bitrate, whatever the host's timing
    load["cycle_load_pct"] = 100.0 * load["bits_per_cycle"] / (period_s * bitrate)
    load["source"] = str(path)
    return load


__all__ = [
    "cyclic_bus_load",
    "read_candump",
]
