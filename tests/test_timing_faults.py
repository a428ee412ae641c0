"""Timing-fault injection (issue 6, part B): profiles, the virtual robot's side in lockstep, the
host's wrapper around its Arm (lockstep and realtime)."""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from drivers.arm import Arm, Fault, LinkStats, Sample
from drivers.fault_injection import TimingFaultArm, with_host_faults
from drivers.recording import read_signals
from hil.bench.run import run_experiment
from profiles import ProfileError
from profiles.bench import load_bench
from profiles.drive import load_drive
from profiles.effects import load_effects
from profiles.experiment import load_experiment
from profiles.robot import load_robot, load_urdf_robot
from profiles.timing_faults import (
    Jitter,
    SideFaults,
    Stall,
    TimingFaults,
    combine,
    draw_jitter,
    stream,
    to_toml,
)
from virtual_robot.simulate import simulate
from virtual_robot.timing_faults import RobotTiming

H = 0.0025
SLCAN = Path(__file__).resolve().parents[1] / "profiles" / "benches" / "virtual-slcan.toml"


def effects_file(tmp_path: Path, text: str, name: str = "fx") -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(f'name = "{name}"\n' + text)
    return path


# ---- profiles -----------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("text", "field", "words"),
    [
        ("[timing_faults.robot]\nlatency_s = -0.001\n", "timing_faults.robot.latency_s", ">= 0"),
        ("[timing_faults.robot]\nlatency_s = 2.0\n", "timing_faults.robot.latency_s", "<= 1.0"),
        ("[timing_faults.robot]\nlatncy_s = 0.001\n", "timing_faults.robot.latncy_s", "unknown"),
        (
            "[timing_faults.robot]\ndrop_probability = 1.5\n",
            "timing_faults.robot.drop_probability",
            "<= 1.0",
        ),
        (
            '[timing_faults.robot]\njitter = { distribution = "cauchy", scale_s = 1e-4 }\n',
            "timing_faults.robot.jitter.distribution",
            "normal, uniform, exponential",
        ),
        (
            "[timing_faults.robot]\njitter = { scale_s = -1e-4 }\n",
            "timing_faults.robot.jitter.scale_s",
            ">= 0",
        ),
        ("[timing_faults.host]\nlatency_s = 0.001\n", "timing_faults.host", "bench profile"),
        ("[timing_faults.robot]\nstall = { at_s = 1.0 }\n", "timing_faults.robot.stall", "unknown"),
        ("[timing_faults]\nseed = -1\n", "timing_faults.seed", ">= 0"),
        ('[timing_faults.trace]\nfile = "nope.csv"\n', "timing_faults.trace.file", "no such"),
        ("timing_faults = 3\n", "timing_faults", "must be a table"),
    ],
)
def test_effects_timing_faults_errors_are_one_line(
    tmp_path: Path, text: str, field: str, words: str
) -> None:
    path = effects_file(tmp_path, text)
    with pytest.raises(ProfileError) as err:
        load_effects(path)
    message = str(err.value)
    assert "\n" not in message
    assert err.value.field == field, message
    assert words in message
    assert str(path) in message


def test_bench_timing_faults_parse_both_sides(tmp_path: Path) -> None:
    text = SLCAN.read_text() + (
        "\n[timing_faults]\nseed = 7\n"
        "[timing_faults.host]\nlatency_s = 0.001\n"
        'jitter = { distribution = "exponential", scale_s = 2e-4 }\n'
        "drop_probability = 0.01\nfeedback_delay_s = 5e-4\n"
        "stall = [{ at_s = 2.0, duration_s = 0.05 }, { at_s = 4.0, duration_s = 0.01 }]\n"
        "[timing_faults.robot]\nlatency_s = 0.002\n"
    )
    path = tmp_path / "bench.toml"
    path.write_text(text)
    tf = load_bench(path).timing_faults
    assert tf is not None and tf.seed == 7
    assert tf.host == SideFaults(
        latency_s=0.001,
        jitter=Jitter("exponential", 2e-4),
        drop_probability=0.01,
        feedback_delay_s=5e-4,
        stalls=(Stall(2.0, 0.05), Stall(4.0, 0.01)),
    )
    assert tf.robot.latency_s == 0.002 and not tf.robot.random
    assert tf.host.random and tf.active
    # a bench without the table has none; the shipped ones are unchanged
    assert load_bench("virtual-slcan").timing_faults is None


