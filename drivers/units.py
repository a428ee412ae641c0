"""Unit conversion between SI and drive units (counts, per-mille of rated torque, INT32 wrap).

Experiments and estimators work in rad, rad/s and Nm; the drives speak counts and per-mille.
Everything that crosses that line goes through these functions, on both ends of the link.
"""

from __future__ import annotations

import math

import numpy as np

INT16_MIN, INT16_MAX = -(2**15), 2**15 - 1
INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1


def wrap_int32(value: int) -> int:
    """Two's-complement wrap of an integer to INT32 (what a 32-bit position register holds)."""
    return (value + 2**31) % 2**32 - 2**31


def unwrap_int32(previous_unwrapped: int, raw: int) -> int:
    """Continue an unbounded count from an INT32 reading, assuming |change| < 2³¹ per sample."""
    # wrap_int32 twice, inline: every joint's reading goes through here once a period
    previous_raw = (previous_unwrapped + 2**31) % 2**32 - 2**31
    return previous_unwrapped + (raw - previous_raw + 2**31) % 2**32 - 2**31


def counts_to_rad(counts: int, counts_per_rev: int) -> float:
    """A number of counts in rad: a velocity (0x606C, counts/s) or a difference of positions."""
    return counts * (2.0 * math.pi / counts_per_rev)


def position_to_rad(counts: int, counts_per_rev: int) -> float:
    """The angle of a position reading 0x6064: the centre of its count's cell.

    An encoder counts edges, so count n means the angle lies in [n, n + 1) counts from its zero
    (the drive floors, docs/virtual-robot.md "Encoder"). The centre, n + ½ counts, is the
    reading without bias; n itself would be ½ count low on average.
    """
    return (counts + 0.5) * (2.0 * math.pi / counts_per_rev)


def torque_to_permille(torque_Nm: float, rated_torque_Nm: float) -> int:
    """0x6071 target torque: nearest per-mille of rated torque, clamped to INT16."""
    if not math.isfinite(torque_Nm):
        raise ValueError(f"torque must be finite, got {torque_Nm}")
    value = round(torque_Nm * 1000.0 / rated_torque_Nm)
    return INT16_MAX if value > INT16_MAX else INT16_MIN if value < INT16_MIN else value


def torques_to_permille(torque_Nm: np.ndarray, rated_torque_Nm: float) -> np.ndarray:
    """:func:`torque_to_permille` of every element (int64; the same arithmetic: round half to
    even, INT16 clamp); the elements must be finite."""
    value = np.rint(np.asarray(torque_Nm, dtype=float) * 1000.0 / rated_torque_Nm)
    return np.clip(value, INT16_MIN, INT16_MAX).astype(np.int64)


def permille_to_torque(permille: int, rated_torque_Nm: float) -> float:
    return permille * rated_torque_Nm / 1000.0
