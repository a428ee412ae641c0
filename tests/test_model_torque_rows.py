"""The nominal model's torque rows from its torques, not its regressor (issue 26, performance):
UrdfArmModel.momentum / static_torque against the regressors' products, the encoder offset's
rows at any angle against their definition from the rebuilt regressor rows, and the builds
they take."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import hil.diagnose.effects.encoder as encoder
import hil.model.urdf_dynamics as urdf_dynamics
from hil.diagnose.columns import (
    _momentum_rows,
    model_torque_rows,
    moving_average,
    recording_rows,
    rigid_torque_rows,
)
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
    the readings (to rounding), which the shifted rows reuse instead of estimating them
    again."""
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


@pytest.mark.parametrize("name", ["cicese3", "panda", "tree", "closed_form"])
def test_torques_at_shifts_equal_the_torques_at_the_shifted_readings(name, cicese3, panda, tree):
    """momentum_at_shifts / static_torque_at_shifts (the frames before the joint built once,
    the rest again per shift) equal momentum / static_torque at q + s e_j, on every joint (the
    tree: branches, a prismatic joint), exactly but for rounding."""
    model = {"cicese3": cicese3, "panda": panda, "tree": tree, "closed_form": ArmModel()}[name]
    theta = _theta(model) if name != "closed_form" else np.linspace(0.05, 0.5, model.n_params)
    q = RNG.uniform(-np.pi, np.pi, (2, 15, model.n_joints))
    dq = RNG.normal(0, 2, q.shape)
    shifts = np.array([0.3, -2.0, 0.0])
    for joint in range(model.n_joints):
        for shifted, plain in (
            (model.momentum_at_shifts, model.momentum),
            (model.static_torque_at_shifts, model.static_torque),
        ):
            got = shifted(theta, q, dq, joint, shifts)
            assert got.shape == (len(shifts), *q.shape)
            for s, at in zip(shifts, got, strict=True):
                moved = q.copy()
                moved[..., joint] += s
                exact = plain(theta, moved, dq)
                np.testing.assert_allclose(at, exact, rtol=0, atol=1e-12 * abs(exact).max())


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
    exact = _regressor_rows(rows, theta, q)
    np.testing.assert_allclose(
        model_torque_rows(rows, theta, offset), exact, rtol=0, atol=1e-12 * abs(exact).max()
    )


@pytest.mark.parametrize("irregular", [False, True])
@pytest.mark.parametrize("name", ["cicese3", "panda", "tree", "closed_form"])
def test_encoder_rows_at_any_angle_equal_the_rebuilt_regressor_rows(
    name, irregular, cicese3, panda, tree
):
    """The shift F[Ψ(q − δ e_j) θ₀] − F[Ψ(q) θ₀] from the few builds of :func:`shifted_rows`
    (a trigonometric polynomial of degree 2 in a revolute joint's δ, a quadratic in a
    prismatic one's) equals the model's torque rows rebuilt at the shifted readings on the
    same two-node rule, at angles small and large, on every joint (the tree: a prismatic
    joint, an unaligned axis and two branches; the closed form with both of its terms), to
    1e-10 of the rows' size (rounding: the builds are at angles up to 144°), and the
    regressor rows rebuilt on Ψ's four nodes: on the smooth regular rows to 1e-8 (the rule's
    O(h⁴): ~1e-10 seen); on the coarse encoder's jittered rows the cubic path between
    samples bends and the two rules part by up to 0.5 % of the shift (seen at 2.5 rad). The
    column, its derivative, equals the central difference of the rebuilt rows to the
    difference's own error."""
    model = {
        "cicese3": cicese3,
        "panda": panda,
        "tree": tree,
        "closed_form": ArmModel(("rotor_inertia", "com_offset")),
    }[name]
    rows = _rows(model, N=300, irregular=irregular)
    theta = _theta(model) if name != "closed_form" else np.linspace(0.05, 0.5, model.n_params)
    psi = rows.Psi  # the filtered design, as the drift stage's Problem.Psi_raw
    ctx = Context([rows], model, theta, psi)
    effect = encoder.EncoderOffset()
    size = abs(psi @ theta).max()

    def shifted(joint: int, delta: float) -> np.ndarray:
        q = rows.q.copy()
        q[:, joint] -= delta
        return q

    def rebuilt(joint: int, delta: float) -> np.ndarray:  # the model's torques, two nodes
        at = replace(rows, q=shifted(joint, delta))
        return moving_average(rigid_torque_rows(at, theta, nodes=encoder.SHIFT_NODES), rows.window)

    def regressor(joint: int, delta: float) -> np.ndarray:  # the definition, Ψ's four nodes
        return moving_average(_regressor_rows(rows, theta, shifted(joint, delta)), rows.window)

    moved = []
    for joint in range(model.n_joints):
        at_zero, defined_at_zero = rebuilt(joint, 0.0), regressor(joint, 0.0)
        for at in (0.03, -0.4, 2.5):
            shift = rebuilt(joint, at) - at_zero
            moved.append(abs(shift).max())  # none about the Panda's vertical first axis
            np.testing.assert_allclose(
                effect.shift(ctx, joint, at), shift, rtol=0, atol=1e-10 * size
            )
            defined = regressor(joint, at) - defined_at_zero
            tolerance = 1e-2 if irregular else 1e-8  # the rules part: docstring
            full = slice(rows.window, None)  # windows of F filled (the rows weighed)
            np.testing.assert_allclose(shift[full], defined[full], rtol=0, atol=tolerance * size)
            s = 1e-4  # central difference: error s² |f'''| / 6 and ε |f| / s
            central = (rebuilt(joint, at + s) - rebuilt(joint, at - s)) / (2 * s)
            np.testing.assert_allclose(
                effect.columns(ctx, joint, at)[:, :, 0], central, rtol=0,
                atol=3e-7 * abs(central).max() + 1e-10 * size,
            )  # fmt: skip
        assert effect.shift(ctx, joint, 0.0) is None
    assert max(moved) > 0.01 * size


