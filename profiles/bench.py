"""Bench profile: which transport and protocol, which robot, time mode, period, safety limits.

A real bench is a profile, not a code change: `transport`/`channel` point at can0, a USB slcan
adapter or a serial port, `virtual = false`, and `confirm_real` must be passed on the command line.
A virtual bench with `attach = true` and a `channel` uses a virtual robot that is already running
(`virtual-robot serve`) instead of starting its own (:func:`attached_bench_text`, `hil run
--attach`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from profiles.limits import parse_limits
from profiles.loader import Fields, ProfileError, load_toml
from profiles.timing_faults import MAX_FEEDBACK_BUDGET_S, TimingFaults, parse_timing_faults

# can: CiA 402; mit: T-Motor/CubeMars MIT mode; odrive: ODrive CANSimple; moteus: mjbots moteus
# register protocol (CAN-FD; fdcanusb: the mjbots USB adapter's serial line protocol on a pty)
PROTOCOLS = ("can", "mit", "odrive", "moteus", "serial")
TRANSPORTS = {
    "can": ("slcan", "socketcan", "socketcand", "virtual"),
    "mit": ("slcan", "socketcan", "virtual"),
    "odrive": ("slcan", "socketcan", "virtual"),
    "moteus": ("fdcanusb", "socketcan"),
    "serial": ("serial",),
}
MODES = ("lockstep", "realtime")
MIN_PERIOD_S = 1e-4  # 10 kHz: below this no Python loop over any link holds its period
DEFAULT_FEEDBACK_BUDGET_S = (
    0.25  # sits out the pty stalls measured beside two CPU hogs (docs/faults.md)
)


@dataclass(frozen=True)
class BenchProfile:
    name: str
    source: str
    virtual: bool
    protocol: str  # can | mit | serial
    transport: str  # slcan | socketcan | socketcand | virtual | serial
    channel: str  # "" for a virtual bench: the virtual robot announces it
    bitrate: int
    baudrate: int
    mode: str
    period_s: float
    robot: str
    effects: str | None
    timeout_s: float  # lockstep feedback timeout, and SDO/request timeout
    # realtime: how long the host waits for a period's feedback before it calls the link dead.
    # Feedback later than one period but within this budget is a timing event (counted, the
    # run goes on); a closed link or a dead robot process is detected at once, not after it.
    feedback_budget_s: float
    # host limits, one entry per joint of the arm ([limits]; bench_for_robot for another arm)
    torque_limit_Nm: tuple[float, ...]
    velocity_limit_rad_s: tuple[float, ...]
    position_limit_rad: tuple[tuple[float, float], ...]
    in_process: bool = False  # python-can `virtual`: the robot runs in a thread of the host
    timing_faults: TimingFaults | None = None  # [timing_faults] (profiles/timing_faults.py)
    pace_bus: bool = False  # virtual CAN: frames take their bit time at `bitrate` (can_bits)
    attach: bool = False  # virtual: use the robot already serving on `channel`, start none


def load_bench(name_or_path: str | Path) -> BenchProfile:
    data, source = load_toml("benches", name_or_path)
    f = Fields(data, source)
    f.only(
        {
            "name",
            "description",
            "virtual",
            "protocol",
            "transport",
            "channel",
            "bitrate",
            "baudrate",
            "mode",
            "period_s",
            "robot",
            "effects",
            "timeout_s",
            "feedback_budget_s",
            "feedback_timeout_periods",
            "limits",
            "pace_bus",
            "timing_faults",
            "attach",
        }
    )
    protocol = f.string("protocol")
    if protocol not in PROTOCOLS:
        raise f.error("protocol", f"must be one of {', '.join(PROTOCOLS)}, got {protocol!r}")
    transport = f.string("transport")
    if transport not in TRANSPORTS[protocol]:
        raise f.error(
            "transport",
            f"for protocol {protocol!r} must be one of "
            f"{', '.join(TRANSPORTS[protocol])}, got {transport!r}",
        )
    mode = f.string("mode", "lockstep")
    if mode not in MODES:
        raise f.error("mode", f"must be one of {', '.join(MODES)}, got {mode!r}")
    virtual = f.boolean("virtual")
    channel = f.string("channel", "")
    if not virtual and not channel:
        raise f.error("channel", "a real bench needs a channel (e.g. can0, /dev/ttyACM0)")
    attach = f.boolean("attach", False)
    if attach and (not virtual or not channel or transport == "virtual"):
        raise f.error(
            "attach",
            "uses a running `virtual-robot serve`: needs virtual = true, a transport that "
            "crosses processes (slcan, socketcand, socketcan, serial) and its channel",
        )
    pace_bus = f.boolean("pace_bus", False)
    if pace_bus and (protocol != "can" or not virtual):
        raise f.error(
            "pace_bus",
            "paces the virtual robot's CAN bus at its bitrate: needs protocol = 'can' and "
            f"virtual = true (this bench: protocol {protocol!r}, virtual = {str(virtual).lower()})",
        )
    limits = parse_limits(f.table("limits"))  # one entry per joint of the bench's arm
    period_s = f.number("period_s", 0.0025, positive=True, hi=1.0)
    if period_s < MIN_PERIOD_S:
        raise f.error(
            "period_s",
            f"{period_s:g} s is below {MIN_PERIOD_S * 1e6:g} µs: no host loop over these links "
            "holds a period that short",
        )
    return BenchProfile(
        name=f.string("name"),
        source=source,
        virtual=virtual,
        protocol=protocol,
        transport=transport,
        channel=channel,
        bitrate=f.integer("bitrate", 1_000_000, lo=10_000, hi=1_000_000),
        baudrate=f.integer("baudrate", 9600, lo=300, hi=4_000_000),
        mode=mode,
        period_s=period_s,
        robot=f.string("robot", "cicese"),
        effects=f.string("effects") if f.has("effects") else None,
        timeout_s=f.number("timeout_s", 0.5, positive=True, hi=60.0),
        feedback_budget_s=_feedback_budget(f, period_s),
        torque_limit_Nm=limits.torque_Nm,
        velocity_limit_rad_s=limits.velocity_rad_s,
        position_limit_rad=limits.position_rad,
        in_process=transport == "virtual",
        pace_bus=pace_bus,
        attach=attach,
        timing_faults=(
            parse_timing_faults(f.table("timing_faults"), host_allowed=True)
            if f.has("timing_faults")
            else None
        ),
    )


def bench_for_robot(bench: BenchProfile, robot: str | None = None) -> BenchProfile:
    """``bench`` carrying ``robot`` (a robot profile name or file; None: the bench's own), with
    host limits for that arm's joints. The bench's ``[limits]`` are its own robot's; another
    robot brings the ``[limits]`` of its profile (a URDF arm's, e.g. cicese3.toml) and, without
    them, keeps the bench's only if they have one entry per joint. A one-line ProfileError when
    nothing fits."""
    from dataclasses import replace

    from profiles.robot import load_any_robot

    name = bench.robot if robot is None else robot
    arm = load_any_robot(name)
    n = arm.n_joints
    if not arm.drives:  # a profile for identification only (e.g. dfki-a0, panda) names none
        raise ProfileError(arm.source, "joints.drives", "names no drives: it cannot run on a bench")
    check_drive_protocol(bench, arm.drives, arm.source)
    own = getattr(arm, "limits", None)  # only a URDF arm's profile may hold [limits]
    if own is not None and name != bench.robot:
        return replace(
            bench,
            robot=name,
            torque_limit_Nm=own.torque_Nm,
            velocity_limit_rad_s=own.velocity_rad_s,
            position_limit_rad=own.position_rad,
        )
    if len(bench.torque_limit_Nm) != n:
        raise ProfileError(
            bench.source,
            "limits",
            f"gives {len(bench.torque_limit_Nm)} joints' limits and robot {arm.name} has {n}; "
            f"its profile ({arm.source}) has no [limits] of its own: add one",
        )
    return replace(bench, robot=name)


def check_drive_protocol(bench: BenchProfile, drives: tuple[str, ...], source: str) -> None:
    """A one-line ProfileError unless the robot's drives speak the bench's protocol (MIT-mode
    drives on an ``mit`` bench, ODrive axes on an ``odrive`` one, CiA 402 drives on a ``can``
    or ``serial`` one)."""
    from profiles.drive import load_drive

    want = bench.protocol if bench.protocol in ("mit", "odrive", "moteus") else "cia402"
    for name in drives:
        drive = load_drive(name)
        if drive.protocol != want:
            raise ProfileError(
                source,
                "joints.drives",
                f"drive {name} speaks {drive.protocol} and bench {bench.name} protocol "
                f"{bench.protocol!r} needs {want} drives",
            )


def attached_bench_text(bench: BenchProfile, channel: str) -> str:
    """The TOML of ``bench`` attached to a running virtual robot on ``channel`` (the ``channel``
    its ``virtual-robot serve`` announced: a pty path, or ``HOST:PORT`` for socketcand)."""
    import json

    if not bench.virtual:
        raise ValueError(f"--attach needs a virtual bench; {bench.name} drives a real arm")
    if bench.transport == "virtual":
        raise ValueError(
            f"--attach: bench {bench.name} runs its robot in-process; use a bench "
            "with transport slcan, socketcand, socketcan or serial"
        )
    lines = Path(bench.source).read_text(encoding="utf-8").splitlines()
    kept = [ln for ln in lines if not ln.replace(" ", "").startswith(("channel=", "attach="))]
    head = [
        f"# {bench.name} attached to a running virtual robot (hil run --attach)",
        "attach = true",
        f"channel = {json.dumps(channel)}",
    ]
    return "\n".join(head + kept) + "\n"


def _feedback_budget(f: Fields, period_s: float) -> float:
    """``feedback_budget_s`` (seconds), or the older ``feedback_timeout_periods`` (periods,
    kept as an alias: n periods = n·period_s seconds); at least one period."""
    if f.has("feedback_budget_s") and f.has("feedback_timeout_periods"):
        raise f.error(
            "feedback_timeout_periods",
            "give feedback_budget_s (seconds) or its alias feedback_timeout_periods, not both",
        )
    if f.has("feedback_timeout_periods"):
        n = f.integer("feedback_timeout_periods", lo=1, hi=100_000)
        budget = n * period_s
        if budget > MAX_FEEDBACK_BUDGET_S:
            raise f.error(
                "feedback_timeout_periods",
                f"{n} periods of {period_s} s is {budget:g} s, above {MAX_FEEDBACK_BUDGET_S:g} s",
            )
        return budget
    budget = f.number(
        "feedback_budget_s", DEFAULT_FEEDBACK_BUDGET_S, positive=True, hi=MAX_FEEDBACK_BUDGET_S
    )
    if budget < period_s:
        raise f.error("feedback_budget_s", f"{budget} s is shorter than one period ({period_s} s)")
    return budget


__all__ = [
    "MODES",
    "PROTOCOLS",
    "TRANSPORTS",
    "BenchProfile",
    "bench_for_robot",
    "load_bench",
]
