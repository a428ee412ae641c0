"""Excitation design (hil/identify/excitation.py, `hil excite`) and the shipped optimal-fourier
profile."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from drivers.recording import read_signals
from hil import cli
from hil.identify.excitation import (
    ExcitationLimits,
    FourierParametrization,
    FourierTrajectory,
    asymmetry_bias,
    condition_number,
    criteria,
    d_optimality,
    derivatives_from_positions,
    design_excitation,
    fit_torque_series,
    nominal_torque,
    parse_trajectory_header,
    profile_toml,
    sample_times,
    stacked_regressor,
    torque_fit_error,
    trajectory_extremes,
)
from hil.model.params import robot_params
from profiles import ProfileError
from profiles.bench import load_bench
from profiles.experiment import JointExcitation, Sine, load_experiment
from profiles.robot import load_robot
from virtual_robot.simulate import simulate

PROFILES = Path(__file__).resolve().parent.parent / "profiles"
SHIPPED = PROFILES / "experiments" / "optimal-fourier.toml"
THETA = robot_params("cicese").theta
H = 0.0025
ASYMMETRY = ((7.17 - 8.049) / 2, 0.0)  # (F⁺ − F⁻)/2 of the CICESE arm, Table I


def bench_limits() -> ExcitationLimits:
    b = load_bench("virtual-slcan")
    return ExcitationLimits.from_bench(
        b.position_limit_rad, b.velocity_limit_rad_s, b.torque_limit_Nm
    )


def realized(experiment: str | Path, tmp: Path, effects=None) -> tuple:
    """World response (virtual robot, default effects) and its q, q̇, q̈ by central differences."""
    simulate(load_robot("cicese"), load_experiment(experiment), tmp, effects=effects, plot=False)
    rec = read_signals(tmp)
    return rec, derivatives_from_positions(rec.q, rec.period_s)


@pytest.fixture(scope="module")
def paper_realized(tmp_path_factory):
    return realized("reyes-kelly", tmp_path_factory.mktemp("paper"))


@pytest.fixture(scope="module")
def shipped_realized(tmp_path_factory):
    return realized(SHIPPED, tmp_path_factory.mktemp("optimal"))


@pytest.fixture(scope="module")
def shipped_trajectory() -> FourierTrajectory:
    return parse_trajectory_header(SHIPPED.read_text(encoding="utf-8"))


# --- the Fourier trajectory ---------------------------------------------------------------------


@pytest.mark.parametrize("harmonics", [2, 5, 9])
def test_parametrization_starts_at_rest_and_is_analytic(harmonics):
    param = FourierParametrization(2 * math.pi * 0.5, harmonics)
    z = np.random.default_rng(harmonics).standard_normal(param.n_free)
    tr = param.trajectory(z)
    q, dq, ddq = tr.evaluate([0.0])
    assert np.abs(np.concatenate([q, dq, ddq], axis=None)).max() < 1e-12
    np.testing.assert_allclose(param.free(tr), z, atol=1e-12)
    # q̇ and q̈ are the derivatives of q (central differences on a fine grid)
    t = np.linspace(0.0, tr.period_s, 20001)
    q, dq, ddq = tr.evaluate(t)
    dt = t[1] - t[0]
    for x, dx in ((q, dq), (dq, ddq)):  # central differences: error ~ (l ω dt)² relative
        fd = (x[2:] - x[:-2]) / (2 * dt)
        assert np.abs(fd - dx[1:-1]).max() < 1e-5 * np.abs(dx).max()
    # periodic
    np.testing.assert_allclose(tr.evaluate([tr.period_s])[0], 0.0, atol=1e-12)


def test_parametrization_needs_two_harmonics():
    with pytest.raises(ValueError, match="at least 2 harmonics"):
        FourierParametrization(1.0, 1)


# --- criteria -----------------------------------------------------------------------------------


def test_criteria_scaling_and_normalization():
    tr = FourierParametrization(math.pi, 4).trajectory(np.random.default_rng(1).standard_normal(12))
    q, dq, ddq = tr.evaluate(sample_times(tr.period_s, 400))
    W = stacked_regressor(q, dq, ddq)
    assert W.shape == (800, 9)
    scale = np.abs(THETA)
    # the column scaling by |θ| changes the condition number a lot (units), by design
    assert condition_number(W, scale) != pytest.approx(condition_number(W, np.ones(9)), rel=0.1)
    # D-optimality is per sample: the same period twice gives the same value
    W2 = np.vstack([W, W])
    assert d_optimality(W2, scale) == pytest.approx(d_optimality(W, scale), abs=1e-9)
    # scaling every column by c shifts -log det by -2*9*log(c), leaves κ alone
    assert d_optimality(W, 2 * scale) == pytest.approx(d_optimality(W, scale) - 18 * math.log(2))
    assert condition_number(W, 2 * scale) == pytest.approx(condition_number(W, scale))


def test_criteria_of_a_motion_that_cannot_identify_everything():
    # joint 2 never moves: θ7, θ9 have zero columns
    t = sample_times(2.0, 400)
    q = np.column_stack([0.5 * np.sin(math.pi * t), np.zeros_like(t)])
    dq = np.column_stack([0.5 * math.pi * np.cos(math.pi * t), np.zeros_like(t)])
    ddq = np.column_stack([-0.5 * math.pi**2 * np.sin(math.pi * t), np.zeros_like(t)])
    c = criteria(q, dq, ddq, THETA)
    assert c["cond"] == math.inf or c["cond"] > 1e12
    assert c["dopt"] == math.inf or c["dopt"] > 50


def test_asymmetry_bias_is_the_least_squares_error_it_predicts():
    """Torques from a model with direction-dependent Coulomb friction, fitted by least squares
    with the 9 columns: the error of θ̂ is what asymmetry_bias predicts (dynamic form)."""
    tr = FourierParametrization(math.pi, 5).trajectory(np.random.default_rng(3).standard_normal(16))
    q, dq, ddq = tr.evaluate(sample_times(tr.period_s, 800))
    tau = inverse_dynamics_asymmetric(q, dq, ddq)
    theta_hat, *_ = np.linalg.lstsq(stacked_regressor(q, dq, ddq), tau.ravel(), rcond=None)
    bias = asymmetry_bias(q, dq, ddq, tr.period_s / 800, THETA, ASYMMETRY)
    np.testing.assert_allclose((theta_hat - THETA) / THETA, bias["filtered_dynamic"], atol=1e-9)
    assert set(bias) == {"filtered_dynamic", "filtered_power", "supplied_energy"}
    zero = asymmetry_bias(q, dq, ddq, tr.period_s / 800, THETA, (0.0, 0.0))
    assert all(np.abs(b).max() == 0.0 for b in zero.values())


def inverse_dynamics_asymmetric(q, dq, ddq):
    from hil.model.closed_form import inverse_dynamics

    tau = inverse_dynamics(THETA, q, dq, ddq)
    tau[:, 0] += ASYMMETRY[0] * np.abs(np.sign(dq[:, 0]))
    return tau


# --- design -------------------------------------------------------------------------------------


@pytest.mark.parametrize("criterion", ["dopt", "cond"])
def test_optimized_design_beats_its_initial_guess_and_keeps_the_limits(criterion):
    limits = bench_limits()
    result = design_excitation(
        THETA,
        limits,
        criterion=criterion,
        harmonics=3,
        seed=1,
        starts=1,
        grid=96,
        max_iterations=60,
    )
    if criterion == "dopt":
        assert result.designed["dopt"] < result.initial["dopt"] - 5.0  # det ≥ e^5 ≈ 150x larger
    else:
        assert result.designed["cond"] < 0.5 * result.initial["cond"]
    ext = trajectory_extremes(result.trajectory, THETA, sample_times(2.0, 20000))
    assert np.all(ext <= limits.as_array() * (1 + 1e-4))
    assert result.starts == 1 and result.elapsed_s > 0


def test_design_is_reproducible_for_a_seed():
    kw = dict(harmonics=3, seed=7, starts=1, grid=64, max_iterations=20)
    a = design_excitation(THETA, bench_limits(), **kw)
    b = design_excitation(THETA, bench_limits(), **kw)
    np.testing.assert_array_equal(a.trajectory.a, b.trajectory.a)
    np.testing.assert_array_equal(a.trajectory.b, b.trajectory.b)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"criterion": "aopt"}, "unknown criterion"),
        ({"harmonics": 1}, "at least 2 harmonics"),
        ({"fundamental_hz": 0.0}, "fundamental"),
        ({"starts": 0}, "starts"),
        ({"max_bias": 0.0}, "max_bias"),
    ],
)
def test_design_rejects_bad_arguments(kwargs, message):
    with pytest.raises(ValueError, match=message):
        design_excitation(THETA, bench_limits(), **kwargs)


def test_limits_from_bench_apply_margins():
    lim = bench_limits()
    assert lim.position_rad == (1.2, 2.0)
    assert lim.velocity_rad_s == pytest.approx((9.6, 20.0))
    assert lim.torque_Nm == pytest.approx((160.0, 12.0))
    with pytest.raises(ValueError, match="torque margin"):
        ExcitationLimits.from_bench([[-3, 3], [-3, 3]], [1, 1], [1, 1], torque_margin=1.5)


# --- torque series and profile round trip -------------------------------------------------------


def test_torque_series_of_a_smooth_model_is_exact():
    """Without Coulomb friction the torque is smooth: 60 harmonics fit it to round-off."""
    theta = THETA.copy()
    theta[7:9] = 0.0
    tr = FourierParametrization(math.pi, 4).trajectory(np.random.default_rng(2).standard_normal(12))
    series = fit_torque_series(tr, theta, 60, time_advance_s=H / 2)
    err = torque_fit_error(series, tr, theta, np.arange(800) * H, time_advance_s=H / 2)
    assert max(err["max_Nm"]) < 1e-8


def test_profile_toml_round_trip(tmp_path):
    tr = FourierParametrization(math.pi, 4).trajectory(np.random.default_rng(4).standard_normal(12))
    series = fit_torque_series(tr, THETA, 50)
    path = tmp_path / "designed.toml"
    path.write_text(
        profile_toml(series, name="designed", period_s=H, duration_s=4.0, header=["a header"])
    )
    exp = load_experiment(path)
    assert exp.kind == "open_loop_torque" and exp.duration_s == 4.0
    t = np.arange(1600) * H
    np.testing.assert_allclose(exp.torque_table(t), series.evaluate(t), atol=1e-9)
    assert exp.joints[0].offset_Nm == pytest.approx(series.offset_Nm[0])


# --- offset_Nm in experiment profiles (profiles/experiment.py) ----------------------------------


def test_joint_excitation_offset():
    j = JointExcitation(0.0, 1.0, (Sine(2.0, 3.0, 0.0),), offset_Nm=-5.0)
    assert j.torque(0.0) == -5.0
    assert j.peak_Nm() == 7.0
    assert JointExcitation(1.0, 1.0, ()).offset_Nm == 0.0  # default keeps old profiles valid
    paper = load_experiment("reyes-kelly")
    assert all(j.offset_Nm == 0.0 for j in paper.joints)


@pytest.mark.parametrize("value", ['"big"', "inf", "true"])
def test_bad_offset_is_a_one_line_error(tmp_path, value):
    text = (PROFILES / "experiments" / "reyes-kelly.toml").read_text(encoding="utf-8")
    path = tmp_path / "bad.toml"
    path.write_text(text.replace("step_Nm = 1.2", f"step_Nm = 1.2\noffset_Nm = {value}"))
    with pytest.raises(ProfileError) as exc:
        load_experiment(path)
    msg = str(exc.value)
    assert "\n" not in msg and str(path) in msg and "joints[1].offset_Nm" in msg


# --- the shipped design -------------------------------------------------------------------------


def test_shipped_design_keeps_the_limits(shipped_trajectory):
    tr = shipped_trajectory
    assert tr.harmonics == 5 and tr.omega_f == pytest.approx(math.pi)  # 0.5 Hz, 2 s period
    q, dq, ddq = tr.evaluate([0.0])
    assert np.abs(np.concatenate([q, dq, ddq], axis=None)).max() < 1e-12  # at rest, hanging
    t = sample_times(tr.period_s, 20000)
    ext = trajectory_extremes(tr, THETA, t)
    bench = load_bench("virtual-slcan")
    tol = 1 + 1e-4  # checked on 8192 samples per period when designed, here on 20000
    assert np.all(ext[0] <= np.array([1.2, 2.0]) * tol)  # |q| (bench: 3.2)
    assert np.all(ext[0] < np.abs(np.array(bench.position_limit_rad)).min(axis=1))
    assert np.all(ext[1] <= 0.8 * np.array(bench.velocity_limit_rad_s) * tol)  # |q̇|
    assert np.all(ext[2] <= 0.8 * np.array(bench.torque_limit_Nm) * tol)  # nominal |τ|
    # it uses its range (an optimum sits on its constraints)
    assert ext[2, 0] > 0.95 * 160.0 and ext[0, 1] > 0.95 * 2.0


def test_shipped_profile_matches_the_designed_torque(shipped_trajectory):
    exp = load_experiment("optimal-fourier")
    assert exp.kind == "open_loop_torque"
    assert exp.period_s == H and exp.duration_s == 10.0 and exp.initial_q_rad == (0.0, 0.0)
    t = np.arange(4000) * H
    err = exp.torque_table(t) - nominal_torque(shipped_trajectory, THETA, t + H / 2)
    rms = np.sqrt(np.mean(err**2, axis=0))
    # the header's fit error: rms 0.72, 0.13 Nm, all of it at the Coulomb sign switches
    assert np.all(rms < [0.75, 0.15])
    tau_rms = np.sqrt(np.mean(nominal_torque(shipped_trajectory, THETA, t) ** 2, axis=0))
    assert np.all(rms / tau_rms < [0.01, 0.025])
    assert np.abs(exp.torque_table(t)).max(axis=0) @ [1, 0] < 0.85 * 200.0
    assert np.abs(exp.torque_table(t)).max(axis=0) @ [0, 1] < 0.85 * 15.0
    header = SHIPPED.read_text(encoding="utf-8").splitlines()[0]
    assert header.startswith("# Generated by: hil excite --criterion dopt") and "--seed 0" in header


def test_shipped_design_beats_the_paper(shipped_trajectory, paper_realized, shipped_realized):
    designed = criteria(*shipped_trajectory.evaluate(sample_times(2.0, 2000)), THETA)
    paper = criteria(*paper_realized[1], THETA)
    real = criteria(*shipped_realized[1], THETA)
    # paper eqs. (31)-(32), realized in the world: κ ≈ 142, −log det ≈ −26.1
    assert paper["dopt"] == pytest.approx(-26.1, abs=0.3)
    assert designed["dopt"] < paper["dopt"] - 5.0  # det(WᵀW) ≥ 150x the paper's
    assert real["dopt"] < paper["dopt"] - 5.0  # and so in the world, open loop
    assert abs(real["dopt"] - designed["dopt"]) < 0.3
    assert real["cond"] < 1.1 * paper["cond"]


def test_shipped_design_is_robust_to_the_coulomb_asymmetry(paper_realized, shipped_realized):
    """The bias the direction-dependent Coulomb friction causes (the main identification error
    on the default virtual robot): ≤ 2 % on every θ_i and regression form for the design, up to
    15 % for eqs. (31)-(32)."""

    def worst(rec_and_samples):
        rec, (q, dq, ddq) = rec_and_samples
        b = asymmetry_bias(q, dq, ddq, rec.period_s, THETA, ASYMMETRY)
        return {form: float(np.abs(v).max()) for form, v in b.items()}

    paper, design = worst(paper_realized), worst(shipped_realized)
    assert paper["supplied_energy"] > 0.10
    assert max(design.values()) < 0.025


def test_shipped_design_stays_in_range_open_loop(shipped_trajectory, shipped_realized):
    rec, _ = shipped_realized
    assert len(rec.t) == 4000
    assert np.all(np.abs(rec.q).max(axis=0) < [1.3, 2.1])  # bench: 3.2 rad
    q_design = shipped_trajectory.evaluate(rec.t)[0]
    assert np.all(np.abs(rec.q - q_design).max(axis=0) < 0.1)  # drift over 5 periods, rad
    assert np.all(np.abs(rec.tau).max(axis=0) < [200.0, 15.0])  # never saturates


# --- the command line ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--harmonics", "1"], "--harmonics"),
        (["--torque-margin", "1.5"], "--torque-margin"),
        (["--fundamental-hz", "0"], "--fundamental-hz"),
        (["--out", "x.txt"], ".toml"),
        (["--position-limit", "a,b"], "--position-limit"),
        (["--position-limit", "1.0"], "--position-limit"),
        (["--max-bias", "-1"], "--max-bias"),
        (["--bench", "no-such-bench"], "no-such-bench"),
    ],
)
def test_cli_bad_arguments_are_one_line_errors(capsys, tmp_path, args, needle):
    out = ["--out", str(tmp_path / "x.toml")] if "--out" not in args else []
    assert cli.main(["excite", *out, *args]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hil excite: error:") and needle in lines[0]
    assert not (tmp_path / "x.toml").exists()


def test_cli_unknown_criterion(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["excite", "--criterion", "aopt"])
    assert exc.value.code == 2
    assert "invalid choice" in capsys.readouterr().err.strip().splitlines()[-1]


def test_cli_designs_checks_and_writes_a_profile_that_loads(capsys, tmp_path):
    out = tmp_path / "small.toml"
    code = cli.main(
        [
            "excite",
            "--harmonics",
            "3",
            "--starts",
            "1",
            "--torque-harmonics",
            "80",
            "--duration",
            "4",
            "--out",
            str(out),
            "--json",
        ]
    )
    captured = capsys.readouterr()
    assert code == 0
    summary = json.loads(captured.out)  # one JSON document, nothing else on stdout
    assert summary["designed"]["dopt"] < summary["initial_guess"]["dopt"]
    # the world check: the paper's excitation and the design, open loop in virtual-robot simulate
    assert summary["paper_realized"]["dopt"] == pytest.approx(-26.1, abs=0.3)
    assert summary["realized"]["in_bench_range"] is True
    assert summary["realized"]["dopt"] == pytest.approx(summary["designed"]["dopt"], abs=1.0)
    exp = load_experiment(out)
    assert exp.name == "small" and exp.duration_s == 4.0
    assert len(exp.joints[0].sines) == 80
    tr = parse_trajectory_header(out.read_text(encoding="utf-8"))
    assert tr.harmonics == 3
    assert Path(summary["plot"]).is_file()


def test_identification_error_before_and_after(paper_realized, shipped_realized):
    """hil.identify.schemes (exact, the issue's default) on the world's open-loop responses: eqs.
    (31)-(32) lose 15 % of θ6 in the supplied-energy scheme to the Coulomb asymmetry; the
    designed excitation keeps every θ_i of every scheme within 3 %."""
    from hil.identify.schemes import identify

    def worst(rec) -> dict[str, float]:
        results = identify(rec.q, rec.tau, rec.period_s)
        return {s: float(np.abs(r.theta / THETA - 1).max()) for s, r in results.items()}

    paper, design = worst(paper_realized[0]), worst(shipped_realized[0])
    assert set(paper) == {"filtered_dynamic", "supplied_energy", "filtered_power"}
    assert paper["supplied_energy"] > 0.10
    assert max(design.values()) < 0.03
