"""Concealed effects on the n-joint virtual arm (issue 14; virtual_robot/urdf_plant.py and
docs/effects.md): effects profiles fitted to any number of joints (arrays per joint, or
``joint = k``), each effect of the 2-DOF vocabulary on the joint it names and no other, the
energy balance with effects, and the one-line errors. The bus run with an effect is
tests/test_urdf_bus.py's."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from cicese3_targets import energy_balance_over_excitation

from drivers.recording import read_signals
from profiles import ProfileError
from profiles.effects import EffectsProfile, load_effects
from profiles.experiment import load_experiment
from profiles.robot import load_robot, load_urdf_robot
from virtual_robot.cli import main as vr_main
from virtual_robot.plant import PlantParams
from virtual_robot.urdf_plant import UrdfPlant, UrdfPlantParams

Q0 = np.array([0.3, -0.5, 0.4])
DQ0 = np.array([0.8, -1.5, -2.0])  # every joint sliding; joint 3 backwards


def robot():
    return load_urdf_robot("cicese3")


def write_effects(tmp_path: Path, text: str, name: str = "fx") -> EffectsProfile:
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return load_effects(path)


def plant_with(effects: EffectsProfile | None = None, **kw) -> UrdfPlant:
    return UrdfPlant(UrdfPlantParams.from_profile(robot(), effects), **kw)


def gravity(plant: UrdfPlant, q: np.ndarray) -> np.ndarray:
    """g(q): the torques that hold the arm still at q (independent of the plant's code)."""
    zero = np.zeros(plant.n_joints)
    return pin.rnea(plant.model, plant.model.createData(), q, zero, zero)


def expected_accelerations(plant: UrdfPlant, tau: np.ndarray, friction: np.ndarray) -> np.ndarray:
    """q̈ = ABA(q, q̇, τ − f) of a sliding arm, f written out by the test."""
    return pin.aba(plant.model, plant.model.createData(), plant.q, plant.dq, tau - friction)


def robot_friction(v: np.ndarray, pos=None, neg=None) -> np.ndarray:
    """cicese3's friction per joint while sliding, b q̇ + F(dir) dir (its robot profile)."""
    b = np.array([2.288, 0.175, 0.05])
    pos = np.array([7.17, 1.734, 0.35]) if pos is None else pos
    neg = np.array([8.049, 1.734, 0.40]) if neg is None else np.asarray(neg)
    return b * v + np.where(v > 0, pos, -neg)


# ---- effects profiles for n joints ----------------------------------------------------------
def test_2dof_profiles_load_unchanged_and_mean_the_same():
    """The shipped 2-DOF profiles fit the 2-DOF arm as before (2-tuples, same values)."""
    cogging = load_effects("cogging").for_joints(2, "cicese")
    assert cogging.cogging.periods_per_rev == (120.0, 96.0)
    assert cogging.cogging.amplitude_Nm == (1.5, 0.12)
    miscal = load_effects("miscalibrated").for_joints(2, "cicese")
    assert miscal.torque_gain_error == (0.04, -0.03) and miscal.torque_offset_Nm == (0.6, 0.05)
    assert miscal.encoder_offset_rad == (0.003, -0.002)
    none = load_effects("none").for_joints(3, "cicese3")
    assert none.encoder_offset_rad == (0.0,) * 3 and none.torque_gain_error == (0.0,) * 3
    p = PlantParams.from_profiles(load_robot("cicese"), load_effects("stribeck"))
    assert p.breakaway_positive_Nm == (7.17 * 1.35, 1.734 * 1.25)
    assert p.encoder_offset_rad == (0.0, 0.0) and p.torque_offset_Nm == (0.0, 0.0)


def test_joint_k_spreads_over_the_arm(tmp_path):
    """``joint = 3``: the value on joint 3, no effect elsewhere; Coulomb keeps the robot's."""
    fx = load_effects("joint3-asymmetry").for_joints(3, "cicese3")
    assert fx.coulomb.positive_Nm == (None, None, 0.25)
    params = UrdfPlantParams.from_profile(robot(), load_effects("joint3-asymmetry"))
    assert params.coulomb_positive_Nm == (7.17, 1.734, 0.25)
    assert params.coulomb_negative_Nm == (8.049, 1.734, 0.65)
    gain = load_effects("joint3-gain").for_joints(7, "panda")  # any arm with a joint 3
    assert gain.torque_gain_error == (0.0, 0.0, 0.07, 0.0, 0.0, 0.0, 0.0)
    fx = write_effects(
        tmp_path, "[stribeck]\njoint = 2\nbreakaway_ratio = 1.5\nvelocity_rad_s = 0.1\n"
    ).for_joints(3, "cicese3")
    assert fx.stribeck.breakaway_ratio == (1.0, 1.5, 1.0)


@pytest.mark.parametrize(
    "text, n, key, words",
    [
        ("[cogging]\nperiods_per_rev = [1, 2]\namplitude_Nm = [1, 2]\n", 3, "periods_per_rev",
         "must be a list of 3 numbers (robot arm has 3 joints), got 2"),
        ("[torque_offset]\noffset_Nm = [1, 2, 3]\n", 2, "torque_offset.offset_Nm",
         "must be a list of 2 numbers"),
        ("[coulomb]\njoint = 3\npositive_Nm = 1\nnegative_Nm = 1\n", 2, "coulomb.joint",
         "joint 3: robot arm has 2 joints"),
    ],
)  # fmt: skip
def test_wrong_length_or_joint_is_one_line_naming_file_and_key(tmp_path, text, n, key, words):
    fx = write_effects(tmp_path, text)
    with pytest.raises(ProfileError) as err:
        fx.for_joints(n, "arm")
    message = str(err.value)
    assert "\n" not in message and str(tmp_path / "fx.toml") in message
    assert key in message and words in message


@pytest.mark.parametrize(
    "text, words",
    [
        ("[transport_delay]\njoint = 1\ndelay_s = 0.001\n", "unknown field"),
        ("[payload]\njoint = 1\nmass_kg = 1\ndistance_m = 0.1\n", "unknown field"),
        ("[torque_offset]\njoint = 3\noffset_Nm = [1, 2]\n", "must be a number"),
        ("[torque_offset]\njoint = 0\noffset_Nm = 1\n", "must be >= 1"),
        ("[torque_offset]\noffset_Nm = 1\n", "one per joint (or set joint = k)"),
        ("[cogging]\njoint = 3\namplitude_Nm = 1\n", "missing"),
    ],
)
def test_bad_joint_tables_are_one_line(tmp_path, text, words):
    with pytest.raises(ProfileError) as err:
        write_effects(tmp_path, text)
    assert "\n" not in str(err.value) and words in str(err.value)


def test_shipped_profiles_run_on_the_3_joint_arm_or_say_why():
    """Every shipped effects profile either runs on cicese3 (finite motion) or is refused in
    one line: arrays written for the 2-DOF arm, or a payload."""
    from profiles import available

    experiment = load_experiment("cicese3-excitation")
    ran = []
    for name in available("effects"):
        try:
            plant = plant_with(load_effects(name))
        except ValueError as err:
            assert "\n" not in str(err) and ("list of 3 numbers" in str(err) or "payload" in name)
            continue
        for k in range(40):
            plant.command(experiment.torque(k * experiment.period_s))
            plant.advance_to((k + 1) * experiment.period_s)
        assert np.all(np.isfinite(plant.q)) and np.ptp(plant.q) > 0, name
        ran.append(name)
    assert {"none", "joint3-asymmetry", "joint3-gain"} <= set(ran)


def test_payload_is_refused_on_the_n_joint_arm():
    with pytest.raises(ValueError, match="takes no payload effect") as err:
        UrdfPlantParams.from_profile(robot(), load_effects("payload"))
    assert "\n" not in str(err.value)


# ---- each effect on joint 3 and no other ----------------------------------------------------
def test_torque_gain_and_offset_act_on_joint_3_only(tmp_path):
    """The plant with a gain/offset error on joint 3, commanded τ, moves exactly as the
    effect-free plant commanded (1 + ε) τ + τ0 on joint 3 and τ elsewhere."""
    fx = write_effects(
        tmp_path, "[torque_gain_error]\njoint = 3\nrelative = 0.07\n"
        "[torque_offset]\njoint = 3\noffset_Nm = -0.05\n"
    )  # fmt: skip
    tau = np.array([12.0, 0.8, 0.6])
    shifted = tau.copy()
    shifted[2] = 1.07 * tau[2] - 0.05
    with_effect, reference = plant_with(fx, q0=Q0), plant_with(q0=Q0)
    with_effect.command(tau)
    reference.command(shifted)
    for plant in (with_effect, reference):
        plant.advance_to(0.05)
    assert np.array_equal(with_effect.q, reference.q) and np.ptp(with_effect.q) > 0
    with_effect.command(tau, powered=[True, True, False])  # unpowered: no offset either
    assert with_effect.command_Nm[2] == 0.0


def test_encoder_offset_is_seen_by_the_encoder_of_joint_3_only(tmp_path):
    fx = write_effects(tmp_path, "[encoder_offset]\noffset_rad = [0.0, 0.0, 0.02]\n")
    plant, reference = plant_with(fx, q0=Q0), plant_with(q0=Q0)
    for p in (plant, reference):
        p.command([12.0, 0.8, 0.6])
        p.advance_to(0.02)
    assert np.array_equal(plant.q, reference.q)  # the arm itself is unchanged
    assert np.allclose(plant.measured_q - plant.q, [0.0, 0.0, 0.02], rtol=0, atol=1e-15)


def test_coulomb_asymmetry_on_joint_3_sets_its_bands_by_direction():
    """Joint 3 held at rest by gravity compensation plus a push: 0.30 Nm forwards breaks the
    effect's 0.25 Nm band (the robot's 0.35 holds it), 0.50 Nm backwards is held by the effect's
    0.65 Nm (the robot's 0.40 lets go). Joints 1 and 2 stay held throughout."""
    fx = load_effects("joint3-asymmetry")
    for push, moves_with_effect in ((0.30, True), (-0.50, False)):
        for effects, moves in ((fx, moves_with_effect), (None, not moves_with_effect)):
            plant = plant_with(effects, q0=Q0)
            assert plant.stuck.all()
            plant.command(gravity(plant, Q0) + np.array([0.0, 0.0, push]))
            plant.advance_to(0.05)
            assert plant.q[0] == Q0[0] and plant.q[1] == Q0[1]
            assert (abs(plant.q[2] - Q0[2]) > 1e-5) == moves, (push, effects, plant.q)
    # sliding backwards, joint 3 feels the effect's 0.65 Nm, joints 1, 2 their robot's levels
    plant = plant_with(fx, q0=Q0, dq0=DQ0)
    tau = np.array([12.0, 0.8, 0.6])
    plant.command(tau)
    friction = robot_friction(DQ0, pos=np.array([7.17, 1.734, 0.25]), neg=[8.049, 1.734, 0.65])
    expected = expected_accelerations(plant, tau, friction)
    assert np.allclose(plant._accelerations(plant.q, plant.dq), expected, rtol=1e-12, atol=1e-12)


def test_stribeck_on_joint_3_breakaway_band_and_sliding_level(tmp_path):
    """Breakaway F_s = 1.5 F_c on joint 3: a push of 1.2 F_c holds it (it moves without the
    effect); sliding, its friction follows F_c + (F_s − F_c) exp(−(|q̇|/v_s)^δ)."""
    fx = write_effects(
        tmp_path, "[stribeck]\njoint = 3\nbreakaway_ratio = 1.5\nvelocity_rad_s = 1.5\n"
        "exponent = 2.0\n"
    )  # fmt: skip
    for effects, moves in ((fx, False), (None, True)):
        plant = plant_with(effects, q0=Q0)
        plant.command(gravity(plant, Q0) + np.array([0.0, 0.0, 1.2 * 0.35]))
        plant.advance_to(0.05)
        assert (abs(plant.q[2] - Q0[2]) > 1e-5) == moves
    plant = plant_with(fx, q0=Q0, dq0=DQ0)
    tau = np.array([12.0, 0.8, 0.6])
    plant.command(tau)
    friction = robot_friction(DQ0)
    friction[2] = -(0.40 + 0.5 * 0.40 * math.exp(-((2.0 / 1.5) ** 2))) - 0.05 * 2.0
    expected = expected_accelerations(plant, tau, friction)
    assert np.allclose(plant._accelerations(plant.q, plant.dq), expected, rtol=1e-12, atol=1e-12)


def test_cogging_and_drag_on_joint_3_enter_its_equation(tmp_path):
    """τ_cog = A sin(N q3 + φ) and the drag −c q̇3|q̇3| on joint 3's equation, nothing on the
    others: the plant's accelerations against the ABA of forces written out here."""
    fx = write_effects(
        tmp_path, "[cogging]\nperiods_per_rev = [0, 0, 40]\namplitude_Nm = [0, 0, 0.2]\n"
        "phase_rad = [0, 0, 0.3]\n[velocity_squared_drag]\njoint = 3\ncoefficient_Nms2 = 0.03\n"
    )  # fmt: skip
    plant = plant_with(fx, q0=Q0, dq0=DQ0)
    tau = np.array([12.0, 0.8, 0.6])
    plant.command(tau)
    friction = robot_friction(DQ0)
    friction[2] += -0.03 * 2.0**2 + -0.2 * math.sin(40 * 0.4 + 0.3)  # drag, and cogging as −f
    expected = expected_accelerations(plant, tau, friction)
    assert np.allclose(plant._accelerations(plant.q, plant.dq), expected, rtol=1e-12, atol=1e-12)
    reference = plant_with(q0=Q0, dq0=DQ0)
    reference.command(tau)
    for p in (plant, reference):
        p.advance_to(0.02)
    assert abs(plant.q[2] - reference.q[2]) > 1e-6  # it changes the motion


def test_amplifier_lag_on_joint_3_and_transport_delay(tmp_path):
    """A first-order lag T on joint 3 only: after t its shaft torque is the mean of
    τ (1 − e^{−s/T}) over the step, joints 1, 2 get the command at once. A transport delay d:
    the arm moves exactly as the effect-free one commanded d later."""
    fx = write_effects(tmp_path, "[amplifier_lag]\njoint = 3\ntime_constant_s = 0.004\n")
    plant = plant_with(fx, q0=Q0, dq0=DQ0)
    tau = np.array([12.0, 0.8, 0.6])
    plant.command(tau)
    h, k, T = 5e-4, 10, 0.004
    plant.advance_to(k * h)
    plant._apply_lag(h)  # the torque of step k + 1: the lag's mean over [k h, (k + 1) h]
    mean = tau[2] * (1 - T / h * (math.exp(-k * h / T) - math.exp(-(k + 1) * h / T)))
    assert plant.command_Nm[2] == pytest.approx(mean, rel=1e-9)
    assert np.array_equal(plant.command_Nm[:2], tau[:2])
    d = 0.0013
    delayed = plant_with(write_effects(tmp_path, f"[transport_delay]\ndelay_s = {d}\n"), q0=Q0)
    reference = plant_with(q0=Q0)
    delayed.command(tau)
    delayed.advance_to(0.03)
    reference.advance_to(d)
    reference.command(tau)
    reference.advance_to(0.03)
    assert np.allclose(delayed.q, reference.q, rtol=0, atol=1e-12) and np.ptp(delayed.q) > 0


def test_energy_balances_with_every_effect(tmp_path):
    """E − E0 = W_in − W_f over 1 s of the excitation with stick events, with lag, delay,
    gain/offset, cogging, Stribeck, drag and the Coulomb override together: the cogging work
    is booked in W_in, the friction beyond the Coulomb levels in W_f (docs/effects.md)."""
    fx = write_effects(
        tmp_path,
        "[amplifier_lag]\ntime_constant_s = [0.002, 0.0, 0.003]\n"
        "[transport_delay]\ndelay_s = 0.0007\n"
        "[torque_gain_error]\nrelative = [0.04, -0.03, 0.07]\n"
        "[torque_offset]\noffset_Nm = [0.5, 0.05, 0.02]\n"
        "[cogging]\nperiods_per_rev = [120, 96, 50]\namplitude_Nm = [1.5, 0.12, 0.1]\n"
        "[stribeck]\nbreakaway_ratio = [1.35, 1.25, 1.5]\nvelocity_rad_s = [0.08, 0.1, 0.2]\n"
        "[velocity_squared_drag]\ncoefficient_Nms2 = [0.5, 0.05, 0.01]\n"
        "[coulomb]\njoint = 3\npositive_Nm = 0.25\nnegative_Nm = 0.65\n",
    )
    plant = plant_with(fx)
    balance = energy_balance_over_excitation(plant, 400)
    assert plant.stick_events > 0 and np.all(np.ptp(plant.q) > 0.01)
    assert abs(balance) < 1e-6 * plant.work_in_J, (balance, plant.work_in_J)


# ---- end to end -----------------------------------------------------------------------------
def test_simulate_cli_with_an_n_joint_effect(tmp_path, capsys):
    """`virtual-robot simulate --robot cicese3 --effects joint3-asymmetry`: the same torques,
    other motion, joint 3 most; meta.json names the effects as the 2-DOF simulate does. A
    2-DOF profile on the 3-joint arm is a one-line error naming the file and key."""
    runs = {}
    for effects in ("none", "joint3-asymmetry"):
        out = tmp_path / effects
        args = ["simulate", "--robot", "cicese3", "--experiment", "cicese3-excitation"]
        assert vr_main([*args, "--effects", effects, "--duration", "0.5", "--out", str(out),
                        "--no-plot"]) == 0  # fmt: skip
        runs[effects] = read_signals(out)
    meta = runs["joint3-asymmetry"].meta
    assert meta["effects"] == "joint3-asymmetry" and meta["effects_enabled"] == ["coulomb"]
    assert np.array_equal(runs["none"].tau, runs["joint3-asymmetry"].tau)
    moved = np.max(np.abs(runs["none"].q - runs["joint3-asymmetry"].q), axis=0)
    assert moved[2] > 0.01 and moved[2] > 5 * max(moved[0], moved[1]), moved
    capsys.readouterr()
    bad = ["--effects", "cogging", "--out", str(tmp_path / "bad"), "--no-plot"]
    code = vr_main(["simulate", "--robot", "cicese3", "--experiment", "cicese3-excitation", *bad])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert "cogging.toml" in err[0] and "cogging.periods_per_rev" in err[0], err
