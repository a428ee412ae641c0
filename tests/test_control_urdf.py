"""The tracking controllers for n joints (hil/control/controllers.py over a URDF arm's model),
tested without the bus: each law on the 3-DOF cicese3 arm (profiles/robots/cicese3.toml).

- One law, two models: on the 2-DOF CICESE arm, the laws over its URDF model (Pinocchio, base
  parameters) give the closed form's torques.
- Computed torque closing the loop on its own n-joint model gives eq. (7) of Khosla & Kanade
  (1987) for every joint.
- Closed loop on the world: the n-joint plant (virtual_robot/urdf_plant.py, stick–slip friction)
  through its three drive models (per-mille torque steps, encoder counts), stepped by the one
  lockstep sequence (virtual_robot/stepping.py), in-process. CT and FED track the first move
  of the cicese3 tracking experiment far better than PD, RFED loses joint 2 to the off-diagonal
  inertia, all stay bounded, and CT with the true model (friction fed forward) tracks to a few
  mrad.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from drivers.units import position_to_rad, torque_to_permille, unwrap_int32
from hil.control.controllers import (
    SCHEMES,
    BackwardDifference,
    ComputedTorque,
    Gains,
    Reference,
    make_controller,
)
from hil.control.tracking import default_experiment, reference_torque_margin
from hil.control.trajectory import PointToPoint, khosla_kanade_moves
from hil.model.params import robot_params
from hil.model.urdf import UrdfArmModel
from profiles import ProfileError
from profiles.drive import load_drive
from profiles.robot import load_urdf_robot
from profiles.tracking import TrackingProfile, load_tracking
from virtual_robot.offline import enable_drives
from virtual_robot.stepping import Stepper
from virtual_robot.urdf_plant import UrdfPlant, UrdfPlantParams

H = 0.0025
ROBOT = "cicese3"
FIRST_MOVE_S = 1.75  # the first move (1 s) and its hold (0.75 s)


@pytest.fixture(scope="module")
def cicese3() -> tuple[UrdfArmModel, TrackingProfile, PointToPoint]:
    exp = load_tracking(default_experiment(ROBOT))
    traj = khosla_kanade_moves(exp.amplitude_rad, exp.pattern, move_s=exp.move_s, hold_s=exp.hold_s)
    return UrdfArmModel.from_profile(ROBOT), exp, traj


def test_the_cicese3_tracking_profile():
    exp = load_tracking(default_experiment(ROBOT))
    assert exp.name == "khosla-kanade-tracking-cicese3" and exp.n_joints == 3
    assert exp.kp[:2] == (40.0, 58.0) and exp.kv[:2] == (12.6, 15.2)  # Table 1
    assert Gains(exp.kp, exp.kv).damping_ratio() == pytest.approx([1.0, 1.0, 1.0], abs=0.005)
    assert default_experiment("cicese") == "khosla-kanade-tracking"  # none shipped: the 2-DOF one


def test_joint_3_gains_give_joint_2_disturbance_rejection(cicese3):
    """kp3 from J33 kp3 / fc3 = J22 kp2 / fc2 (the profile's comment), J = diag M̃(0)."""
    model, exp, _ = cicese3
    theta = model.base_theta()
    J = np.diagonal(model.mass_matrix(theta, np.zeros(3)))
    fc = load_urdf_robot(ROBOT).coulomb_Nm
    assert J[2] * exp.kp[2] / fc[2] == pytest.approx(J[1] * exp.kp[1] / fc[1], rel=0.01)


def test_the_reference_leaves_torque_for_the_feedback(cicese3):
    model, _, traj = cicese3
    limits = [load_drive(d).max_torque_Nm for d in load_urdf_robot(ROBOT).drives]
    margin = reference_torque_margin(model.base_theta(), traj, limits, H, model)
    assert margin["peak_reference_torque_Nm"] == pytest.approx([55.3, 11.1, 1.64], abs=0.05)
    assert min(margin["margin_fraction"]) > 0.25


def test_tracking_loader_takes_the_joint_count_from_the_amplitudes(tmp_path: Path):
    src = Path(load_tracking(default_experiment(ROBOT)).source).read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(src.replace("kp = [40.0, 58.0, 430.0]", "kp = [40.0, 58.0]"))
    with pytest.raises(ProfileError) as exc:
        load_tracking(bad)
    assert exc.value.field == "gains.kp" and "3 numbers" in str(exc.value)


@pytest.mark.parametrize("scheme", SCHEMES)
def test_one_law_on_the_urdf_model_gives_the_closed_form_torques(scheme):
    """The same law over the CICESE arm's URDF model (Pinocchio, its base parameters) and over
    the closed form (θ1..θ9): the same torque and the same split, to rounding."""
    urdf = UrdfArmModel.from_profile("cicese")
    gains, limits = Gains((40.0, 58.0), (12.6, 15.2)), (1e6, 1e6)
    closed = make_controller(scheme, robot_params("cicese").theta, gains, limits)
    other = make_controller(scheme, urdf.base_theta(), gains, limits, model=urdf)
    np.testing.assert_allclose(other.J, closed.J, rtol=1e-12)
    rng = np.random.default_rng(3)
    for _ in range(20):
        q, dq, qd, dqd, ddqd = rng.uniform(-2, 2, size=(5, 2))
        a = closed(0.0, q, dq, Reference(qd, dqd, ddqd))
        b = other(0.0, q, dq, Reference(qd, dqd, ddqd))
        np.testing.assert_allclose(b.tau_law, a.tau_law, rtol=1e-10, atol=1e-10)
        for part in closed.part_names:
            np.testing.assert_allclose(b.parts[part], a.parts[part], rtol=1e-10, atol=1e-10)


def test_gains_and_limits_must_match_the_model_joint_count(cicese3):
    model, exp, _ = cicese3
    with pytest.raises(ValueError, match="need 3 values"):
        make_controller(
            "ct", model.base_theta(), Gains((1.0, 1.0), (1.0, 1.0)), (1, 1, 1), model=model
        )
    with pytest.raises(ValueError, match="torque limits: need 3"):
        make_controller("pd", model.base_theta(), Gains(exp.kp, exp.kv), (1, 1), model=model)


def test_computed_torque_on_its_own_n_joint_model_gives_eq_7(cicese3):
    """CT with the exact frictionless model closing a continuous loop on that model (forward
    dynamics q̈ = M̃⁻¹ (τ − C̃q̇ − g̃), integrated to 1e-10): every joint's error obeys
    ë + k_v ė + k_p e = 0."""
    model, exp, traj = cicese3
    theta = model.base_theta()
    theta[model.term_columns("friction")] = 0.0
    gains = Gains(exp.kp, exp.kv)
    ct = ComputedTorque(theta, gains, (1e6,) * 3, model=model)
    e0 = np.array([0.05, -0.08, 0.1])

    def deriv(t: float, x: np.ndarray) -> np.ndarray:
        q, dq = x[:3], x[3:]
        tau = ct(t, q, dq, Reference(*traj.at(t))).tau
        rhs = tau - model.coriolis_vector(theta, q, dq) - model.gravity_vector(theta, q)
        return np.concatenate([dq, np.linalg.solve(model.mass_matrix(theta, q), rhs)])

    x0 = np.concatenate([traj.at(0.0)[0] - e0, np.zeros(3)])
    tt = np.linspace(0.0, 0.4, 81)
    sol = solve_ivp(deriv, (0.0, 0.4), x0, t_eval=tt, rtol=1e-10, atol=1e-12)
    assert sol.success
    errors = traj.at(tt)[0] - sol.y[:3].T
    for j in range(3):
        r1, r2 = np.roots([1.0, gains.kv[j], gains.kp[j]])
        c2 = -r1 * e0[j] / (r2 - r1)
        analytic = np.real((e0[j] - c2) * np.exp(r1 * tt) + c2 * np.exp(r2 * tt))
        assert np.max(np.abs(errors[:, j] - analytic)) < 1e-6


# ---- closed loop on the world, in-process ------------------------------------------------------


def track_on_the_plant(
    scheme: str, model, exp: TrackingProfile, traj: PointToPoint, friction_velocity: str
) -> dict[str, np.ndarray]:
    """One scheme on the cicese3 plant through its drives, lockstep, for FIRST_MOVE_S: at each
    SYNC the encoders are read (counts, unwrapped), the law evaluated with the backward-
    difference velocity, and its torque written to the drives in per-mille."""
    robot = load_urdf_robot(ROBOT)
    drive_profiles = [load_drive(name) for name in robot.drives]
    plant = UrdfPlant(UrdfPlantParams.from_profile(robot), max_step_s=0.0005)
    drives = enable_drives(drive_profiles, H, plant.measured_q, plant.dq)
    stepper = Stepper(plant, drives, H)
    controller = make_controller(
        scheme,
        model.base_theta(),
        Gains(exp.kp, exp.kv),
        [p.max_torque_Nm for p in drive_profiles],
        model=model,
        q_typical=exp.typical_q_rad,
        friction_velocity=friction_velocity,
    )
    n = round(FIRST_MOVE_S / H)
    qd, dqd, ddqd = traj.at(np.arange(n) * H)
    velocity = BackwardDifference(H, 3)
    counts = [d.position_counts for d in drives]
    q = np.zeros(3)
    error, clipped = np.empty((n, 3)), np.zeros(3, dtype=int)
    for k in range(n):
        t = stepper.sync()
        for i, d in enumerate(drives):
            counts[i] = unwrap_int32(counts[i], d.position_counts)
            q[i] = position_to_rad(counts[i], drive_profiles[i].counts_per_rev)
        cmd = controller(t, q, velocity(q), Reference(qd[k], dqd[k], ddqd[k]))
        clipped += cmd.clipped
        for i, d in enumerate(drives):
            d.write_target_torque(
                torque_to_permille(cmd.tau[i], drive_profiles[i].rated_torque_Nm), t
            )
        error[k] = qd[k] - q
    return {"max": np.max(np.abs(error), axis=0), "clipped": clipped}


@pytest.fixture(scope="module")
def on_the_plant(cicese3) -> dict[str, dict[str, np.ndarray]]:
    model, exp, traj = cicese3
    runs = {s: track_on_the_plant(s, model, exp, traj, exp.ct_friction_velocity) for s in SCHEMES}
    runs["ct-reference"] = track_on_the_plant("ct", model, exp, traj, "reference")
    return runs


def test_ct_and_fed_track_far_better_than_pd_and_all_stay_bounded(on_the_plant):
    """Measured (max |e| of PD / scheme, joints 1/2/3): CT 21/14/5.2x, FED 116/255/194x."""
    pd = on_the_plant["pd"]["max"]
    assert np.all(pd > 0.1)  # PD leaves tenths of a radian: it has no model of the motion
    assert np.all(pd / on_the_plant["ct"]["max"] > 4.0)
    assert np.all(pd / on_the_plant["fed"]["max"] > 50.0)
    for run in on_the_plant.values():
        assert np.all(np.isfinite(run["max"])) and np.all(run["max"] < 0.5)
        assert not run["clipped"].any()


def test_rfed_loses_joint_2_to_the_off_diagonal_inertia(on_the_plant):
    """RFED leaves out (M̃(q_d) − J) q̈_d; the coupling falls on joint 2 (measured 105x FED's)."""
    assert on_the_plant["rfed"]["max"][1] > 20 * on_the_plant["fed"]["max"][1]


def test_ct_with_the_true_model_tracks_to_a_few_mrad(on_the_plant):
    """With f̃ at the reference velocity (no wait for breakaway) the host's model is the plant's
    but for stiction at rest: the error stays at a few encoder-and-torque steps (1.5 mrad)."""
    assert np.all(on_the_plant["ct-reference"]["max"] < 0.004)


# ---- end to end: `hil control --robot cicese3` over a virtual bench -----------------------------


def test_cli_compare_over_the_bus_for_three_joints(tmp_path, capsys):
    """The first second of the cicese3 experiment, PD and FED, in-process; then FED over slcan
    gives the same recording bit for bit (lockstep)."""
    from hil.cli import main as cli_main

    common = ("--robot", ROBOT, "--duration", "1.0", "--no-plot", "--json")
    status = cli_main(
        [
            *("control", "--compare", "--bench", "virtual-inprocess", "--schemes", "pd,fed"),
            *common,
            *("--out", str(tmp_path / "inprocess")),
        ]
    )
    out = capsys.readouterr()
    assert status == 0, out.err
    doc = json.loads(out.out)
    assert doc["experiment"] == "khosla-kanade-tracking-cicese3"
    assert len(doc["gains"]["kp"]) == 3
    pd = doc["results"]["profile"]["pd"]
    assert len(pd["max_position_error_rad"]) == 3 and pd["torque_limit_Nm"] == [200, 15, 4]
    assert all(r > 20 for r in doc["max_position_error_reduction_vs_pd"]["profile"]["fed"])
    header = (tmp_path / "inprocess" / "profile" / "fed" / "signals.csv").open().readline()
    assert header.startswith("t,q1,q2,q3,tau1,tau2,tau3")
    log = (tmp_path / "inprocess" / "profile" / "fed" / "control.csv").open().readline()
    assert "feedback3" in log and "tau_law3" in log

    status = cli_main(
        [
            *("control", "--scheme", "fed", "--bench", "virtual-slcan"),
            *common,
            *("--out", str(tmp_path / "slcan")),
        ]
    )
    out = capsys.readouterr()
    assert status == 0, out.err
    a = (tmp_path / "inprocess" / "profile" / "fed" / "signals.csv").read_bytes()
    assert (tmp_path / "slcan" / "signals.csv").read_bytes() == a


@pytest.mark.parametrize(
    "args,needle",
    [
        (("--experiment", "khosla-kanade-tracking"), "moves 2 joints, robot cicese3 has 3"),
        (("--kp", "40", "58"), "--kp takes 3 finite gains"),
        (("--params", "p.json"), "'theta' must be a list of 18 numbers"),
        (("--params", "p.json#exact"), "has no schemes"),
    ],
)
def test_cli_errors_for_a_urdf_arm_are_one_line(args, needle, tmp_path, monkeypatch, capsys):
    from hil.cli import main as cli_main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "p.json").write_text('{"theta": [1, 1, 1, 1, 1, 1, 1, 1, 1]}')
    status = cli_main(
        ["control", "--scheme", "ct", "--bench", "virtual-inprocess", "--robot", ROBOT, *args]
    )
    err = capsys.readouterr()
    assert status == 2, (err.out, err.err)
    last = err.err.strip().splitlines()[-1]
    assert last.startswith("hil control: error:") and needle in last, err.err
    assert not (tmp_path / "runs").exists()


