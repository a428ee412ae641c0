"""Controllers (hil/control/controllers.py), reference trajectory (hil/control/trajectory.py),
tracking profile.

Pure tests, no bench: the control laws against Khosla & Kanade (1987) eqs. (2)-(4), the quintic
moves of Section 4.2, and computed torque closing the loop on the host model itself (where the
error must obey s² + k_v s + k_p = 0, eq. (7)).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from hil.bench.run import UsageError
from hil.control.controllers import (
    BackwardDifference,
    ComputedTorque,
    Feedforward,
    Gains,
    PDGravity,
    ReducedFeedforward,
    Reference,
    make_controller,
    typical_inertia,
)
from hil.control.tracking import (
    parameter_sets,
    parse_params_spec,
    reference_torque_margin,
    tracking_errors,
)
from hil.control.trajectory import PointToPoint, khosla_kanade_moves, quintic
from hil.model.closed_form import (
    coriolis_vector,
    forward_dynamics,
    friction_torque,
    gravity_vector,
    inverse_dynamics,
    mass_matrix,
)
from hil.model.params import robot_params
from profiles import ProfileError
from profiles.experiment import load_experiment
from profiles.tracking import load_tracking

THETA = robot_params("cicese").theta
TABLE1 = Gains(kp=(40.0, 58.0), kv=(12.6, 15.2))
LIMITS = (200.0, 15.0)
H = 0.0025


def shipped_trajectory() -> PointToPoint:
    exp = load_tracking("khosla-kanade-tracking")
    return khosla_kanade_moves(exp.amplitude_rad, exp.pattern, move_s=exp.move_s, hold_s=exp.hold_s)


# --- trajectory ----------------------------------------------------------------------------------


def test_quintic_rest_to_rest():
    s, ds, dds = quintic([0.0, 0.5, 1.0])
    assert s.tolist() == [0.0, 0.5, 1.0]
    assert ds[0] == ds[2] == 0.0 and dds[0] == dds[2] == 0.0
    assert ds[1] == pytest.approx(1.875)
    # the derivatives are the derivatives (central differences of s and s')
    x = np.linspace(0.01, 0.99, 99)
    e = 1e-6
    assert np.allclose((quintic(x + e)[0] - quintic(x - e)[0]) / (2 * e), quintic(x)[1], atol=1e-6)
    assert np.allclose((quintic(x + e)[1] - quintic(x - e)[1]) / (2 * e), quintic(x)[2], atol=1e-5)


def test_shipped_trajectory_is_section_4_2_adapted():
    traj = shipped_trajectory()
    assert traj.duration_s == pytest.approx(6.0)
    t = np.array([0.0, 0.75, 1.5, 2.25, 3.0, 3.75, 4.5, 5.25, 6.0, 7.0])
    q, dq, ddq = traj.at(t)
    expected = [0.0, 1.5, 1.5, 0.0, 0.0, -1.5, -1.5, 0.0, 0.0, 0.0]
    for j in range(2):  # both joints move, ±1.5 rad, 0.75 s moves and 0.75 s holds
        assert q[:, j] == pytest.approx(expected, abs=1e-12)
    assert np.all(np.abs(dq) < 1e-12) and np.all(np.abs(ddq) < 1e-9)
    peaks = traj.peaks()
    assert peaks["velocity_rad_s"] == pytest.approx([3.75, 3.75])
    assert peaks["acceleration_rad_s2"] == pytest.approx([15.396] * 2, abs=1e-3)


def test_trajectory_is_continuous_in_position_velocity_acceleration():
    traj = shipped_trajectory()
    t = np.arange(0.0, 6.5, 1e-4)
    q, dq, ddq = traj.at(t)
    # no jumps: the largest step between samples is what the peak slope allows
    assert np.max(np.abs(np.diff(q, axis=0))) <= 3.75 * 1e-4 * 1.001
    assert np.max(np.abs(np.diff(dq, axis=0))) <= 15.4 * 1e-4 * 1.001
    jerk_peak = 1.5 * 60 / 0.75**3  # s‴(0) = 60
    assert np.max(np.abs(np.diff(ddq, axis=0))) <= jerk_peak * 1e-4 * 1.001
    # and they are each other's derivatives
    assert np.allclose(np.gradient(q, 1e-4, axis=0), dq, atol=2e-3)
    assert np.allclose(np.gradient(dq, 1e-4, axis=0), ddq, atol=3e-2)  # jerk steps
    # scalar and vector calls agree
    for tk in (0.3, 1.0, 2.0, 5.9):
        qs, dqs, ddqs = traj.at(tk)
        k = round(tk / 1e-4)
        assert np.allclose(qs, q[k]) and np.allclose(dqs, dq[k]) and np.allclose(ddqs, ddq[k])


def test_trajectory_rejects_bad_shapes():
    with pytest.raises(ValueError):
        PointToPoint((0.0, 0.0), ((1.0,), (1.0, 2.0)), move_s=1.0, hold_s=0.0)
    with pytest.raises(ValueError):
        PointToPoint((0.0,), ((1.0,),), move_s=0.0, hold_s=0.0)


def test_reference_torques_stay_inside_the_drive_limits():
    """The inverse dynamics along the shipped reference: what is left of 200 / 15 Nm."""
    margin = reference_torque_margin(THETA, shipped_trajectory(), LIMITS, H)
    peak = margin["peak_reference_torque_Nm"]
    assert 50 < peak[0] < 70 and 5 < peak[1] < 9, peak
    assert margin["margin_fraction"][0] > 0.6 and margin["margin_fraction"][1] > 0.4


# --- control laws ------------------------------------------------------------------------------


def _ref(t: float) -> Reference:
    return Reference(*shipped_trajectory().at(t))


def test_gains_of_table_1_are_critically_damped():
    assert TABLE1.damping_ratio() == pytest.approx([1.0, 1.0], abs=0.01)
    with pytest.raises(ValueError):
        Gains(kp=(1.0, 2.0), kv=(1.0,))
    with pytest.raises(ValueError):
        Gains(kp=(-1.0, 2.0), kv=(1.0, 1.0))


def test_typical_inertia_is_the_diagonal_at_the_typical_position():
    inertia = typical_inertia(THETA, (0.0, 0.0))
    assert inertia == pytest.approx([THETA[0] + 2 * THETA[1], THETA[2]])
    assert typical_inertia(THETA, (0.3, math.pi / 2)) == pytest.approx([THETA[0], THETA[2]])


@pytest.mark.parametrize("t", [0.2, 0.4, 1.9, 3.3, 5.0])
def test_on_the_reference_ct_and_fed_give_the_inverse_dynamics(t):
    """With q = q_d and q̇ = q̇_d, eqs. (2) and (3) both reduce to τ_d = M q̈_d + C q̇_d + g + f."""
    ref = _ref(t)
    tau_d = inverse_dynamics(THETA, ref.q, ref.dq, ref.ddq)
    for cls in (ComputedTorque, Feedforward):
        cmd = cls(THETA, TABLE1, LIMITS)(t, ref.q, ref.dq, ref)
        assert cmd.tau_law == pytest.approx(tau_d, abs=1e-12)
        assert sum(cmd.parts.values()) == pytest.approx(cmd.tau_law, abs=1e-12)
        assert not cmd.clipped.any() and np.array_equal(cmd.tau, cmd.tau_law)
    # RFED misses exactly the off-diagonal and configuration-dependent inertia: (M(q_d) − J) q̈_d
    rfed = ReducedFeedforward(THETA, TABLE1, LIMITS)
    cmd = rfed(t, ref.q, ref.dq, ref)
    missing = (mass_matrix(THETA, ref.q) - np.diag(rfed.J)) @ ref.ddq
    assert tau_d - cmd.tau_law == pytest.approx(missing, abs=1e-12)


def test_ct_split_is_that_of_figs_20_22():
    ref = _ref(0.3)
    q = ref.q + np.array([0.01, -0.02])
    dq = ref.dq + np.array([-0.1, 0.05])
    cmd = ComputedTorque(THETA, TABLE1, LIMITS)(0.3, q, dq, ref)
    u = np.array(TABLE1.kp) * (ref.q - q) + np.array(TABLE1.kv) * (ref.dq - dq) + ref.ddq
    assert cmd.parts["inertial"] == pytest.approx(mass_matrix(THETA, q) @ u)  # eq. (2)
    assert cmd.parts["coriolis"] == pytest.approx(coriolis_vector(THETA, q, dq))
    assert cmd.parts["gravity"] == pytest.approx(gravity_vector(THETA, q))
    assert cmd.parts["friction"] == pytest.approx(friction_torque(THETA, dq))
    ref_friction = ComputedTorque(THETA, TABLE1, LIMITS, friction_velocity="reference")
    assert ref_friction(0.3, q, dq, ref).parts["friction"] == pytest.approx(
        friction_torque(THETA, ref.dq)
    )


def test_pd_is_j_scaled_feedback_plus_gravity():
    ref = _ref(0.3)
    q, dq = ref.q - 0.1, ref.dq
    pd = PDGravity(THETA, TABLE1, LIMITS)
    cmd = pd(0.3, q, dq, ref)
    assert cmd.tau_law == pytest.approx(pd.J * np.array(TABLE1.kp) * 0.1 + gravity_vector(THETA, q))


def test_saturation_clips_and_flags_each_joint():
    ref = _ref(0.3)
    q = ref.q - np.array([10.0, 0.0])  # a huge joint-1 error only
    cmd = make_controller("pd", THETA, TABLE1, LIMITS)(0.3, q, ref.dq, ref)
    assert cmd.clipped.tolist() == [True, False]
    assert cmd.tau[0] == 200.0 and cmd.tau_law[0] > 200.0
    assert cmd.tau[1] == cmd.tau_law[1]
    with pytest.raises(ValueError, match="unknown scheme"):
        make_controller("lqr", THETA, TABLE1, LIMITS)
    with pytest.raises(ValueError, match="friction_velocity"):
        make_controller("ct", THETA, TABLE1, LIMITS, friction_velocity="psychic")


def test_backward_difference_is_one_count_per_period_quantized():
    est = BackwardDifference(H)
    count = 2 * math.pi / 1024000
    assert est((0.0, 0.0)).tolist() == [0.0, 0.0]  # no previous sample: at rest
    dq = est((3 * count, 0.0))
    assert dq[0] == pytest.approx(3 * count / H) and dq[1] == 0.0
    assert count / H == pytest.approx(0.002454, abs=1e-6)  # the velocity resolution, joint 1


def test_computed_torque_on_its_own_model_gives_eq_7():
    """CT with the exact model closing the loop on that model: ë + k_v ė + k_p e = 0 (eq. (7)).

    Friction set to zero (sgn q̇ is not a differential equation an RK4 step can honour); the
    loop is continuous (the law evaluated inside every RK4 stage) so no sampling effects.
    """
    theta = THETA.copy()
    theta[5:] = 0.0
    traj = shipped_trajectory()
    ct = ComputedTorque(theta, TABLE1, (1e6, 1e6))
    e0 = np.array([0.05, -0.08])

    def accel(t: float, x: np.ndarray) -> np.ndarray:
        ref = Reference(*traj.at(t))
        tau = ct(t, x[:2], x[2:], ref).tau
        return np.concatenate([x[2:], forward_dynamics(theta, x[:2], x[2:], tau)])

    x = np.concatenate([traj.at(0.0)[0] - e0, [0.0, 0.0]])
    dt, t = 5e-4, 0.0
    errors = []
    for _ in range(int(1.0 / dt)):
        k1 = accel(t, x)
        k2 = accel(t + dt / 2, x + dt / 2 * k1)
        k3 = accel(t + dt / 2, x + dt / 2 * k2)
        k4 = accel(t + dt, x + dt * k3)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        t += dt
        errors.append(traj.at(t)[0] - x[:2])
    # the analytic error of s² + k_v s + k_p from e(0) = e0, ė(0) = 0
    tt = dt * np.arange(1, len(errors) + 1)
    for j in range(2):
        kp, kv = TABLE1.kp[j], TABLE1.kv[j]
        r1, r2 = np.roots([1.0, kv, kp])
        c2 = -r1 * e0[j] / (r2 - r1)
        analytic = np.real((e0[j] - c2) * np.exp(r1 * tt) + c2 * np.exp(r2 * tt))
        assert np.max(np.abs(np.array(errors)[:, j] - analytic)) < 1e-6


def test_tracking_errors_of_a_perfect_recording_are_zero():
    traj = shipped_trajectory()
    t = np.arange(0, 600) * H
    q = traj.at(t)[0]
    err = tracking_errors(t, q, traj)
    assert err["max_position_error_rad"] == [0.0, 0.0]
    # central differences of the quintic: O(h²) velocity error only
    assert max(err["max_velocity_error_rad_s"]) < 0.05
    shifted = tracking_errors(t, q - np.array([0.01, -0.02]), traj)
    assert shifted["max_position_error_rad"] == pytest.approx([0.01, 0.02])
    assert shifted["rms_position_error_rad"] == pytest.approx([0.01, 0.02])


# --- tracking profile and parameter specs ------------------------------------------------------


def test_tracking_profile_holds_table_1_and_the_choices():
    exp = load_tracking("khosla-kanade-tracking")
    assert exp.kp == (40.0, 58.0) and exp.kv == (12.6, 15.2)
    assert exp.amplitude_rad == (1.5, 1.5) and exp.move_s == 0.75 and exp.hold_s == 0.75
    assert exp.typical_q_rad == (0.0, 0.0) and exp.velocity == "backward_difference"
    assert exp.duration_s == pytest.approx(6.0)


def test_hil_run_loader_refuses_a_tracking_experiment():
    with pytest.raises(ProfileError) as exc:
        load_experiment("khosla-kanade-tracking")
    msg = str(exc.value)
    assert "\n" not in msg and "hil control" in msg and exc.value.field == "kind"


def test_tracking_loader_refuses_bad_profiles(tmp_path: Path):
    with pytest.raises(ProfileError, match="tracking experiment"):
        load_tracking("reyes-kelly")
    src = Path(load_tracking("khosla-kanade-tracking").source).read_text()
    for old, new, field in [
        ('velocity = "backward_difference"', 'velocity = "tachometer"', "model.velocity"),
        ("kp = [40.0, 58.0]", "kp = [40.0]", "gains.kp"),
        ("move_s = 0.75", "move_s = -1", "trajectory.move_s"),
        ("pattern = [1.0, 0.0, -1.0, 0.0]", "pattern = []", "trajectory.pattern"),
        ('ct_friction_velocity = "measured"', 'ct_friction_velocity = "x"', None),
    ]:
        path = tmp_path / "bad.toml"
        path.write_text(src.replace(old, new))
        with pytest.raises(ProfileError) as exc:
            load_tracking(path)
        assert "\n" not in str(exc.value) and str(path) in str(exc.value)
        if field:
            assert exc.value.field == field


def test_params_specs_and_labels(tmp_path: Path):
    a = tmp_path / "exact" / "params.json"
    a.parent.mkdir()
    a.write_text('{"theta": [2.3, 0.08, 0.1, 38, 1.8, 2.3, 0.17, 7.6, 1.7]}')
    b = tmp_path / "b.json"
    b.write_text(
        '{"selected": "x", "schemes": {"x": {"theta": [1, 0, 0.1, 1, 1, 0, 0, 0, 0]},'
        ' "y": {"theta": [2, 0, 0.1, 1, 1, 0, 0, 0, 0]}}}'
    )
    assert parse_params_spec(str(a)).label == "exact/params"
    assert parse_params_spec(f"paper={b}").label == "paper"
    picked = parse_params_spec(f"{b}#y")
    assert picked.label == "b#y" and picked.params.theta[0] == 2.0
    sets = parameter_sets([str(b), str(b)], include_profile=True, robot="cicese")
    assert [s.label for s in sets] == ["profile", "b", "b-2"]
    with pytest.raises(UsageError):
        parse_params_spec("label=")
