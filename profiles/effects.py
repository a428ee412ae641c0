"""Effects profile: concealed physics switched on in the virtual robot (the host never sees it).

Each table of an effects profile names one effect of ``virtual_robot.effects``; its equation is
documented there and in docs/effects.md. Unknown table names are an error, not silently ignored.

Per-joint values are given either as arrays with one entry per joint of the robot (``[a, b]``
for the 2-DOF arm, ``[a, b, c]`` for a 3-joint arm), or, in a table with ``joint = k``, as one
number for joint k alone (the other joints get no effect; for ``coulomb``, their robot
profile's levels). The profile does not know the robot: :meth:`EffectsProfile.for_joints` fits
it to one when the plant is built, and an array of the wrong length is a one-line error naming
the file and the key.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from profiles.loader import Fields, ProfileError, load_toml
from profiles.timing_faults import TimingFaults, parse_timing_faults

Pair = tuple[float, float]
PerJoint = tuple[float, ...]  # one value per joint once fitted (EffectsProfile.for_joints)


@dataclass(frozen=True)
class Stribeck:
    breakaway_ratio: PerJoint  # F_s / F_c per joint (>= 1)
    velocity_rad_s: PerJoint  # Stribeck velocity v_s
    exponent: float = 2.0  # δ


@dataclass(frozen=True)
class Cogging:
    periods_per_rev: PerJoint
    amplitude_Nm: PerJoint
    phase_rad: PerJoint = ()  # () = zero on every joint


@dataclass(frozen=True)
class Payload:
    mass_kg: float
    distance_m: float  # from joint 2 along link 2
    inertia_kgm2: float = 0.0  # about the payload's own centre


@dataclass(frozen=True)
class Coulomb:
    positive_Nm: tuple[float | None, ...]  # None: the robot profile's level on that joint
    negative_Nm: tuple[float | None, ...]


@dataclass(frozen=True)
class EffectsProfile:
    name: str = "none"
    source: str = "<none>"
    description: str = ""
    stribeck: Stribeck | None = None
    cogging: Cogging | None = None
    amplifier_lag_s: PerJoint | None = None  # first-order lag time constant per joint
    transport_delay_s: float = 0.0  # command → shaft delay (every joint)
    encoder_offset_rad: PerJoint = ()  # () = zero on every joint
    torque_gain_error: PerJoint = ()  # relative; applied = (1 + e) τ_cmd + offset
    torque_offset_Nm: PerJoint = ()
    payload: Payload | None = None
    coulomb: Coulomb | None = None  # replaces the robot profile's Coulomb levels
    velocity_squared_drag_Nms2: PerJoint | None = None  # τ_drag = −c q̇|q̇| per joint
    enabled: tuple[str, ...] = field(default_factory=tuple)
    timing_faults: TimingFaults | None = None  # robot side only (profiles/timing_faults.py)
    # tables written for one joint (``joint = k``, 1-based): their values are 1-tuples
    joint_of: tuple[tuple[str, int], ...] = ()

    def for_joints(self, n_joints: int, robot: str) -> EffectsProfile:
        """This profile on a robot of ``n_joints`` joints: every per-joint value a tuple of
        ``n_joints`` (a ``joint = k`` table spread over the joints with no effect elsewhere,
        unset values the neutral ones). Raises a one-line :class:`ProfileError` naming the file
        and key for an array of another length or a joint the robot does not have."""
        joints = dict(self.joint_of)

        def fit(table: str, key: str, values: tuple | None, neutral: float | None) -> Any:
            if values is None:
                return None
            if not values:
                return (neutral,) * n_joints
            if table in joints:
                k = joints[table]
                if k > n_joints:
                    raise ProfileError(
                        self.source,
                        f"{table}.joint",
                        f"joint {k}: robot {robot} has {n_joints} joints",
                    )
                return tuple(values[0] if i == k - 1 else neutral for i in range(n_joints))
            if len(values) != n_joints:
                raise ProfileError(
                    self.source,
                    f"{table}.{key}",
                    f"must be a list of {n_joints} numbers (robot {robot} has {n_joints} "
                    f"joints), got {len(values)}",
                )
            return tuple(values)

        kw: dict[str, Any] = {}
        if self.stribeck is not None:
            s = self.stribeck
            kw["stribeck"] = replace(
                s,
                breakaway_ratio=fit("stribeck", "breakaway_ratio", s.breakaway_ratio, 1.0),
                velocity_rad_s=fit("stribeck", "velocity_rad_s", s.velocity_rad_s, 1.0),
            )
        if self.cogging is not None:
            c = self.cogging
            kw["cogging"] = replace(
                c,
                periods_per_rev=fit("cogging", "periods_per_rev", c.periods_per_rev, 0.0),
                amplitude_Nm=fit("cogging", "amplitude_Nm", c.amplitude_Nm, 0.0),
                phase_rad=fit("cogging", "phase_rad", c.phase_rad, 0.0),
            )
        if self.coulomb is not None:
            c = self.coulomb
            kw["coulomb"] = Coulomb(
                fit("coulomb", "positive_Nm", c.positive_Nm, None),
                fit("coulomb", "negative_Nm", c.negative_Nm, None),
            )
        for table, key, attr in _PER_JOINT_FIELDS:
            kw[attr] = fit(table, key, getattr(self, attr), 0.0)
        return replace(self, **kw)


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
# effects with one value for every joint: no ``joint = k``
_WHOLE_ARM = ("transport_delay", "payload")
# (table, key, EffectsProfile attribute) of the per-joint values held directly on the profile
_PER_JOINT_FIELDS = (
    ("amplifier_lag", "time_constant_s", "amplifier_lag_s"),
    ("encoder_offset", "offset_rad", "encoder_offset_rad"),
    ("torque_gain_error", "relative", "torque_gain_error"),
    ("torque_offset", "offset_Nm", "torque_offset_Nm"),
    ("velocity_squared_drag", "coefficient_Nms2", "velocity_squared_drag_Nms2"),
)


def _selected_joint(t: Fields, table: str) -> int | None:
    """The ``joint = k`` of an effect table (1-based), or None when it gives per-joint arrays."""
    if table in _WHOLE_ARM or not t.has("joint"):
        return None
    return t.integer("joint", lo=1)


def _per_joint(
    t: Fields, key: str, joint: int | None, default: Any = None, **limits: Any
) -> PerJoint:
    """One value per joint: an array of any length (fitted to the robot later, see
    :meth:`EffectsProfile.for_joints`), or with ``joint = k`` one number (a 1-tuple).
    ``default`` (missing key): ``()``, the neutral value on every joint."""
    if not t.has(key):
        if default is not None:
            return default
        raise t.error(key, "missing")
    if joint is not None:
        return (t.number(key, **limits),)
    value = t.data.get(key)
    if not isinstance(value, list) or not value:
        raise t.error(key, "must be a list of numbers, one per joint (or set joint = k)")
    return t.numbers(key, len(value), **limits)


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
    joint_of: list[tuple[str, int]] = []

    def table(name: str, keys: set[str]) -> tuple[Fields, int | None]:
        t = f.table(name)
        t.only(keys if name in _WHOLE_ARM else keys | {"joint"})
        joint = _selected_joint(t, name)
        if joint is not None:
            joint_of.append((name, joint))
        return t, joint

    if f.has("stribeck"):
        t, j = table("stribeck", {"breakaway_ratio", "velocity_rad_s", "exponent"})
        kw["stribeck"] = Stribeck(
            _per_joint(t, "breakaway_ratio", j, lo=1.0),
            _per_joint(t, "velocity_rad_s", j, positive=True),
            t.number("exponent", 2.0, positive=True, hi=10.0),
        )
    if f.has("cogging"):
        t, j = table("cogging", {"periods_per_rev", "amplitude_Nm", "phase_rad"})
        kw["cogging"] = Cogging(
            _per_joint(t, "periods_per_rev", j, lo=0.0),
            _per_joint(t, "amplitude_Nm", j, lo=0.0),
            _per_joint(t, "phase_rad", j, ()),
        )
    if f.has("amplifier_lag"):
        t, j = table("amplifier_lag", {"time_constant_s"})
        kw["amplifier_lag_s"] = _per_joint(t, "time_constant_s", j, lo=0.0, hi=1.0)
    if f.has("transport_delay"):
        t, _ = table("transport_delay", {"delay_s"})
        kw["transport_delay_s"] = t.number("delay_s", lo=0.0, hi=1.0)
    if f.has("encoder_offset"):
        t, j = table("encoder_offset", {"offset_rad"})
        kw["encoder_offset_rad"] = _per_joint(t, "offset_rad", j, lo=-3.2, hi=3.2)
    if f.has("torque_gain_error"):
        t, j = table("torque_gain_error", {"relative"})
        kw["torque_gain_error"] = _per_joint(t, "relative", j, lo=-0.9, hi=10.0)
    if f.has("torque_offset"):
        t, j = table("torque_offset", {"offset_Nm"})
        kw["torque_offset_Nm"] = _per_joint(t, "offset_Nm", j)
    if f.has("payload"):
        t, _ = table("payload", {"mass_kg", "distance_m", "inertia_kgm2"})
        kw["payload"] = Payload(
            t.number("mass_kg", lo=0.0),
            t.number("distance_m", lo=0.0),
            t.number("inertia_kgm2", 0.0, lo=0.0),
        )
    if f.has("coulomb"):
        t, j = table("coulomb", {"positive_Nm", "negative_Nm"})
        kw["coulomb"] = Coulomb(
            _per_joint(t, "positive_Nm", j, lo=0.0), _per_joint(t, "negative_Nm", j, lo=0.0)
        )
    if f.has("velocity_squared_drag"):
        t, j = table("velocity_squared_drag", {"coefficient_Nms2"})
        kw["velocity_squared_drag_Nms2"] = _per_joint(t, "coefficient_Nms2", j, lo=0.0)
    if f.has("timing_faults"):
        kw["timing_faults"] = parse_timing_faults(f.table("timing_faults"), host_allowed=False)
    kw["enabled"] = tuple(k for k in data if k in EFFECT_NAMES)
    kw["joint_of"] = tuple(joint_of)
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
    "PerJoint",
    "Stribeck",
    "load_effects",
    "parse_effects",
]
