"""One stepping sequence of drives and plant: the served robot's and the offline simulation's.

:class:`Stepper` is the one place where the drives' torques reach the plant, the plant is
integrated and the encoders are sampled. :class:`~virtual_robot.robot.VirtualRobot` (behind every
transport) and :func:`~virtual_robot.simulate.simulate` (``virtual-robot simulate``) both step
through it, so a lockstep run over any bench and an offline simulation of the same torques are
one computation (docs/design.md "Time").

**Lockstep** (:meth:`Stepper.sync`, one SYNC or serial step): robot time stands still between
SYNCs. SYNC 0 samples at t_0 = 0. SYNC n > 0 first gives the plant the torques the drives hold
(written since SYNC n − 1, so issued at t_{n−1}) with their power states, integrates the plant
over [t_{n−1}, t_n) with that torque held, t_n = n·h, then samples every drive's encoder at t_n.
With timing faults or a timing trace (virtual_robot/timing_faults.py) the command of cycle k
takes effect when :class:`RobotTiming` says and sample n is taken at its ``sample_time(n)``.

**Realtime** (:class:`VirtualRobot` in realtime mode) uses :meth:`Stepper.sample` and
:meth:`Stepper.apply` on its own clock; :meth:`Stepper.sync` is lockstep only.

No lock and no I/O here: the served robot calls a stepper with its own lock held (a server
thread and a period-timer thread share it); the offline simulation, alone with it, calls it
directly, which keeps ``simulate`` well above real time.

The stepper knows the plant only through :class:`SteppedPlant` and the drives only through
:class:`SteppedDrive`, for any number of joints: the 2-DOF :class:`~virtual_robot.plant.Plant`
or an n-joint plant with the same methods.

May import: numpy; nothing of this project beyond virtual_robot.timing_faults (types only).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Protocol

import numpy as np

if TYPE_CHECKING:
    from virtual_robot.timing_faults import RobotTiming


class SteppedPlant(Protocol):
    """What a stepper needs of a plant (virtual_robot.plant.Plant has it)."""

    t: float  # plant time: integrated up to here

    @property
    def measured_q(self) -> Sequence[float]: ...  # what the encoders see, rad

    @property
    def dq(self) -> Sequence[float]: ...  # joint rates, rad/s

    def command(
        self,
        torque_Nm: Sequence[float],
        issued_at: float | None = None,
        powered: Sequence[bool] | None = None,
        deliver_at: float | None = None,
    ) -> None: ...

    def set_powered(self, powered: Sequence[bool]) -> None: ...

    def advance_to(self, t_end: float) -> None: ...


class SteppedDrive(Protocol):
    """What a stepper needs of a drive (virtual_robot.drive.DriveModel has it)."""

    @property
    def torque_Nm(self) -> float: ...  # the torque it applies now (0 unless enabled)

    @property
    def powered(self) -> bool: ...  # power stage on

    def update(
        self, now: float, position_rad: float, velocity_rad_s: float, count_period: bool = True
    ) -> None: ...


class Stepper:
    """Drives and plant stepped through robot time (module docstring). Not thread-safe."""

    def __init__(
        self,
        plant: SteppedPlant,
        drives: Sequence[SteppedDrive],
        period_s: float,
        *,
        timing: RobotTiming | None = None,
        lockstep: bool = True,
    ) -> None:
        self.plant = plant
        self.drives = tuple(drives)
        self.period_s = period_s
        self.timing = timing
        self.lockstep = lockstep
        self.t = 0.0  # robot time of the last sample (lockstep) or event (realtime)
        self.syncs = 0  # SYNCs (serial steps) so far
        # the drives hold commands the plant has not been given yet (lockstep: every write
        # between two SYNCs; realtime: writes made with apply=False)
        self.unapplied = False
        self._pushed: tuple[int, tuple[float, ...]] | None = None  # lockstep: last queued

    # ---- the two primitives -----------------------------------------------------------------
    def sample(self, now: float, count_period: bool = True) -> None:
        """Every drive samples its encoder (the plant's measured q and q̇) at ``now``;
        ``count_period``: one period of its command watchdog passes (DriveModel.update)."""
        measured, rates = self.plant.measured_q, self.plant.dq
        if hasattr(measured, "tolist"):  # numpy's: the drives' arithmetic on its scalars costs
            measured, rates = measured.tolist(), rates.tolist()  # twice Python floats' (same bits)
        for i, d in enumerate(self.drives):
            d.update(now, measured[i], rates[i], count_period)

    def apply(
        self,
        now: float,
        from_host: bool = True,
        held: tuple[tuple[float, ...], tuple[bool, ...]] | None = None,
    ) -> float | None:
        """Give the plant the drives' torques and power states, issued at ``now`` (``held``:
        those the caller knows the drives hold, (torques, powered), instead of reading them).

        ``from_host``: a command the host just sent (timing faults delay it); else the robot's
        own re-issue of what the drives hold (a period tick, a safe stop), which with timing
        faults only switches the power stages at once. Returns when a host's command takes
        effect, for the realtime event log (None where nothing is logged: a re-issue, or a
        lockstep delivery under timing faults).
        """
        self.unapplied = False
        if held is None:
            drives = self.drives
            powered = tuple([d.powered for d in drives])
            cmd = tuple([d.torque_Nm for d in drives])
        else:
            cmd, powered = held
        timing = self.timing
        if timing is None:
            self.plant.command(cmd, issued_at=now, powered=powered)
            return now if from_host else None
        if not from_host:
            self.plant.set_powered(powered)
            return None
        if not self.lockstep:
            at = timing.realtime_delivery(now)
            self.plant.command(cmd, issued_at=now, powered=powered, deliver_at=at)
            return at
        self._deliver_lockstep(timing, now, cmd, powered)
        return None

    # ---- lockstep -----------------------------------------------------------------------------
    def advance(self, held: tuple[tuple[float, ...], tuple[bool, ...]] | None = None) -> float:
        """Lockstep: the plant given the held commands (issued at t_{n−1}; ``held``: as
        :meth:`apply` takes it) and integrated to the time t_n of the next sample
        (n = :attr:`syncs`); no sample. Returns t_n."""
        if self.unapplied:
            self.apply(self.t, held=held)
        n = self.syncs
        timing = self.timing
        if n > 0:
            if timing is None:
                # t_n = n·h exactly, as the recordings compute it (no accumulated sum)
                self.t = n * self.period_s
                self.plant.advance_to(self.t)
            else:  # the sample time a timing trace imposes, on the trace's integration grid
                self.t = timing.sample_time(n)
                timing.advance(self.plant, self.t)
        elif timing is not None and timing.trace is not None:
            # a trace runs on the recorded robot's clock: the plant, at rest until now, starts
            # there (so the replay integrates the same time arithmetic)
            self.t = self.plant.t = timing.sample_time(0)
        return self.t

    def sync(self) -> float:
        """Lockstep: one SYNC (:meth:`advance`, then every drive samples at t_n, one drive
        period). Until the next SYNC the plant stands still; whatever the drives are commanded
        meanwhile, it is given then. Returns t_n."""
        return self.sampled(self.advance())

    def sampled(self, t: float, drives: bool = True) -> float:
        """Lockstep: the rest of a SYNC after :meth:`advance` to t_n: every drive samples at t_n
        (``drives`` False: none does; the caller reads the plant itself and brings the drives
        up to date later, virtual_robot.offline's held rows), one drive period. Returns t_n."""
        if drives:
            self.sample(t, True)
        self.unapplied = True
        self.syncs += 1
        return t

    def advance_held(
        self,
        torques: np.ndarray,
        bounds: tuple[np.ndarray, np.ndarray],
        q_out: np.ndarray,
        dq_out: np.ndarray,
    ) -> tuple[int, bool]:
        """Lockstep without timing faults, the drives bypassed (virtual_robot.offline's held
        rows): SYNCs one after another, before the j-th the plant given ``torques[j]`` held
        over its period with every amplifier powered (:meth:`advance`), after it the plant's
        measured q and q̇ into q_out[j], dq_out[j] and no drive samples (:meth:`sampled`).
        Stops after the first SYNC where some |q̇_i| > bounds[0]_i or |q_i| > bounds[1]_i (or
        a NaN): that SYNC is not counted and its drives not sampled; the plant stands at its
        time, :attr:`t`. Returns (SYNCs advanced, whether the last was inside the bounds). A
        plant with ``advance_periods`` (the n-joint plant's compiled kernel) takes the periods
        it can in one call; the rest go one :meth:`advance` at a time."""
        assert self.timing is None and self.lockstep and self.unapplied
        m, h = len(torques), self.period_s
        done, inside = 0, True
        periods = getattr(self.plant, "advance_periods", None)
        if periods is not None and m:
            done, inside = periods(torques, self.syncs, h, bounds, q_out, dq_out)
            if done:  # as :meth:`advance` and :meth:`sampled` leave it, SYNC by SYNC
                self.unapplied = inside  # given; after a counted SYNC, the next row's is not
                self.t = (self.syncs + done - 1) * h
                self.syncs += done - (0 if inside else 1)
        if not inside:
            return done, False
        powered = (True,) * len(self.drives)
        max_speed, max_q = bounds
        for j, row in enumerate(torques[done:].tolist(), start=done):
            t = self.advance((tuple(row), powered))
            q, dq = self.plant.measured_q, self.plant.dq
            q_out[j], dq_out[j] = q, dq
            if not ((np.abs(dq) <= max_speed).all() and (np.abs(q) <= max_q).all()):
                return j + 1, False
            self.sampled(t, drives=False)
        return m, True

    def _deliver_lockstep(
        self,
        timing: RobotTiming,
        now: float,
        cmd: tuple[float, ...],
        powered: tuple[bool, ...],
    ) -> None:
        """Lockstep with timing faults or a trace: queue the command of cycle k = syncs − 1 for
        the time it takes effect (before the first sample: now). Each new command is queued
        once; where a trace has joint 1's command arrive before the others', joint 1's goes
        first, with the other joints still holding the previous one."""
        k = self.syncs - 1
        first, at = timing.deliveries(k, now) if k >= 0 else (now, now)
        pushed = self._pushed
        if pushed is not None and pushed[1] == cmd:
            self.plant.set_powered(powered)  # nothing new to deliver
            return
        if pushed is not None and pushed[0] == k:  # a second write of the same cycle
            first = at
        if first < at and pushed is not None:
            joint1_first = (cmd[0], *pushed[1][1:])
            self.plant.command(joint1_first, issued_at=now, powered=powered, deliver_at=first)
        self.plant.command(cmd, issued_at=now, powered=powered, deliver_at=at)
        self._pushed = (k, cmd)