def identify_json(model: UrdfArmModel, theta: np.ndarray, **changes) -> dict:
    """What `hil identify --robot cicese3` writes, with ``theta`` as the identified values."""
    doc = {
        "robot": ROBOT,
        "model": "urdf",
        "terms": list(model.terms),
        "method": "weighted least squares",
        "parameters": [
            {"name": n, "meaning": m, "unit": u, "identified": float(x), "nominal": float(y)}
            for n, m, u, x, y in zip(
                model.names, model.meanings, model.units, theta, model.base_theta(), strict=True
            )
        ],
    }
    return {**doc, **changes}


def test_base_parameters_from_identify_json(cicese3, tmp_path):
    from hil.model.params import ParamsError, load_base_params

    model = cicese3[0]
    theta = model.base_theta() * 1.03
    path = tmp_path / "identify.json"
    path.write_text(json.dumps(identify_json(model, theta)))
    params = load_base_params(path, model)
    np.testing.assert_array_equal(params.theta, theta)
    assert params.scheme == "weighted least squares"
    bad = identify_json(model, theta)
    bad["parameters"][2]["meaning"] = "Iyy1"
    for doc, needle in [
        (identify_json(model, theta, robot="panda"), "not cicese3"),
        (identify_json(model, theta, terms=[]), "model terms"),
        (bad, "beta3 is 'Iyy1' there"),
        ({"theta": [1.0] * 9}, "18 numbers"),
    ]:
        path.write_text(json.dumps(doc))
        with pytest.raises(ParamsError, match=needle) as exc:
            load_base_params(path, model)
        assert "\n" not in str(exc.value)