def test_robot_side_in_bench_and_effects_is_refused() -> None:
    a = TimingFaults("a.toml", robot=SideFaults(latency_s=0.001))
    b = TimingFaults("b.toml", robot=SideFaults(drop_probability=0.1))
    with pytest.raises(ValueError, match="robot-side timing faults are set in both"):
        combine(a, b)
    h = TimingFaults("h.toml", host=SideFaults(latency_s=0.001))
    both = combine(h, a)
    assert both is not None and both.host == h.host and both.robot == a.robot
    assert combine(None, TimingFaults()) is None


def test_to_toml_round_trips_a_profile() -> None:
    data = tomllib.loads((Path(SLCAN)).read_text())
    data["timing_faults"] = {
        "seed": 3,
        "robot": {"latency_s": 1e-3, "jitter": {"distribution": "normal", "scale_s": 2e-4}},
        "host": {"stall": [{"at_s": 1.0, "duration_s": 0.02}]},
    }
    data["description"] = 'quote " and back\\slash'
    assert tomllib.loads(to_toml(data)) == data


def test_jitter_draws_are_non_negative_and_seeded() -> None:
    for dist in ("normal", "uniform", "exponential"):
        j = Jitter(dist, 1e-3)
        a = [draw_jitter(stream(5, 1), j) for _ in range(3)]
        rng = stream(5, 1)
        b = np.array([draw_jitter(rng, j) for _ in range(2000)])
        assert a[0] == a[1] == a[2]  # a fresh stream of the same seed: the same first draw
        assert b.min() >= 0
        mean = {"normal": math.sqrt(2 / math.pi), "uniform": 0.5, "exponential": 1.0}[dist]
        assert b.mean() == pytest.approx(mean * 1e-3, rel=0.08)
    assert draw_jitter(stream(0, 1), None) == 0.0


# ---- robot side, lockstep ------------------------------------------------------------------------
def test_robot_timing_lockstep_delays() -> None:
    """d_k = latency + feedback delay + J_k of both sides; frames do not overtake."""
    faults = TimingFaults(
        robot=SideFaults(latency_s=1e-3, jitter=Jitter("uniform", 4e-3)),
        host=SideFaults(feedback_delay_s=5e-4),
    )
    timing = RobotTiming(faults, lockstep=True, period_s=H, seed=1)
    deliveries = [timing.deliveries(k, k * H)[1] for k in range(400)]
    assert timing.deliveries(399, 399 * H)[1] == deliveries[-1]  # drawn once per cycle
    delays = np.array(deliveries) - np.arange(400) * H
    assert delays.min() >= 1.5e-3 - 1e-15
    assert np.all(np.diff(deliveries) >= 0)
    again = RobotTiming(faults, lockstep=True, period_s=H, seed=1)
    assert [again.deliveries(k, k * H)[1] for k in range(400)] == deliveries
    other = RobotTiming(faults, lockstep=True, period_s=H, seed=2)
    assert [other.deliveries(k, k * H)[1] for k in range(400)] != deliveries


def test_robot_latency_in_lockstep_is_a_transport_delay(tmp_path: Path) -> None:
    """An injected 1 ms robot-side latency in lockstep applies τ_k at exactly t_k + 1 ms: the
    run is bit-identical to the offline simulation with a 1 ms transport delay effect."""
    latency = effects_file(tmp_path, "[timing_faults.robot]\nlatency_s = 0.001\n", "lat")
    delay = effects_file(tmp_path, "[transport_delay]\ndelay_s = 0.001\n", "delay")
    run = run_experiment(
        "virtual-inprocess",
        "reyes-kelly",
        tmp_path / "run",
        duration_s=1.0,
        effects=str(latency),
        plot=False,
        progress=False,
    )
    assert run["status"] == "complete"
    sim = tmp_path / "sim"
    experiment = load_experiment("reyes-kelly")
    robot = load_robot("cicese")
    simulate(robot, experiment, sim, effects=load_effects(delay), duration_s=1.0, plot=False)
    simulate(robot, experiment, tmp_path / "plain", duration_s=1.0, plot=False)
    a, b, plain = (
        read_signals(tmp_path / "run"),
        read_signals(sim),
        read_signals(tmp_path / "plain"),
    )
    assert np.array_equal(a.q, b.q) and np.array_equal(a.tau, b.tau)
    assert np.max(np.abs(a.q - plain.q)) > 1e-4  # the latency does move the arm differently
    meta = json.loads((tmp_path / "run" / "meta.json").read_text())
    assert meta["timing_faults"]["robot"]["latency_s"] == 0.001