def test_encoder_rows_are_built_once_per_joint(panda, monkeypatch):
    """A selection builds every joint's column, refines (Gauss–Newton points) and starts
    again: the model's torques are built once unshifted and four times per joint (the
    Fourier angles), and no more however many points are asked."""
    rows = _rows(panda, N=400)
    ctx = Context([rows], panda, panda.base_theta(), rows.Psi)
    built = []

    def counted(r, th, joint=None, shifts=(), nodes=4):
        built.append(1 if joint is None else len(shifts))  # one build per shift
        return rigid_torque_rows(r, th, joint, shifts, nodes)

    monkeypatch.setattr(encoder, "rigid_torque_rows", counted)
    effect = encoder.EncoderOffset()
    for joint in range(7):
        effect.columns(ctx, joint, 0.0)
    assert sum(built) == 1 + 4 * 7
    for refined in (2, 4):
        for step in range(1, REFINE_STEPS + 1):
            effect.columns(ctx, refined, 0.01 * step)
            effect.shift(ctx, refined, 0.01 * step)
    for joint in range(7):
        effect.columns(ctx, joint, 0.0)
    assert sum(built) == 1 + 4 * 7


@pytest.mark.parametrize("name", ["cicese3", "panda", "tree"])
def test_batched_regressor_rows_equal_pinocchio_state_by_state(name, cicese3, panda, tree):
    """The momentum and static rows of the bodies' parameters, computed for many states at once
    through the kinematic tree (urdf_dynamics.Chain), equal Pinocchio's, state by state: M(q) q̇
    its joint torque regressor without gravity at q̈ = q̇, q̇ = 0; g(q) at rest; ∂K/∂q its
    kinetic energy regressor differenced in q (a tree with a prismatic joint too); the public
    regressors, over more states than one pass holds, the same rows to the last bit."""
    import pinocchio as pin

    import hil.model.urdf as urdf

    model = {"cicese3": cicese3, "panda": panda, "tree": tree}[name]
    n, nb = model.n_joints, model.n_body_params
    N = urdf.REGRESSOR_STATES_PER_CHUNK + 5
    q = RNG.uniform(-np.pi, np.pi, (N, n))
    dq = RNG.normal(0, 2, q.shape)
    momentum = model._standard_momentum(q, dq)
    static = model._standard_static(q, dq)
    np.testing.assert_array_equal(model.momentum_regressor(q, dq), model._to_base(momentum))
    np.testing.assert_array_equal(model.static_regressor(q, dq), model._to_base(static))
    momentum, static = momentum[..., :nb], static[..., :nb]
    free = pin.Model(model._model)
    free.gravity.linear = np.zeros(3)
    free_data, data = free.createData(), model._model.createData()
    zero, step = np.zeros(n), 1e-6
    for k in RNG.choice(N, 40, replace=False):
        P = pin.computeJointTorqueRegressor(free, free_data, q[k], zero, dq[k])
        np.testing.assert_allclose(momentum[k], P, rtol=0, atol=1e-12 * abs(P).max())
        g = pin.computeJointTorqueRegressor(model._model, data, q[k], zero, zero)
        dK = np.empty((n, nb))
        for i in range(n):
            e = np.zeros(n)
            e[i] = step
            dK[i] = (
                pin.computeKineticEnergyRegressor(free, free_data, q[k] + e, dq[k])
                - pin.computeKineticEnergyRegressor(free, free_data, q[k] - e, dq[k])
            ) / (2 * step)
        np.testing.assert_allclose(static[k], g - dK, rtol=0, atol=1e-7 * abs(g - dK).max())


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
