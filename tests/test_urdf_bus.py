"""N drives on the bus for a URDF arm (issue 14): the virtual robot serving the 3-DOF example arm
(cicese3) behind every transport, `hil run --robot cicese3` recording it bit-identical to
`virtual-robot simulate` (also with a concealed effect on joint 3), host limits per joint from the
robot profile, and what the n-joint plant does not take refused in one line."""

from __future__ import annotations

import json
import re
from pathlib import Path

import can
import numpy as np
import pytest
from cicese3_targets import check_cicese3_identified
from cli_run import assert_same_recording, hil

from drivers.recording import base_columns, read_signals
from profiles import ProfileError
from profiles.bench import bench_for_robot, load_bench
from profiles.effects import load_effects
from profiles.experiment import load_experiment
from profiles.robot import load_urdf_robot
from virtual_robot.robot import VirtualRobot
from virtual_robot.urdf_plant import UrdfPlant, simulate_urdf

EXPERIMENT = "cicese3-excitation"  # moves every joint from the first period (joint 3: 3 sines)
DURATION_S = 1.0
ROWS = 400
# the shipped benches whose transports the 2-DOF arm's lockstep test covers (tests/test_hil_run)
BENCHES = ["virtual-inprocess", "virtual-slcan", "virtual-serial"]


def simulate_cicese3(out: Path, effects: str | None = None) -> object:
    """`virtual-robot simulate --robot cicese3 [--effects E]` of the excitation's first second."""
    simulate_urdf(
        load_urdf_robot("cicese3"),
        load_experiment(EXPERIMENT),
        out,
        effects=load_effects(effects),
        duration_s=DURATION_S,
        plot=False,
    )
    return read_signals(out)


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> object:
    """`virtual-robot simulate --robot cicese3` of the first second of the excitation."""
    return simulate_cicese3(tmp_path_factory.mktemp("sim3"))


def run_cicese3(out: Path, bench: str, *options: str) -> dict:
    """`hil run --bench BENCH --robot cicese3` of the excitation into ``out``; its summary."""
    args = ["--bench", bench, "--robot", "cicese3", "--experiment", EXPERIMENT, *options]
    proc = hil("run", *args, "--out", str(out), "--json", "--no-plot")
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def test_virtual_robot_serves_one_drive_per_joint_of_a_urdf_arm():
    """Nodes and unit addresses 1..3 (the drive profiles'), the n-joint plant, one feedback per
    drive per SYNC; the drives enable over the object dictionary as a host would."""
    core = VirtualRobot(load_urdf_robot("cicese3"))
    assert isinstance(core.plant, UrdfPlant) and core.plant.n_joints == 3
    assert sorted(core.by_node) == [1, 2, 3] and sorted(core.by_unit) == [1, 2, 3]
    for node in (1, 2, 3):
        core.write(0x6060, 0, 10, node=node)  # cyclic synchronous torque
        for cw in (0x06, 0x07, 0x0F):
            core.write(0x6040, 0, cw, node=node)
    feedback = core.sync()
    assert [f.node for f in feedback] == [1, 2, 3]
    assert all(f.statusword & 0x6F == 0x27 for f in feedback)  # operation enabled
    core.write(0x6071, 0, 250, node=3)  # 25 % of joint 3's 4 Nm
    for _ in range(40):
        feedback = core.sync()
    assert feedback[2].position_counts > 0 and core.t == pytest.approx(40 * 0.0025)
    # the arm is coupled: the reaction turns joint 2 the other way; joint 1's 7 Nm band holds
    assert feedback[1].position_counts < 0 and feedback[0].position_counts == 0


def test_n_joint_robot_refuses_what_it_cannot_take():
    """A 2-DOF effects profile (arrays of 2) and a payload on the n-joint arm: a one-line error
    when the robot is built, not a run that silently lacks them. Timing faults it takes
    (tests/test_timing_faults.py, "n joints")."""
    robot = load_urdf_robot("cicese3")
    for name, words in (
        ("cogging", "must be a list of 3 numbers (robot cicese3 has 3 joints)"),
        ("payload", "takes no payload effect"),
    ):
        with pytest.raises(ValueError, match=re.escape(words)) as err:
            VirtualRobot(robot, load_effects(name))
        assert "\n" not in str(err.value)
    VirtualRobot(robot, load_effects("none"))  # the empty profile is no effect
    core = VirtualRobot(robot, load_effects("joint3-gain"))
    assert isinstance(core.plant, UrdfPlant) and core.plant._gain_offset is not None