def test_robot_drops_are_counted_and_deterministic(tmp_path: Path, capsys) -> None:
    fx = effects_file(
        tmp_path, "[timing_faults]\nseed = 4\n[timing_faults.robot]\ndrop_probability = 0.1\n"
    )
    runs = []
    for name in ("a", "b"):
        capsys.readouterr()
        run = run_experiment(
            "virtual-inprocess",
            "reyes-kelly",
            tmp_path / name,
            duration_s=1.0,
            effects=str(fx),
            plot=False,
            progress=False,
        )
        assert run["status"] == "complete"
        line = next(ln for ln in capsys.readouterr().err.splitlines() if "timing faults:" in ln)
        runs.append(json.loads(line.split("timing faults: ", 1)[1]))
    frames = 2 * 400  # one RPDO per drive per cycle (and the safe stop's)
    dropped = runs[0]["dropped_commands"]
    assert abs(dropped - 0.1 * frames) < 4 * math.sqrt(frames * 0.1 * 0.9), dropped
    assert runs[1]["dropped_commands"] == dropped
    a, b = read_signals(tmp_path / "a"), read_signals(tmp_path / "b")
    assert np.array_equal(a.q, b.q)


# ---- host side -----------------------------------------------------------------------------------
class StubArm(Arm):
    """An Arm that records what it is sent; q_k = (k, -k)."""

    def __init__(self, mode: str = "lockstep") -> None:
        self.period_s, self.mode, self.stats = H, mode, LinkStats()
        self.sent: list[tuple[float, ...]] = []
        self.k = 0

    def open(self) -> None: ...
    def close(self) -> None: ...
    def enable(self) -> None: ...
    def disable(self) -> None: ...
    def clear_faults(self) -> None: ...

    def faults(self) -> list[Fault]:
        return []

    def start(self) -> Sample:
        self.k = 0
        return Sample(0.0, (0.0, 0.0), (0x1637, 0x1637))

    def cycle(self, tau_Nm: Sequence[float], deadline: float | None = None) -> Sample:
        self.sent.append(tuple(tau_Nm))
        self.k += 1
        return Sample(self.k * H, (float(self.k), -float(self.k)), (0x1637, 0x1637), tuple(tau_Nm))


def drive(arm: Arm, n: int) -> list[Sample]:
    arm.start()
    return [arm.cycle((float(k), 10.0 + k)) for k in range(n)]


def test_host_drops_hold_the_previous_command_and_are_counted() -> None:
    stub = StubArm()
    arm = TimingFaultArm(stub, SideFaults(drop_probability=0.25), seed=3)
    drive(arm, 1000)
    held = [k for k, tau in enumerate(stub.sent) if tau != (float(k), 10.0 + k)]
    assert arm.fault_stats.dropped_commands == len(held)
    assert abs(len(held) - 250) < 4 * math.sqrt(1000 * 0.25 * 0.75)
    for k in held:  # the drives hold what reached them last
        assert stub.sent[k] == stub.sent[k - 1]
    again = TimingFaultArm(StubArm(), SideFaults(drop_probability=0.25), seed=3)
    drive(again, 1000)
    assert again.fault_stats.dropped_commands == len(held)


def test_host_stall_in_lockstep_holds_the_last_command() -> None:
    stub = StubArm()
    arm = TimingFaultArm(stub, SideFaults(stalls=(Stall(0.1, 0.02),)))
    drive(arm, 100)
    stalled = [k for k in range(100) if 0.1 <= k * H < 0.12]
    assert stalled == list(range(40, 48))
    assert all(stub.sent[k] == stub.sent[39] for k in stalled)
    assert stub.sent[48] == (48.0, 58.0)
    assert arm.fault_stats.stalled_cycles == 8 and arm.fault_stats.stalls == 1


def test_host_feedback_drop_reuses_the_previous_sample() -> None:
    arm = TimingFaultArm(StubArm(), SideFaults(feedback_drop_probability=0.3), seed=1)
    samples = drive(arm, 500)
    stale = [k for k in range(1, 500) if samples[k].q_rad[0] != k + 1]
    assert len(stale) == arm.fault_stats.dropped_feedback > 100
    for k in stale:
        assert samples[k].q_rad == samples[k - 1].q_rad
        assert samples[k].t == (k + 1) * H  # the cycle's own time


