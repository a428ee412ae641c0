"""hil.model.openloop (the host's open-loop simulation of its model) against the world, and on its
own."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.recording import read_signals
from hil.model import closed_form as model
from hil.model.metrics import nrmse
from hil.model.openloop import OpenLoopExtras, simulate_open_loop
from hil.model.params import robot_params
from profiles.effects import Cogging, Coulomb, EffectsProfile, Stribeck, load_effects
from profiles.experiment import load_experiment
from profiles.robot import load_robot
from virtual_robot.plant import Plant, PlantParams
from virtual_robot.simulate import simulate

H = 0.0025
SECONDS = 3.0
COUNT = 2 * math.pi / np.array([1_024_000, 655_360])  # encoder resolution, rad (drive profiles)
POSITIVE = (7.17, 1.734)  # Table I: joint 1 Coulomb level moving positive / negative
NEGATIVE = (8.049, 1.734)


@pytest.fixture(scope="module")
def theta() -> np.ndarray:
    return robot_params().theta


def world_recording(tmp_path_factory, effects: str):
    out = tmp_path_factory.mktemp(effects)
    simulate(
        load_robot("cicese"),
        load_experiment("reyes-kelly"),
        out,
        effects=load_effects(effects),
        duration_s=SECONDS,
        plot=False,
    )
    return read_signals(out)


def world_positions(effects: str, tau: np.ndarray) -> np.ndarray:
    """The plant's true q at t = k·h under zero-order-held ``tau`` (no encoder, no drive)."""
    plant = Plant(PlantParams.from_profiles(load_robot("cicese"), load_effects(effects)))
    q = np.empty_like(tau)
    for k, row in enumerate(tau):
        q[k] = plant.q
        plant.command((float(row[0]), float(row[1])))
        plant.advance_to((k + 1) * H)
    return q


# ---- (a) the host's model and the world agree when the world has no extra effects ----------------


@pytest.mark.parametrize(
    ("effects", "levels"),
    [
        ("symmetric-coulomb", {}),  # θ8 = mean of Table I's two levels: the paper's model exactly
        ("none", {"coulomb_positive": POSITIVE, "coulomb_negative": NEGATIVE}),
    ],
)
def test_host_model_reproduces_the_world_recording(tmp_path_factory, theta, effects, levels):
    rec = world_recording(tmp_path_factory, effects)
    sim = simulate_open_loop(theta, rec.tau, H, **levels)
    assert sim.q.shape == rec.q.shape == (round(SECONDS / H), 2)
    # The recording is an encoder reading, floor(q / count) counts, read at the centre of its
    # count (drivers.units.position_to_rad): the simulation must sit within ½ count of it.
    # Measured: max |Δq| = 3.07e-6, 4.79e-6 rad, i.e. ½ count (at t = 0, q = 0 is an edge), over
    # 3 s and over 10 s alike; the model itself is ~1e-12 rad off (next test).
    delta = sim.q - rec.q
    assert np.all(np.abs(delta) <= COUNT / 2 + 1e-9), np.abs(delta).max(axis=0)
    assert abs(delta.mean()) < 0.1 * COUNT.min()  # without bias
    assert np.all(nrmse(rec.q, sim.q) < 1e-4)
    assert np.ptp(rec.q, axis=0).min() > 0.2  # the arm moved: the check is not vacuous
    assert sim.stick_events.sum() > 20  # and it stuck and broke away often (stick-slip exercised)


@pytest.mark.parametrize(
    ("effects", "levels"),
    [
        ("symmetric-coulomb", {}),
        ("none", {"coulomb_positive": POSITIVE, "coulomb_negative": NEGATIVE}),
    ],
)
def test_host_model_matches_the_plant_state_to_round_off(theta, effects, levels):
    """Without the encoder between them: the same physics to ~1e-12 rad (measured 3.7e-13)."""
    tau = load_experiment("reyes-kelly").torque_table(np.arange(round(SECONDS / H)) * H)
    world = world_positions(effects, tau)
    sim = simulate_open_loop(theta, tau, H, **levels)
    assert np.max(np.abs(sim.q - world)) < 1e-9


