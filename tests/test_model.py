"""hil.model.closed_form (the host's model) against virtual_robot.dynamics (the world's reference
equations).

Also the regressor identities the identification schemes rely on (Reyes & Kelly 1997 eqs.
(8), (11)-(15)), and the physical-consistency check.
"""

from __future__ import annotations

import numpy as np
import pytest

from hil.model import closed_form as model
from hil.model.params import robot_params
from virtual_robot import dynamics

N = 64


@pytest.fixture(scope="module")
def theta() -> np.ndarray:
    return robot_params().theta


@pytest.fixture(scope="module")
def states() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(7)
    q = rng.uniform(-np.pi, np.pi, (N, 2))
    dq = rng.uniform(-4, 4, (N, 2))
    ddq = rng.uniform(-20, 20, (N, 2))
    tau = rng.uniform(-60, 60, (N, 2))
    return q, dq, ddq, tau


def random_theta(rng: np.random.Generator) -> np.ndarray:
    """A θ with every entry non-zero and M(q) positive definite, to exercise every column."""
    t2 = rng.uniform(0.05, 0.3)
    t3 = rng.uniform(0.05, 0.5)
    t1 = 2.5 * t2 + t3 + t2**2 / t3 + rng.uniform(0.1, 2.0)
    return np.array(
        [t1, t2, t3, *rng.uniform(0.5, 40, 2), *rng.uniform(0.1, 3, 2), *rng.uniform(0.5, 8, 2)]
    )