def test_with_host_faults_wraps_only_when_needed() -> None:
    stub = StubArm()
    assert with_host_faults(stub, None) is stub
    delays = TimingFaults(host=SideFaults(latency_s=1e-3))
    assert with_host_faults(stub, delays) is stub  # lockstep: the robot imposes delays
    assert isinstance(with_host_faults(StubArm("realtime"), delays), TimingFaultArm)
    drops = TimingFaults(host=SideFaults(drop_probability=0.1), seed=9)
    wrapped = with_host_faults(stub, drops)
    assert isinstance(wrapped, TimingFaultArm) and wrapped.seed == 9
    assert with_host_faults(stub, drops, seed=2).seed == 2  # --seed overrides the profile


def realtime_bench(tmp_path: Path, name: str, extra: str = "") -> Path:
    """virtual-slcan under another name with ``extra`` TOML appended."""
    text = SLCAN.read_text().replace('name = "virtual-slcan"', f'name = "{name}"')
    path = tmp_path / f"{name}.toml"
    path.write_text(text + extra)
    return path


def test_host_latency_is_measured_in_the_recorded_timestamps(tmp_path: Path) -> None:
    """Realtime: 1 ms of host-side latency makes every SYNC leave at least 1 ms after its
    deadline and the feedback arrive at least 0.5 ms later; the recording's stamps show it.

    Only floors are asserted: the injected delay is a sleep that never ends early, so every cycle
    keeps it, while a loaded machine only adds to it (CI beside other work measured 2.6 ms for
    the 10th percentile where a quiet machine gives 1.0 ms)."""
    lateness = {}
    for name, extra in (
        ("plain", ""),
        ("late", "\n[timing_faults.host]\nlatency_s = 0.001\nfeedback_delay_s = 0.0005\n"),
    ):
        bench = realtime_bench(tmp_path, name, extra)
        run = run_experiment(
            str(bench),
            "reyes-kelly",
            tmp_path / name,
            duration_s=1.0,
            mode="realtime",
            plot=False,
            progress=False,
        )
        assert run["status"] == "complete", run["reason"]
        c = read_signals(tmp_path / name).columns
        # row 0 is the start-up sample, not a cycle
        lateness[name] = (
            (c["sync_sent_s"] - c["deadline_s"])[1:],
            (c["feedback_s"] - c["sync_sent_s"])[1:],
        )
    release, feedback = lateness["late"]
    assert release.min() >= 1e-3 - 1e-6
    assert feedback.min() >= 5e-4 - 1e-6
    # the floor is the injection's, not the machine's: without it the fastest cycles are faster
    assert lateness["plain"][0].min() < release.min()
    meta = json.loads((tmp_path / "late" / "meta.json").read_text())
    injected = meta["timing_faults"]["host_injected"]
    assert injected["cycles"] == 400 and injected["mean_delay_s"] == pytest.approx(1e-3)


# ---- n joints: the same faults on the n-joint plant (virtual_robot/urdf_plant.py) --------------
CICESE3_EXCITATION = "cicese3-excitation"


def run_cicese3(out: Path, effects: Path, bench: str = "virtual-inprocess") -> dict:
    """`hil run --robot cicese3` of the first second of its excitation with ``effects``."""
    return run_experiment(
        bench,
        CICESE3_EXCITATION,
        out,
        duration_s=1.0,
        effects=str(effects),
        plot=False,
        progress=False,
        robot="cicese3",
    )