def test_host_model_matches_the_plant_over_ten_seconds(theta):
    """Includes t = 6.9925 s, where joint 2 breaks away and reverses inside one plant step
    (the plant used to take the zero at the step start and freeze the arm for a period)."""
    tau = load_experiment("reyes-kelly").torque_table(np.arange(4000) * H)
    world = world_positions("symmetric-coulomb", tau)
    sim = simulate_open_loop(theta, tau, H)
    assert np.max(np.abs(sim.q - world)) < 1e-9


def test_sub_steps_converge(theta):
    """RK4 with located stick events: 5 sub-steps per period are within 1e-9 rad of 50."""
    tau = load_experiment("reyes-kelly").torque_table(np.arange(2000) * H)
    fine = simulate_open_loop(theta, tau, H, steps_per_period=50)
    default = simulate_open_loop(theta, tau, H)
    assert np.max(np.abs(default.q - fine.q)) < 1e-9
    assert np.array_equal(default.stick_events, fine.stick_events)


# ---- (b) stick–slip ------------------------------------------------------------------------------


def hold_at(theta: np.ndarray, q0: tuple[float, float], extra: tuple[float, float], rows: int):
    """Torques that cancel gravity at q0 plus ``extra`` (Nm), held for ``rows`` periods."""
    tau = model.gravity_vector(theta, q0) + np.asarray(extra)
    return np.tile(tau, (rows, 1))


def test_torque_inside_the_coulomb_band_leaves_the_arm_at_rest(theta):
    q0 = (0.6, -0.4)
    inside = (0.95 * theta[7], -0.95 * theta[8])
    sim = simulate_open_loop(theta, hold_at(theta, q0, inside, 400), H, q0=q0)
    assert np.all(sim.q == q0) and np.all(sim.dq == 0.0)
    assert np.all(sim.stuck) and np.array_equal(sim.stuck_fraction, [1.0, 1.0])
    assert sim.breakaways.sum() == 0


@pytest.mark.parametrize(("joint", "sign"), [(0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0)])
def test_torque_just_outside_the_band_breaks_away_in_its_direction(theta, joint, sign):
    q0 = (0.6, -0.4)
    extra = [0.0, 0.0]
    extra[joint] = sign * 1.05 * theta[7 + joint]
    sim = simulate_open_loop(theta, hold_at(theta, q0, tuple(extra), 80), H, q0=q0)
    moved = sim.q[-1, joint] - q0[joint]
    assert sign * moved > 1e-4, moved
    assert sim.breakaways[joint] >= 1
    assert not sim.stuck[1, joint]  # breaks away within the first period


def test_direction_dependent_coulomb_levels(theta):
    """7.5 Nm beyond gravity: more than 7.17 Nm (positive band), less than 8.049 Nm (negative)."""
    q0 = (0.3, 0.2)
    levels = {"coulomb_positive": POSITIVE, "coulomb_negative": NEGATIVE}
    up = simulate_open_loop(theta, hold_at(theta, q0, (7.5, 0.0), 80), H, q0=q0, **levels)
    down = simulate_open_loop(theta, hold_at(theta, q0, (-7.5, 0.0), 80), H, q0=q0, **levels)
    assert up.q[-1, 0] - q0[0] > 1e-4
    assert np.all(down.q == q0)
    # the symmetric model (θ8 = 7.6095 Nm) holds both
    sym = simulate_open_loop(theta, hold_at(theta, q0, (7.5, 0.0), 80), H, q0=q0)
    assert np.all(sym.q == q0)


