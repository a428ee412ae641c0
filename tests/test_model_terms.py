"""hil.model.closed_form.ArmModel: the 9-parameter model unchanged, and the extra terms (rotor
inertia,
centre-of-mass offset) against an arm written from its bodies, independently of the regressors.

The reference arm here is written from positions and velocities of its bodies (two links with
centres of mass off their axes, two rotors geared by gr), not from the θ parametrisation: its
Lagrangian is differentiated numerically, so a sign or factor slip in the model's columns fails.
"""

from __future__ import annotations

import numpy as np
import pytest

from hil.model import closed_form as model
from hil.model.closed_form import TERMS, ArmModel

G = 9.81
# A made-up arm with every effect present (SI units).
ARM = dict(
    l1=0.3, m1=0.6, lc1=0.25, ly1=0.02, I1c=0.004,  # link 1: I about its centre of mass
    m2=0.63, lc2=0.17, ly2=-0.015, I2c=0.006,
    Ir=7e-5, gr=6.0, sign=-1.0,  # rotor 2 turns by q1 + sign·gr·q2 (DFKI: minus)
)  # fmt: skip


def body_lagrangian(q: np.ndarray, dq: np.ndarray, a: dict = ARM) -> np.ndarray:
    """L = K − U of the reference arm from its bodies; q, dq (..., 2)."""
    q1, q2 = q[..., 0], q[..., 1]
    w1, w2 = dq[..., 0], dq[..., 0] + dq[..., 1]

    def e(phi):
        return np.stack([np.sin(phi), -np.cos(phi)], -1)

    def n(phi):
        return np.stack([np.cos(phi), np.sin(phi)], -1)

    v1 = w1[..., None] * (a["lc1"] * n(q1) - a["ly1"] * e(q1))
    p1 = a["lc1"] * e(q1) + a["ly1"] * n(q1)
    p2 = a["l1"] * e(q1) + a["lc2"] * e(q1 + q2) + a["ly2"] * n(q1 + q2)
    v2 = a["l1"] * w1[..., None] * n(q1) + w2[..., None] * (
        a["lc2"] * n(q1 + q2) - a["ly2"] * e(q1 + q2)
    )
    K = 0.5 * a["m1"] * np.sum(v1**2, -1) + 0.5 * a["I1c"] * w1**2
    K += 0.5 * a["m2"] * np.sum(v2**2, -1) + 0.5 * a["I2c"] * w2**2
    K += 0.5 * a["Ir"] * (a["gr"] * dq[..., 0]) ** 2  # rotor 1 on the base
    K += 0.5 * a["Ir"] * (dq[..., 0] + a["sign"] * a["gr"] * dq[..., 1]) ** 2  # rotor 2 on link 1
    U = G * (a["m1"] * p1[..., 1] + a["m2"] * p2[..., 1])
    return K - U


def body_theta(a: dict = ARM) -> np.ndarray:
    """θ of ArmModel(("rotor_inertia", "com_offset")) for the reference arm (no friction)."""
    I1 = a["I1c"] + a["m1"] * (a["lc1"] ** 2 + a["ly1"] ** 2)  # about joint 1
    I2 = a["I2c"] + a["m2"] * (a["lc2"] ** 2 + a["ly2"] ** 2)  # about joint 2
    gr, Ir, s = a["gr"], a["Ir"], a["sign"]
    return np.array(
        [
            I1 + I2 + a["m2"] * a["l1"] ** 2 + (gr**2 + 1) * Ir,
            a["l1"] * a["m2"] * a["lc2"],
            I2 + s * gr * Ir,
            G * (a["m1"] * a["lc1"] + a["m2"] * a["l1"]),
            G * a["m2"] * a["lc2"],
            0.0, 0.0, 0.0, 0.0,
            gr**2 * Ir - s * gr * Ir,
            a["l1"] * a["m2"] * a["ly2"],
            G * a["m1"] * a["ly1"],
            G * a["m2"] * a["ly2"],
        ]
    )  # fmt: skip


def trajectory(t: np.ndarray):
    q = np.stack([0.9 * np.sin(1.7 * t) + 0.4 * t, 1.3 * np.cos(2.3 * t) - 0.2], -1)
    dq = np.stack([0.9 * 1.7 * np.cos(1.7 * t) + 0.4, -1.3 * 2.3 * np.sin(2.3 * t)], -1)
    ddq = np.stack([-0.9 * 1.7**2 * np.sin(1.7 * t), -1.3 * 2.3**2 * np.cos(2.3 * t)], -1)
    return q, dq, ddq