def test_bench_for_robot_takes_host_limits_from_the_robot_profile(tmp_path):
    bench = load_bench("virtual-slcan")
    assert bench_for_robot(bench) == bench  # the bench's own robot keeps the bench's limits
    three = bench_for_robot(bench, "cicese3")
    own = load_urdf_robot("cicese3").limits
    assert own is not None and three.robot == "cicese3"
    assert three.torque_limit_Nm == own.torque_Nm == (200.0, 15.0, 4.0)
    assert three.velocity_limit_rad_s == (12.0, 25.0, 25.0)
    assert three.position_limit_rad == ((-3.2, 3.2),) * 3
    with pytest.raises(ProfileError, match="names no drives") as err:  # panda.toml: none
        bench_for_robot(bench, "panda")
    assert "\n" not in str(err.value)
    panda = tmp_path / "panda.toml"  # with drives but without [limits]: 2 joints' limits, 7 joints
    text = Path(load_urdf_robot("panda").source).read_text()
    text = text.replace('urdf = "panda.urdf"', f'urdf = "{load_urdf_robot("panda").urdf}"')
    drives = ", ".join(['"dm1200a"'] * 7)
    panda.write_text(text.replace("[joints]\n", f"[joints]\ndrives = [{drives}]\n"))
    with pytest.raises(ProfileError, match="panda has 7") as err:
        bench_for_robot(bench, str(panda))
    assert "\n" not in str(err.value)
    # a bench whose [limits] are a 3-joint arm's: its own robot uses them
    text = Path(bench.source).read_text().replace('robot = "cicese"', 'robot = "cicese3"')
    text = text.split("[limits]")[0] + (
        "[limits]\ntorque_Nm = [100.0, 10.0, 2.0]\nvelocity_rad_s = [5.0, 5.0, 5.0]\n"
        "position_rad = [[-1.0, 1.0], [-2.0, 2.0], [-3.0, 3.0]]\n"
    )
    path = tmp_path / "three.toml"
    path.write_text(text)
    mine = bench_for_robot(load_bench(path))
    assert mine.torque_limit_Nm == (100.0, 10.0, 2.0) and mine.position_limit_rad[2] == (-3, 3)
    path.write_text(text.replace("[-3.0, 3.0]]", "]"))
    with pytest.raises(ProfileError, match="position_rad"):
        load_bench(path)


@pytest.mark.parametrize("bench", BENCHES)
def test_lockstep_run_of_cicese3_equals_offline_simulation(bench, reference, tmp_path):
    """`hil run --robot cicese3` over CAN (in-process, slcan) and the serial multi-drop line:
    three drives, q1..q3 and tau1..tau3 bit-identical to `virtual-robot simulate`."""
    summary = run_cicese3(tmp_path, bench, "--duration", str(DURATION_S))
    assert summary["status"] == "complete" and summary["rows"] == ROWS
    rec = read_signals(tmp_path)
    assert rec.n_joints == 3 and list(rec.columns)[:7] == list(base_columns(3))
    assert_same_recording(rec, reference)
    assert np.ptp(rec.q[:, 2]) > 0.05  # joint 3 really moves
    meta = json.loads((tmp_path / "meta.json").read_text())
    assert meta["status"] == "complete" and meta["robot"] == "cicese3"
    log = Path(summary["traffic_log"])
    if log.name == "bus.log":  # node 3's RPDO and both TPDOs on the bus
        ids = {m.arbitration_id for m in can.LogReader(str(log))}
        assert {0x183, 0x203, 0x283} <= ids
    else:
        assert "3_" in log.read_text()  # unit address 3 on the multi-drop line


# the torque path (delay, lag), cogging within the step and the encoder offset, per joint
TORQUE_PATH = """name = "torque-path"
[transport_delay]
delay_s = 0.0007
[amplifier_lag]
time_constant_s = [0.002, 0.0, 0.003]
[cogging]
joint = 3
periods_per_rev = 50
amplitude_Nm = 0.1
[encoder_offset]
offset_rad = [0.001, 0.0, -0.002]
"""