def test_a_sliding_joint_stops_where_the_analytic_solution_says():
    """No gravity, joint 1 coasting against viscous + Coulomb friction, joint 2 held by its band.

    θ1' v̇ = −b v − F  ⇒  it stops at t* = (m/b) ln(1 + b v0 / F), having moved
    (m/b) v0 − F t*/b. The stop falls inside a sub-step, so this checks the event location.
    """
    theta = robot_params().theta.copy()
    theta[3:5] = 0.0
    m, b, F, v0 = theta[0] + 2 * theta[1], theta[5], theta[7], 2.0  # m11 at q2 = 0
    t_stop = (m / b) * math.log(1 + b * v0 / F)
    q_stop = (m / b) * v0 - F * t_stop / b
    sim = simulate_open_loop(theta, np.zeros((400, 2)), H, dq0=(v0, 0.0))
    k = math.ceil(t_stop / H)
    assert not sim.stuck[k - 1, 0] and np.all(sim.stuck[k:, 0])
    assert np.all(sim.stuck[:, 1]) and np.all(sim.q[:, 1] == 0.0)
    assert sim.stick_events[0] == 1 and sim.breakaways[0] == 0
    assert np.all(sim.dq[k:, 0] == 0.0)
    assert abs(sim.q[-1, 0] - q_stop) < 1e-10, sim.q[-1, 0] - q_stop
    # before the stop, the analytic velocity (v + F/b) e^{−bt/m} − F/b
    t = sim.t[:k]
    np.testing.assert_allclose(sim.dq[:k, 0], (v0 + F / b) * np.exp(-b * t / m) - F / b, atol=1e-9)


def test_a_swinging_arm_comes_to_rest_inside_its_friction_band(theta):
    """Coulomb friction stops the arm off the vertical; a viscous-only model would not."""
    sim = simulate_open_loop(theta, np.zeros((1200, 2)), H, dq0=(3.0, -4.0))
    assert np.all(sim.stuck[-1]) and np.all(sim.dq[-1] == 0.0)
    rest = sim.q[-1]
    assert np.all(sim.q[-40:] == rest)  # no creep once stuck
    hold = model.gravity_vector(theta, rest)  # friction holding the arm = its weight
    assert abs(hold[0]) <= theta[7] and abs(hold[1]) <= theta[8]
    assert np.max(np.abs(rest)) > 1e-3  # not back at the bottom
    assert sim.breakaways.sum() >= 1  # swung back at least once


# ---- (c) energy ----------------------------------------------------------------------------------


def frictionless(theta: np.ndarray) -> np.ndarray:
    th = theta.copy()
    th[5:9] = 0.0
    return th


def test_energy_is_conserved_without_friction(theta):
    th = frictionless(theta)
    sim = simulate_open_loop(th, np.zeros((800, 2)), H, q0=(1.2, -0.7), dq0=(0.5, 2.0))
    energy = model.total_energy(th, sim.q, sim.dq)
    # measured: 2.5e-11 relative drift over 2 s (RK4, 0.5 ms sub-steps)
    assert np.max(np.abs(energy - energy[0])) < 1e-9 * energy[0]
    assert np.ptp(sim.q[:, 1]) > 1.0  # it moved (link 2 flails)
    assert not sim.stuck.any()


def test_energy_balance_with_held_torques_and_no_friction(theta):
    """ℰ(t_{k+1}) − ℰ(t_k) = τ_kᵀ (q_{k+1} − q_k): the work of a torque held over a period."""
    th = frictionless(theta)
    t = np.arange(800) * H
    tau = np.stack([20 * np.sin(6 * t), 3 * np.sin(11 * t + 0.4)], -1)
    sim = simulate_open_loop(th, tau, H)
    energy = model.total_energy(th, sim.q, sim.dq)
    work = np.sum(tau[:-1] * np.diff(sim.q, axis=0), axis=1)
    assert np.max(np.abs(np.diff(energy) - work)) < 1e-9
    assert np.max(np.abs(work)) > 1e-2


# ---- conventions and bad input -------------------------------------------------------------------


def test_row_k_is_the_state_before_tau_k(theta):
    tau = hold_at(theta, (0.0, 0.0), (30.0, 0.0), 10)
    sim = simulate_open_loop(theta, tau, H, q0=(0.0, 0.0))
    assert np.array_equal(sim.q[0], [0.0, 0.0]) and sim.q[1, 0] > 0
    np.testing.assert_array_equal(sim.t, np.arange(10) * H)
    changed = tau.copy()
    changed[-1] = (-100.0, 50.0)  # the last torque acts after the last sample
    assert np.array_equal(simulate_open_loop(theta, changed, H).q, sim.q)
    assert simulate_open_loop(theta, tau[:1], H).q.shape == (1, 2)


