"""The virtual robot behind any transport: plant + one drive model per joint + the object
dictionary.

The plant is the 2-DOF closed-form :class:`~virtual_robot.plant.Plant` for a 2-DOF robot profile
(with the concealed effects of an effects profile), or the n-joint
:class:`~virtual_robot.urdf_plant.UrdfPlant` for an arm described by its URDF (nodes and unit
addresses are its drive profiles', 1..N for the shipped arms), with the same concealed effects
per joint. Timing faults (virtual_robot/timing_faults.py) act on either plant the same way:
the one :class:`~virtual_robot.stepping.Stepper` decides when a command takes effect and the plant
takes it then (``command(..., deliver_at=...)``).

Protocol servers (CAN, serial) decode what arrives and call this core; it never does I/O.
Time has two modes (docs/design.md "Time"):

* **lockstep**: robot time stands still between SYNCs. The first SYNC samples at t = 0; every
  later SYNC first advances the plant one period with the torques held since the previous one,
  then samples. A torque written between SYNC k and SYNC k+1 is applied at t_k. The sequence is
  :class:`~virtual_robot.stepping.Stepper`'s, the one the offline simulation steps through too
  (sample at t_k, command, hold over [t_k, t_k + h)). As nothing moves in between, the plant is
  given the drives' commands and power states once per SYNC, just before it advances (the same
  command, issued at the same t_k).
* **realtime**: robot time is the clock passed in. Every call first integrates the plant up to
  now with the torques held so far; a late command is applied late. The drives' own period
  timer (:meth:`tick`, called every period by the server) counts the command watchdog; a SYNC
  only samples.

All methods take the core's lock, so a server thread and a period-timer thread may share it.
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from drivers.protocol import cia402 as co
from drivers.protocol.cia402 import SdoAbortError
from profiles.drive import LOOP_PROTOCOLS, DriveProfile, load_drive
from profiles.effects import EffectsProfile
from profiles.robot import RobotProfile, UrdfRobotProfile
from virtual_robot.drive import DriveError, DriveModel, Emcy
from virtual_robot.loop_drive import LoopDrive
from virtual_robot.mit_drive import MitDrive
from virtual_robot.moteus_drive import MoteusDrive
from virtual_robot.odrive_drive import OdriveAxis
from virtual_robot.plant import DEFAULT_STEP_S, Plant, PlantParams
from virtual_robot.stepping import SteppedPlant, Stepper
from virtual_robot.timing_faults import RobotTiming

LOCKSTEP, REALTIME = "lockstep", "realtime"

# Objects whose value lives in the drive model: the DriveModel attribute that holds each one
# (read on every TPDO: keep this a flat table).
_LIVE_OBJECTS: dict[tuple[int, int], str] = {
    (0x1001, 0): "error_register",
    (0x603F, 0): "error_code",
    (0x6040, 0): "controlword",
    (0x6041, 0): "statusword",
    (0x6060, 0): "mode",
    (0x6061, 0): "mode",
    (0x6064, 0): "position_counts",
    (0x606C, 0): "velocity_counts_s",
    (0x6071, 0): "target_torque_permille",
    (0x6072, 0): "max_torque_permille",
    (0x6077, 0): "torque_actual_permille",
}
# (index, subindex) -> (lowest, highest) value of every object a transport may write
_WRITABLE: dict[tuple[int, int], tuple[int, int]] = {
    (o.index, o.subindex): o.limits() for o in co.OBJECTS if o.access is not co.Access.RO
}


@dataclass
class Feedback:
    """What one drive reports after a SYNC / sample."""

    node: int
    statusword: int
    position_counts: int
    velocity_counts_s: int
    torque_actual_permille: int


class VirtualRobot:
    """Plant and drives of one robot, addressed by CAN node id (or serial unit address)."""

    def __init__(
        self,
        robot: RobotProfile | UrdfRobotProfile,
        effects: EffectsProfile | None = None,
        *,
        mode: str = LOCKSTEP,
        period_s: float = 0.0025,
        clock: Callable[[], float] | None = None,
        step_s: float = DEFAULT_STEP_S,
        q0: Sequence[float] | None = None,
        timing: RobotTiming | None = None,
    ) -> None:
        if mode not in (LOCKSTEP, REALTIME):
            raise ValueError(f"mode must be {LOCKSTEP!r} or {REALTIME!r}, got {mode!r}")
        if mode == REALTIME and clock is None:
            raise ValueError("realtime mode needs a clock")
        self.robot = robot
        self.effects = effects or EffectsProfile()
        self.mode = mode
        self.period_s = period_s
        self._clock = clock
        self._t0 = clock() if clock is not None else 0.0
        self.lock = threading.RLock()
        if not robot.drives:  # a profile for identification only names none
            raise ValueError(
                f"{robot.source}: [joints] drives: the virtual robot needs one per joint"
            )
        self.profiles: tuple[DriveProfile, ...] = tuple(load_drive(n) for n in robot.drives)
        kinds = {p.protocol for p in self.profiles}
        if len(kinds) > 1:
            raise ValueError(f"{robot.source}: its drives speak different protocols ({kinds})")
        self.protocol = (
            kinds.pop()
        )  # "cia402", "mit", "odrive" or "moteus" (profiles.drive.PROTOCOLS)
        # the drive period: the bench's period for CiA 402; the drives' own loop's for MIT mode
        # and ODrive, which divides the host's period into mit_substeps (one lockstep host
        # period = that many; profiles.drive.LOOP_PROTOCOLS)
        self.mit_substeps = 1
        self.host_period_s = period_s  # the bench's period: the realtime period timer's
        self.own_loop = self.protocol in LOOP_PROTOCOLS
        if self.own_loop:
            rate = max(p.loop_rate_hz for p in self.profiles)
            self.mit_substeps = max(1, round(period_s * rate))
            period_s = period_s / self.mit_substeps
            self.period_s = period_s
        self.drives: list[DriveModel] | list[MitDrive] | list[OdriveAxis] | list[MoteusDrive] = (
            [MitDrive(p, period_s) for p in self.profiles]
            if self.protocol == "mit"
            else [OdriveAxis(p, period_s) for p in self.profiles]
            if self.protocol == "odrive"
            else [MoteusDrive(p, period_s) for p in self.profiles]
            if self.protocol == "moteus"
            else [DriveModel(p, period_s=period_s) for p in self.profiles]
        )
        self.by_node = {p.node_id: i for i, p in enumerate(self.profiles)}
        self._node_drives = tuple(
            (p.node_id, d) for p, d in zip(self.profiles, self.drives, strict=True)
        )
        self.by_unit = {p.unit_address: i for i, p in enumerate(self.profiles)}
        if len(self.by_node) != len(self.profiles) or len(self.by_unit) != len(self.profiles):
            raise ValueError(
                f"{robot.source}: two drives share a CAN node id or a serial unit address "
                f"(nodes {[p.node_id for p in self.profiles]}, "
                f"units {[p.unit_address for p in self.profiles]})"
            )
        self.plant: SteppedPlant = self._plant(robot, q0, min(step_s, period_s))
        # the stepping sequence (sample, apply, advance); its time, SYNC count, pending commands
        # and timing faults are the robot's
        self.stepper = Stepper(
            self.plant, self.drives, period_s, timing=timing, lockstep=mode == LOCKSTEP
        )
        # event_log(event, n, t): "sample" / "command" times for `hil replay` (realtime runs)
        self.event_log: Callable[[str, int, float], None] | None = None
        # bumped whenever the stored objects change (PDO map, COB-IDs, 0x1017, reset node), so a
        # server may cache what it derives from them (routing, TPDO packing, heartbeat period)
        self.config_version = 0
        self._mapping_cache: dict[tuple[int, int], tuple[tuple[int, int], ...]] = {}
        self._store: list[dict[tuple[int, int], int]] = [
            self._initial_objects(p) for p in self.profiles
        ]
        self.stepper.sample(0.0, count_period=False)  # power on: transition 1, SWITCH ON DISABLED

    def _plant(
        self,
        robot: RobotProfile | UrdfRobotProfile,
        q0: Sequence[float] | None,
        max_step_s: float,
    ) -> SteppedPlant:
        """The 2-DOF closed-form plant with the effects, or the n-joint plant of a URDF arm with
        them."""
        if not isinstance(robot, UrdfRobotProfile):
            q = (0.0, 0.0) if q0 is None else (float(q0[0]), float(q0[1]))
            return Plant(
                PlantParams.from_profiles(robot, self.effects), q0=q, max_step_s=max_step_s
            )
        # Pinocchio is loaded only for an n-joint arm: the 2-DOF robot starts without it
        from virtual_robot.urdf_plant import UrdfPlant, UrdfPlantParams

        return UrdfPlant(
            UrdfPlantParams.from_profile(robot, self.effects), q0=q0, max_step_s=max_step_s
        )

    # ---- time ---------------------------------------------------------------------------
    @property
    def t(self) -> float:
        """Robot time of the last sample / event."""
        return self.stepper.t

    @property
    def syncs(self) -> int:
        """SYNCs (serial steps) so far."""
        return self.stepper.syncs

    @property
    def timing(self) -> RobotTiming | None:
        """Injected timing faults or an imposed timing trace (virtual_robot/timing_faults.py)."""
        return self.stepper.timing

    def now(self) -> float:
        if self.mode == LOCKSTEP:
            return self.t
        assert self._clock is not None
        return self._clock() - self._t0

    def _catch_up(self) -> float:
        """Realtime: integrate to now with the torques held so far. Returns robot time."""
        if self.mode == REALTIME:
            now = self.now()
            if self.own_loop:
                self._pd_steps(now)
            if now > self.plant.t:
                self.plant.advance_to(now)
                if self.event_log is not None:  # the integration grid, for `hil replay`
                    self.event_log("advance", self.syncs, now)
            stepper = self.stepper
            stepper.t = max(stepper.t, now)
        return self.stepper.t

    def _pd_steps(self, now: float) -> None:
        """Realtime, drives with their own loop: the plant integrated to ``now`` in drive
        periods, each ending with every drive's sample (its loop and watchdog) and its new
        torque applied, as the drives' own loop runs (virtual_robot.loop_drive)."""
        h, plant, stepper = self.period_s, self.plant, self.stepper
        while now - plant.t >= h:
            t = plant.t + h
            plant.advance_to(t)
            stepper.sample(t, True)
            stepper.apply(t, from_host=False)
            stepper.t = max(stepper.t, t)

    def catch_up(self) -> float:
        """Realtime: integrate to now with the torques held so far (a server's frame arrived);
        lockstep: nothing. Returns robot time. Call with :attr:`lock` held."""
        return self._catch_up()

    def step_host_period(self) -> None:
        """Lockstep: one host period of drives that run their own loop, ``mit_substeps`` drive
        periods each ending with the drives' sample and their torques applied
        (virtual_robot.stepping.Stepper). Call with :attr:`lock` held."""
        stepper = self.stepper
        stepper.unapplied = True
        for _ in range(self.mit_substeps):
            stepper.sync()

    def apply_now(self, now: float) -> None:
        """The drives' present commands reach the plant: at once in realtime, at the next
        step in lockstep (robot time stands still until then). Call with :attr:`lock` held."""
        if self.mode == LOCKSTEP:
            self.stepper.unapplied = True
        else:
            self._apply_torques(now)

    def _apply_torques(self, now: float, from_host: bool = True) -> None:
        """Give the plant the drives' torques and power states (Stepper.apply); a host's
        command taking effect goes to the event log."""
        at = self.stepper.apply(now, from_host)
        if at is not None and self.event_log is not None:  # when the command takes effect
            self.event_log("command", self.stepper.syncs, at)

    def drop_command(self) -> bool:
        """Whether a cyclic command frame from the host is lost (robot-side timing fault): only
        once the cyclic exchange runs (after the first SYNC), never during set-up."""
        with self.lock:
            return self.timing is not None and self.syncs > 0 and self.timing.drop_command()

    def feedback_delay_s(self) -> float:
        """Realtime: how long a server holds this SYNC's feedback back (robot-side fault)."""
        if self.timing is None or self.mode != REALTIME:
            return 0.0
        return self.timing.feedback_delay_s()

    def _sample_realtime(self, now: float, count_period: bool) -> None:
        stepper = self.stepper
        stepper.sample(now, count_period)
        # A fault in update() zeroes torque at once. A sample that falls between a host's
        # writes and their application (none does through the servers, which apply an RPDO
        # under the lock) delivers them: that is when the host's command takes effect, so it
        # is one (delayed by timing faults, in the event log for `hil replay`).
        self._apply_torques(now, from_host=stepper.unapplied)

    # ---- events from a transport ----------------------------------------------------------
    def sync(self) -> list[Feedback]:
        """SYNC (or the serial step): advance as the time mode says, sample every drive."""
        with self.lock:
            self.sync_sample()
            return [self._feedback(i) for i in range(len(self.drives))]

    def sync_sample(self) -> None:
        """:meth:`sync` without building its feedback (a server reads the objects it maps)."""
        with self.lock:
            if self.mode == LOCKSTEP:
                self.stepper.sync()
                return
            now = self._catch_up()
            self._sample_realtime(now, count_period=False)
            if self.event_log is not None:
                self.event_log("sample", self.stepper.syncs, now)
            self.stepper.syncs += 1

    def tick(self) -> None:
        """Realtime only: one period of the drives' own timer (command watchdog)."""
        with self.lock:
            if self.mode != REALTIME:
                return
            now = self._catch_up()  # MIT mode: the drives' periods run in there
            self._sample_realtime(now, count_period=not self.own_loop)

    def start_period_timer(self, stop: threading.Event) -> threading.Thread | None:
        """Realtime: a daemon thread calling :meth:`tick` every period until ``stop`` is set.

        Deadlines are absolute (t0 + k·h), so the timer does not drift; a late wake-up runs
        one tick and re-aligns. Lockstep needs no timer (returns None).
        """
        if self.mode != REALTIME:
            return None
        assert self._clock is not None
        clock = self._clock

        def run() -> None:
            k = 1
            start = clock()
            while not stop.is_set():
                delay = start + k * self.host_period_s - clock()
                if delay > 0 and stop.wait(delay):
                    return
                self.tick()
                k = max(k + 1, int((clock() - start) / self.host_period_s) + 1)

        thread = threading.Thread(target=run, name="drive-period-timer", daemon=True)
        thread.start()
        return thread

    def write(
        self,
        index: int,
        subindex: int,
        value: int,
        *,
        node: int | None = None,
        unit: int | None = None,
        apply: bool = True,
    ) -> None:
        """Write an object of one drive; raises SdoAbortError with the CiA 301 code.

        ``apply=False``: the plant keeps its torque command until :meth:`apply_commands` (or,
        in lockstep, the next SYNC), so writes that arrive together (the objects of an RPDO)
        reach the plant once.
        """
        with self.lock:
            i = self._drive_index(node, unit)
            limits = _WRITABLE.get((index, subindex))
            if limits is None:
                co.lookup(index, subindex)  # raises the right abort for unknown objects
                raise SdoAbortError(index, subindex, co.ABORT_READ_ONLY)
            lo, hi = limits
            if not lo <= value <= hi:
                code = co.ABORT_VALUE_TOO_HIGH if value > hi else co.ABORT_VALUE_TOO_LOW
                raise SdoAbortError(index, subindex, code)
            now = self.t if self.mode == LOCKSTEP else self._catch_up()
            d = self.drives[i]
            try:
                if index == 0x6040:
                    d.write_controlword(value, now)
                elif index == 0x6071:
                    d.write_target_torque(value, now)
                elif index == 0x6060:
                    d.write_mode(value)
                elif index == 0x6072:
                    d.write_max_torque(value)
                else:
                    self._write_stored(i, index, subindex, value)
            except DriveError as exc:
                raise SdoAbortError(index, subindex, exc.abort_code) from None
            if apply:
                self._apply_torques(now)
            else:
                self.stepper.unapplied = True

    def apply_commands(self) -> None:
        """Give the plant the drives' torque commands and power states of the writes made with
        ``apply=False``: now in realtime; in lockstep, where robot time stands still until the
        next SYNC, when that SYNC advances the plant (the same command, issued at the same t)."""
        with self.lock:
            if self.stepper.unapplied and self.mode == REALTIME:
                self._apply_torques(self._catch_up())

    def read(
        self, index: int, subindex: int, *, node: int | None = None, unit: int | None = None
    ) -> int:
        """Read an object of one drive; raises SdoAbortError with the CiA 301 code."""
        with self.lock:
            i = self._drive_index(node, unit)
            attribute = _LIVE_OBJECTS.get((index, subindex))
            if attribute is not None:
                return getattr(self.drives[i], attribute)
            value = self._store[i].get((index, subindex))
            if value is None:
                co.lookup(index, subindex)  # raises the right abort
                raise SdoAbortError(index, subindex, co.ABORT_NO_OBJECT)
            return value

    def reader(self, index: int, subindex: int, *, node: int) -> Callable[[], int]:
        """A function returning what :meth:`read` would, for a per-SYNC hot path.

        It does not take the lock (call it with :attr:`lock` held) and is valid until
        :attr:`config_version` changes. Raises SdoAbortError now for an unknown object.
        """
        i = self._drive_index(node, None)
        attribute = _LIVE_OBJECTS.get((index, subindex))
        if attribute is not None:
            return functools.partial(getattr, self.drives[i], attribute)
        self.read(index, subindex, node=node)  # raises the right abort
        return functools.partial(self._store[i].__getitem__, (index, subindex))

    def reset_node(self, node: int) -> None:
        """NMT reset node: drive back to power-on (errors cleared), PDO configuration cleared."""
        with self.lock:
            i = self._drive_index(node, None)
            now = self._catch_up()
            self.drives[i].reset(now)
            self.drives[i].update(
                now, self.plant.measured_q[i], self.plant.dq[i], count_period=False
            )
            self._store[i] = self._initial_objects(self.profiles[i])
            self._mapping_cache.clear()
            self.config_version += 1
            self._apply_torques(now)

    def reset_communication(self, node: int) -> None:
        """NMT reset communication (CiA 301): the communication profile area (0x1000-0x1FFF:
        PDO COB-IDs, transmission types and mappings, 0x1017) back to power-on values; the
        drive (the application) is left as it is."""
        with self.lock:
            i = self._drive_index(node, None)
            power_on = self._initial_objects(self.profiles[i])
            store = self._store[i]
            for key, value in power_on.items():
                if 0x1000 <= key[0] <= 0x1FFF:
                    store[key] = value
            self._mapping_cache.clear()
            self.config_version += 1

    def disable_all(self) -> None:
        """Safe stop: every drive to SWITCH ON DISABLED, torque zero (e.g. host lost)."""
        with self.lock:
            now = self._catch_up()
            for d in self.drives:
                if isinstance(d, LoopDrive):
                    d.safe_stop(now)
                else:
                    d.write_controlword(co.CW_DISABLE_VOLTAGE, now)
            self._apply_torques(now, from_host=False)

    def reset_faults(self) -> list[int]:
        """Fault reset (CiA 402 transition 15) of every drive in FAULT, as a host's controlword
        0x80 then 0 would do; the error codes cleared, one per drive that held one."""
        with self.lock:
            now = self._catch_up()
            cleared = []
            for d in self.drives:
                if getattr(d, "state", None) is co.State.FAULT:  # CiA 402 drives only
                    cleared.append(d.error_code)
                    d.write_controlword(co.CW_DISABLE_VOLTAGE, now)  # bit 7 low first: an edge
                    d.write_controlword(co.CW_FAULT_RESET, now)
                    d.write_controlword(co.CW_DISABLE_VOLTAGE, now)
            self._apply_torques(now, from_host=False)
            return cleared

    def fault_all(self, error_code: int) -> None:
        """Every drive to FAULT with ``error_code`` (a communication error), torque zero."""
        with self.lock:
            now = self._catch_up()
            for d in self.drives:
                d.communication_fault(error_code, now)
            self._apply_torques(now, from_host=False)

    def pop_emcy(self) -> list[tuple[int, Emcy]]:
        """EMCY events since the last call, as (node id, event)."""
        with self.lock:
            out: list[tuple[int, Emcy]] = []
            for node, d in self._node_drives:
                events = d.pop_emcy()
                if events:
                    out.extend((node, e) for e in events)
            return out

    def feedback(self, node: int | None = None, unit: int | None = None) -> Feedback:
        with self.lock:
            return self._feedback(self._drive_index(node, unit))

    # ---- helpers ----------------------------------------------------------------------------
    def _feedback(self, i: int) -> Feedback:
        d = self.drives[i]
        return Feedback(
            self.profiles[i].node_id,
            d.statusword,
            d.position_counts,
            d.velocity_counts_s,
            d.torque_actual_permille,
        )

    def _drive_index(self, node: int | None, unit: int | None) -> int:
        i = self.by_node.get(node) if node is not None else self.by_unit.get(unit)  # type: ignore[arg-type]
        if i is None:
            raise KeyError(
                f"no drive at node {node}" if node is not None else f"no drive at unit {unit}"
            )
        return i

    def pdo_mapping(self, node: int, mapping_index: int) -> tuple[tuple[int, int], ...]:
        """The configured mapping of a PDO (0x1600 RPDO1, 0x1A00 TPDO1, 0x1A01 TPDO2)."""
        with self.lock:
            i = self._drive_index(node, None)
            cached = self._mapping_cache.get((i, mapping_index))
            if cached is not None:
                return cached
            store = self._store[i]
            n = store[(mapping_index, 0)]
            mapping = tuple(
                (store[(mapping_index, s)] >> 16, store[(mapping_index, s)] >> 8 & 0xFF)
                for s in range(1, n + 1)
            )
            self._mapping_cache[(i, mapping_index)] = mapping
            return mapping

    def pdo_cob_id(self, node: int, comm_index: int) -> int | None:
        """COB-ID of a PDO if it is valid (bit 31 clear), else None."""
        with self.lock:
            value = self._store[self._drive_index(node, None)][(comm_index, 1)]
            return None if value & 0x80000000 else value & 0x7FF

    @staticmethod
    def _initial_objects(p: DriveProfile) -> dict[tuple[int, int], int]:
        """Power-on values (the EDS defaults, drivers.protocol.cia402.power_on_objects)."""
        return co.power_on_objects(
            p.node_id, p.vendor_id, p.product_code, p.rated_torque_Nm, p.counts_per_rev
        )

    def _write_stored(self, i: int, index: int, subindex: int, value: int) -> None:
        self._mapping_cache.clear()
        self.config_version += 1
        store = self._store[i]
        if index in (0x1600, 0x1A00, 0x1A01):
            if subindex == 0:
                if value > 2:
                    raise SdoAbortError(index, subindex, co.ABORT_VALUE_TOO_HIGH)
                entries = [store[(index, s)] for s in range(1, value + 1)]
                size = 0
                for e in entries:
                    obj = co.OBJECT_MAP.get((e >> 16, e >> 8 & 0xFF))
                    if obj is None or not obj.pdo or (e & 0xFF) != obj.size * 8:
                        raise SdoAbortError(index, subindex, co.ABORT_NOT_MAPPABLE)
                    if (index == 0x1600) != (obj.access is co.Access.RW):
                        raise SdoAbortError(index, subindex, co.ABORT_NOT_MAPPABLE)
                    size += obj.size
                if size > 8:
                    raise SdoAbortError(index, subindex, co.ABORT_PDO_LENGTH)
            elif store[(index, 0)] != 0:
                # CiA 301: entries may only change while the mapping is disabled (sub 0 = 0)
                raise SdoAbortError(index, subindex, co.ABORT_NOT_IN_STATE)
        elif index in (0x1400, 0x1800, 0x1801) and subindex == 2 and value != co.TRANSMISSION_SYNC:
            raise SdoAbortError(index, subindex, co.ABORT_VALUE_RANGE)  # only synchronous (1)
        elif index in (0x1400, 0x1800, 0x1801) and subindex == 1:
            base = {0x1400: co.RPDO1_BASE, 0x1800: co.TPDO1_BASE, 0x1801: co.TPDO2_BASE}[index]
            if value & 0x7FF != base + self.profiles[i].node_id or value & 0x3FFFF800:
                raise SdoAbortError(index, subindex, co.ABORT_VALUE_RANGE)
        store[(index, subindex)] = value
