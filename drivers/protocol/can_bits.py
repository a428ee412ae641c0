"""Bits on the wire of classical CAN frames, with the bit stuffing of each actual frame.

ISO 11898-1 classical frame, as the bus carries it:

* standard (11-bit id): SOF, id (11), RTR, IDE, r0, DLC (4), data (8·n), CRC (15) — the
  34 + 8·n bits that are *stuffed* — then CRC delimiter, ACK slot, ACK delimiter, EOF (7)
  and the 3-bit intermission: 13 fixed-form bits. Unstuffed: 47 + 8·n bits (111 for n = 8).
* extended (29-bit id): SOF, base id (11), SRR, IDE, id extension (18), RTR, r1, r0, DLC,
  data, CRC: 54 + 8·n stuffed bits, + 13: 67 + 8·n bits unstuffed.

Bit stuffing: after five consecutive bits of the same level the transmitter inserts one bit of
the opposite level, which itself starts the next run (stuff bits count). At most one stuff bit
per four stuffed bits after the first: 8·n + 47 + ⌊(34 + 8·n − 1)/4⌋ bits for a standard frame
(Davis, Burns, Bril & Lukkien, "Controller Area Network (CAN) schedulability analysis",
Real-Time Systems 35, 2007, eq. (3)): 135 bits for 8 data bytes, hence the 111–135 range.

The CRC is CRC-15/CAN (polynomial x¹⁵+x¹⁴+x¹⁰+x⁸+x⁷+x⁴+x³+1 = 0x4599, initial value 0) over
SOF … data, most significant bit first. Remote frames carry no data field but keep their DLC.

Pure functions, no clocks; :func:`bus_load` does what ``canbusload`` (can-utils) does with the
exact lengths: bits seen per interval divided by interval × bitrate.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

CRC15_POLY = 0x4599
INTERMISSION_BITS = 3
TAIL_BITS = 1 + 1 + 1 + 7 + INTERMISSION_BITS  # CRC delim, ACK slot, ACK delim, EOF, IFS
STUFF_RUN = 5


def _bits(value: int, width: int) -> list[int]:
    """``value`` as ``width`` bits, most significant first."""
    return [(value >> i) & 1 for i in range(width - 1, -1, -1)]


def crc15(bits: Iterable[int]) -> int:
    """CRC-15/CAN of a bit sequence (ISO 11898-1 §10.4.2.6; 0x4599, init 0, no reflection)."""
    crc = 0
    for bit in bits:
        feedback = bit ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if feedback:
            crc ^= CRC15_POLY
    return crc


def _stuff_step(level: int, run: int, bit: int) -> tuple[int, int, int]:
    """The bit stuffing rule (ISO 11898-1 §10.5): after ``bit`` on a run of ``run`` bits at
    ``level``, the run's (level, length) and the stuff bits inserted (0 or 1): one after every
    run of five equal levels, and the inserted bit, of the opposite level, starts the next run."""
    level, run = (level, run + 1) if bit == level else (bit, 1)
    if run == STUFF_RUN:
        return 1 - bit, 1, 1
    return level, run, 0


def stuff_bit_count(bits: Sequence[int]) -> int:
    """Stuff bits a transmitter inserts into ``bits`` (:func:`_stuff_step` bit by bit)."""
    level, run, count = -1, 0, 0
    for bit in bits:
        level, run, stuffed = _stuff_step(level, run, bit)
        count += stuffed
    return count


def _checked_head(
    can_id: int, data: bytes, extended: bool, remote: bool, dlc: int | None
) -> tuple[int, int]:
    """(DLC, RTR bit) of a classical CAN frame, or a ValueError saying what does not fit."""
    n = len(data) if dlc is None else dlc
    if not 0 <= n <= 8 or (not remote and len(data) != n):
        raise ValueError(f"a classical CAN frame has 0..8 data bytes and a matching DLC, got {n}")
    if extended and not 0 <= can_id <= 0x1FFFFFFF:
        raise ValueError(f"extended id 0x{can_id:X} beyond 29 bits")
    if not extended and not 0 <= can_id <= 0x7FF:
        raise ValueError(f"standard id 0x{can_id:X} beyond 11 bits")
    return n, 1 if remote else 0


def stuffed_region(
    can_id: int,
    data: bytes,
    *,
    extended: bool = False,
    remote: bool = False,
    dlc: int | None = None,
) -> list[int]:
    """The bits of a frame from SOF to the end of the CRC sequence, before stuffing."""
    n, rtr = _checked_head(can_id, data, extended, remote, dlc)
    if extended:
        head = [0, *_bits(can_id >> 18, 11), 1, 1, *_bits(can_id & 0x3FFFF, 18), rtr, 0, 0]
    else:
        head = [0, *_bits(can_id, 11), rtr, 0, 0]
    bits = head + _bits(n, 4)
    if not remote:
        for byte in data:
            bits += _bits(byte, 8)
    return bits + _bits(crc15(bits), 15)


def _crc15_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 7
        for _ in range(8):
            crc = ((crc << 1) ^ CRC15_POLY if crc & 0x4000 else crc << 1) & 0x7FFF
        table.append(crc)
    return tuple(table)


def _stuff_table() -> dict[tuple[int, int], tuple[tuple[int, int, int], ...]]:
    """(level, run) before a byte -> per byte value: (level, run, stuff bits) after it."""
    table = {}
    for level in (0, 1):
        for run in range(1, STUFF_RUN):
            row = []
            for byte in range(256):
                lv, rn, count = level, run, 0
                for i in range(7, -1, -1):
                    lv, rn, stuffed = _stuff_step(lv, rn, (byte >> i) & 1)
                    count += stuffed
                row.append((lv, rn, count))
            table[(level, run)] = tuple(row)
    return table


_CRC15_TABLE = _crc15_table()
_STUFF_TABLE = _stuff_table()


def frame_bits(
    can_id: int,
    data: bytes,
    *,
    extended: bool = False,
    remote: bool = False,
    dlc: int | None = None,
) -> int:
    """Bits this frame occupies on the bus, stuffing and the 3-bit intermission included.

    The same count as ``len(r) + stuff_bit_count(r) + TAIL_BITS`` for ``r =``
    :func:`stuffed_region` (tested), computed a byte at a time: a few µs per frame.
    """
    n, rtr = _checked_head(can_id, data, extended, remote, dlc)
    if extended:
        # SOF, base id, SRR, IDE, id extension, RTR, r1, r0, DLC: 39 bits (SOF = 0 leads)
        head = (can_id >> 18) << 27 | 3 << 25 | (can_id & 0x3FFFF) << 7 | rtr << 6 | n
        length = 39
    else:
        head = can_id << 7 | rtr << 6 | n  # SOF, id, RTR, IDE, r0, DLC: 19 bits
        length = 19
    if not remote and n:
        head = head << (8 * n) | int.from_bytes(data, "big")
        length += 8 * n
    # CRC-15 a byte at a time; leading zero bits do not change a CRC with initial value 0
    crc = 0
    for byte in head.to_bytes((length + 7) // 8, "big"):
        crc = ((crc << 8) & 0x7FFF) ^ _CRC15_TABLE[((crc >> 7) ^ byte) & 0xFF]
    region = head << 15 | crc
    length += 15
    # stuff bits: the first length % 8 bits one by one, then a byte at a time
    lead = length % 8
    level, run, count = -1, 0, 0
    for i in range(length - 1, length - 1 - lead, -1):
        level, run, stuffed = _stuff_step(level, run, (region >> i) & 1)
        count += stuffed
    rest = length - lead
    for byte in (region & ((1 << rest) - 1)).to_bytes(rest // 8, "big"):
        level, run, stuffed = _STUFF_TABLE[(level, run)][byte]
        count += stuffed
    return length + count + TAIL_BITS


def frame_bits_bounds(n_bytes: int, *, extended: bool = False) -> tuple[int, int]:
    """(no stuffing, worst-case stuffing) bits of a data frame with ``n_bytes`` bytes
    (Davis et al. 2007, eq. (3))."""
    stuffed = (54 if extended else 34) + 8 * n_bytes
    return stuffed + TAIL_BITS, stuffed + TAIL_BITS + (stuffed - 1) // 4


def bus_load(
    timestamps_s: Sequence[float],
    bits: Sequence[int],
    bitrate: int,
    interval_s: float = 1.0,
) -> dict[str, object]:
    """Bus load as ``canbusload`` reports it: bits seen per interval / (interval × bitrate).

    ``timestamps_s[i]`` and ``bits[i]`` are the time and the on-wire length of frame i. Returns
    the overall load (all bits over the span from the first frame to the last interval's end),
    the per-interval loads (intervals of ``interval_s`` from the first frame on; the last, partial
    one is scaled by its own length) and their maximum, in percent, with the frame rate.
    """
    if bitrate <= 0 or interval_s <= 0:
        raise ValueError("bitrate and interval_s must be > 0")
    if len(timestamps_s) != len(bits):
        raise ValueError(f"{len(timestamps_s)} timestamps but {len(bits)} lengths")
    if not len(bits):
        return {
            "bitrate": bitrate,
            "frames": 0,
            "bits": 0,
            "span_s": 0.0,
            "frames_per_s": 0.0,
            "load_pct": 0.0,
            "interval_s": interval_s,
            "interval_load_pct": [],
            "max_interval_load_pct": 0.0,
        }
    t0 = min(timestamps_s)
    # the span ends when the last frame has been transmitted (timestamps mark a frame's end or
    # start depending on the tool; one frame either way)
    last = max(range(len(bits)), key=timestamps_s.__getitem__)
    span = timestamps_s[last] - t0 + bits[last] / bitrate
    n_full = int(span // interval_s)
    per_interval = [0] * (n_full + 1)
    for t, b in zip(timestamps_s, bits, strict=True):
        per_interval[min(n_full, int((t - t0) // interval_s))] += b
    lengths = [interval_s] * n_full + [span - n_full * interval_s]
    # canbusload prints whole intervals; a last, partial one counts only if at least half long
    loads = [
        100.0 * b / (length * bitrate)
        for b, length in zip(per_interval, lengths, strict=True)
        if length >= 0.5 * interval_s
    ]
    total = sum(bits)
    load = 100.0 * total / (span * bitrate)
    return {
        "bitrate": bitrate,
        "frames": len(bits),
        "bits": total,
        "span_s": span,
        "frames_per_s": len(bits) / span,
        "load_pct": load,
        "interval_s": interval_s,
        "interval_load_pct": [round(x, 2) for x in loads],
        "max_interval_load_pct": max(loads) if loads else load,
    }