@pytest.mark.parametrize(("torque", "speed"), [(1e6, 0.0), (1e7, 0.0), (1e12, 3.0)])
@pytest.mark.parametrize("compiled", [True, False])
def test_a_diverging_simulation_is_nan_from_there_on(theta, torque, speed, compiled, monkeypatch):
    """A model that leaves every finite angle gives NaN rows from the first state past the
    range on, not an exception (a torque gain of about -100 % that the training rows could
    not determine, simulated on DFKI C.0 trajectories 04 -> 05, ended `hil diagnose` in `math
    domain error`: sin of an infinite angle); chunk after chunk, with the compiled sub-steps or
    without."""
    import hil.model.openloop_core as core

    if not compiled:
        monkeypatch.setattr(core, "compiled", lambda: False)
    tau = np.full((100, 2), (torque, 0.0))
    tau[:5] = 0.0
    start = (0.0, 0.0, speed, -speed)
    friction = core.Friction((1.0, 1.0), (1.0, 1.0))
    sim = core.integrate(theta, tau, H, 5, start, friction)
    lost = ~np.isfinite(sim.q).all(axis=1)
    assert np.isfinite(sim.q[:6]).all() and lost.any(), sim.q[:8]
    assert lost[np.argmax(lost) :].all() and np.isnan(sim.dq[lost]).all()
    assert (np.abs(sim.q[~lost]) < core.DIVERGED).all()
    arm = core.ClosedFormArm(theta, friction, None)
    pieces = list(core.integrate_chunks(arm, tau, H, 5, start, chunk=7))
    np.testing.assert_array_equal(np.concatenate([p.q for p in pieces]), sim.q)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"tau": np.zeros((10, 3))}, "tau must have shape"),
        ({"tau": np.zeros(10)}, "tau must have shape"),
        ({"tau": np.zeros((0, 2))}, "no rows"),
        ({"tau": np.array([[0.0, 0.0], [np.nan, 1.0]])}, "non-finite value at row 1"),
        ({"period_s": 0.0}, "period_s"),
        ({"period_s": -0.0025}, "period_s"),
        ({"period_s": math.inf}, "period_s"),
        ({"period_s": "fast"}, "period_s"),
        ({"theta": np.ones(8)}, "theta must hold 9"),
        ({"theta": [*robot_params().theta[:8], math.nan]}, "non-finite"),
        ({"theta": [2.35, 0.5, *robot_params().theta[2:]]}, "not positive definite"),
        ({"theta": [*robot_params().theta[:7], -1.0, 1.7]}, "Coulomb"),
        ({"steps_per_period": 0}, "steps_per_period"),
        ({"steps_per_period": 2.5}, "steps_per_period"),
        ({"q0": (0.0,)}, "q0"),
        ({"dq0": (0.0, math.inf)}, "dq0"),
        ({"coulomb_positive": (7.0, -1.0)}, "coulomb_positive"),
        ({"coulomb_negative": (7.0, 1.0, 2.0)}, "coulomb_negative"),
    ],
)
def test_bad_input_is_rejected_with_a_clear_message(theta, kwargs, message):
    args = {"theta": theta, "tau": np.zeros((5, 2)), "period_s": H, **kwargs}
    with pytest.raises(ValueError, match=message) as info:
        simulate_open_loop(args.pop("theta"), args.pop("tau"), args.pop("period_s"), **args)
    assert "\n" not in str(info.value)


# ---- hil.model.metrics.nrmse -----------------------------------------------------------------


