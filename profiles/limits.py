"""Host-side safety limits per joint: a ``[limits]`` table of a bench profile or of a robot profile.

``torque_Nm`` (one number per joint, > 0), ``velocity_rad_s`` (one per joint, > 0) and
``position_rad`` (one ``[lo, hi]`` pair per joint), all of the same length. A bench profile's
table holds the limits of the arm on that bench; a robot profile described by its URDF may hold
its own, which a bench whose table has another number of joints uses for that arm
(:func:`profiles.bench.bench_for_robot`).

Imports profiles.loader only.
"""

from __future__ import annotations

from dataclasses import dataclass

from profiles.loader import Fields


@dataclass(frozen=True)
class JointLimits:
    """Torque, speed and position limits, one entry per joint."""

    torque_Nm: tuple[float, ...]
    velocity_rad_s: tuple[float, ...]
    position_rad: tuple[tuple[float, float], ...]

    @property
    def n_joints(self) -> int:
        return len(self.torque_Nm)


def parse_limits(limits: Fields, n_joints: int | None = None) -> JointLimits:
    """A ``[limits]`` table: ``n_joints`` entries per list, or as many as ``torque_Nm`` has."""
    limits.only({"torque_Nm", "velocity_rad_s", "position_rad"})
    raw_torque = limits.data.get("torque_Nm")
    n = n_joints
    if n is None:
        n = len(raw_torque) if isinstance(raw_torque, list) and raw_torque else 0
        if n == 0:
            raise limits.error("torque_Nm", "must be a non-empty list of numbers, one per joint")
    raw_pos = limits.data.get("position_rad")
    if (
        not isinstance(raw_pos, list)
        or len(raw_pos) != n
        or not all(isinstance(p, list) and len(p) == 2 for p in raw_pos)
    ):
        pairs = ", ".join(f"[lo{j}, hi{j}]" for j in range(1, n + 1))
        raise limits.error("position_rad", f"must be [{pairs}] in rad")
    position = []
    for j, pair in enumerate(raw_pos):
        sub = Fields({"lo": pair[0], "hi": pair[1]}, limits.source, f"limits.position_rad[{j}].")
        lo, hi = sub.number("lo"), sub.number("hi")
        if lo >= hi:
            raise limits.error(f"position_rad[{j}]", f"lower bound {lo} must be below {hi}")
        position.append((lo, hi))
    return JointLimits(
        torque_Nm=limits.numbers("torque_Nm", n, positive=True),
        velocity_rad_s=limits.numbers("velocity_rad_s", n, positive=True),
        position_rad=tuple(position),
    )


__all__ = ["JointLimits", "parse_limits"]