def test_cli_runs_a_urdf_arm_with_identified_base_parameters(cicese3, tmp_path, capsys):
    """`hil control --robot cicese3 --params identify.json`: the file's base parameters drive
    the laws (here the profile's with every rigid-body parameter 30 % high: CT is worse)."""
    from hil.cli import main as cli_main

    model = cicese3[0]
    theta = model.base_theta()
    rigid = np.ones(model.n_params, dtype=bool)
    rigid[model.term_columns("friction")] = False
    theta[rigid] *= 1.3
    (tmp_path / "id").mkdir()
    (tmp_path / "id" / "identify.json").write_text(json.dumps(identify_json(model, theta)))
    status = cli_main(
        [
            *("control", "--compare", "--schemes", "ct", "--bench", "virtual-inprocess"),
            *("--robot", ROBOT, "--duration", "1.0", "--no-plot", "--json"),
            *("--params", str(tmp_path / "id" / "identify.json"), "--out", str(tmp_path / "o")),
        ]
    )
    out = capsys.readouterr()
    assert status == 0, out.err
    doc = json.loads(out.out)
    assert [p["label"] for p in doc["parameter_sets"]] == ["profile", "id/identify"]
    np.testing.assert_allclose(doc["parameter_sets"][1]["theta"], theta)
    exact, off = (
        doc["results"][k]["ct"]["max_position_error_rad"] for k in ("profile", "id/identify")
    )
    # joint 1's gravity 30 % high (the first moments are rigid-body parameters too): 6x the error
    assert off[0] > 3 * exact[0]