def lagrange_torque(t: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """τ = d/dt ∂L/∂q̇ − ∂L/∂q of the body Lagrangian, by central differences."""

    def partial(fn, x, j):
        d = np.zeros(2)
        d[j] = eps
        return (fn(x + d) - fn(x - d)) / (2 * eps)

    def momentum(tt):
        q, dq, _ = trajectory(tt)
        return np.stack([partial(lambda v: body_lagrangian(q, v), dq, j) for j in range(2)], -1)

    q, dq, _ = trajectory(t)
    dpdt = (momentum(t + 1e-4) - momentum(t - 1e-4)) / 2e-4
    dLdq = np.stack([partial(lambda x: body_lagrangian(x, dq), q, j) for j in range(2)], -1)
    return dpdt - dLdq


def test_no_terms_is_the_nine_parameter_model_exactly():
    rng = np.random.default_rng(3)
    theta = np.array([2.35, 0.084, 0.102, 38.5, 1.83, 2.29, 0.175, 7.6, 1.73])
    q, dq, ddq = (rng.uniform(-3, 3, (50, 2)) for _ in range(3))
    m = ArmModel(())
    assert m.n_params == 9 and m.names == model.THETA_NAMES
    assert np.array_equal(m.mass_matrix(theta, q), model.mass_matrix(theta, q))
    assert np.array_equal(m.coriolis_vector(theta, q, dq), model.coriolis_vector(theta, q, dq))
    assert np.array_equal(m.gravity_vector(theta, q), model.gravity_vector(theta, q))
    assert np.array_equal(m.friction_torque(theta, dq), model.friction_torque(theta, dq))
    assert np.array_equal(m.torque(theta, q, dq, ddq), model.inverse_dynamics(theta, q, dq, ddq))
    assert np.array_equal(m.momentum_regressor(q, dq), model.momentum_regressor(q, dq))
    assert np.array_equal(m.static_regressor(q, dq), model.static_regressor(q, dq))
    assert np.array_equal(m.dynamic_regressor(q, dq, ddq), model.dynamic_regressor(q, dq, ddq))
    assert np.array_equal(m.energy_regressor(q, dq)[:, :5], model.energy_regressor(q, dq))
    assert m.physical_consistency(theta) == model.physical_consistency(theta)


def test_terms_append_named_columns_in_order():
    m = ArmModel(("com_offset", "rotor_inertia"))
    assert m.n_params == 13
    assert m.names[9:] == ("theta2_perp", "theta4_perp", "theta5_perp", "theta_rotor")
    assert m.term_columns("rotor_inertia") == slice(12, 13)
    assert len(m.units) == len(m.meanings) == 13
    with pytest.raises(ValueError, match="unknown model term"):
        ArmModel(("cogging",))


def test_extended_regressor_reproduces_the_body_lagrangian_torque():
    t = np.linspace(0.1, 3.0, 40)
    q, dq, ddq = trajectory(t)
    m = ArmModel(TERMS)
    theta = body_theta()
    expected = lagrange_torque(t)
    assert np.allclose(m.torque(theta, q, dq, ddq), expected, atol=2e-6, rtol=1e-6)
    # The 9-parameter model (the same arm without its extra terms) does not.
    assert np.max(np.abs(model.inverse_dynamics(theta[:9], q, dq, ddq) - expected)) > 1e-3
    # τ = d/dt[P θ] + R θ (the split the filters use), d/dt by central difference.
    P = lambda tt: m.momentum_regressor(*trajectory(tt)[:2]) @ theta  # noqa: E731
    split = (P(t + 1e-5) - P(t - 1e-5)) / 2e-5 + m.static_regressor(q, dq) @ theta
    assert np.allclose(split, expected, atol=1e-5)
    # M(q), C q̇, g(q) put back together give the same torque.
    parts = (
        np.einsum("kij,kj->ki", m.mass_matrix(theta, q), ddq)
        + m.coriolis_vector(theta, q, dq)
        + m.gravity_vector(theta, q)
    )
    assert np.allclose(parts, expected, atol=2e-6)


def test_energy_balance_of_a_simulated_arm_with_rotor_and_offset():
    """Simulate the extended model under a torque; the body energy must change by the work."""
    m = ArmModel(TERMS)
    theta = body_theta()
    h, n = 1e-4, 5000
    x = np.array([0.3, -0.5, 0.0, 0.0])
    work = 0.0

    def tau(t):
        return np.array([0.8 * np.sin(3 * t), 0.3 * np.cos(5 * t)])

    def f(t, s):
        return np.r_[s[2:], m.forward_dynamics(theta, s[:2], s[2:], tau(t))]

    def energy(s):
        return -body_lagrangian(s[:2], s[2:]) + 2 * kinetic(s)

    def kinetic(s):  # K = (L(q, q̇) − L(q, 0)); E = K + U = 2K − L
        return body_lagrangian(s[:2], s[2:]) - body_lagrangian(s[:2], np.zeros(2))

    e0 = energy(x)
    for k in range(n):
        t = k * h
        k1 = f(t, x)
        k2 = f(t + h / 2, x + h / 2 * k1)
        k3 = f(t + h / 2, x + h / 2 * k2)
        k4 = f(t + h, x + h * k3)
        x_new = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        mid = 0.5 * (x[2:] + x_new[2:])
        work += h * tau(t + h / 2) @ mid
        x = x_new
    assert abs(energy(x) - e0 - work) < 1e-5 * max(1.0, abs(work))
    # The model's own energy regressor agrees with the body energy.
    assert np.isclose(
        m.total_energy(theta, x[:2], x[2:]) - m.total_energy(theta, *np.zeros((2, 2))),
        energy(x) - energy(np.zeros(4)),
    )


def test_physical_consistency_closed_form_matches_eigenvalues():
    m = ArmModel(TERMS)
    rng = np.random.default_rng(5)
    theta = body_theta()
    assert m.physical_consistency(theta)["consistent"]
    for _ in range(300):
        th = theta * rng.uniform(-0.5, 2.5, theta.size)
        th[5:9] = 0.1
        th[9] = abs(th[9])
        closed = m.physical_consistency(th)["consistent"]
        assert closed == (m.min_mass_eigenvalue(th, 721) > 0), th