def test_n_joint_robot_latency_in_lockstep_is_a_transport_delay(tmp_path: Path) -> None:
    """The 2-DOF test above on the 3-joint arm: a 1 ms robot-side latency in lockstep applies
    τ_k at t_k + 1 ms on every joint, bit-identical to the n-joint offline simulation with a
    1 ms transport delay effect, and the recording differs from the undelayed one."""
    from virtual_robot.urdf_plant import simulate_urdf

    latency = effects_file(tmp_path, "[timing_faults.robot]\nlatency_s = 0.001\n", "lat")
    delay = effects_file(tmp_path, "[transport_delay]\ndelay_s = 0.001\n", "delay")
    assert run_cicese3(tmp_path / "run", latency)["status"] == "complete"
    robot, experiment = load_urdf_robot("cicese3"), load_experiment(CICESE3_EXCITATION)
    for name, fx in (("sim", load_effects(delay)), ("plain", None)):
        simulate_urdf(robot, experiment, tmp_path / name, effects=fx, duration_s=1.0, plot=False)
    a, b, plain = (read_signals(tmp_path / name) for name in ("run", "sim", "plain"))
    assert a.q.shape == (400, 3)
    assert np.array_equal(a.q, b.q) and np.array_equal(a.tau, b.tau)
    moved = np.max(np.abs(a.q - plain.q), axis=0)
    assert np.all(moved > 1e-5), moved  # the latency moves every joint differently
    meta = json.loads((tmp_path / "run" / "meta.json").read_text())
    assert meta["timing_faults"]["robot"]["latency_s"] == 0.001


@pytest.mark.parametrize("bench", ["virtual-inprocess", "virtual-serial"])
def test_n_joint_robot_drops_are_counted_and_deterministic(
    tmp_path: Path, capsys, bench: str
) -> None:
    """Lost command frames on the 3-joint arm, on the bus and on the serial line: counted at
    the injected rate, the same run for the same seed, and the arm moves otherwise than
    without them (a drive holds its previous torque)."""
    fx = effects_file(
        tmp_path, "[timing_faults]\nseed = 4\n[timing_faults.robot]\ndrop_probability = 0.1\n"
    )
    runs = []
    for name in ("a", "b"):
        capsys.readouterr()
        assert run_cicese3(tmp_path / name, fx, bench)["status"] == "complete"
        # the robot's summary line: on stderr in process, in virtual-robot.log from its process
        log = tmp_path / name / "virtual-robot.log"
        lines = capsys.readouterr().err + (log.read_text() if log.exists() else "")
        line = next(ln for ln in lines.splitlines() if "timing faults:" in ln)
        runs.append(json.loads(line.split("timing faults: ", 1)[1]))
    frames = 3 * 400  # one command frame per drive per cycle
    dropped = runs[0]["dropped_commands"]
    assert abs(dropped - 0.1 * frames) < 4 * math.sqrt(frames * 0.1 * 0.9), dropped
    assert runs[1]["dropped_commands"] == dropped
    a, b = read_signals(tmp_path / "a"), read_signals(tmp_path / "b")
    assert np.array_equal(a.q, b.q)
    plain = effects_file(tmp_path, "", "plain")
    assert run_cicese3(tmp_path / "plain", plain, bench)["status"] == "complete"
    assert np.max(np.abs(a.q - read_signals(tmp_path / "plain").q)) > 1e-4


def test_n_joint_realtime_command_takes_effect_after_the_latency() -> None:
    """Realtime on the 3-joint arm: a command arriving at t takes effect at t + latency (the
    plant holds the previous torque until then), and the event log says when."""
    from virtual_robot.drive import MODE_CST
    from virtual_robot.offline import ENABLE_SEQUENCE
    from virtual_robot.robot import REALTIME, VirtualRobot

    now = [0.0]
    faults = TimingFaults("latency.toml", robot=SideFaults(latency_s=0.001))
    robot = load_urdf_robot("cicese3")
    core = VirtualRobot(
        robot,
        mode=REALTIME,
        period_s=H,
        clock=lambda: now[0],
        timing=RobotTiming(faults, lockstep=False, period_s=H),
    )
    events: list[tuple[str, int, float]] = []
    core.event_log = lambda event, n, t: events.append((event, n, t))
    for node in (1, 2, 3):
        core.write(0x6060, 0, MODE_CST, node=node)
        for cw in ENABLE_SEQUENCE:
            core.write(0x6040, 0, cw, node=node)
    now[0] = 0.001
    core.sync_sample()
    now[0] = 0.0015
    core.write(0x6071, 0, 250, node=3)  # 25 % of joint 3's rated torque
    now[0] = 0.0024
    core.tick()
    assert np.array_equal(core.plant.command_Nm, np.zeros(3))  # not arrived yet
    now[0] = 0.0026
    core.tick()
    rated = load_drive(robot.drives[2]).rated_torque_Nm
    assert np.array_equal(core.plant.command_Nm, [0.0, 0.0, 0.25 * rated])
    assert ("command", 1, pytest.approx(0.0025)) in events
    assert core.timing is not None and core.timing.stats.max_delay_s == pytest.approx(0.001)
