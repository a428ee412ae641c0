"""Drive profile: one servo drive's encoder, torque scaling, limits and bus addresses."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

from profiles.loader import Fields, ProfileError, load_toml

WATCHDOG_DEFAULT_S = 0.5  # 2× the benches' default feedback budget (docs/virtual-robot.md)


PROTOCOLS = ("cia402", "mit", "odrive", "moteus")
# protocols whose drives run their own loop (a drive period shorter than the host's)
LOOP_PROTOCOLS = ("mit", "odrive", "moteus")


@dataclass(frozen=True)
class MitProfile:
    """An MIT-mode drive's [mit] table: the ranges its firmware packs the fields over
    (drivers.protocol.mit.MitRanges.of), the reply's length, its axis direction and its PD loop."""

    p_max: float  # rad: positions in commands and replies span ±p_max (16 bits)
    v_max: float  # rad/s (12 bits)
    kp_max: float  # Nm/rad, kp spans [0, kp_max] (12 bits)
    kd_max: float  # Nm s/rad (12 bits)
    t_max: float  # Nm: feed-forward and reply torque span ±t_max (12 bits); the torque limit
    reply_length: int  # 6 (Mini Cheetah firmware, AK80-6 V1.1) or 8 (+ temperature, error)
    # +1, or -1: the drive counts positive the other way round from the joint (the DFKI driver's
    # AXIS_DIRECTION of the AK80-6 V1.1 firmware flips p, v and t back)
    axis_direction: int
    pd_rate_hz: float  # how often the drive computes τ = kp(p_des − p) + kd(v_des − v) + τ_ff
    velocity_window_s: float  # the drive's velocity: encoder counts over this window


@dataclass(frozen=True)
class OdriveProfile:
    """An ODrive axis' [odrive] table (CANSimple, firmware 0.6): its control loop, its velocity
    estimate and its cyclic messages (the firmware's ``can.heartbeat_msg_rate_ms`` and
    ``can.encoder_msg_rate_ms``)."""

    control_rate_hz: float  # how often the axis applies its torque setpoint and samples
    velocity_window_s: float  # the velocity estimate: encoder counts over this window
    heartbeat_period_s: float  # the cyclic heartbeat (wall time)
    encoder_period_s: float  # realtime: the cyclic Get_Encoder_Estimates (0: on request only)


@dataclass(frozen=True)
class MoteusProfile:
    """A moteus controller's [moteus] table (register protocol, docs/reference.md of
    mjbots/moteus): its control loop, its velocity estimate and the position gains that the
    commands' kp_scale and kd_scale multiply (``servo.pid_position.kp``, ``.kd``)."""

    control_rate_hz: float  # how often the controller runs its position loop and samples
    velocity_window_s: float  # the velocity: encoder counts over this window
    kp_Nm_per_rev: float  # servo.pid_position.kp (Nm per revolution of the output)
    kd_Nm_s_per_rev: float  # servo.pid_position.kd (Nm per revolution/s)


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
    # the drive's CAN protocol: "cia402" (docs/protocol.md) or "mit" (T-Motor/CubeMars MIT
    # mode, the [mit] table: MitProfile)
    protocol: str = "cia402"
    mit: MitProfile | None = None
    odrive: OdriveProfile | None = None  # protocol "odrive" (ODrive CANSimple): its table
    moteus: MoteusProfile | None = None  # protocol "moteus" (mjbots register protocol)

    @property
    def loop_rate_hz(self) -> float:
        """The drive's own loop rate (its drive period), for the protocols that run one."""
        if self.mit is not None:
            return self.mit.pd_rate_hz
        if self.odrive is not None:
            return self.odrive.control_rate_hz
        if self.moteus is not None:
            return self.moteus.control_rate_hz
        raise ValueError(f"{self.source}: a {self.protocol} drive runs no loop of its own")

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
            "protocol",
            "mit",
            "odrive",
            "moteus",
        }
    )
    protocol = f.string("protocol", "cia402") if f.has("protocol") else "cia402"
    if protocol not in PROTOCOLS:
        raise f.error("protocol", f"must be one of {', '.join(PROTOCOLS)}, got {protocol!r}")
    if (protocol == "mit") != f.has("mit"):
        raise f.error(
            "mit", "an MIT-mode drive (protocol = 'mit') needs a [mit] table, and only it"
        )
    mit = _mit(f.table("mit")) if protocol == "mit" else None
    if (protocol == "odrive") != f.has("odrive"):
        raise f.error(
            "odrive", "an ODrive axis (protocol = 'odrive') needs an [odrive] table, and only it"
        )
    odrive = _odrive(f.table("odrive")) if protocol == "odrive" else None
    if odrive is not None and f.integer("node_id", lo=1, hi=127) > 63:
        raise f.error("node_id", "an ODrive node id has 6 bits (CAN id = node_id << 5 | cmd)")
    if (protocol == "moteus") != f.has("moteus"):
        raise f.error(
            "moteus",
            "a moteus controller (protocol = 'moteus') needs a [moteus] table, and only it",
        )
    moteus = _moteus(f.table("moteus")) if protocol == "moteus" else None
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
        protocol=protocol,
        mit=mit,
        odrive=odrive,
        moteus=moteus,
    )


