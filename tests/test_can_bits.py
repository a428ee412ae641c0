"""Bits on the wire of CAN frames (stuffing of each actual frame), bus load, the bus pacer."""

from __future__ import annotations

import random

import pytest

from drivers.protocol.can_bits import (
    TAIL_BITS,
    bus_load,
    crc15,
    frame_bits,
    frame_bits_bounds,
    stuff_bit_count,
    stuffed_region,
)
from hil.timing.bus_load import cyclic_bus_load, read_candump
from profiles import ProfileError
from profiles.bench import load_bench
from virtual_robot.bus_pacing import BusPacer


def _bits_of(text: bytes) -> list[int]:
    return [(byte >> i) & 1 for byte in text for i in range(7, -1, -1)]


def test_crc15_check_value():
    # CRC-15/CAN of the ASCII bytes "123456789" is 0x059E (the CRC catalogue's check value)
    assert crc15(_bits_of(b"123456789")) == 0x059E


@pytest.mark.parametrize(
    ("bits", "stuffed"),
    [
        ("0000", 0),
        ("00000", 1),  # 00000[1]
        ("000001111", 2),  # 00000[1]1111[0]: the stuff bit starts the run of ones
        ("0000000000", 2),  # 00000[1]00000[1]
        ("0101010101", 0),
        ("1111100000", 2),  # 11111[0]0000[1]
    ],
)
def test_stuff_bits_of_hand_worked_sequences(bits, stuffed):
    assert stuff_bit_count([int(b) for b in bits]) == stuffed


def test_known_frame_lengths():
    # id 0, DLC 0: SOF..DLC are 19 zeros and the CRC of zeros is 0: 34 zeros, a stuff bit
    # after every 5 (6), + 13 bits of delimiters, ACK, EOF and intermission = 53
    assert stuffed_region(0, b"") == [0] * 34
    assert frame_bits(0, b"") == 34 + 6 + 13 == 53
    # an 8-byte standard frame: 111 bits unstuffed, at most 135 (the range)
    assert frame_bits_bounds(8) == (111, 135)
    assert frame_bits_bounds(0) == (47, 55)
    assert frame_bits_bounds(8, extended=True) == (131, 160)


def test_fast_count_equals_the_bit_by_bit_definition():
    rng = random.Random(7)
    for _ in range(3000):
        extended = rng.random() < 0.3
        remote = rng.random() < 0.1
        can_id = rng.randrange(0x20000000 if extended else 0x800)
        n = rng.randrange(9)
        data = bytes(rng.choice([0x00, 0xFF, 0x0F, rng.randrange(256)]) for _ in range(n))
        if remote:
            data = bytes(n)
        region = stuffed_region(can_id, data, extended=extended, remote=remote, dlc=n)
        expected = len(region) + stuff_bit_count(region) + TAIL_BITS
        got = frame_bits(can_id, b"" if remote else data, extended=extended, remote=remote, dlc=n)
        assert got == expected
        lo, hi = frame_bits_bounds(0 if remote else n, extended=extended)
        assert lo <= got <= hi


def test_bad_frames_are_refused():
    with pytest.raises(ValueError, match="11 bits"):
        frame_bits(0x800, b"")
    with pytest.raises(ValueError, match=r"0\.\.8"):
        frame_bits(0x100, bytes(9))


def test_bus_load_like_canbusload():
    # 1000 frames of 100 bits per second for 3 s on 1 Mbit/s: 10 % in every 1 s interval
    stamps = [k / 1000 for k in range(3000)]
    load = bus_load(stamps, [100] * 3000, 1_000_000)
    assert load["load_pct"] == pytest.approx(10.0, rel=1e-3)
    assert load["interval_load_pct"] == pytest.approx([10.0, 10.0, 10.0], rel=1e-3)
    assert load["frames_per_s"] == pytest.approx(1000, rel=1e-3)
    assert bus_load([], [], 500_000)["load_pct"] == 0.0


