"""hil.model.urdf: an arm from a URDF through Pinocchio, exact against the CICESE closed form, its
base parameters, and the identification of the real Panda excitation of Gaz et al. (2019)."""

from __future__ import annotations

from dataclasses import replace

import gaz_reference
import numpy as np
import pytest

import hil.model.closed_form as closed_form
from drivers.one_per_line import read_one_per_line_log
from drivers.recording import Recording, RecordingWriter, read_signals
from hil.identify.urdf import (
    filtered_rows,
    identify_torque,
    smoothed_motion,
    torque_at_samples,
    torque_nrmse,
)
from hil.model.urdf import UrdfArmModel, _bilinear_inertia_regressor
from profiles import ProfileError
from profiles.robot import load_robot, load_urdf_robot

RNG = np.random.default_rng(7)


@pytest.fixture(scope="module")
def cicese() -> UrdfArmModel:
    return UrdfArmModel.from_profile("cicese")


@pytest.fixture(scope="module")
def panda() -> UrdfArmModel:
    return UrdfArmModel.from_profile("panda")


def _samples(n_joints: int, N: int = 60):
    q = RNG.uniform(-np.pi, np.pi, (N, n_joints))
    return q, RNG.normal(0, 2, (N, n_joints)), RNG.normal(0, 5, (N, n_joints))


# --- CICESE: the URDF model is the closed form -------------------------------------------------

# The base parameters the pivoted QR finds for cicese.urdf (joints turn about y, links along −z):
#   β1 = mx1, β2 = mz1 − l1 m2, β3 = Iyy1 + l1² m2, β4 = mx2, β5 = mz2, β6 = Iyy2, β7..β10 friction
# with first/second moments about each joint. Against θ1..θ9 of Reyes & Kelly (1997) Sec. 5:
#   θ1 = β3 + β6,  θ2 = −l1 β5,  θ3 = β6,  θ4 = −g β2,  θ5 = −g β5,  θ6..θ9 = β7..β10,
# and β1 = β4 = 0: the closed form puts each centre of mass on its link's line. So every URDF
# column but mx1, mx2 is a fixed combination of closed-form columns, Y_urdf = Y_cf T.
CICESE_MEANINGS = ("mx1", "mz1 - 0.45 m2", "Iyy1 + 0.2025 m2", "mx2", "mz2", "Iyy2")
L1, G = 0.45, 9.81
T = np.zeros((9, 10))
T[3, 1] = -G  # β2 column = −g · θ4 column
T[0, 2] = 1.0  # β3 column = θ1 column
T[1, 4], T[4, 4] = -L1, -G  # β5 column = −l1 θ2 column − g θ5 column
T[0, 5] = T[2, 5] = 1.0  # β6 column = θ1 column + θ3 column
T[5:, 6:] = np.eye(4)  # friction
ALIGNED = [1, 2, 4, 5, 6, 7, 8, 9]  # all base columns but mx1, mx2


def test_cicese_base_parameters_are_named_combinations(cicese):
    assert cicese.n_joints == 2
    assert cicese.meanings[:6] == CICESE_MEANINGS
    assert cicese.meanings[6:] == ("fv1", "fv2", "fc1", "fc2")
    theta = load_robot("cicese").theta()
    b = cicese.base_theta()
    assert b[0] == 0 and b[3] == 0  # Table I: centres of mass on the links
    # θ = the closed-form parameters of the same arm, through the mapping above
    assert np.allclose(
        [b[2] + b[5], -L1 * b[4], b[5], -G * b[1], -G * b[4], *b[6:]], theta, rtol=0, atol=1e-12
    )


def test_cicese_urdf_dynamics_equal_closed_form(cicese):
    theta, b = load_robot("cicese").theta(), cicese.base_theta()
    q, dq, ddq = _samples(2)
    cases = [
        (cicese.mass_matrix(b, q), closed_form.mass_matrix(theta, q)),
        (cicese.coriolis_vector(b, q, dq), closed_form.coriolis_vector(theta, q, dq)),
        (cicese.gravity_vector(b, q), closed_form.gravity_vector(theta, q)),
        (cicese.friction_torque(b, dq), closed_form.friction_torque(theta, dq)),
        (cicese.torque(b, q, dq, ddq), closed_form.inverse_dynamics(theta, q, dq, ddq)),
    ]
    for ours, theirs in cases:
        assert ours.shape == theirs.shape
        assert np.abs(ours - theirs).max() < 1e-12


