"""The host's n-joint open-loop simulation sticks as the arm does (issue 14).

`hil.model.openloop.simulate_segments` (the n-joint diagnosis's held-out simulation) runs the
2-DOF simulation's stick–slip integrator (hil.model.openloop_core.integrate_arm) over the URDF
model object (hil.model.openloop.ModelArm), not Coulomb friction as f_c sgn q̇. A slow motion of
the 3-joint arm that sticks and breaks away on every joint, recorded from the n-joint plant
(the world: virtual_robot.urdf_plant), is simulated by the host at the profile's own θ with the
stops where the plant has them.
"""

from __future__ import annotations

import numpy as np
import pytest

from hil.model.openloop import ModelArm, rk4_held, simulate_segments
from hil.model.urdf import UrdfArmModel
from profiles.robot import load_urdf_robot
from virtual_robot.urdf_plant import UrdfPlant, UrdfPlantParams

H = 0.0025
STEP = 5e-4  # the plant's integration step; the host's sub-steps are the same


def slow_recording(seconds: float = 4.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, q, τ) of the cicese3 plant under slow sines just above each joint's Coulomb level
    (7.17 / 8.049, 1.734, 0.35 / 0.40 Nm): every joint stops for a while at each reversal."""
    rows = round(seconds / H)
    t = np.arange(rows) * H
    tau = np.sin(2 * np.pi * 0.5 * t)[:, None] * np.array([10.0, 2.5, 0.6])
    plant = UrdfPlant(UrdfPlantParams.from_profile(load_urdf_robot("cicese3")), max_step_s=STEP)
    q = np.empty((rows, 3))
    for k in range(rows):
        q[k] = plant.measured_q  # sample at t_k, then τ_k held over [t_k, t_k+1)
        plant.command(tau[k])
        plant.advance_to(t[k] + H)
    return t, q, tau


def still_rows(q: np.ndarray) -> np.ndarray:
    """Rows where a joint's position equals the previous row's exactly (stuck), per joint."""
    return np.vstack([np.zeros((1, q.shape[1]), bool), np.diff(q, axis=0) == 0.0])


def test_slow_motion_that_sticks_is_simulated_with_the_stick() -> None:
    t, q, tau = slow_recording()
    stuck = still_rows(q)
    assert np.all(stuck.mean(axis=0) > 0.05), stuck.mean(axis=0)  # every joint sticks a while
    model = UrdfArmModel.from_profile("cicese3")
    theta = model.base_theta()
    (sim,) = simulate_segments(model, theta, t, q, tau, [(0, len(t))], np.zeros((1, 3)),
                               max_step_s=STEP)  # fmt: skip
    # the host holds the joints still where the plant did, and moves them as it did
    assert np.array_equal(still_rows(sim)[stuck], np.ones(int(stuck.sum()), bool))
    error = np.max(np.abs(sim - q), axis=0)
    assert np.all(error < 1e-6), error
    # Coulomb friction as f_c sgn q̇ (what the host simulated before) creeps where the arm sticks
    acc = lambda qq, vv, uu: model.forward_dynamics(theta, qq, vv, uu)  # noqa: E731
    x_q, x_v, creep = q[:1].copy(), np.zeros((1, 3)), [q[0]]
    for k in range(len(t) - 1):
        x_q, x_v, _ = rk4_held(acc, x_q, x_v, tau[k : k + 1], H / 5, 5)
        creep.append(x_q[0])
    assert np.max(np.abs(np.array(creep) - q)) > 100 * error.max()


def test_model_arm_holds_a_joint_inside_its_band_and_releases_it_outside() -> None:
    """Karnopp's test through ModelArm.holding_torques: at rest at q = 0 (hanging), joint 3 is
    held by friction for any torque in [−0.40, 0.35] Nm (the profile's levels by direction:
    f_c = 0.375 around the offset f_o = −0.025), released beyond."""
    model = UrdfArmModel.from_profile("cicese3")
    arm = ModelArm(model, model.base_theta())
    assert arm.friction.static_positive == pytest.approx((7.6095, 1.734, 0.375))
    state = (0.0,) * 6
    stuck, direction = (True, True, True), (1.0, 1.0, 1.0)
    for tau3, holds in ((0.34, True), (-0.39, True), (0.36, False), (-0.41, False)):
        held = arm.holding_torques(state, (0.0, 0.0, tau3), stuck, direction)
        # the friction that holds it, beyond the offset, against Coulomb's ±f_c = ±0.375 Nm
        inside = abs(held[2]) <= 0.375
        assert inside == holds, (tau3, held)


def test_negative_coulomb_level_is_refused_in_one_line() -> None:
    model = UrdfArmModel.from_profile("cicese3")
    theta = model.base_theta()
    theta[np.arange(theta.size)[model.term_columns("friction")][3]] = -0.1  # f_c of joint 1
    with pytest.raises(ValueError, match="negative Coulomb level") as err:
        ModelArm(model, theta)
    assert "\n" not in str(err.value)