def _mit(f: Fields) -> MitProfile:
    f.only(
        {
            "p_max",
            "v_max",
            "kp_max",
            "kd_max",
            "t_max",
            "reply_length",
            "axis_direction",
            "pd_rate_hz",
            "velocity_window_s",
        }
    )
    reply_length = f.integer("reply_length", 6, lo=6, hi=8)
    if reply_length == 7:
        raise f.error("reply_length", "must be 6 or 8")
    axis = f.integer("axis_direction", 1, lo=-1, hi=1)
    if axis == 0:
        raise f.error("axis_direction", "must be 1 or -1")
    return MitProfile(
        p_max=f.number("p_max", positive=True),
        v_max=f.number("v_max", positive=True),
        kp_max=f.number("kp_max", positive=True),
        kd_max=f.number("kd_max", positive=True),
        t_max=f.number("t_max", positive=True),
        reply_length=reply_length,
        axis_direction=axis,
        pd_rate_hz=f.number("pd_rate_hz", 4000.0, lo=100.0, hi=100000.0),
        velocity_window_s=f.number("velocity_window_s", 0.001, lo=0.0, hi=0.1),
    )


def _odrive(f: Fields) -> OdriveProfile:
    f.only({"control_rate_hz", "velocity_window_s", "heartbeat_period_s", "encoder_period_s"})
    return OdriveProfile(
        control_rate_hz=f.number("control_rate_hz", 1000.0, lo=100.0, hi=100000.0),
        velocity_window_s=f.number("velocity_window_s", 0.002, lo=0.0, hi=0.1),
        heartbeat_period_s=f.number("heartbeat_period_s", 0.1, lo=0.001, hi=10.0),
        encoder_period_s=f.number("encoder_period_s", 0.01, lo=0.0, hi=10.0),
    )


def _moteus(f: Fields) -> MoteusProfile:
    f.only({"control_rate_hz", "velocity_window_s", "kp_Nm_per_rev", "kd_Nm_s_per_rev"})
    return MoteusProfile(
        control_rate_hz=f.number("control_rate_hz", 1000.0, lo=100.0, hi=100000.0),
        velocity_window_s=f.number("velocity_window_s", 0.002, lo=0.0, hi=0.1),
        kp_Nm_per_rev=f.number("kp_Nm_per_rev", lo=0.0, hi=1e4),
        kd_Nm_s_per_rev=f.number("kd_Nm_s_per_rev", lo=0.0, hi=1e3),
    )


__all__ = [
    "LOOP_PROTOCOLS",
    "PROTOCOLS",
    "DriveProfile",
    "MitProfile",
    "MoteusProfile",
    "OdriveProfile",
    "load_drive",
]
