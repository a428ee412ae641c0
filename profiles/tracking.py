"""Tracking-experiment profile (kind = "tracking"): reference moves, gains, model choices.

Read by `hil control`; `hil run` (open-loop torques, profiles/experiment.py) refuses this kind.
Shipped: ``khosla-kanade-tracking`` (Khosla & Kanade 1987, Section 4.2 and Table 1, adapted to
the 2-DOF CICESE arm) and ``khosla-kanade-tracking-cicese3`` (the same for the 3-DOF cicese3).
The joint count is that of ``amplitude_rad``; gains and ``typical_q_rad`` give one number per
joint.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from profiles.loader import Fields, ProfileError, load_toml

KIND = "tracking"
VELOCITY_ESTIMATORS = ("backward_difference",)
FRICTION_VELOCITIES = ("measured", "reference")


@dataclass(frozen=True)
class TrackingProfile:
    name: str
    source: str
    period_s: float
    amplitude_rad: tuple[float, ...]  # one per joint: the joint count
    pattern: tuple[float, ...]  # successive targets in units of the amplitude, from q = 0
    move_s: float
    hold_s: float
    start_hold_s: float
    kp: tuple[float, ...]
    kv: tuple[float, ...]
    typical_q_rad: tuple[float, ...]
    velocity: str
    ct_friction_velocity: str

    @property
    def n_joints(self) -> int:
        return len(self.amplitude_rad)

    @property
    def duration_s(self) -> float:
        return self.start_hold_s + len(self.pattern) * (self.move_s + self.hold_s)


def load_tracking(name_or_path: str | Path) -> TrackingProfile:
    data, source = load_toml("experiments", name_or_path)
    f = Fields(data, source)
    kind = f.string("kind")
    if kind != KIND:
        raise f.error(
            "kind", f"`hil control` needs a tracking experiment (kind = {KIND!r}), got {kind!r}"
        )
    f.only({"name", "description", "kind", "period_s", "trajectory", "gains", "model"})
    traj = f.table("trajectory")
    traj.only({"amplitude_rad", "pattern", "move_s", "hold_s", "start_hold_s"})
    raw_amplitude = traj.data.get("amplitude_rad")
    if not isinstance(raw_amplitude, list) or not raw_amplitude:
        raise traj.error("amplitude_rad", "must be a non-empty list of numbers (one per joint)")
    n = len(raw_amplitude)
    amplitude = traj.numbers("amplitude_rad", n, lo=-math.pi, hi=math.pi)
    raw_pattern = traj.data.get("pattern")
    if not isinstance(raw_pattern, list) or not raw_pattern:
        raise traj.error("pattern", "must be a non-empty list of numbers (targets / amplitude)")
    pattern = traj.numbers("pattern", len(raw_pattern), lo=-2.0, hi=2.0)
    gains = f.table("gains")
    gains.only({"kp", "kv"})
    model = f.table("model", {})
    model.only({"typical_q_rad", "velocity", "ct_friction_velocity"})
    velocity = model.string("velocity", "backward_difference")
    if velocity not in VELOCITY_ESTIMATORS:
        raise model.error(
            "velocity", f"must be one of {', '.join(VELOCITY_ESTIMATORS)}, got {velocity!r}"
        )
    ct_friction = model.string("ct_friction_velocity", "measured")
    if ct_friction not in FRICTION_VELOCITIES:
        raise model.error(
            "ct_friction_velocity",
            f"must be one of {', '.join(FRICTION_VELOCITIES)}, got {ct_friction!r}",
        )
    return TrackingProfile(
        name=f.string("name"),
        source=source,
        period_s=f.number("period_s", 0.0025, positive=True, hi=1.0),
        amplitude_rad=amplitude,
        pattern=pattern,
        move_s=traj.number("move_s", positive=True, hi=600.0),
        hold_s=traj.number("hold_s", lo=0.0, hi=600.0),
        start_hold_s=traj.number("start_hold_s", 0.0, lo=0.0, hi=600.0),
        kp=gains.numbers("kp", n, lo=0.0, hi=1e6),
        kv=gains.numbers("kv", n, lo=0.0, hi=1e4),
        typical_q_rad=model.numbers("typical_q_rad", n, [0.0] * n, lo=-2 * math.pi, hi=2 * math.pi),
        velocity=velocity,
        ct_friction_velocity=ct_friction,
    )


__all__ = ["KIND", "ProfileError", "TrackingProfile", "load_tracking"]
