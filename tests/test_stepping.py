"""The one stepping sequence (virtual_robot.stepping.Stepper) and the served robot's use of it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from drivers.recording import read_signals
from drivers.units import position_to_rad, torque_to_permille
from profiles.drive import load_drive
from profiles.experiment import load_experiment
from profiles.robot import load_robot
from profiles.timing_faults import SideFaults, TimingFaults
from virtual_robot.drive import MODE_CST, DriveModel
from virtual_robot.offline import ENABLE_SEQUENCE
from virtual_robot.robot import LOCKSTEP, REALTIME, VirtualRobot
from virtual_robot.simulate import simulate
from virtual_robot.stepping import Stepper
from virtual_robot.timing_faults import RobotTiming

ROBOT = load_robot("cicese")
H = 0.0025


class UnitMasses:
    """n independent unit inertias (q̈_i = τ_i), exact under a held torque: a plant that is
    not the 2-DOF arm, with the methods a stepper uses."""

    def __init__(self, n: int) -> None:
        self.t = 0.0
        self.q = [0.0] * n
        self.v = [0.0] * n
        self.tau = [0.0] * n
        self.log: list[tuple[float, tuple[float, ...]]] = []  # (issued_at, torque) per command

    @property
    def measured_q(self) -> list[float]:
        return self.q

    @property
    def dq(self) -> list[float]:
        return self.v

    def command(self, torque_Nm, issued_at=None, powered=None, deliver_at=None) -> None:
        self.tau = [t if p else 0.0 for t, p in zip(torque_Nm, powered, strict=True)]
        self.log.append((issued_at, tuple(torque_Nm)))

    def set_powered(self, powered) -> None:
        raise AssertionError("not used without timing faults")

    def advance_to(self, t_end: float) -> None:
        dt = t_end - self.t
        for i, a in enumerate(self.tau):
            self.q[i] += self.v[i] * dt + 0.5 * a * dt * dt
            self.v[i] += a * dt
        self.t = t_end


def _enabled_drives(n: int) -> list[DriveModel]:
    drives = [DriveModel(load_drive(ROBOT.drives[i % 2]), period_s=H) for i in range(n)]
    for d in drives:
        d.update(0.0, 0.0, 0.0, count_period=False)
        d.write_mode(MODE_CST)
        for cw in ENABLE_SEQUENCE:
            d.write_controlword(cw, 0.0)
    return drives


def test_lockstep_sequence_on_an_n_joint_plant() -> None:
    """Sample at t_k, command, hold over [t_k, t_k+1): each torque written after SYNC k reaches
    the plant at the next SYNC, issued at t_k, and moves it exactly over one period."""
    plant = UnitMasses(3)
    drives = _enabled_drives(3)
    stepper = Stepper(plant, drives, H)
    assert stepper.sync() == 0.0 and plant.log == []  # nothing commanded before SYNC 0
    permille = (100, -50, 0)
    for d, p in zip(drives, permille, strict=True):
        d.write_target_torque(p, 0.0)
    tau = [d.torque_Nm for d in drives]
    assert stepper.sync() == H
    assert plant.log == [(0.0, tuple(tau))]
    assert plant.q == [0.5 * a * H * H for a in tau]
    assert stepper.sync() == 2 * H  # the torque is held: re-issued at t_1
    assert plant.log[-1] == (H, tuple(tau)) and plant.v == [a * 2 * H for a in tau]
    stepper.advance()  # the held torque over one more period, no sample
    assert plant.t == 3 * H and stepper.syncs == 3
    counts = [d.position_counts for d in drives]  # sampled at 2H, not at 3H
    assert counts == [
        int(np.floor(0.5 * a * (2 * H) ** 2 / d.profile.rad_per_count))
        for a, d in zip(tau, drives, strict=True)
    ]


def test_served_lockstep_is_the_offline_simulation(tmp_path: Path) -> None:
    """The served robot stepped by hand (writes between SYNCs) records what `simulate` does."""
    n = 200
    simulate(ROBOT, load_experiment("reyes-kelly"), tmp_path, duration_s=n * H, plot=False)
    rec = read_signals(tmp_path)
    core = VirtualRobot(ROBOT, mode=LOCKSTEP, period_s=H)
    for node in (1, 2):
        core.write(0x6060, 0, MODE_CST, node=node)
        for cw in ENABLE_SEQUENCE:
            core.write(0x6040, 0, cw, node=node)
    drives = [load_drive(name) for name in ROBOT.drives]
    q = []
    for k in range(n):
        fb = core.sync()
        q.append(
            [
                position_to_rad(f.position_counts, d.counts_per_rev)
                for f, d in zip(fb, drives, strict=True)
            ]
        )
        for i, node in enumerate((1, 2)):
            permille = torque_to_permille(rec.tau[k, i], drives[i].rated_torque_Nm)
            core.write(0x6071, 0, permille, node=node, apply=False)
    assert np.array_equal(np.array(q), rec.q)
    assert np.max(np.abs(rec.q)) > 0.2  # it moved


class FakeClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def _realtime_core(timing: RobotTiming | None = None) -> tuple[VirtualRobot, FakeClock, list]:
    clock = FakeClock()
    core = VirtualRobot(ROBOT, mode=REALTIME, period_s=H, clock=clock, timing=timing)
    events: list[tuple[str, int, float]] = []
    core.event_log = lambda event, n, t: events.append((event, n, t))
    for node in (1, 2):
        core.write(0x6060, 0, MODE_CST, node=node)
        for cw in ENABLE_SEQUENCE:
            core.write(0x6040, 0, cw, node=node)
    clock.now = 0.001
    core.sync_sample()
    return core, clock, events


def test_a_tick_between_writes_and_their_application_is_a_logged_command() -> None:
    """Realtime: a period tick that falls between a host's writes (apply=False) and their
    application delivers them; the event log must say so at that time, or `hil replay` applies
    the command later than the run did (the 2–3 count replay flake)."""
    core, clock, events = _realtime_core()
    clock.now = 0.0015
    core.write(0x6071, 0, 500, node=1, apply=False)
    assert core.plant.command_Nm == (0.0, 0.0)  # not applied yet
    clock.now = 0.0020
    core.tick()
    assert core.plant.command_Nm[0] != 0.0  # the tick applied it
    assert ("command", 1, 0.0020) in events
    clock.now = 0.0024
    del events[:]
    core.apply_commands()
    assert events == []  # already applied, at the tick


def test_a_tick_does_not_lose_a_pending_command_under_timing_faults() -> None:
    """With injected latency the tick's delivery is a host command (delayed), not a bare power
    switch that would drop the pending torque until the next write."""
    faults = TimingFaults("latency.toml", robot=SideFaults(latency_s=0.0002))
    core, clock, events = _realtime_core(RobotTiming(faults, lockstep=False, period_s=H))
    clock.now = 0.0015
    core.write(0x6071, 0, 500, node=1, apply=False)
    clock.now = 0.0020
    core.tick()
    core.apply_commands()
    clock.now = 0.0030
    core.tick()
    expected = 500 * load_drive(ROBOT.drives[0]).rated_torque_Nm / 1000
    assert core.plant.command_Nm == (expected, 0.0)
    assert [e for e in events if e[0] == "command"][-1] == ("command", 1, 0.0020 + 0.0002)
