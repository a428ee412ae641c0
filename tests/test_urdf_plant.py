"""The n-joint virtual arm (virtual_robot/urdf_plant.py), n-joint recordings and experiments, and
the 3-DOF example arm end to end: `virtual-robot simulate --robot cicese3`, then
`hil identify --from ... --robot cicese3` recovering its base parameters (issue 14)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from cicese3_targets import check_cicese3_identified, energy_balance_over_excitation

from drivers.recording import BASE_COLUMNS, RecordingWriter, base_columns, read_signals
from hil.cli import main as hil_main
from hil.model.urdf import UrdfArmModel
from profiles.experiment import load_experiment
from profiles.robot import load_any_robot, load_robot, load_urdf_robot
from virtual_robot.cli import main as vr_main
from virtual_robot.plant import Plant, PlantParams
from virtual_robot.urdf_plant import UrdfPlant, UrdfPlantParams


def test_recording_writer_n_joints_and_2dof_unchanged(tmp_path):
    assert base_columns() == BASE_COLUMNS == ("t", "q1", "q2", "tau1", "tau2")
    with RecordingWriter(tmp_path / "two", {"period_s": 0.0025}) as rec:
        rec.write((0.0, 0.1, 0.2, 1.0, 2.0))
    assert (tmp_path / "two" / "signals.csv").read_text().splitlines()[0] == "t,q1,q2,tau1,tau2"
    with RecordingWriter(tmp_path / "three", {"period_s": 0.0025}, ("s1",), n_joints=3) as rec:
        rec.write((0.0, 0.1, 0.2, 0.3, 1.0, 2.0, 3.0, 7))
        rec.write((0.0025, 0.11, 0.21, 0.31, 1.5, 2.5, 3.5, 7))
        with pytest.raises(ValueError, match="8 columns"):
            rec.write((0.005, 0.1, 0.2, 1.0, 2.0))
    header = (tmp_path / "three" / "signals.csv").read_text().splitlines()[0]
    assert header == "t,q1,q2,q3,tau1,tau2,tau3,s1"
    back = read_signals(tmp_path / "three")
    assert back.n_joints == 3
    assert back.q[1].tolist() == [0.11, 0.21, 0.31] and back.tau[1].tolist() == [1.5, 2.5, 3.5]
    with pytest.raises(ValueError, match="at least one joint"):
        base_columns(0)


def test_experiment_n_joints():
    three = load_experiment("cicese3-excitation")
    assert three.n_joints == 3 and three.initial_q_rad == (0.0, 0.0, 0.0)
    assert three.torque_table(np.array([0.0, 0.1])).shape == (2, 3)
    two = load_experiment("reyes-kelly")
    assert two.n_joints == 2 and two.torque_table(np.array([0.0])).shape == (1, 2)
    with pytest.raises(ValueError, match="drives 2 joint") as exc:
        two.check_joints(3, "cicese3")
    assert "\n" not in str(exc.value)


def _planar_pair(step_s: float = 5e-4):
    """The CICESE arm twice: the closed-form 2-DOF plant and the URDF plant of cicese.urdf."""
    closed = Plant(PlantParams.from_profiles(load_robot("cicese")), max_step_s=step_s)
    urdf = UrdfPlant(UrdfPlantParams.from_profile(load_urdf_robot("cicese")), max_step_s=step_s)
    return closed, urdf


def test_urdf_plant_matches_the_closed_form_plant():
    """Same arm, same held torques (Reyes & Kelly eqs. (31)-(32), 10 s), sticks included: the
    Pinocchio plant and the closed-form plant agree to round-off, stick event for event."""
    closed, urdf = _planar_pair()
    experiment = load_experiment("reyes-kelly")
    h = experiment.period_s
    rows = round(experiment.duration_s / h)  # the paper's 10 s; 126 stick events
    torques = experiment.torque_table(np.arange(rows) * h)
    worst = 0.0
    for k in range(rows):
        closed.command(tuple(torques[k]), issued_at=k * h)
        urdf.command(torques[k])
        closed.advance_to((k + 1) * h)
        urdf.advance_to((k + 1) * h)
        worst = max(worst, abs(closed.q1 - urdf.q[0]), abs(closed.q2 - urdf.q[1]))
    assert urdf.stick_events > 10 and closed.stick_events == urdf.stick_events
    assert worst < 1e-10, worst  # 5e-12 rad measured


def textbook_rk4(plant: UrdfPlant, dt: float) -> tuple[np.ndarray, np.ndarray, float]:
    """The oracle for the plant's step: classical RK4 on (q, q̇) with q̈ of the current stick
    mode from CRBA and RNEA, M_FF q̈_F = (τ − C q̇ − g − f)_F, q̈_S = 0, solved by numpy; and the
    RK4 quadrature of the viscous power bᵀq̇²."""
    m, d, n = plant.model, plant.data, plant.n_joints
    free = ~plant.stuck
    tau, b, level = plant.command_Nm, plant.b, plant._level

    def accel(q, v):
        M = pin.crba(m, d, q)
        M = np.triu(M) + np.triu(M, 1).T
        r = tau - pin.nonLinearEffects(m, d, q, v) - (b * v + level)
        a = np.zeros(n)
        a[free] = np.linalg.solve(M[np.ix_(free, free)], r[free])
        return a

    q, v, h = plant.q, plant.dq, 0.5 * dt
    a1 = accel(q, v)
    y = v + h * a1
    a2 = accel(q + h * v, y)
    z = v + h * a2
    a3 = accel(q + h * y, z)
    u = v + dt * a3
    a4 = accel(q + dt * z, u)
    k = dt / 6
    viscous = k * b @ (v * v + 2 * y * y + 2 * z * z + u * u)
    return q + k * (v + 2 * y + 2 * z + u), v + k * (a1 + 2 * a2 + 2 * a3 + a4), viscous


def test_mode_steps_equal_the_textbook_rk4():
    """The plant's step (:func:`_rk4_aba`: the arm's ABA, or the ABA of the arm with its stuck
    joints locked) against :func:`textbook_rk4`, every joint sliding and with joint 2 stuck."""
    robot = load_urdf_robot("cicese3")
    for dq0 in ([1.0, -2.0, 3.0], [1.0, 0.0, 3.0]):
        plant = UrdfPlant(UrdfPlantParams.from_profile(robot), q0=[0.3, -0.4, 0.5], dq0=dq0)
        stuck = dq0[1] == 0.0
        assert plant.stuck.tolist() == [False, stuck, False]
        plant.command([20.0, 0.3, 0.7])
        fast = plant._rk4_mode(5e-4)
        for a, b in zip(fast, textbook_rk4(plant, 5e-4), strict=True):
            assert np.allclose(a, b, rtol=1e-12, atol=1e-13)
        if stuck:
            assert fast[1][1] == 0.0 and fast[0][1] == plant.q[1]


def test_plant_dynamics_are_the_host_models_and_energy_balances():
    """The world's ABA agrees with the host's URDF model (built separately) on M q̈ + C q̇ + g +
    f = τ, and over 3 s with stick events the energy balance E − E0 = W_in − W_f holds."""
    robot = load_urdf_robot("cicese3")
    host = UrdfArmModel.from_profile(robot)
    plant = UrdfPlant(UrdfPlantParams.from_profile(robot), q0=[0.2, -0.3, 0.4], dq0=[0.5, 1, -2])
    tau = np.array([10.0, 1.0, -0.2])
    plant.command(tau)
    a = plant._accelerations(plant.q, plant.dq)
    model_tau = host.torque(host.base_theta(), plant.q[None], plant.dq[None], a[None])[0]
    # the plant's Coulomb level per direction is the host's mean level sgn q̇ plus its offset
    assert np.allclose(model_tau, tau, rtol=0, atol=1e-9)
    balance = energy_balance_over_excitation(plant, 1200)
    assert plant.stick_events > 0
    assert abs(balance) < 1e-6 * plant.work_in_J, (balance, plant.work_in_J)


def test_stuck_joint_holds_inside_its_band_and_breaks_away_outside():
    robot = load_urdf_robot("cicese3")
    plant = UrdfPlant(UrdfPlantParams.from_profile(robot))
    assert plant.stuck.all()  # at rest, hanging down: every joint stuck
    plant.command([5.0, 1.0, 0.3])  # inside every static band (7.17, 1.734, 0.35 Nm)
    plant.advance_to(0.2)
    assert np.array_equal(plant.q, np.zeros(3)) and plant.stuck.all()
    plant.command([0.0, 0.0, 0.5])  # beyond joint 3's 0.35 Nm
    plant.advance_to(0.4)
    # the wrist moves; its reaction on joint 1 stays far inside joint 1's 7 Nm band
    assert plant.q[2] > 0.001 and plant.stuck[0] and plant.q[0] == 0.0
    assert plant.work_in_J > 0


def test_simulate_cli_writes_an_n_joint_recording(tmp_path, capsys):
    out = tmp_path / "sim"
    args = ["simulate", "--robot", "cicese3", "--experiment", "cicese3-excitation"]
    assert vr_main([*args, "--duration", "0.5", "--out", str(out), "--no-plot", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["rows"] == 200 and summary["faults"] == []
    rec = read_signals(out)
    assert rec.n_joints == 3 and list(rec.columns)[:7] == list(base_columns(3))
    assert "status3" in rec.columns and rec.meta["n_joints"] == 3
    assert np.abs(rec.q[-1]).min() > 0  # every joint moved
    # a 2-joint experiment on the 3-joint arm, a 3-joint one on the 2-DOF arm, and effects the
    # n-joint plant does not have: one-line errors, nothing written
    for bad in (
        ["--robot", "cicese3", "--experiment", "reyes-kelly"],
        ["--robot", "cicese", "--experiment", "cicese3-excitation"],
        ["--robot", "cicese3", "--experiment", "cicese3-excitation", "--effects", "cogging"],
    ):
        assert vr_main(["simulate", *bad, "--out", str(tmp_path / "no"), "--no-plot"]) == 2
        err = capsys.readouterr().err.strip()
        assert "error" in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "no" / "signals.csv").exists()
    assert isinstance(load_any_robot("cicese3"), type(load_urdf_robot("cicese3")))


def test_cicese3_identified_from_its_simulation(tmp_path, capsys):
    """`virtual-robot simulate` then `hil identify --from` on the 3-DOF arm: the base parameters
    within the CICESE targets of docs/identification.md (inertial and gravity ones within 2 %,
    viscous and Coulomb within 10 %), the centre-of-mass offsets (nominal 0) within 1 % of the
    joint's gravity parameter, and a held-out last quarter predicted as well as the true model."""
    sim = tmp_path / "sim"
    args = ["simulate", "--robot", "cicese3", "--experiment", "cicese3-excitation"]
    assert vr_main([*args, "--out", str(sim), "--no-plot", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["faults"] == []
    out = tmp_path / "id"
    assert hil_main(["identify", "--from", str(sim), "--robot", "cicese3", "--out", str(out)]) == 0
    report = json.loads((out / "identify.json").read_text())
    check_cicese3_identified(report)
    # without --robot the recording's own robot (meta.json) is used; the 2-DOF model refuses
    # an n-joint recording in one line
    again = tmp_path / "id-again"
    assert hil_main(["identify", "--from", str(sim), "--out", str(again)]) == 0
    assert json.loads((again / "identify.json").read_text())["parameters"] == report["parameters"]
    capsys.readouterr()
    for bad in (
        ["identify", "--from", str(sim), "--robot", "cicese", "--out", str(tmp_path / "x")],
        ["diagnose", str(sim), "--robot", "cicese", "--out", str(tmp_path / "y")],
    ):
        assert hil_main(bad) == 2
        err = capsys.readouterr().err.strip().splitlines()[-1]
        assert "3 joints" in err and "takes 2" in err, err


def test_simulate_refuses_an_arm_without_drives(tmp_path, capsys):
    experiment = tmp_path / "seven.toml"
    joints = "\n".join("[[joints]]\nstep_Nm = 0.0" for _ in range(7))
    head = 'name = "seven"\nkind = "open_loop_torque"\nperiod_s = 0.0025\nduration_s = 0.1\n'
    experiment.write_text(f"{head}{joints}\n")
    assert load_experiment(experiment).n_joints == 7
    out = tmp_path / "panda"
    args = ["simulate", "--robot", "panda", "--experiment", str(experiment), "--out", str(out)]
    assert vr_main(args) == 2
    err = capsys.readouterr().err.strip()
    assert "drives" in err and len(err.splitlines()) == 1, err


# ---- the plant's trajectory, frozen (issue 14 speed work must not change the physics) ---------
REFERENCE = Path(__file__).parent / "data" / "urdf_plant_reference.npz"


def reference_run(robot_name: str) -> dict[str, np.ndarray]:
    """2 s of the n-joint plant at h = 2.5 ms, 0.5 ms RK4 steps, in every regime: all joints
    sliding, some stuck while others move, sticks and breakaways. cicese3: its excitation for
    1.2 s, then 0.8 s of a small torque inside the bands (the joints stop and stick one by one).
    panda: gravity compensation at the row's start (the plant's own RNEA) plus sines of 0.2 to
    1.5 Nm around a mid configuration: its joints sweep through zero velocity many times.
    Returns the state after every row and the energy bookkeeping at the end."""
    robot = load_urdf_robot(robot_name)
    h, rows = 0.0025, 800
    if robot_name == "panda":
        q0 = [0.0, 0.2, 0.0, -1.6, 0.0, 1.8, 0.4]
        plant = UrdfPlant(UrdfPlantParams.from_profile(robot), q0=q0)
        amp = np.linspace(1.5, 0.2, 7)
        w = np.linspace(3.0, 11.0, 7)

        def torque(k: int) -> np.ndarray:
            g = pin.computeGeneralizedGravity(plant.model, plant.data, plant.q)
            return g + amp * np.sin(w * k * h + np.arange(7))
    else:
        plant = UrdfPlant(UrdfPlantParams.from_profile(robot))
        experiment = load_experiment(robot.name + "-excitation")

        def torque(k: int) -> np.ndarray:
            tau = np.asarray(experiment.torque(k * h), dtype=float)
            return tau if k < 480 else 0.02 * tau

    q, dq = np.zeros((rows, plant.n_joints)), np.zeros((rows, plant.n_joints))
    for k in range(rows):
        plant.command(torque(k))
        plant.advance_to((k + 1) * h)
        q[k], dq[k] = plant.q, plant.dq
    counts = np.array([plant.steps, plant.stick_events])
    return {
        "q": q,
        "dq": dq,
        "energy": np.array([plant.work_in_J, plant.dissipated_J]),
        "counts": counts,
    }


def write_reference() -> None:
    """Regenerate tests/data/urdf_plant_reference.npz (only when the physics change on purpose):
    python -c "import sys; sys.path.insert(0, 'tests'); import test_urdf_plant as t;
    t.write_reference()" """
    runs = {name: reference_run(name) for name in ("cicese3", "panda")}
    np.savez_compressed(
        REFERENCE, **{f"{name}_{k}": v for name, run in runs.items() for k, v in run.items()}
    )


@pytest.fixture(params=["python", "compiled"])
def plant_kernel(request, monkeypatch):
    """Each plant step in turn (virtual_robot/compiled_step.py): the Python step forced, and
    the compiled one required (skipped only on a machine without a C++ compiler). Yields a
    counter of the compiled calls, to show the compiled step did run."""
    from virtual_robot import urdf_plant
    from virtual_robot.compiled_step import KERNEL_ENV, kernel_status

    monkeypatch.setenv(KERNEL_ENV, request.param)
    if request.param == "compiled":
        import os
        import shutil

        if shutil.which(os.environ.get("CXX", "g++")) is None:
            pytest.skip("no C++ compiler: the compiled plant step cannot be built here")
        assert kernel_status().kernel == "compiled"
    calls = [0]
    advance = urdf_plant.UrdfPlant._advance_compiled

    def counted(self, t_end):
        calls[0] += 1
        return advance(self, t_end)

    monkeypatch.setattr(urdf_plant.UrdfPlant, "_advance_compiled", counted)
    return request.param, calls


@pytest.mark.parametrize("robot_name", ["cicese3", "panda"])
def test_plant_trajectory_unchanged(robot_name, plant_kernel):
    """The plant of today, with the Python step and with the compiled one, against its
    trajectory frozen before the speed work of issue 14 (generated at commit 88ab6f1 by
    :func:`write_reference`): same steps, same stick events, the state after each of 800 rows
    equal to round-off."""
    kernel, compiled_calls = plant_kernel
    expected = np.load(REFERENCE)
    run = reference_run(robot_name)
    assert (compiled_calls[0] > 40) == (kernel == "compiled")  # 415 and 48 calls measured
    assert run["counts"].tolist() == expected[f"{robot_name}_counts"].tolist()
    assert run["counts"][1] > 10  # the scenario does exercise sticking
    assert np.allclose(run["q"], expected[f"{robot_name}_q"], rtol=0, atol=1e-11)
    assert np.allclose(run["dq"], expected[f"{robot_name}_dq"], rtol=0, atol=1e-9)
    assert np.allclose(run["energy"], expected[f"{robot_name}_energy"], rtol=1e-11, atol=1e-11)
