"""The nominal model's torque rows from its torques, not its regressor (issue 26, performance):
UrdfArmModel.momentum / static_torque against the regressors' products, the encoder-offset
column against its definition from the rebuilt regressor rows, and the memo of shifted rows."""

from __future__ import annotations

import numpy as np
import pytest

import hil.diagnose.effects.encoder as encoder
import hil.model.urdf_dynamics as urdf_dynamics
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
    """Ψ(q) θ before F from the regressor rows (the definition), with the recording's
    velocities: readings shifted by a constant per joint (an encoder offset) move no velocity
    (estimated again from the shifted readings, they differ by rounding only, which the
    interval rows' 1/h² lifts to 1e-8 of a row: `test_a_constant_shift_moves_no_velocity`)."""
    args = (rows.h, rows.stamps, rows.half_window, rows.model)
    return _momentum_rows(q, rows.tau, *args, v=rows.v)[2] @ theta


@pytest.mark.parametrize("irregular", [False, True])
def test_a_constant_shift_moves_no_velocity(cicese3, irregular):
    """The velocities estimated from readings shifted by a constant per joint are those of
    the readings (to rounding), which :func:`model_torque_rows` reuses instead of estimating
    them again."""
    rows = _rows(cicese3, irregular=irregular)
    offset = np.array([0.03, -0.05, 0.2])[: rows.q.shape[1]]
    args = (rows.h, rows.stamps, rows.half_window, rows.model)
    v = _momentum_rows(rows.q + offset, rows.tau, *args)[4]
    finite = np.isfinite(rows.v)
    assert finite.any() and np.array_equal(finite, np.isfinite(v))
    np.testing.assert_allclose(
        v[finite], rows.v[finite], rtol=0, atol=1e-12 * abs(rows.v[finite]).max()
    )


# a tree (link1 carries two branches) with a prismatic joint and an unaligned revolute one:
# the joint types and the shape UrdfArmModel's batched kinematics (urdf_dynamics.Chain) must follow
# (name, type, parent, child, origin xyz, origin rpy, axis)
TREE_JOINTS = (
    ("j1", "revolute", "base", "l1", "0.1 0 0.3", "0.2 0 0", "0 0 1"),
    ("j2", "prismatic", "l1", "l2", "0 0.2 0.1", "0 0.4 0.1", "1 0 0"),
    ("j3", "revolute", "l2", "l3", "0.3 0 0", "0 0 0.5", "0.3 0.5 0.8"),
    ("j4", "revolute", "l1", "l4", "0 -0.2 0.1", "0.3 0 0", "0 1 0"),
)
JOINT = """<joint name="{}" type="{}"><parent link="{}"/><child link="{}"/>
  <origin xyz="{}" rpy="{}"/><axis xyz="{}"/>
  <limit lower="-1" upper="1" effort="10" velocity="5"/></joint>"""
LINK = """<link name="{name}"><inertial><origin xyz="{c}" rpy="0.1 0.2 0.3"/><mass value="{m}"/>
  <inertia ixx="{i}" ixy="0.001" ixz="0.002" iyy="{i}" iyz="0.001" izz="{i}"/></inertial></link>"""


@pytest.fixture(scope="module")
def tree(tmp_path_factory) -> UrdfArmModel:
    links = [
        LINK.format(name=f"l{j}", c=f"{0.05 * j} 0.02 {0.1 - 0.01 * j}", m=1.0 + j, i=0.02 * j)
        for j in range(1, 5)
    ]
    joints = [JOINT.format(*joint) for joint in TREE_JOINTS]
    body = "\n".join(['<link name="base"/>', *links, *joints])
    path = tmp_path_factory.mktemp("urdf") / "tree.urdf"
    path.write_text(f'<?xml version="1.0"?>\n<robot name="tree">\n{body}\n</robot>\n')
    return UrdfArmModel(path, viscous=np.full(4, 0.1), coulomb=np.full(4, 0.2))


