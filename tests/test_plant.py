"""Physics of the virtual arm: solve_ivp agreement, energy balance, stick-slip, effects."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from profiles.effects import Cogging, EffectsProfile, Payload, Stribeck, load_effects
from profiles.experiment import load_experiment
from profiles.robot import Link, load_robot
from virtual_robot import dynamics
from virtual_robot.plant import Plant, PlantParams, _rk4_step, _sliding_rk4

H = 0.0025  # control period of the paper


@pytest.fixture(scope="module")
def robot():
    return load_robot("cicese")


@pytest.fixture(scope="module")
def params(robot):
    return PlantParams.from_profiles(robot)


def run_torques(plant: Plant, torques: np.ndarray, h: float = H) -> np.ndarray:
    """Zero-order-held torques, one row per period; returns q at the start of each period."""
    qs = np.empty((len(torques) + 1, 2))
    qs[0] = plant.q
    t0 = plant.t
    for k, tau in enumerate(torques):
        plant.command((float(tau[0]), float(tau[1])))
        plant.advance_to(t0 + (k + 1) * h)
        qs[k + 1] = plant.q
    return qs


def hold(plant: Plant, tau: tuple[float, float], seconds: float) -> None:
    plant.command(tau)
    plant.advance(seconds)


# ---- rigid body ---------------------------------------------------------------------------


def test_reference_dynamics_properties(params):
    rng = np.random.default_rng(1)
    theta = params.theta
    for _ in range(50):
        q, dq = rng.uniform(-3, 3, 2), rng.uniform(-5, 5, 2)
        M = dynamics.mass_matrix(theta, q)
        assert np.allclose(M, M.T) and np.all(np.linalg.eigvalsh(M) > 0)
        # g = ∂U/∂q (eq. 2), by central differences
        eps = 1e-6
        grad = [
            (dynamics.potential_energy(theta, q + e) - dynamics.potential_energy(theta, q - e))
            / (2 * eps)
            for e in np.eye(2) * eps
        ]
        assert np.allclose(grad, dynamics.gravity_vector(theta, q), atol=1e-7)
        # q̇ᵀ(Ṁ − 2C)q̇ = 0: the passivity property that makes eq. (25) hold
        Mdot = (
            dynamics.mass_matrix(theta, q + dq * eps) - dynamics.mass_matrix(theta, q - dq * eps)
        ) / (2 * eps)
        assert abs(dq @ (Mdot - 2 * dynamics.coriolis_matrix(theta, q, dq)) @ dq) < 1e-6
        # inverse ∘ forward = identity
        tau = rng.uniform(-50, 50, 2)
        ddq = dynamics.forward_dynamics(theta, q, dq, tau)
        assert np.allclose(dynamics.inverse_dynamics(theta, q, dq, ddq), tau)


def test_scalar_plant_matches_reference_equations(params):
    """The unrolled scalar code of the plant is the same model as virtual_robot.dynamics."""
    rng = np.random.default_rng(2)
    for _ in range(50):
        q, dq, tau = rng.uniform(-3, 3, 2), rng.uniform(-5, 5, 2), rng.uniform(-50, 50, 2)
        plant = Plant(params, q0=tuple(q), dq0=tuple(dq))
        plant._set_mode()
        a1, a2, power, fpower = plant._deriv(*q, *dq, *tau)
        d1, d2 = plant.slip_dir
        friction = np.array(params.viscous_Nms) * dq + [
            d1 * (params.coulomb_positive_Nm[0] if d1 > 0 else params.coulomb_negative_Nm[0]),
            d2 * (params.coulomb_positive_Nm[1] if d2 > 0 else params.coulomb_negative_Nm[1]),
        ]
        expected = dynamics.forward_dynamics(params.theta, q, dq, tau - friction)
        assert np.allclose([a1, a2], expected, rtol=1e-12, atol=1e-12)
        assert power == pytest.approx(tau @ dq)
        assert fpower == pytest.approx(friction @ dq)
        assert plant.energy_J() == pytest.approx(dynamics.total_energy(params.theta, q, dq))
        # the sliding step written out: the general derivative's RK4, bit for bit
        fast = _sliding_rk4(*plant._constants, plant._mode[2], plant._mode[3])
        dt = rng.uniform(1e-5, 1e-3)
        assert fast(*q, *dq, *tau, dt) == _rk4_step(plant._deriv)(*q, *dq, *tau, dt)


def test_agrees_with_solve_ivp_on_a_smooth_case(params):
    """Viscous friction only (no Coulomb): RK4 at 0.5 ms against solve_ivp (DOP853, rtol 1e-11)."""
    smooth = replace(
        params,
        coulomb_positive_Nm=(0.0, 0.0),
        coulomb_negative_Nm=(0.0, 0.0),
        breakaway_positive_Nm=(0.0, 0.0),
        breakaway_negative_Nm=(0.0, 0.0),
    )
    exp = load_experiment("reyes-kelly")
    n = 800  # 2 s
    torques = exp.torque_table(np.arange(n) * H)
    plant = Plant(smooth)
    q_plant = run_torques(plant, torques)

    theta, b = np.array(smooth.theta), np.array(smooth.viscous_Nms)
    state = np.zeros(4)
    q_ref = [state[:2].copy()]
    for k in range(n):
        tau = torques[k]

        def rhs(_t, x, tau=tau):
            q, dq = x[:2], x[2:]
            return np.concatenate([dq, dynamics.forward_dynamics(theta, q, dq, tau - b * dq)])

        sol = solve_ivp(rhs, (0.0, H), state, method="DOP853", rtol=1e-11, atol=1e-12)
        state = sol.y[:, -1]
        q_ref.append(state[:2].copy())
    err = np.max(np.abs(q_plant - np.array(q_ref)))
    # far below one count of the finer encoder (2π/1,024,000 = 6.1e-6 rad)
    assert err < 1e-8, err


def test_energy_balance_with_stick_slip(params):
    """Work in = change of energy + dissipated (eq. (25)), through stick-slip events."""
    exp = load_experiment("reyes-kelly")
    plant = Plant(params)
    e0 = plant.energy_J()
    qs = run_torques(plant, exp.torque_table(np.arange(1600) * H))
    assert plant.stick_events > 10  # the run really exercises stiction
    delta_e = dynamics.total_energy(params.theta, plant.q, plant.dq) - e0
    balance = plant.work_in_J - delta_e - plant.dissipated_J
    assert abs(balance) < 1e-8 * plant.work_in_J, balance
    # The supplied work, independently: a torque held over a period does τ·Δq of work exactly.
    torques = exp.torque_table(np.arange(1600) * H)
    work = float(np.sum(torques * np.diff(qs, axis=0)))
    assert work == pytest.approx(plant.work_in_J, rel=1e-9)


def test_step_size_convergence(params):
    """Halving the 0.5 ms default step moves q by < 1e-9 rad (1/6000 of the finer count)."""
    exp = load_experiment("reyes-kelly")
    torques = exp.torque_table(np.arange(1600) * H)
    coarse = run_torques(Plant(params, max_step_s=5e-4), torques)
    fine = run_torques(Plant(params, max_step_s=2.5e-4), torques)
    count = 2 * math.pi / 1_024_000
    assert np.max(np.abs(coarse - fine)) < 1e-9 < count / 6000


# ---- stick-slip -----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "tau1, moves",
    [(5.0, False), (7.1, False), (7.3, True), (-7.5, False), (-8.0, False), (-8.2, True)],
)
def test_joint1_static_band_is_direction_dependent(params, tau1, moves):
    """Hanging at q = 0 (no gravity torque): joint 1 holds inside [−8.049, 7.17] Nm (Table I)."""
    plant = Plant(params)
    hold(plant, (tau1, 0.0), 1.0)
    if moves:
        assert math.copysign(1, plant.q[0]) == math.copysign(1, tau1) and abs(plant.q[0]) > 1e-4
    else:
        assert plant.q == (0.0, 0.0) and plant.dq == (0.0, 0.0)  # exactly: no creep, no tanh


def test_joint2_holds_inside_its_band_and_breaks_away_outside(params):
    for tau2, moves in ((1.7, False), (-1.7, False), (1.8, True), (-1.8, True)):
        plant = Plant(params)
        hold(plant, (0.0, tau2), 0.5)
        assert (plant.q[1] != 0.0) == moves, tau2


def test_breakaway_happens_when_a_ramp_leaves_the_band(params):
    """τ1 ramps at ±2 Nm/s: joint 1 stays put until |τ1| crosses 7.17 (up) / 8.049 (down)."""
    for slope, band in ((2.0, 7.17), (-2.0, 8.049)):
        plant = Plant(params)
        t_break = None
        for k in range(2400):  # 6 s
            plant.command((slope * k * H, 0.0))
            plant.advance_to((k + 1) * H)
            if plant.q[0] != 0.0 and t_break is None:
                t_break = k * H
        assert t_break is not None
        assert abs(slope) * t_break == pytest.approx(band, abs=abs(slope) * H * 1.01)


def test_sliding_joint_comes_to_rest_and_stays(params):
    plant = Plant(params, dq0=(0.0, 3.0))
    hold(plant, (0.0, 0.0), 3.0)
    assert plant.stick_events >= 1
    q_rest = plant.q
    assert plant.dq[1] == 0.0
    hold(plant, (0.0, 0.0), 1.0)
    assert plant.q == q_rest


def test_stick_slip_against_gravity_settles_inside_the_band(params):
    """Released at 30°, the arm swings and sticks where gravity is inside the friction band."""
    plant = Plant(params, q0=(math.radians(30), 0.0))
    hold(plant, (0.0, 0.0), 8.0)
    assert plant.dq == (0.0, 0.0)
    gravity = dynamics.gravity_vector(params.theta, plant.q)
    assert -params.coulomb_positive_Nm[0] <= gravity[0] <= params.coulomb_negative_Nm[0]
    assert abs(gravity[1]) <= params.coulomb_positive_Nm[1]


# ---- effects -----------------------------------------------------------------------------


def test_encoder_offset_is_on_the_measurement_only(robot):
    fx = EffectsProfile(encoder_offset_rad=(0.01, -0.02))
    plant = Plant(PlantParams.from_profiles(robot, fx))
    hold(plant, (20.0, 3.0), 0.5)
    ref = Plant(PlantParams.from_profiles(robot))
    hold(ref, (20.0, 3.0), 0.5)
    assert plant.q == ref.q
    assert plant.measured_q == pytest.approx((ref.q[0] + 0.01, ref.q[1] - 0.02))


def test_torque_gain_and_offset_equal_a_rescaled_command(robot):
    fx = EffectsProfile(torque_gain_error=(0.05, -0.1), torque_offset_Nm=(1.0, -0.2))
    a = Plant(PlantParams.from_profiles(robot, fx))
    b = Plant(PlantParams.from_profiles(robot))
    hold(a, (20.0, 3.0), 0.5)
    hold(b, (1.05 * 20.0 + 1.0, 0.9 * 3.0 - 0.2), 0.5)
    assert a.q == pytest.approx(b.q, abs=1e-12)


def test_amplifier_lag_is_first_order(robot):
    fx = EffectsProfile(amplifier_lag_s=(0.002, 0.004))
    plant = Plant(PlantParams.from_profiles(robot, fx))
    hold(plant, (5.0, 1.0), 0.002)  # below the bands: the arm stays put, only the lag moves
    assert plant.amplifier_Nm[0] == pytest.approx(5.0 * (1 - math.exp(-1)), rel=1e-12)
    assert plant.amplifier_Nm[1] == pytest.approx(1.0 * (1 - math.exp(-0.5)), rel=1e-12)


def test_transport_delay_shifts_the_response(robot):
    d = 0.0013  # deliberately not a multiple of the integrator step
    delayed = Plant(PlantParams.from_profiles(robot, EffectsProfile(transport_delay_s=d)))
    direct = Plant(PlantParams.from_profiles(robot))
    delayed.command((30.0, 4.0), issued_at=0.0)
    direct.command((30.0, 4.0), issued_at=0.0)
    delayed.advance_to(d)
    assert delayed.q == (0.0, 0.0)  # nothing has reached the shaft yet
    delayed.advance_to(0.3 + d)
    direct.advance_to(0.3)
    assert delayed.q == pytest.approx(direct.q, abs=1e-9)


def test_cogging_adds_position_dependent_torque(robot):
    # 7.0 Nm alone holds; + 0.5 sin(π/2) of cogging at q = 0 breaks away.
    fx = EffectsProfile(cogging=Cogging((50.0, 0.0), (0.5, 0.0), (math.pi / 2, 0.0)))
    plant = Plant(PlantParams.from_profiles(robot, fx))
    hold(plant, (7.0, 0.0), 0.2)
    assert plant.q[0] > 0
    # energy balance still holds with cogging counted as supplied torque
    exp = load_experiment("reyes-kelly")
    plant = Plant(PlantParams.from_profiles(robot, fx))
    e0 = plant.energy_J()
    run_torques(plant, exp.torque_table(np.arange(400) * H))
    assert abs(plant.work_in_J - (plant.energy_J() - e0) - plant.dissipated_J) < 1e-6


def test_stribeck_raises_the_breakaway_level(robot):
    fx = EffectsProfile(stribeck=Stribeck((1.35, 1.25), (0.08, 0.1), 2.0))
    p = PlantParams.from_profiles(robot, fx)
    assert p.breakaway_positive_Nm[0] == pytest.approx(7.17 * 1.35)
    held = Plant(p)
    hold(held, (9.0, 0.0), 0.5)  # above Coulomb 7.17, below breakaway 9.68: stays stuck
    assert held.q == (0.0, 0.0)
    moved = Plant(p)
    hold(moved, (9.9, 0.0), 0.5)
    assert moved.q[0] > 0


def test_payload_matches_a_heavier_link2(robot):
    """A point payload changes θ exactly as merging it into link 2 (parallel-axis theorem)."""
    mp, lp, ip = 1.5, 0.25, 0.002
    p = PlantParams.from_profiles(robot, EffectsProfile(payload=Payload(mp, lp, ip)))
    m2, lc2, i2 = robot.link2.mass_kg, robot.link2.com_m, robot.link2.inertia_kgm2
    m = m2 + mp
    lc = (m2 * lc2 + mp * lp) / m
    inertia = i2 + m2 * (lc2 - lc) ** 2 + ip + mp * (lp - lc) ** 2
    merged = replace(robot, link2=Link(m, lc, inertia))
    assert np.allclose(p.theta, merged.theta()[:5], rtol=1e-12)


def test_shipped_effects_profiles_run(robot):
    exp = load_experiment("reyes-kelly")
    torques = exp.torque_table(np.arange(200) * H)
    from profiles import available

    for name in available("effects"):
        effects = load_effects(name)
        if any(joint > 2 for _, joint in effects.joint_of):
            continue  # written for a longer arm: tests/test_urdf_effects.py runs it
        plant = Plant(PlantParams.from_profiles(robot, effects))
        qs = run_torques(plant, torques)
        assert np.all(np.isfinite(qs)), name


def test_symmetric_coulomb_effect(robot):
    p = PlantParams.from_profiles(robot, load_effects("symmetric-coulomb"))
    plant = Plant(p)
    hold(plant, (-7.7, 0.0), 0.5)  # holds at −8.049 by default, slides at −7.6095
    assert plant.q[0] < 0


def test_unpowered_amplifier_puts_no_torque_on_the_shaft(robot):
    """A disabled or faulted drive's power stage is off: the torque offset does not act."""
    fx = EffectsProfile(torque_offset_Nm=(10.0, 0.0), amplifier_lag_s=(0.002, 0.0))
    powered = Plant(PlantParams.from_profiles(robot, fx))
    hold(powered, (0.0, 0.0), 0.5)
    assert powered.q[0] > 0.01  # 10 Nm of offset breaks away
    off = Plant(PlantParams.from_profiles(robot, fx))
    off.command((0.0, 0.0), powered=(False, False))
    off.advance(0.5)
    assert off.q == (0.0, 0.0)