def test_nrmse_definition():
    y = np.array([[1.0, 5.0], [2.0, 5.0], [3.0, 5.0], [4.0, 5.0]])
    assert np.array_equal(nrmse(y, y)[0], 0.0)
    mean_model = np.tile(y.mean(axis=0), (4, 1))
    result = nrmse(y, mean_model)
    assert result.shape == (2,)
    assert result[0] == pytest.approx(1.0)  # the mean of y scores 1
    assert math.isnan(result[1])  # constant reference: no scale
    off = y[:, 0] + 0.5
    expected = math.sqrt(4 * 0.25) / math.sqrt(1.5**2 + 0.5**2 + 0.5**2 + 1.5**2)
    assert float(nrmse(y[:, 0], off)) == pytest.approx(expected)
    assert nrmse(y[:, 0], off).shape == ()
    with pytest.raises(ValueError, match="shape"):
        nrmse(y, y[:, :1])
    with pytest.raises(ValueError, match="no samples"):
        nrmse(np.zeros((0, 2)), np.zeros((0, 2)))


# ---- (d) the diagnosis's extra physics (OpenLoopExtras) against the world's effects -------------

SYMMETRIC = Coulomb((7.6095, 1.734), (7.6095, 1.734))
# each: the world's effects profile and the same physics for the host, in the diagnosis vocabulary
EXTRAS_CASES = {
    "torque_offset": (
        EffectsProfile(coulomb=SYMMETRIC, torque_offset_Nm=(1.0, 0.15)),
        OpenLoopExtras(torque_offset_Nm=(1.0, 0.15)),
    ),
    "torque_gain": (
        EffectsProfile(coulomb=SYMMETRIC, torque_gain_error=(0.06, -0.06)),
        OpenLoopExtras(torque_gain=(0.06, -0.06)),
    ),
    "actuator_lag": (
        EffectsProfile(coulomb=SYMMETRIC, amplifier_lag_s=(0.003, 0.002)),
        OpenLoopExtras(actuator_lag_s=(0.003, 0.002)),
    ),
    "transport_delay": (  # one period
        EffectsProfile(coulomb=SYMMETRIC, transport_delay_s=0.0025),
        OpenLoopExtras(transport_delay_s=0.0025),
    ),
    "transport_delay_fraction": (  # not a multiple of h: sub-steps cut at the arrivals
        EffectsProfile(coulomb=SYMMETRIC, transport_delay_s=0.0061),
        OpenLoopExtras(transport_delay_s=0.0061),
    ),
    "cogging": (
        EffectsProfile(coulomb=SYMMETRIC, cogging=Cogging((120.0, 96.0), (1.5, 0.15), (0.3, 0.5))),
        OpenLoopExtras(
            cogging_periods_per_rev=(120.0, 96.0),
            cogging_amplitude_Nm=(1.5, 0.15),
            cogging_phase_rad=(0.3, 0.5),
        ),
    ),
    "angle_offset": (
        EffectsProfile(coulomb=SYMMETRIC, encoder_offset_rad=(0.02, -0.04)),
        OpenLoopExtras(angle_offset_rad=(0.02, -0.04)),
    ),
    "stribeck": (
        EffectsProfile(coulomb=SYMMETRIC, stribeck=Stribeck((1.35, 1.25), (0.08, 0.10), 2.0)),
        OpenLoopExtras(stribeck_breakaway_ratio=(1.35, 1.25), stribeck_velocity_rad_s=(0.08, 0.10)),
    ),
    "all_with_asymmetric_coulomb": (
        EffectsProfile(
            coulomb=Coulomb((7.17, 1.6), (8.049, 1.9)),
            torque_offset_Nm=(0.5, 0.1),
            torque_gain_error=(0.03, -0.02),
            amplifier_lag_s=(0.002, 0.001),
            transport_delay_s=0.0011,
            cogging=Cogging((120.0, 96.0), (1.0, 0.1)),
            stribeck=Stribeck((1.2, 1.1), (0.1, 0.1), 1.5),
            encoder_offset_rad=(0.01, 0.02),
        ),
        OpenLoopExtras(
            torque_offset_Nm=(0.5, 0.1),
            torque_gain=(0.03, -0.02),
            actuator_lag_s=(0.002, 0.001),
            transport_delay_s=0.0011,
            cogging_periods_per_rev=(120.0, 96.0),
            cogging_amplitude_Nm=(1.0, 0.1),
            stribeck_breakaway_ratio=(1.2, 1.1),
            stribeck_velocity_rad_s=(0.1, 0.1),
            stribeck_exponent=1.5,
            angle_offset_rad=(0.01, 0.02),
        ),
    ),
}