def test_cicese_urdf_regressors_equal_closed_form_columns(cicese):
    q, dq, ddq = _samples(2)
    pairs = [
        (cicese.torque_regressor(q, dq, ddq), closed_form.dynamic_regressor(q, dq, ddq)),
        (cicese.momentum_regressor(q, dq), closed_form.momentum_regressor(q, dq)),
        (cicese.static_regressor(q, dq), closed_form.static_regressor(q, dq)),
    ]
    for ours, cf in pairs:
        assert np.abs(ours[..., ALIGNED] - (cf @ T)[..., ALIGNED]).max() < 1e-12
    energy = cicese.energy_regressor(q, dq)
    assert (
        np.abs(
            energy[..., ALIGNED[:4]]
            - (closed_form.energy_regressor(q, dq) @ T[:5])[..., ALIGNED[:4]]
        ).max()
        < 1e-12
    )
    power = cicese.friction_power_regressor(dq)
    assert np.abs(power[..., 6:] - closed_form.friction_power_regressor(dq)).max() < 1e-12
    # the centre-of-mass offsets are real columns the closed form has not
    assert np.abs(cicese.torque_regressor(q, dq, ddq)[..., [0, 3]]).max() > 1.0


# --- any arm: the base parameters and the momentum/static split ------------------------------


def test_base_parameters_reproduce_every_standard_vector(panda):
    assert panda.n_joints == 7
    # rigid base parameters of the Panda: 43 (Gaz et al. (2019) also find 43)
    assert panda.n_params - panda.n_friction == 43
    q, dq, ddq = _samples(7, 30)
    theta_std = RNG.normal(size=len(panda.standard_names))  # any vector, consistent or not
    b = panda.base_theta(theta_std)
    Y_std = panda.standard_regressor(q, dq, ddq)
    assert np.abs(Y_std @ theta_std - panda.torque_regressor(q, dq, ddq) @ b).max() < 1e-9


def test_momentum_static_split_is_the_torque_along_a_trajectory(panda):
    """τ = d/dt[P θ] + R θ (Reyes & Kelly (1997) eq. (13)) along q(t) = a sin(ωt + φ)."""
    a, w, phi = RNG.uniform(0.3, 1.0, 7), RNG.uniform(1, 3, 7), RNG.uniform(0, 6, 7)
    t = np.linspace(0.1, 1.0, 7)
    h = 1e-4

    def motion(s):
        return a * np.sin(w * s + phi), a * w * np.cos(w * s + phi)

    theta = panda.base_theta(RNG.normal(size=len(panda.standard_names)))
    for s in t:
        q, dq = motion(s)
        ddq = -a * w**2 * np.sin(w * s + phi)
        dP = (
            panda.momentum_regressor(*motion(s + h)) - panda.momentum_regressor(*motion(s - h))
        ) / (2 * h)
        lhs = (dP + panda.static_regressor(q, dq)) @ theta
        rhs = panda.torque(theta, q, dq, ddq)
        assert np.abs(lhs - rhs).max() < 1e-6 * max(1.0, np.abs(rhs).max())


def test_energy_regressors_are_the_energies(panda):
    q, dq, _ = _samples(7, 20)
    b = panda.base_theta()
    K = panda.kinetic_energy_regressor(q, dq) @ b
    M = panda.mass_matrix(b, q)
    assert np.allclose(K, 0.5 * np.einsum("ni,nij,nj->n", dq, M, dq), rtol=1e-12, atol=1e-12)
    assert np.allclose(panda.potential_energy_regressor(np.zeros((1, 7))) @ b, 0.0)
    # P θ = M q̇ and the kinetic regressor's q̇-gradient agree
    assert np.allclose(panda.momentum_regressor(q, dq) @ b, np.einsum("nij,nj->ni", M, dq))


