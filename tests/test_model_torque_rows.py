"""The nominal model's torque rows from its torques, not its regressor (issue 26, performance):
UrdfArmModel.momentum / static_torque against the regressors' products, the encoder-offset
column against its definition from the rebuilt regressor rows, and the memo of shifted rows."""

from __future__ import annotations

import numpy as np
import pytest

import hil.diagnose.effects.encoder as encoder
import hil.model.urdf as urdf
from hil.diagnose.columns import _momentum_rows, model_torque_rows, moving_average, recording_rows
from hil.diagnose.effects.base import REFINE_STEPS, Context
from hil.model.closed_form import ArmModel
from hil.model.urdf import UrdfArmModel

RNG = np.random.default_rng(3)


@pytest.fixture(scope="module")
def cicese3() -> UrdfArmModel:
    # with the armature term: its I_a q̇ is part of the momentum, not of the bodies
    return UrdfArmModel.from_profile("cicese3", terms=("rotor_inertia", "friction_offset"))


@pytest.fixture(scope="module")
def panda() -> UrdfArmModel:
    return UrdfArmModel.from_profile("panda")


def _theta(model) -> np.ndarray:
    """A base vector off the URDF's (every parameter 30 % off): an identified θ₀, not the
    nominal bodies."""
    return model.base_theta() * (1 + 0.3 * RNG.standard_normal(model.n_params))


def _rows(model, N: int = 700, irregular: bool = False):
    """Rows of a smooth multi-joint motion (irregular: jittered stamps and a coarse encoder,
    so the rows take the real stamps and wider velocity fits)."""
    n, h = model.n_joints, 1e-3
    t = np.arange(N) * h
    q = 0.6 * np.sin(np.outer(t, 2.0 + np.arange(n)) + RNG.uniform(0, 6, n))
    if irregular:
        t = t + RNG.uniform(0, 0.3 * h, N)
        q = np.round(q / 2e-4) * 2e-4
    tau = RNG.normal(size=q.shape)
    return recording_rows(q, tau, h, window=20, t=t if irregular else None, model=model)


def _regressor_rows(rows, theta, q) -> np.ndarray:
    """Ψ(q) θ before F from the regressor rows (the definition)."""
    args = (rows.h, rows.stamps, rows.half_window, rows.model)
    return _momentum_rows(q, rows.tau, *args)[2] @ theta


@pytest.mark.parametrize("name", ["cicese3", "panda"])
def test_urdf_torques_are_the_regressor_products(name, cicese3, panda):
    model = {"cicese3": cicese3, "panda": panda}[name]
    theta = _theta(model)
    q = RNG.uniform(-np.pi, np.pi, (3, 20, model.n_joints))
    dq = RNG.normal(0, 2, q.shape)
    for fast, regressor in (
        (model.momentum, model.momentum_regressor),
        (model.static_torque, model.static_regressor),
    ):
        exact = regressor(q, dq) @ theta
        assert fast(theta, q, dq).shape == exact.shape
        np.testing.assert_allclose(fast(theta, q, dq), exact, rtol=0, atol=1e-12 * abs(exact).max())
    assert model._theta_bodies(theta) is not None  # through Pinocchio's bodies, not the fallback


def test_bodies_that_miss_the_regressors_fall_back_to_them(cicese3, monkeypatch):
    theta = _theta(cicese3)
    q, dq = RNG.normal(size=(2, 30, 3))
    monkeypatch.setattr(urdf, "THETA_BODIES_TOL", -1.0)  # no bodies ever agree
    monkeypatch.setattr(cicese3, "_bodies_of", (b"", None))
    assert cicese3._theta_bodies(theta) is None
    assert np.array_equal(
        cicese3.static_torque(theta, q, dq), cicese3.static_regressor(q, dq) @ theta
    )
    assert np.array_equal(cicese3.momentum(theta, q, dq), cicese3.momentum_regressor(q, dq) @ theta)