def levels_of(effects: EffectsProfile) -> dict:
    assert effects.coulomb is not None
    return {
        "coulomb_positive": effects.coulomb.positive_Nm,
        "coulomb_negative": effects.coulomb.negative_Nm,
    }


def measured_world(effects: EffectsProfile, tau: np.ndarray) -> np.ndarray:
    """The plant's measured q (true + encoder offset, not floored) at t = k·h; commands issued
    at k·h as the offline loop does (the transport delay counts from there)."""
    plant = Plant(PlantParams.from_profiles(load_robot("cicese"), effects))
    q = np.empty_like(tau)
    for k, row in enumerate(tau):
        q[k] = plant.measured_q
        plant.command((float(row[0]), float(row[1])), issued_at=k * H)
        plant.advance_to((k + 1) * H)
    return q


@pytest.mark.parametrize("name", sorted(EXTRAS_CASES))
def test_extras_reproduce_the_world_recording(tmp_path, theta, name):
    """Through the drives and encoders (virtual_robot.simulate): the recorded q are floored
    encoder readings read at the centre of the count, so the host's q sit within ½ count of
    them, as in the plain case."""
    effects, extras = EXTRAS_CASES[name]
    simulate(
        load_robot("cicese"),
        load_experiment("reyes-kelly"),
        tmp_path,
        effects=effects,
        duration_s=SECONDS,
        plot=False,
    )
    rec = read_signals(tmp_path)
    q0 = extras.angle_offset_rad  # the arm starts at q = 0: its reading is the offset
    sim = simulate_open_loop(theta, rec.tau, H, q0=q0, extras=extras, **levels_of(effects))
    delta = sim.q - rec.q
    assert np.all(np.abs(delta) <= COUNT / 2 + 1e-9), np.abs(delta).max(axis=0)
    # not vacuous: the model without the extra misses the recording by far more than a count
    plain = simulate_open_loop(theta, rec.tau, H, **levels_of(effects))
    assert np.abs(plain.q - rec.q).max() > 20 * COUNT.max(), name


@pytest.mark.parametrize("name", sorted(EXTRAS_CASES))
def test_extras_match_the_plant_state_to_round_off(theta, name):
    """Without the encoder: the same physics (measured ≤ 4.7e-13 rad over 3 s of eqs. (31)-(32)
    and ≤ 2e-10 rad over whole runs of all four shipped excitations with random effects)."""
    effects, extras = EXTRAS_CASES[name]
    tau = load_experiment("reyes-kelly").torque_table(np.arange(round(SECONDS / H)) * H)
    world = measured_world(effects, tau)
    q0 = extras.angle_offset_rad
    sim = simulate_open_loop(theta, tau, H, q0=q0, extras=extras, **levels_of(effects))
    assert np.max(np.abs(sim.q - world)) < 1e-9


def test_extras_match_the_plant_on_the_diagnosis_experiment(theta):
    """20 s of fast excitation, then slow moves and holds: every extra at once, including the
    chattering case of a lagged break-away (the plant skips the rest of that step; so does the
    host, see hil/model/openloop_effects.py). Measured 2.5e-14 rad."""
    effects, extras = EXTRAS_CASES["all_with_asymmetric_coulomb"]
    tau = load_experiment("diagnosis").torque_table(np.arange(8000) * H)
    world = measured_world(effects, tau)
    q0 = extras.angle_offset_rad
    sim = simulate_open_loop(theta, tau, H, q0=q0, extras=extras, **levels_of(effects))
    assert np.max(np.abs(sim.q - world)) < 1e-9
    assert sim.stick_events.sum() > 60