@pytest.mark.parametrize(
    "bench, effects", [("virtual-slcan", "joint3-asymmetry"), ("virtual-inprocess", TORQUE_PATH)]
)
def test_lockstep_run_with_effects_equals_its_simulation(bench, effects, reference, tmp_path):
    """`hil run --robot cicese3 --effects joint3-asymmetry` over slcan (and a profile with the
    torque-path effects in process): bit-identical to `virtual-robot simulate` with the same
    effects, not to the effect-free run; meta.json records the effects' name as the 2-DOF run
    does, and the host never loads the profile's contents (the robot process applies them)."""
    if "\n" in effects:
        (tmp_path / "torque-path.toml").write_text(effects)
        effects = str(tmp_path / "torque-path.toml")
    simulated = simulate_cicese3(tmp_path / "sim", effects)
    summary = run_cicese3(tmp_path / "run", bench, "--effects", effects,
                          "--duration", str(DURATION_S))  # fmt: skip
    assert summary["status"] == "complete" and summary["rows"] == ROWS
    rec = read_signals(tmp_path / "run")
    assert_same_recording(rec, simulated)
    assert np.array_equal(rec.tau, reference.tau)
    assert np.max(np.abs(rec.q[:, 2] - reference.q[:, 2])) > 0.001  # the effect is there
    meta = json.loads((tmp_path / "run" / "meta.json").read_text())
    assert meta["effects"] == effects and simulated.meta["effects"] == Path(effects).stem
    for concealed in ("coulomb", "amplifier_lag", "cogging"):  # the name only, never the values
        assert concealed not in json.dumps(meta)


def test_run_refuses_what_the_robot_cannot_take(tmp_path):
    """A 2-joint experiment on the 3-joint arm, and a 2-DOF effects profile on it: the host
    refuses both before starting the robot (usage, 2; the effects profile checked for the
    robot's joints by hil.bench.run.check_virtual_robot_profiles, issue 31), one line each
    naming the profile's file and key, and --out left unwritten."""
    for extra, words, status in (
        (["--experiment", "reyes-kelly"], "robot cicese3 has 3", 2),
        (
            ["--experiment", EXPERIMENT, "--effects", "cogging"],
            "field 'cogging.periods_per_rev'",
            2,
        ),
    ):
        out = tmp_path / f"r{len(extra)}"
        args = ["run", "--bench", "virtual-inprocess", "--robot", "cicese3", *extra]
        proc = hil(*args, "--duration", "0.1", "--out", str(out), "--no-plot", timeout=50)
        assert proc.returncode == status, proc.stderr
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and words in lines[0], proc.stderr
        assert not out.exists()


def test_realtime_run_of_cicese3_completes(tmp_path):
    """A short realtime run over slcan: every row, drives enabled throughout, every joint
    moving. Loose by design (the shared machine's load): timing figures are `make bench`'s."""
    summary = run_cicese3(tmp_path, "virtual-slcan", "--mode", "realtime", "--duration", "1")
    assert summary["status"] == "complete"
    rec = read_signals(tmp_path)
    assert len(rec) == ROWS and rec.n_joints == 3
    for col in ("status1", "status2", "status3"):
        assert np.all((rec.columns[col].astype(int) & 0x6F) == 0x27)  # operation enabled
    assert np.all(np.ptp(rec.q, axis=0) > 0.01)  # every joint moves


def test_cicese3_identified_from_its_bus_recording(tmp_path):
    """The whole excitation (20 s) over slcan in lockstep, then `hil identify --from` it: the
    robot is read from the recording's meta.json, and the base parameters meet the targets the
    offline simulation's identification meets (tests/test_urdf_plant.py)."""
    run = tmp_path / "run"
    assert run_cicese3(run, "virtual-slcan")["rows"] == 8000
    out = tmp_path / "id"
    proc = hil("identify", "--from", str(run), "--out", str(out), "--no-plot")
    assert proc.returncode == 0, proc.stderr
    report = json.loads((out / "identify.json").read_text())
    assert report["robot"] == "cicese3"  # from meta.json: no --robot given
    check_cicese3_identified(report)