def test_bilinear_inertia_regressor_matches_pinocchio_kinetic_energy():
    import pinocchio as pin

    v = RNG.normal(size=6)
    inertia = pin.Inertia.Random()
    pi = inertia.toDynamicParameters()
    expected = v @ (inertia.matrix() @ v)
    assert abs(_bilinear_inertia_regressor(v, v) @ pi - expected) < 1e-12


def test_physical_consistency_flags_impossible_bodies(panda):
    assert panda.physical_consistency()["consistent"]
    bad = panda.standard_theta.copy()
    bad[0] = -1.0  # negative mass of body 1
    bad[10 + 4] = 100.0  # Ixx2 beyond the triangle inequality
    found = panda.physical_consistency(bad)
    assert not found["consistent"]
    text = " | ".join(found["violations"])
    assert "panda_joint1: mass -1 kg <= 0" in text
    assert "panda_joint2: pseudo-inertia not positive semidefinite" in text
    # base parameters: friction signs and M(q) > 0 at sampled configurations
    b = panda.base_theta()
    assert panda.physical_consistency(b)["consistent"]
    b_bad = b.copy()
    b_bad[panda.meanings.index("Izz7")] = -1.0
    b_bad[panda.friction_columns[0]] = -0.1
    text = " | ".join(panda.physical_consistency(b_bad)["violations"])
    assert "negative fv1 = -0.1" in text and "M(q) not positive definite" in text
    with pytest.raises(ValueError, match="base or 91 standard parameters"):
        panda.physical_consistency(np.zeros(5))


def test_rotor_inertia_term_adds_armature_columns(cicese):
    arm = UrdfArmModel(
        cicese.urdf, gravity_m_s2=9.81, armature=[0.0, 0.05], terms=("rotor_inertia",)
    )
    # the joint-1 armature is absorbed by Iyy1; the joint-2 armature is its own base parameter
    assert arm.n_params == cicese.n_params + 1
    assert "Ia2" in arm.meanings and not any(m.startswith("Ia1") for m in arm.meanings)
    q, _, _ = _samples(2)
    M = arm.mass_matrix(arm.base_theta(), q)
    M0 = cicese.mass_matrix(cicese.base_theta(), q)
    assert np.allclose(M - M0, np.diag([0.0, 0.05]), atol=1e-12)


@pytest.mark.parametrize(
    ("profile", "terms"),
    [
        ("cicese3", ("rotor_inertia", "friction_offset")),
        ("kuka-lwr4", None),
        ("dfki-pendulum", None),
    ],
)
def test_dynamics_of_any_base_vector_equal_its_regressors(profile, terms):
    """UrdfArmModel.dynamics(θ) (M(q) = Σ J_jᵀ I_j J_j + diag(I_a), C q̇ + g by one regressor
    call: the open-loop simulation's accelerations) equals the regressor definitions, M's
    column i = P(q, e_i) θ and C q̇ + g = Y(q, q̇, 0) θ without friction, for random base
    vectors that are no arm (zero and negative masses among their bodies)."""
    model = UrdfArmModel.from_profile(profile, terms=terms)
    n = model.n_joints
    q, dq, _ = _samples(n, N=12)
    friction = np.zeros(model.n_params, bool)
    friction[model.term_columns("friction")] = True
    for _ in range(3):
        theta = RNG.normal(size=model.n_params)
        unit = np.broadcast_to(np.eye(n)[:, None], (n, len(q), n))
        reference = np.stack([model.momentum_regressor(q, e) @ theta for e in unit], axis=-1)
        scale = np.abs(reference).max()
        assert np.allclose(model.mass_matrix(theta, q), reference, rtol=0, atol=1e-12 * scale)
        dyn = model.dynamics(theta)
        bias = model.torque_regressor(q, dq, np.zeros_like(q)) @ np.where(friction, 0.0, theta)
        got = np.array([dyn.rigid_bias(a, b) for a, b in zip(q, dq, strict=True)])
        assert np.allclose(got, bias, rtol=0, atol=1e-12 * np.abs(bias).max())
        assert np.array_equal(model.standard_of_base(theta)[model.base.independent], theta)