@pytest.mark.parametrize("name", ["cicese3", "panda", "tree"])
@pytest.mark.parametrize("which", ["near the URDF", "any base vector"])
def test_urdf_torques_are_the_regressor_products(name, which, cicese3, panda, tree):
    """M(q) q̇ and g − Cᵀq̇ + f on the bodies that carry θ equal the regressors' products for
    any θ: also one whose standard vector has zero or negative masses (no Pinocchio
    inertia can hold it)."""
    model = {"cicese3": cicese3, "panda": panda, "tree": tree}[name]
    theta = _theta(model) if which == "near the URDF" else RNG.normal(size=model.n_params)
    q = RNG.uniform(-np.pi, np.pi, (3, 20, model.n_joints))
    dq = RNG.normal(0, 2, q.shape)
    for fast, regressor in (
        (model.momentum, model.momentum_regressor),
        (model.static_torque, model.static_regressor),
    ):
        exact = regressor(q, dq) @ theta
        assert fast(theta, q, dq).shape == exact.shape
        np.testing.assert_allclose(fast(theta, q, dq), exact, rtol=0, atol=1e-12 * abs(exact).max())
    # and M(q) q̇ is the mass matrix's product (one mechanism: UrdfDynamics)
    M = model.mass_matrix(theta, q[0])
    np.testing.assert_allclose(
        model.momentum(theta, q[0], dq[0]), np.einsum("kij,kj->ki", M, dq[0]), rtol=0,
        atol=1e-12 * abs(M).max() * abs(dq[0]).max(),
    )  # fmt: skip


def test_only_revolute_and_prismatic_joints(tmp_path):
    """A 1-DOF joint that is neither (a helical one: Pinocchio's JointModelHZ has nq = 1)
    is refused with one line, not computed wrong."""
    import pinocchio as pin

    model = pin.Model()
    model.addJoint(0, pin.JointModelHZ(0.1), pin.SE3.Identity(), "screw")
    with pytest.raises(ValueError, match="only revolute and prismatic"):
        urdf_dynamics.Chain(model)


@pytest.mark.parametrize("irregular", [False, True])
@pytest.mark.parametrize("name", ["cicese3", "panda", "closed_form"])
def test_model_torque_rows_equal_the_regressor_rows(name, irregular, cicese3, panda):
    model = {"cicese3": cicese3, "panda": panda, "closed_form": ArmModel(("rotor_inertia",))}[name]
    rows = _rows(model, irregular=irregular)
    theta = _theta(model) if name != "closed_form" else np.linspace(0.05, 0.5, model.n_params)
    q = rows.q.copy()
    q[:, -1] -= 0.04
    offset = np.zeros(rows.q.shape[1])
    offset[-1] = -0.04
    exact = _regressor_rows(rows, theta, q)  # the velocities estimated again from q
    np.testing.assert_allclose(
        model_torque_rows(rows, theta, offset), exact, rtol=0, atol=1e-12 * abs(exact).max()
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

    def counted(r, th, offset=None):
        built.append(1)
        return model_torque_rows(r, th, offset)

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


def test_many_states_are_computed_in_chunks_with_the_same_result(panda, monkeypatch):
    """The recursions run over ``STATES_PER_CHUNK`` states at a time (60 s of a 7-joint arm at
    1 kHz at once peaked near 0.8 GB): the same torques as one pass, to the last bit."""
    dynamics = panda.dynamics(_theta(panda))
    q = RNG.uniform(-np.pi, np.pi, (1000, panda.n_joints))
    dq = RNG.normal(0, 2, q.shape)
    whole = (dynamics.momentum(q, dq), dynamics.static_torque(q, dq))
    monkeypatch.setattr(urdf_dynamics, "STATES_PER_CHUNK", 64)
    chunked = (dynamics.momentum(q, dq), dynamics.static_torque(q, dq))
    for a, b in zip(whole, chunked, strict=True):
        np.testing.assert_array_equal(a, b)