def trajectory(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A smooth trajectory with q̇ ≠ 0 on (0, 2) s (so sgn q̇ is constant), and its derivatives."""
    w1, w2 = 1.3, 0.9
    q = np.stack([0.7 * np.sin(w1 * t) + 2.0 * t, -1.1 * np.cos(w2 * t) - 1.5 * t], -1)
    dq = np.stack([0.7 * w1 * np.cos(w1 * t) + 2.0, 1.1 * w2 * np.sin(w2 * t) - 1.5], -1)
    ddq = np.stack([-0.7 * w1**2 * np.sin(w1 * t), 1.1 * w2**2 * np.cos(w2 * t)], -1)
    return q, dq, ddq


# ---- the host's model = the world's equations ------------------------------------------------


def test_rigid_body_terms_match_the_reference_equations(theta, states):
    q, dq, ddq, tau = states
    M = model.mass_matrix(theta, q)
    Cdq = model.coriolis_vector(theta, q, dq)
    g = model.gravity_vector(theta, q)
    tau_id = model.inverse_dynamics(theta, q, dq, ddq, friction=False)
    ddq_fd = model.forward_dynamics(theta, q, dq, tau, friction=False)
    energy = model.total_energy(theta, q, dq)
    for k in range(N):
        np.testing.assert_allclose(M[k], dynamics.mass_matrix(theta, q[k]), rtol=1e-13)
        np.testing.assert_allclose(
            Cdq[k], dynamics.coriolis_vector(theta, q[k], dq[k]), rtol=1e-12, atol=1e-12
        )
        np.testing.assert_allclose(g[k], dynamics.gravity_vector(theta, q[k]), atol=1e-12)
        np.testing.assert_allclose(
            tau_id[k], dynamics.inverse_dynamics(theta, q[k], dq[k], ddq[k]), atol=1e-10
        )
        np.testing.assert_allclose(
            ddq_fd[k], dynamics.forward_dynamics(theta, q[k], dq[k], tau[k]), atol=1e-10
        )
        assert energy[k] == pytest.approx(dynamics.total_energy(theta, q[k], dq[k]), abs=1e-10)


def test_friction_and_its_place_in_the_dynamics(theta, states):
    q, dq, ddq, _ = states
    f = model.friction_torque(theta, dq)
    expected = np.stack(
        [
            theta[5] * dq[:, 0] + theta[7] * np.sign(dq[:, 0]),
            theta[6] * dq[:, 1] + theta[8] * np.sign(dq[:, 1]),
        ],
        -1,
    )
    np.testing.assert_allclose(f, expected, rtol=1e-14)
    np.testing.assert_allclose(
        model.inverse_dynamics(theta, q, dq, ddq),
        model.inverse_dynamics(theta, q, dq, ddq, friction=False) + f,
        atol=1e-12,
    )
    # forward and inverse dynamics are each other's inverse (with friction, q̇ ≠ 0)
    ddq_back = model.forward_dynamics(theta, q, dq, model.inverse_dynamics(theta, q, dq, ddq))
    np.testing.assert_allclose(ddq_back, ddq, atol=1e-9)
    # sgn(0) = 0 in the model's f (stiction is hil.model.openloop's business)
    assert np.array_equal(model.friction_torque(theta, [0.0, 0.0]), [0.0, 0.0])


def test_mass_matrix_is_symmetric_positive_definite(theta, states):
    M = model.mass_matrix(theta, states[0])
    assert np.array_equal(M, np.swapaxes(M, -1, -2))
    assert np.all(np.linalg.eigvalsh(M) > 0)


# ---- regressors -------------------------------------------------------------------------------


def test_dynamic_regressor_times_theta_is_the_inverse_dynamics(theta, states):
    q, dq, ddq, _ = states
    rng = np.random.default_rng(3)
    for th in (theta, random_theta(rng), random_theta(rng)):
        Y = model.dynamic_regressor(q, dq, ddq)
        np.testing.assert_allclose(Y @ th, model.inverse_dynamics(th, q, dq, ddq), atol=1e-10)
    # linear in θ column by column: each unit θ picks out one column
    Y = model.dynamic_regressor(q, dq, ddq)
    for i in range(model.N_PARAMS):
        e = np.zeros(model.N_PARAMS)
        e[i] = 1.0
        np.testing.assert_allclose(
            Y[..., i], model.inverse_dynamics(e, q, dq, ddq), atol=1e-12, err_msg=f"column {i}"
        )


def test_momentum_regressor_is_the_generalized_momentum(theta, states):
    q, dq, _, _ = states
    P = model.momentum_regressor(q, dq)
    np.testing.assert_allclose(
        P @ theta, np.einsum("nij,nj->ni", model.mass_matrix(theta, q), dq), atol=1e-12
    )
    assert np.all(P[..., 3:] == 0)  # gravity and friction have no momentum


EPS = 1e-5  # the central difference's step along a trajectory, s


def _trajectory_and_neighbours():
    """(q, q̇, q̈) of :func:`trajectory` at 41 instants in [0.1, 1.9] s, and at each ± EPS."""
    t = np.linspace(0.1, 1.9, 41)
    return trajectory(t), trajectory(t + EPS), trajectory(t - EPS)


def test_momentum_derivative_plus_static_regressor_is_the_dynamic_regressor():
    """τ = d/dt[P(q, q̇) θ] + R(q, q̇) θ = Y(q, q̇, q̈) θ, eqs. (11)-(13), along a trajectory."""
    rng = np.random.default_rng(11)
    (q, dq, ddq), (qp, dqp, _), (qm, dqm, _) = _trajectory_and_neighbours()
    for th in (robot_params().theta, random_theta(rng)):
        dP = (model.momentum_regressor(qp, dqp) - model.momentum_regressor(qm, dqm)) / (2 * EPS)
        lhs = dP @ th + model.static_regressor(q, dq) @ th
        rhs = model.dynamic_regressor(q, dq, ddq) @ th
        np.testing.assert_allclose(lhs, rhs, rtol=1e-7, atol=1e-7)
        # and column by column (the identity holds for the regressors, not only for one θ)
        np.testing.assert_allclose(
            dP + model.static_regressor(q, dq), model.dynamic_regressor(q, dq, ddq), atol=1e-7
        )


def test_energy_regressor_gives_kinetic_plus_potential_energy(theta, states):
    q, dq, _, _ = states
    phi = model.energy_regressor(q, dq)
    assert phi.shape == (N, 5)
    for k in range(N):
        assert phi[k] @ theta[:5] == pytest.approx(
            dynamics.total_energy(theta, q[k], dq[k]), abs=1e-10
        )
    assert model.energy_regressor([0.0, 0.0], [0.0, 0.0]) @ theta[:5] == 0.0  # hanging at rest


def test_energy_rate_is_the_power_supplied_minus_friction_power():
    """d/dt ℰ = q̇ᵀ(τ − f), eq. (25), with τ from the inverse dynamics along a trajectory."""
    rng = np.random.default_rng(5)
    (q, dq, ddq), (qp, dqp, _), (qm, dqm, _) = _trajectory_and_neighbours()
    for th in (robot_params().theta, random_theta(rng)):
        tau = model.inverse_dynamics(th, q, dq, ddq)
        f = model.friction_torque(th, dq)
        rate = (model.total_energy(th, qp, dqp) - model.total_energy(th, qm, dqm)) / (2 * EPS)
        power = np.sum(dq * (tau - f), axis=-1)
        np.testing.assert_allclose(rate, power, rtol=1e-7, atol=1e-6)
        assert np.max(np.abs(power)) > 1.0  # the check is not vacuous
        # the friction power regressor books q̇ᵀ f per θ6..θ9
        np.testing.assert_allclose(
            model.friction_power_regressor(dq) @ th[5:9], np.sum(dq * f, axis=-1), rtol=1e-12
        )


# ---- shapes ------------------------------------------------------------------------------------


def test_vectorized_and_single_sample_shapes(theta, states):
    q, dq, ddq, tau = states
    cases = [
        (lambda a, b, c, d: model.mass_matrix(theta, a), (2, 2)),
        (lambda a, b, c, d: model.coriolis_vector(theta, a, b), (2,)),
        (lambda a, b, c, d: model.gravity_vector(theta, a), (2,)),
        (lambda a, b, c, d: model.friction_torque(theta, b), (2,)),
        (lambda a, b, c, d: model.inverse_dynamics(theta, a, b, c), (2,)),
        (lambda a, b, c, d: model.forward_dynamics(theta, a, b, d), (2,)),
        (lambda a, b, c, d: model.dynamic_regressor(a, b, c), (2, 9)),
        (lambda a, b, c, d: model.momentum_regressor(a, b), (2, 9)),
        (lambda a, b, c, d: model.static_regressor(a, b), (2, 9)),
        (lambda a, b, c, d: model.energy_regressor(a, b), (5,)),
        (lambda a, b, c, d: model.friction_power_regressor(b), (4,)),
        (lambda a, b, c, d: model.total_energy(theta, a, b), ()),
    ]
    for fn, shape in cases:
        batch = fn(q, dq, ddq, tau)
        assert batch.shape == (N, *shape)
        one = fn(q[3], dq[3], ddq[3], tau[3])
        assert one.shape == shape
        np.testing.assert_allclose(one, batch[3], rtol=1e-12, atol=1e-12)
        # lists work as well as arrays
        listed = fn(q[3].tolist(), dq[3].tolist(), ddq[3].tolist(), tau[3].tolist())
        np.testing.assert_allclose(listed, one, rtol=0, atol=0)


# ---- physical consistency -----------------------------------------------------------------------


def test_physical_consistency_accepts_the_cicese_arm(theta):
    verdict = model.physical_consistency(theta)
    assert verdict == {"consistent": True, "violations": []}


@pytest.mark.parametrize("index", [5, 6, 7, 8])
def test_physical_consistency_rejects_negative_friction(theta, index):
    bad = theta.copy()
    bad[index] = -0.1
    verdict = model.physical_consistency(bad)
    assert verdict["consistent"] is False
    assert len(verdict["violations"]) == 1
    assert f"theta{index + 1}" in verdict["violations"][0]
    assert "friction" in verdict["violations"][0]


@pytest.mark.parametrize(
    ("changes", "needle"),
    [
        ({2: -0.01}, "theta3"),  # m22 = θ3 ≤ 0
        ({0: 0.15}, "q2 = pi"),  # m11 = θ1 − 2θ2 ≤ 0 with the arm folded
        ({1: 0.5}, "q2 = 0"),  # det M = θ1θ3 − θ3² − θ2² ≤ 0 stretched out
    ],
)
def test_physical_consistency_rejects_a_mass_matrix_that_is_not_positive_definite(
    theta, changes, needle
):
    bad = theta.copy()
    for i, value in changes.items():
        bad[i] = value
    verdict = model.physical_consistency(bad)
    assert verdict["consistent"] is False
    assert any(needle in v and "positive definite" in v for v in verdict["violations"]), verdict
    # the verdict is right: M(q) really is not positive definite somewhere
    q2 = np.linspace(-np.pi, np.pi, 721)
    M = model.mass_matrix(bad, np.stack([np.zeros_like(q2), q2], -1))
    assert np.min(np.linalg.eigvalsh(M)) <= 0


def test_physical_consistency_names_every_violation(theta):
    bad = theta.copy()
    bad[[6, 8]] = -1.0
    bad[2] = 0.0
    violations = model.physical_consistency(bad)["violations"]
    assert any("theta7" in v for v in violations)
    assert any("theta9" in v for v in violations)
    assert any("theta3" in v for v in violations)