def test_profile_errors_are_one_line(tmp_path):
    p = tmp_path / "arm.toml"
    p.write_text('name = "arm"\ngravity_m_s2 = 9.81\nurdf = "nowhere.urdf"\n[joints]\ncount = 2\n')
    with pytest.raises(ProfileError, match="no such URDF file") as exc:
        load_urdf_robot(p)
    assert "\n" not in str(exc.value)
    with pytest.raises(ProfileError, match="names no URDF"):
        load_urdf_robot(_write(tmp_path, "n.toml", ""))
    p.write_text(
        f'name = "arm"\ngravity_m_s2 = 9.81\nurdf = "{load_urdf_robot("panda").urdf}"\n'
        "[joints]\ncount = 2\n[friction]\nviscous_Nms = [0, 0]\n"
        "coulomb_positive_Nm = [0, 0]\ncoulomb_negative_Nm = [0, 0]\n"
    )
    with pytest.raises(ValueError, match="profile says 2 joints"):
        UrdfArmModel.from_profile(p)


def _write(folder, name, extra):
    path = folder / name
    path.write_text(f'name = "n"\ngravity_m_s2 = 9.81\n{extra}[joints]\ncount = 1\n')
    return path


def test_one_per_line_log_reader(tmp_path):
    t = np.arange(5) * 1e-3
    q = RNG.normal(size=(5, 3))
    np.savetxt(tmp_path / "x_time.txt", t)
    np.savetxt(tmp_path / "x_positions.txt", q.reshape(-1))
    np.savetxt(tmp_path / "x_torques.txt", (2 * q).reshape(-1))
    rec = read_one_per_line_log(tmp_path, n_joints=3, prefix="x")
    assert np.allclose(rec.q, q) and np.allclose(rec.tau, 2 * q) and rec.n_joints == 3
    rec.write_csv(tmp_path / "std.csv")
    assert (tmp_path / "std.csv").read_text().splitlines()[0] == "t,q1,q2,q3,tau1,tau2,tau3"
    np.savetxt(tmp_path / "x_torques.txt", q.reshape(-1)[:-1])
    with pytest.raises(ValueError, match="14 numbers, expected 5 samples x 3 joints"):
        read_one_per_line_log(tmp_path, n_joints=3, prefix="x")


def test_identification_recovers_a_simulated_arm(cicese):
    """Torques of the URDF arm itself along a multisine, on jittered time stamps: the fit finds
    its base parameters and predicts the held-out torque."""
    t = np.cumsum(RNG.uniform(0.8e-3, 1.2e-3, 12_000))
    w = np.array([[0.7, 1.9, 3.1], [1.1, 2.3, 2.9]])[None]  # rad/s, (1, joint, harmonic)
    a = np.array([0.8, 0.4, 0.2])
    arg = t[:, None, None] * w
    q = (a * np.sin(arg)).sum(-1)
    dq = (a * w * np.cos(arg)).sum(-1)
    ddq = (-a * w**2 * np.sin(arg)).sum(-1)
    truth = cicese.base_theta()
    tau = cicese.torque(truth, q, dq, ddq)
    result = identify_torque(
        cicese, Recording.from_arrays(t, q, tau, source="simulated"), cutoff_hz=5.0
    )
    rel = np.abs(result.theta - truth) / np.maximum(np.abs(truth), 1e-2)
    assert rel.max() < 0.02, dict(zip(cicese.meanings, rel.round(4), strict=True))
    assert result.nrmse_held_out.max() < 0.01


# --- the real Panda excitation (Gaz et al. 2019; GPL-3, read from ../shared only) --------------