@pytest.mark.parametrize("irregular", [False, True])
@pytest.mark.parametrize("name", ["cicese3", "panda", "closed_form"])
def test_model_torque_rows_equal_the_regressor_rows(name, irregular, cicese3, panda):
    model = {"cicese3": cicese3, "panda": panda, "closed_form": ArmModel(("rotor_inertia",))}[name]
    rows = _rows(model, irregular=irregular)
    theta = _theta(model) if name != "closed_form" else np.linspace(0.05, 0.5, model.n_params)
    q = rows.q.copy()
    q[:, -1] -= 0.04
    exact = _regressor_rows(rows, theta, q)
    np.testing.assert_allclose(
        model_torque_rows(rows, theta, q), exact, rtol=0, atol=1e-12 * abs(exact).max()
    )


@pytest.mark.parametrize("irregular", [False, True])
def test_encoder_column_equals_its_regressor_definition(cicese3, irregular):
    """The column d/dδ F[Ψ(q − δ e_j) θ₀] (forward difference at δ̂) and the shift at δ̂, as
    they were defined from the rebuilt regressor rows, on every joint: the rows agree to
    1e-13, the column to 1e-8 of its size, its own rounding (ε |P|/h of the momentum
    difference of each row, divided by STEP_RAD: 1e-16 · 1e3 / 1e-4 ≈ 1e-9 of P's size)."""
    rows = _rows(cicese3, irregular=irregular)
    theta = _theta(cicese3)
    psi = rows.Psi  # the filtered design, as the drift stage's Problem.Psi_raw
    ctx = Context([rows], cicese3, theta, psi)
    effect = encoder.EncoderOffset()
    s = encoder.STEP_RAD

    def old(joint: int, delta: float) -> np.ndarray:
        if delta == 0.0:
            return psi @ theta
        q = rows.q.copy()
        q[:, joint] -= delta
        return moving_average(_regressor_rows(rows, theta, q), rows.window)

    for joint in range(cicese3.n_joints):
        for at in (0.0, 0.03):
            column = (old(joint, at + s) - old(joint, at)) / s
            got = effect.columns(ctx, joint, at)[:, :, 0]
            assert abs(column).max() > 0
            np.testing.assert_allclose(got, column, rtol=0, atol=1e-8 * abs(column).max())
        shift = old(joint, 0.03) - psi @ theta
        np.testing.assert_allclose(
            effect.shift(ctx, joint, 0.03), shift, rtol=0, atol=1e-13 * abs(psi @ theta).max()
        )


def test_memo_keeps_every_joints_start_through_a_refinement(panda, monkeypatch):
    """A 7-joint selection builds every joint's first column, refines candidates (two rows per
    Gauss–Newton point) and starts again: the first columns and the latest points are kept."""
    rows = _rows(panda, N=400)
    ctx = Context([rows], panda, panda.base_theta(), rows.Psi)
    built = []

    def counted(r, th, q=None):
        built.append(1)
        return model_torque_rows(r, th, q)

    monkeypatch.setattr(encoder, "model_torque_rows", counted)
    effect = encoder.EncoderOffset()
    for joint in range(7):
        effect.columns(ctx, joint, 0.0)
    assert len(built) == 7
    for refined in (2, 4):  # two candidates refined, 16 shifted rows
        for step in range(1, REFINE_STEPS + 1):
            effect.columns(ctx, refined, 0.01 * step)
            effect.shift(ctx, refined, 0.01 * step)
    assert len(built) == 7 + 4 * REFINE_STEPS
    for joint in range(7):
        effect.columns(ctx, joint, 0.0)
    assert len(built) == 7 + 4 * REFINE_STEPS  # nothing rebuilt
    effect.columns(ctx, 4, 0.01 * REFINE_STEPS)  # the last point: still kept
    assert len(built) == 7 + 4 * REFINE_STEPS
    assert len(ctx.memo) <= encoder.memo_size(7)