def test_default_extras_are_the_plain_model_bit_for_bit(theta):
    tau = load_experiment("reyes-kelly").torque_table(np.arange(800) * H)
    plain = simulate_open_loop(theta, tau, H)
    same = simulate_open_loop(theta, tau, H, extras=OpenLoopExtras())
    assert np.array_equal(plain.q, same.q) and np.array_equal(plain.dq, same.dq)
    assert np.array_equal(plain.stuck, same.stuck)
    # an angle offset only changes what is reported
    shifted = simulate_open_loop(
        theta, tau, H, q0=(0.02, -0.04), extras=OpenLoopExtras(angle_offset_rad=(0.02, -0.04))
    )
    assert np.array_equal(shifted.q, plain.q + np.array([0.02, -0.04]))
    assert np.array_equal(shifted.dq, plain.dq)


def test_offset_gain_and_whole_period_delay_equal_changed_torques(theta):
    """Checks on the host alone: τ_0 and (1 + r) act on the commanded torque; a delay of m
    periods shifts the rows by m (zero torque first)."""
    tau = load_experiment("validation-multisine").torque_table(np.arange(1200) * H)
    by_hand = simulate_open_loop(theta, 1.05 * tau + [0.8, -0.1], H)
    extra = OpenLoopExtras(torque_gain=(0.05, 0.05), torque_offset_Nm=(0.8, -0.1))
    np.testing.assert_allclose(
        simulate_open_loop(theta, tau, H, extras=extra).q, by_hand.q, atol=1e-9
    )
    shifted = np.vstack([np.zeros((3, 2)), tau[:-3]])
    delayed = simulate_open_loop(theta, tau, H, extras=OpenLoopExtras(transport_delay_s=3 * H))
    np.testing.assert_allclose(delayed.q, simulate_open_loop(theta, shifted, H).q, atol=1e-9)
    # a lag T much shorter than a sub-step acts like a delay of T: the change it makes is ∝ T
    plain = simulate_open_loop(theta, tau, H).q
    change = [
        np.abs(
            simulate_open_loop(theta, tau, H, extras=OpenLoopExtras(actuator_lag_s=(T, T))).q
            - plain
        ).max()
        for T in (1e-7, 1e-8)
    ]
    assert 1e-7 < change[0] < 2e-6 and change[0] / change[1] == pytest.approx(10.0, rel=0.01)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"torque_gain": (-1.0, 0.0)}, "torque_gain must be > -1"),
        ({"actuator_lag_s": (0.001, -0.001)}, "actuator_lag_s must be >= 0"),
        ({"transport_delay_s": -0.001}, "transport_delay_s must be >= 0"),
        ({"transport_delay_s": math.nan}, "transport_delay_s must be finite"),
        ({"transport_delay_s": "soon"}, "transport_delay_s must be a number"),
        ({"torque_offset_Nm": (1.0,)}, "torque_offset_Nm must be 2 numbers"),
        ({"cogging_amplitude_Nm": (1.0, math.inf)}, "cogging_amplitude_Nm holds a non-finite"),
        ({"cogging_periods_per_rev": (-1.0, 0.0)}, "cogging_periods_per_rev must be >= 0"),
        ({"angle_offset_rad": "zero"}, "angle_offset_rad must be 2 numbers"),
        ({"stribeck_breakaway_ratio": (1.2, 1.2)}, "needs stribeck_velocity_rad_s"),
        ({"stribeck_velocity_rad_s": (0.0, 0.1)}, "stribeck_velocity_rad_s must be > 0"),
        (
            {"stribeck_velocity_rad_s": (0.1, 0.1), "stribeck_breakaway_ratio": (0.9, 1.0)},
            "stribeck_breakaway_ratio must be >= 1",
        ),
        ({"stribeck_velocity_rad_s": (0.1, 0.1), "stribeck_exponent": 0.0}, "stribeck_exponent"),
    ],
)
def test_bad_extras_are_rejected_with_a_clear_message(kwargs, message):
    with pytest.raises(ValueError, match=message) as info:
        OpenLoopExtras(**kwargs)
    assert "\n" not in str(info.value)


def test_extras_of_the_wrong_type_are_rejected(theta):
    with pytest.raises(ValueError, match="extras must be an OpenLoopExtras"):
        simulate_open_loop(theta, np.zeros((5, 2)), H, extras={"torque_offset_Nm": (1.0, 0.0)})