def test_panda_identification_against_the_published_model(panda):
    if not gaz_reference.available():
        pytest.skip(f"Panda data of Gaz et al. not found at {gaz_reference.MODEL_DIR}")
    rec = read_one_per_line_log(gaz_reference.LOG_DIR)
    assert rec.n_joints == 7 and len(rec.t) == 20_544
    result = identify_torque(panda, rec)
    held = result.rows.t >= result.fit_until_s
    motion = smoothed_motion(rec)
    # their model on the held-out stretch only, on the same blocks of 10 rows as ours
    start = 10 * (int(np.searchsorted(motion.t, result.fit_until_s - 1.0)) // 10)
    sub = type(motion)(
        *(x[start:] for x in (motion.t, motion.q, motion.dq, motion.ddq, motion.tau)),
        motion.cutoff_hz,
    )
    theirs_tau = gaz_reference.GazModel().torque(sub.q, sub.dq, sub.ddq)
    theirs = filtered_rows(sub, theirs_tau[..., None])
    tail = theirs.t >= result.fit_until_s
    assert np.array_equal(theirs.t[tail], result.rows.t[held])
    # every model on the rows ours is judged on: the held-out rows, less those near friction
    # steps of a joint whose fit left them out (joint 7 here: its residual there is 3 times
    # the rest's; hil.identify.urdf.leave_out_friction_steps)
    same_rows = result.rows.select(held)
    ours = result.nrmse_held_out
    reference = torque_nrmse(np.ones(1), replace(same_rows, Y=theirs.Y[tail]))
    # the URDF's nominal parameters, for scale
    nominal = torque_nrmse(panda.base_theta(), same_rows)
    assert np.all(ours < 0.25), ours
    assert ours.mean() < 1.15 * reference.mean(), (ours, reference)
    assert ours.mean() < 0.5 * nominal.mean(), (ours, nominal)
    # least squares leaves M(q) indefinite here: what is returned is the consistent fit (issue 29
    # item 2a), which predicts as well
    assert result.theta_least_squares is not None
    assert not panda.physical_consistency(result.theta_least_squares)["consistent"]
    assert panda.physical_consistency(result.theta)["consistent"]
    assert result.method.startswith("physically consistent least squares (least squares is not")
    feasible = identify_torque(panda, rec, consistent=True)
    assert panda.physical_consistency(feasible.theta_standard)["consistent"]
    assert panda.physical_consistency(feasible.theta)["consistent"]
    assert feasible.nrmse_held_out.mean() < 1.15 * reference.mean()


def test_log_cholesky_jacobian_is_the_derivative():
    """The consistent fit's Jacobian of the body parameters in their log-Cholesky factors, in
    closed form (hil.identify.urdf._pi_jacobian), equals their central difference."""
    from hil.identify.urdf import _pi_from_cholesky, _pi_jacobian

    x = np.random.default_rng(5).normal(size=(3, 10))
    jacobian, step = _pi_jacobian(x), 1e-6
    for body in range(3):
        for k in range(10):
            e = np.zeros(10)
            e[k] = step
            central = (_pi_from_cholesky(x[body] + e) - _pi_from_cholesky(x[body] - e)) / (2 * step)
            np.testing.assert_allclose(jacobian[body, :, k], central, rtol=0, atol=1e-7)


def test_log_cholesky_parametrization_round_trips_and_is_always_consistent():
    from hil.identify.urdf import _cholesky_from_pi, _pi_from_cholesky

    arm = UrdfArmModel.from_profile("panda")
    pi = arm.standard_theta[10:20]  # body 2 of the URDF
    assert np.allclose(_pi_from_cholesky(_cholesky_from_pi(pi)), pi, atol=1e-5)
    for _ in range(20):
        theta = arm.standard_theta.copy()
        theta[:10] = _pi_from_cholesky(RNG.normal(size=10))
        assert arm.physical_consistency(theta)["consistent"]


def test_planar_loader_refuses_a_urdf_only_arm_in_one_line():
    with pytest.raises(ProfileError, match="described by its URDF only") as exc:
        load_robot("panda")
    assert "\n" not in str(exc.value)
    assert load_robot("cicese").urdf == load_urdf_robot("cicese").urdf


def _synthetic_csv(path, model: UrdfArmModel, seconds: float, seed: int) -> np.ndarray:
    """A jittered 1 kHz multisine of ``model``'s own torques (1 % noise) as a standard CSV."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.8e-3, 1.2e-3, int(seconds * 1000)))
    w = rng.uniform(0.5, 4.0, (model.n_joints, 3))
    a = rng.uniform(0.05, 0.25, (model.n_joints, 3))
    arg = t[:, None, None] * w + rng.uniform(0, 6, (model.n_joints, 3))
    q = (a * np.sin(arg)).sum(-1) + np.array([0, 0, 0, -1.6, 0, 1.8, 0])
    dq = (a * w * np.cos(arg)).sum(-1)
    ddq = (-a * w**2 * np.sin(arg)).sum(-1)
    tau = model.torque(model.base_theta(), q, dq, ddq)
    tau += 0.01 * tau.std(0) * rng.normal(size=tau.shape)
    Recording.from_arrays(t, q, tau).write_csv(path)
    return tau


def test_hil_identify_robot_panda_on_a_standard_csv(tmp_path, panda, capsys):
    import json

    from hil.cli import main as hil_main

    csv = tmp_path / "panda.csv"
    _synthetic_csv(csv, panda, 12.0, 3)
    code = hil_main(["identify", "--from", str(csv), "--robot", "panda", "--out",
                     str(tmp_path / "out"), "--json"])  # fmt: skip
    assert code == 0
    report = json.loads(capsys.readouterr().out)
    assert report["model"] == "urdf" and len(report["parameters"]) == panda.n_params
    assert (tmp_path / "out" / "identify.json").is_file()
    nrmse_identified = np.array(report["validation"]["torque_nrmse_identified"])
    assert nrmse_identified.max() < 0.05, nrmse_identified
    # a 2-joint recording for a 7-joint arm: one line, no report
    two = tmp_path / "two.csv"
    t50 = np.arange(50) * 1e-3
    q50 = np.column_stack([np.sin(20 * t50), np.cos(20 * t50)])  # it moves: only n is wrong
    Recording.from_arrays(t50, q50, np.zeros((50, 2))).write_csv(two)
    code = hil_main(["identify", "--from", str(two), "--robot", "panda", "--out",
                     str(tmp_path / "out2")])  # fmt: skip
    assert code != 0
    err = capsys.readouterr().err.strip().splitlines()
    notes = [line for line in err[:-1] if ": note: " in line]  # torque 0 in every row, said
    assert err[-1].endswith("two.csv: 2 joints (q1..q2), robot panda has 7") and notes == err[:-1]
    assert not (tmp_path / "out2" / "identify.json").exists()


def test_identification_takes_the_recording_every_analysis_reads(tmp_path, cicese):
    """One recording type (drivers.recording.Recording): what `read_signals` returns goes into
    the n-joint identification as it is. Its torque is held over each period when this bench
    wrote it (meta.json's period beside commanded torques) and sampled with the positions in a
    bare CSV, and the rows treat it so."""
    t = np.arange(3000) * 2e-3
    q = np.column_stack([0.8 * np.sin(1.3 * t), 0.5 * np.sin(2.1 * t + 0.4)])
    tau = np.column_stack([3.0 * np.cos(0.9 * t), np.sin(1.7 * t)])
    bare = tmp_path / "bare.csv"
    Recording.from_arrays(t, q, tau).write_csv(bare)
    with RecordingWriter(tmp_path / "run", {"period_s": 2e-3, "robot": "cicese"}) as w:
        for row in np.column_stack([t, q, tau]):
            w.write(row.tolist())
    sampled, held = read_signals(bare), read_signals(tmp_path / "run")
    assert not sampled.torque_held and held.torque_held
    assert Recording.from_arrays(t, q, tau, held=True).torque_held
    np.testing.assert_allclose(torque_at_samples(sampled), sampled.tau)
    np.testing.assert_allclose(torque_at_samples(held)[1:], 0.5 * (tau[1:] + tau[:-1]))
    for rec in (sampled, held):
        result = identify_torque(cicese, rec, cutoff_hz=5.0)
        assert np.all(np.isfinite(result.theta)) and result.theta.shape == (cicese.n_params,)
