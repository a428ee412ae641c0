"""Drive profile: one servo drive's encoder, torque scaling, limits and bus addresses."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

from profiles.loader import Fields, ProfileError, load_toml

WATCHDOG_DEFAULT_S = 0.5  # 2× the benches' default feedback budget (docs/virtual-robot.md)


@dataclass(frozen=True)
class DriveProfile:
    model: str
    source: str
    node_id: int  # CAN node id, 1..127
    unit_address: int  # serial multi-drop address, 0..255
    counts_per_rev: int
    rated_torque_Nm: float  # 0x6076: 1000 ‰
    max_torque_permille: int  # 0x6072
    max_velocity_rad_s: float  # overspeed fault threshold
    # command watchdog (CiA 301 RPDO timeout, 0x8250): an enabled drive without a torque
    # command for this long faults (zero torque). In time, so it means the same at any rate.
    watchdog_s: float
    vendor_id: int = 0
    product_code: int = 0

    @property
    def rad_per_count(self) -> float:
        return 2.0 * math.pi / self.counts_per_rev

    def watchdog_periods(self, period_s: float) -> int:
        """The watchdog in drive periods at ``period_s``: the first whole number of periods
        that covers ``watchdog_s`` (a drive counts its own period timer), at least 1."""
        return max(1, math.ceil(self.watchdog_s / period_s - 1e-9))

    @property
    def max_torque_Nm(self) -> float:
        return self.rated_torque_Nm * self.max_torque_permille / 1000.0


def load_drive(name_or_path: str | Path) -> DriveProfile:
    """The drive profile ``name_or_path``; ``"name@k"`` is that drive at CAN node id and serial
    unit address k, so an arm with several drives of one model (robots/ur5e.toml) gives each its
    own address without a copy of the drive's numbers."""
    if isinstance(name_or_path, str) and "@" in name_or_path:
        name, _, address = name_or_path.rpartition("@")
        if not address.isdigit() or not 1 <= int(address) <= 127:
            raise ProfileError(name_or_path, None, "the address after '@' must be a node id 1..127")
        k = int(address)
        return replace(load_drive(name), node_id=k, unit_address=k)
    data, source = load_toml("drives", name_or_path)
    f = Fields(data, source)
    f.only(
        {
            "model",
            "vendor",
            "node_id",
            "unit_address",
            "counts_per_rev",
            "rated_torque_Nm",
            "max_torque_permille",
            "max_velocity_rad_s",
            "watchdog_s",
            "watchdog_periods",
            "vendor_id",
            "product_code",
        }
    )
    if f.has("vendor"):
        f.string("vendor")
    if f.has("watchdog_periods"):
        raise f.error(
            "watchdog_periods",
            "the command watchdog is in time now: write watchdog_s (seconds), e.g. 0.2",
        )
    return DriveProfile(
        model=f.string("model"),
        source=source,
        node_id=f.integer("node_id", lo=1, hi=127),
        unit_address=f.integer("unit_address", lo=0, hi=255),
        counts_per_rev=f.integer("counts_per_rev", lo=1),
        rated_torque_Nm=f.number("rated_torque_Nm", positive=True),
        max_torque_permille=f.integer("max_torque_permille", lo=1, hi=32767),
        max_velocity_rad_s=f.number("max_velocity_rad_s", positive=True),
        watchdog_s=f.number("watchdog_s", WATCHDOG_DEFAULT_S, lo=1e-4, hi=10.0),
        vendor_id=f.integer("vendor_id", 0, lo=0, hi=0xFFFFFFFF),
        product_code=f.integer("product_code", 0, lo=0, hi=0xFFFFFFFF),
    )


__all__ = [
    "DriveProfile",
    "load_drive",
]