def test_cyclic_bus_load_of_a_candump_log(tmp_path):
    log = tmp_path / "bus.log"
    lines = ["(100.000000) can0 601#4000100000000000 T", "(100.000100) can0 581#4300100092010200 R"]
    for k in range(2000):  # 2 s at 1 kHz: RPDO x2, SYNC, TPDO x4 per cycle
        t = 101.0 + k * 1e-3
        lines += [
            f"({t:.6f}) can0 201#0F000000 T",
            f"({t:.6f}) can0 202#0F000000 T",
            f"({t + 1e-5:.6f}) can0 080# T",
            f"({t + 2e-4:.6f}) can0 181#3706FBFF0000 R",
            f"({t + 2e-4:.6f}) can0 281#000000000000 R",
            f"({t + 2e-4:.6f}) can0 182#3706000000FF R",
            f"({t + 2e-4:.6f}) can0 282#00000000FFFF R",
        ]
    log.write_text("\n".join(lines) + "\n")
    stamps, bits, ids = read_candump(log)
    assert len(stamps) == 2 + 7 * 2000 and ids[4] == 0x080 and bits[4] == frame_bits(0x80, b"")
    load = cyclic_bus_load(log, 1_000_000, 1e-3)
    per_cycle = (
        frame_bits(0x201, bytes.fromhex("0F000000"))
        + frame_bits(0x202, bytes.fromhex("0F000000"))
        + frame_bits(0x80, b"")
        + frame_bits(0x181, bytes.fromhex("3706FBFF0000"))
        + frame_bits(0x281, bytes(6))
        + frame_bits(0x182, bytes.fromhex("3706000000FF"))
        + frame_bits(0x282, bytes.fromhex("00000000FFFF"))
    )
    assert load["frames_per_cycle"] == pytest.approx(7.0)
    assert load["bits_per_cycle"] == pytest.approx(per_cycle)
    # bits per ms / 1000 bits per ms, over the 1999 whole cycles (the span ends at the last
    # frame's end, a few µs short of 1999 ms)
    assert load["load_pct"] == pytest.approx(per_cycle / 10, rel=2e-3)
    assert len(load["interval_load_pct"]) == 2  # the SDO set-up before the first SYNC is out


class SimClock:
    def __init__(self) -> None:
        self.t = 50.0

    def clock(self) -> float:
        return self.t

    def sleep(self, d: float) -> None:
        self.t += d

    def spin(self) -> float:  # a clock read in the spin loop moves time a little
        self.t += 1e-6
        return self.t


def test_pacer_serializes_frames_at_the_bit_time():
    sim = SimClock()
    pacer = BusPacer(1_000_000, clock=sim.spin, sleep=sim.sleep)
    tpdos = [(0x181, bytes(6), False, False), (0x281, bytes(6), False, False)]
    bits = sum(frame_bits(i, d) for i, d, _, _ in tpdos)
    end = pacer.occupy(tpdos, offered_at=50.0)
    assert end == pytest.approx(50.0 + bits * 1e-6)
    # a SYNC offered while they are still on the bus waits for them
    sync_end = pacer.occupy([(0x080, b"", False, False)], offered_at=50.0001)
    assert sync_end == pytest.approx(end + frame_bits(0x80, b"") * 1e-6)
    # delays: the second TPDO behind the first, the SYNC behind both
    first = frame_bits(0x181, bytes(6)) * 1e-6
    assert pacer.counters.delayed_s == pytest.approx(first + end - 50.0001)
    # pace(): returns when the frames have been transmitted
    sim.t = 60.0
    pacer.pace([(0x201, bytes(4), False, False)])
    assert sim.t >= 60.0 + frame_bits(0x201, bytes(4)) * 1e-6
    assert pacer.counters.frames == 4


def test_pace_bus_needs_a_virtual_can_bench(tmp_path):
    text = """
name = "x"
virtual = true
protocol = "serial"
transport = "serial"
pace_bus = true
[limits]
torque_Nm = [1.0, 1.0]
velocity_rad_s = [1.0, 1.0]
position_rad = [[-1.0, 1.0], [-1.0, 1.0]]
"""
    path = tmp_path / "b.toml"
    path.write_text(text)
    with pytest.raises(ProfileError, match=r"pace_bus.*protocol = 'can'"):
        load_bench(path)
    path.write_text(text.replace('"serial"', '"can"', 1).replace('"serial"', '"slcan"'))
    assert load_bench(path).pace_bus
    path.write_text(text.replace("pace_bus = true", 'pace_bus = "yes"'))
    with pytest.raises(ProfileError, match="true or false"):
        load_bench(path)
