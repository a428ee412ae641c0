"""Effects profile: concealed physics switched on in the virtual robot (the host never sees it).

Each table of an effects profile names one effect of ``virtual_robot.effects``; its equation is
documented there and in docs/effects.md. Unknown table names are an error, not silently ignored.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from profiles.loader import Fields, load_toml
from profiles.timing_faults import TimingFaults, parse_timing_faults

Pair = tuple[float, float]


@dataclass(frozen=True)
class Stribeck:
    breakaway_ratio: Pair  # F_s / F_c per joint (>= 1)
    velocity_rad_s: Pair  # Stribeck velocity v_s
    exponent: float = 2.0  # δ


@dataclass(frozen=True)
class Cogging:
    periods_per_rev: Pair
    amplitude_Nm: Pair
    phase_rad: Pair = (0.0, 0.0)


@dataclass(frozen=True)
class Payload:
    mass_kg: float
    distance_m: float  # from joint 2 along link 2
    inertia_kgm2: float = 0.0  # about the payload's own centre


@dataclass(frozen=True)
class Coulomb:
    positive_Nm: Pair
    negative_Nm: Pair


@dataclass(frozen=True)
class EffectsProfile:
    name: str = "none"
    source: str = "<none>"
    description: str = ""
    stribeck: Stribeck | None = None
    cogging: Cogging | None = None
    amplifier_lag_s: Pair | None = None  # first-order lag time constant per joint
    transport_delay_s: float = 0.0  # command → shaft delay
    encoder_offset_rad: Pair = (0.0, 0.0)
    torque_gain_error: Pair = (0.0, 0.0)  # relative; applied = (1 + e) τ_cmd + offset
    torque_offset_Nm: Pair = (0.0, 0.0)
    payload: Payload | None = None
    coulomb: Coulomb | None = None  # replaces the robot profile's Coulomb levels
    velocity_squared_drag_Nms2: Pair | None = None  # τ_drag = −c q̇|q̇| per joint
    enabled: tuple[str, ...] = field(default_factory=tuple)
    timing_faults: TimingFaults | None = None  # robot side only (profiles/timing_faults.py)


EFFECT_NAMES = (
    "stribeck",
    "cogging",
    "amplifier_lag",
    "transport_delay",
    "encoder_offset",
    "torque_gain_error",
    "torque_offset",
    "payload",
    "coulomb",
    "velocity_squared_drag",
)


def parse_effects(data: dict, source: str) -> EffectsProfile:
    f = Fields(data, source)
    for key, value in data.items():
        if key in ("name", "description", "timing_faults"):
            continue
        if key not in EFFECT_NAMES:
            raise f.error(key, f"unknown effect; known effects: {', '.join(EFFECT_NAMES)}")
        if not isinstance(value, dict):
            raise f.error(key, "must be a table of the effect's parameters")
    kw: dict = {
        "name": f.string("name", Path(source).stem),
        "description": f.string("description", ""),
        "source": source,
    }
    if f.has("stribeck"):
        t = f.table("stribeck")
        t.only({"breakaway_ratio", "velocity_rad_s", "exponent"})
        kw["stribeck"] = Stribeck(
            t.numbers("breakaway_ratio", 2, lo=1.0),
            t.numbers("velocity_rad_s", 2, positive=True),
            t.number("exponent", 2.0, positive=True, hi=10.0),
        )
    if f.has("cogging"):
        t = f.table("cogging")
        t.only({"periods_per_rev", "amplitude_Nm", "phase_rad"})
        kw["cogging"] = Cogging(
            t.numbers("periods_per_rev", 2, lo=0.0),
            t.numbers("amplitude_Nm", 2, lo=0.0),
            t.numbers("phase_rad", 2, (0.0, 0.0)),
        )
    if f.has("amplifier_lag"):
        t = f.table("amplifier_lag")
        t.only({"time_constant_s"})
        kw["amplifier_lag_s"] = t.numbers("time_constant_s", 2, lo=0.0, hi=1.0)
    if f.has("transport_delay"):
        t = f.table("transport_delay")
        t.only({"delay_s"})
        kw["transport_delay_s"] = t.number("delay_s", lo=0.0, hi=1.0)
    if f.has("encoder_offset"):
        t = f.table("encoder_offset")
        t.only({"offset_rad"})
        kw["encoder_offset_rad"] = t.numbers("offset_rad", 2, lo=-3.2, hi=3.2)
    if f.has("torque_gain_error"):
        t = f.table("torque_gain_error")
        t.only({"relative"})
        kw["torque_gain_error"] = t.numbers("relative", 2, lo=-0.9, hi=10.0)
    if f.has("torque_offset"):
        t = f.table("torque_offset")
        t.only({"offset_Nm"})
        kw["torque_offset_Nm"] = t.numbers("offset_Nm", 2)
    if f.has("payload"):
        t = f.table("payload")
        t.only({"mass_kg", "distance_m", "inertia_kgm2"})
        kw["payload"] = Payload(
            t.number("mass_kg", lo=0.0),
            t.number("distance_m", lo=0.0),
            t.number("inertia_kgm2", 0.0, lo=0.0),
        )
    if f.has("coulomb"):
        t = f.table("coulomb")
        t.only({"positive_Nm", "negative_Nm"})
        kw["coulomb"] = Coulomb(
            t.numbers("positive_Nm", 2, lo=0.0), t.numbers("negative_Nm", 2, lo=0.0)
        )
    if f.has("velocity_squared_drag"):
        t = f.table("velocity_squared_drag")
        t.only({"coefficient_Nms2"})
        kw["velocity_squared_drag_Nms2"] = t.numbers("coefficient_Nms2", 2, lo=0.0)
    if f.has("timing_faults"):
        kw["timing_faults"] = parse_timing_faults(f.table("timing_faults"), host_allowed=False)
    kw["enabled"] = tuple(k for k in data if k in EFFECT_NAMES)
    return EffectsProfile(**kw)


def load_effects(name_or_path: str | Path | None) -> EffectsProfile:
    if name_or_path is None:
        return EffectsProfile()
    data, source = load_toml("effects", name_or_path)
    return parse_effects(data, source)


__all__ = [
    "EFFECT_NAMES",
    "Cogging",
    "Coulomb",
    "EffectsProfile",
    "Payload",
    "Stribeck",
    "load_effects",
    "parse_effects",
]
