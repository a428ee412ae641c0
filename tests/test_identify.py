"""Identification (Reyes & Kelly 1997): regressions, estimators, accuracy targets, online RLS, CLI.

Recordings come from the offline simulation of the virtual robot (bit-identical to a lockstep run
over any bench, tests/test_hil_run.py), so the full 10 s excitation costs ~0.2 s here; one test
runs `hil identify` end to end over a bench.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from drivers.recording import read_signals
from hil.identify.online import OnlineIdentifier
from hil.identify.schemes import format_table_ii, identify, validate, validate_many
from hil.model.estimators import (
    RecursiveLeastSquares,
    least_squares,
    recursive_least_squares,
    weighted_least_squares,
)
from hil.model.params import ParamsError, load_params, robot_params
from hil.model.regressors import SCHEMES, build_regression
from profiles.effects import load_effects
from profiles.experiment import load_experiment
from profiles.robot import load_robot
from virtual_robot.simulate import simulate

# one worker runs the whole module under `pytest -n` (`--dist loadgroup`): its module
# fixtures are built once, not once per worker
pytestmark = pytest.mark.xdist_group("identify")

REFERENCE = robot_params("cicese").theta


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """10 s of eqs. (31)-(32) on the default robot and with symmetric Coulomb friction, and the
    held-out multisine on the default robot."""
    robot = load_robot("cicese")
    out = {}
    for name, experiment, effects in (
        ("default", "reyes-kelly", None),
        ("symmetric", "reyes-kelly", "symmetric-coulomb"),
        ("held_out", "validation-multisine", None),
        ("designed", "optimal-fourier", None),
    ):
        d = tmp_path_factory.mktemp(name)
        simulate(
            robot,
            load_experiment(experiment),
            d,
            effects=load_effects(effects) if effects else None,
            plot=False,
        )
        out[name] = read_signals(d)
    return out


def rel_err(theta):
    return np.abs((theta - REFERENCE) / REFERENCE)


# --- accuracy targets (issue 4), exact mode, 10 s ----------------------------------------------


@pytest.mark.parametrize("scheme", ["filtered_dynamic", "filtered_power"])
def test_default_robot_exact_mode_meets_the_targets(recordings, scheme):
    """θ1, θ2, θ3, θ5 within 2 %, θ4 within 3 %, θ6..θ9 within 10 % (joint 1's Coulomb friction
    is direction-dependent, which the 9-parameter model cannot express)."""
    rec = recordings["default"]
    res = identify(rec.q, rec.tau, rec.period_s, schemes=[scheme])[scheme]
    err = rel_err(res.theta)
    assert np.all(err[[0, 1, 2, 4]] < 0.02), err
    assert err[3] < 0.03, err
    assert np.all(err[5:] < 0.10), err
    assert res.consistency["consistent"]


def test_default_robot_supplied_energy(recordings):
    """The inertial and gravity parameters meet the targets; θ6 does not on this excitation.

    eqs. (31)-(32) drive joint 1 at one dominant frequency, so ∫q̇1² and ∫|q̇1| grow almost in
    proportion and the cumulative energy model can barely tell viscous from Coulomb friction:
    the unmodelled direction dependence (a −0.44 Nm offset while moving) is traded between θ6
    and θ8 (docs/identification.md). The test pins the known miss so that a change shows up.
    """
    rec = recordings["default"]
    res = identify(rec.q, rec.tau, rec.period_s, schemes=["supplied_energy"])["supplied_energy"]
    err = rel_err(res.theta)
    assert np.all(err[[0, 1, 2, 4]] < 0.02), err
    assert err[3] < 0.03, err
    assert np.all(err[[6, 7, 8]] < 0.10), err
    assert 0.10 < err[5] < 0.20, err  # θ6: the known miss


@pytest.mark.parametrize("scheme", SCHEMES)
def test_designed_excitation_meets_the_targets_with_every_scheme(recordings, scheme):
    """10 s of the shipped optimal-fourier excitation (hil excite): all three schemes, default
    robot, within the issue's targets, supplied energy included."""
    rec = recordings["designed"]
    res = identify(rec.q, rec.tau, rec.period_s, schemes=[scheme])[scheme]
    err = rel_err(res.theta)
    assert np.all(err[[0, 1, 2, 4]] < 0.02), err
    assert err[3] < 0.03, err
    assert np.all(err[5:] < 0.10), err


@pytest.mark.parametrize("scheme", SCHEMES)
def test_symmetric_coulomb_exact_mode_meets_the_tighter_targets(recordings, scheme):
    """With the model structure exact: θ1..θ5 within 1 %, θ6..θ9 within 5 % (all schemes)."""
    rec = recordings["symmetric"]
    res = identify(rec.q, rec.tau, rec.period_s, schemes=[scheme])[scheme]
    err = rel_err(res.theta)
    assert np.all(err[:5] < 0.01), err
    assert np.all(err[5:] < 0.05), err


def test_paper_discretization_biases_the_inertias(recordings):
    """The paper's filters and backward difference misalign the two sides in time: with the
    model structure exact, its filtered dynamic estimates of θ1..θ3 are several % low, and more
    so at λ = 2π·50 rad/s, while the exact mode is within 0.2 %."""
    rec = recordings["symmetric"]
    paper = identify(rec.q, rec.tau, rec.period_s, schemes=["filtered_dynamic"],
                     discretization="paper")["filtered_dynamic"]  # fmt: skip
    paper_314 = identify(rec.q, rec.tau, rec.period_s, schemes=["filtered_dynamic"],
                         discretization="paper", lam=2 * np.pi * 50)  # fmt: skip
    paper_314 = paper_314["filtered_dynamic"]
    exact = identify(rec.q, rec.tau, rec.period_s, schemes=["filtered_dynamic"])["filtered_dynamic"]
    signed = (paper.theta - REFERENCE) / REFERENCE
    assert np.all(signed[:3] < -0.03), signed
    assert np.all((paper_314.theta[:3] - REFERENCE[:3]) / REFERENCE[:3] < -0.2)
    assert np.all(rel_err(exact.theta)[:3] < 0.002)


def test_exact_regression_holds_with_the_true_parameters(recordings):
    """With the world's θ and the model structure exact, y − Ψθ is tiny against y."""
    rec = recordings["symmetric"]
    for scheme in SCHEMES:
        reg = build_regression(scheme, rec.q, rec.tau, rec.period_s, 50.0, "exact")
        resid = reg.y - np.einsum("kmp,p->km", reg.Psi, REFERENCE)
        used = reg.weights > 0
        ratio = np.linalg.norm(resid[used]) / np.linalg.norm(reg.y[used])
        assert ratio < 2e-3, (scheme, ratio)


def test_validation_prefers_identified_over_wrong_parameters(recordings):
    rec, held = recordings["symmetric"], recordings["held_out"]
    good = validate(REFERENCE, rec)
    assert max(good["position_nrmse"]) < 1e-3  # same physics: only the encoder differs
    wrong = REFERENCE.copy()
    wrong[0] *= 1.2
    bad = validate(wrong, rec)
    assert bad["position_nrmse"][0] > 10 * good["position_nrmse"][0]
    assert bad["torque_nrmse"][0] > 5 * good["torque_nrmse"][0]
    assert set(validate(REFERENCE, held)) >= {"position_nrmse", "torque_nrmse"}


def test_a_theta_the_simulator_refuses_is_validated_by_torque_only(recordings):
    """A least-squares θ may not be simulable (M(q) not positive definite, a negative Coulomb
    level): validated beside others, it gets no position error and one line saying why, its
    torque prediction still; the other θ get the numbers they get alone."""
    rec = recordings["default"]
    not_pd, negative_coulomb = REFERENCE.copy(), REFERENCE.copy()
    not_pd[2] = -0.01  # θ3 = M22 < 0
    negative_coulomb[8] = -0.5
    good, bad_m, bad_f = validate_many([REFERENCE, not_pd, negative_coulomb], rec)
    alone = validate(REFERENCE, rec)
    assert good["position_nrmse"] == alone["position_nrmse"]
    assert "simulation_not_possible" not in good
    for bad, why in ((bad_m, "not positive definite"), (bad_f, "Coulomb")):
        assert bad["position_nrmse"] is None and bad["simulated_q"] is None
        assert why in bad["simulation_not_possible"] and "\n" not in bad["simulation_not_possible"]
        assert all(np.isfinite(bad["torque_nrmse"]))


def test_cli_identify_both_keeps_the_schemes_it_can_simulate(tmp_path):
    """0.2 s of excitation at λ = 2000 rad/s: some schemes' θ have a negative Coulomb level or
    an indefinite M(q), which made `--discretization both` exit 2 with nothing written. Now
    exit 0: those schemes' validation says in one line why it was not simulated, every other
    result is kept."""
    run = tmp_path / "run"
    simulate(load_robot("cicese"), load_experiment("reyes-kelly"), run, duration_s=0.2, plot=False)
    out = tmp_path / "id"
    proc = _hil("identify", "--from", str(run), "--out", str(out), "--discretization", "both",
                "--lambda", "2000", "--no-plot")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((out / "identify.json").read_text())
    validations = {
        (disc, s): v["validation"]["fit"]
        for disc, entry in doc["discretizations"].items()
        for s, v in entry["schemes"].items()
    }
    refused = {k for k, v in validations.items() if "simulation_not_possible" in v}
    assert refused and refused != set(validations), validations
    for key, v in validations.items():
        assert (v["position_nrmse"] is None) == (key in refused)
        assert all(np.isfinite(v["torque_nrmse"]))
    said = [line for line in proc.stdout.splitlines() if "simulation not possible:" in line]
    assert len(said) == len(refused)
    # a discretization's parameter file only when its selected scheme's θ is an arm (issue 31)
    for disc, name in (("exact", "params.json"), ("paper", "params-paper.json")):
        usable = doc["discretizations"][disc]["schemes"]["filtered_dynamic"]["usable"]
        assert (out / name).is_file() == usable
    assert doc["selection"]["usable"] and (out / "params.json").is_file()


def test_cli_identify_on_rows_all_near_a_stick_gives_no_torque_error_for_that_joint(tmp_path):
    """0.08 s from rest at λ = 50 rad/s: every torque row of joint 2 holds its stuck start
    within the filter's memory, so there is nothing to compare it on. That stopped the
    command (exit 2, "nrmse: no samples"); now its torque NRMSE is null, printed –."""
    run = tmp_path / "run"
    simulate(load_robot("cicese"), load_experiment("reyes-kelly"), run, duration_s=0.08, plot=False)
    out = tmp_path / "id"
    proc = _hil("identify", "--from", str(run), "--out", str(out), "--lambda", "50",
                "--no-plot", "--json")  # fmt: skip
    doc = json.loads(proc.stdout)
    # 0.08 s is too little to identify an arm: the θ is not physical, FAILED, exit 1 (issue 31)
    assert proc.returncode == (0 if doc["selection"]["usable"] else 1), proc.stderr
    if not doc["selection"]["usable"]:  # nor is it read as parameters from identify.json
        with pytest.raises(ParamsError, match=r"filtered_dynamic: (not physically|FAILED)"):
            load_params(out / "identify.json")
    torque = doc["profile_validation"]["fit"]["torque_nrmse"]
    assert torque[1] is None and 0 < torque[0] < 1, torque


def test_table_ii_text_has_every_parameter(recordings):
    rec = recordings["default"]
    res = identify(rec.q, rec.tau, rec.period_s)
    text = format_table_ii(REFERENCE, res, title="t")
    assert "Supplied Energy" in text and "Filtered Dynamic" in text
    assert all(f"θ{i}" in text for i in range(1, 10))


# --- estimators -------------------------------------------------------------------------------


def test_rls_converges_to_least_squares_and_weights_drop_rows():
    rng = np.random.default_rng(1)
    theta = rng.normal(size=4) * [1, 10, 0.1, 3]
    Psi = rng.normal(size=(500, 2, 4))
    y = np.einsum("kmp,p->km", Psi, theta) + 1e-3 * rng.normal(size=(500, 2))
    ls = least_squares(Psi, y)
    hist = recursive_least_squares(Psi, y)
    assert np.allclose(hist[-1], ls, rtol=1e-5, atol=1e-6)
    assert np.allclose(ls, theta, atol=1e-3)
    # corrupt rows with weight 0 change nothing
    y_bad = y.copy()
    y_bad[:50] += 100.0
    w = np.ones(y.shape)
    w[:50] = 0.0
    assert np.allclose(least_squares(Psi, y_bad, w), least_squares(Psi[50:], y[50:]))
    assert np.allclose(recursive_least_squares(Psi, y_bad, w)[-1], hist[-1], rtol=1e-4, atol=1e-5)
    # scalar path equals the general update
    rls = RecursiveLeastSquares(4)
    for k in range(200):
        rls.update(Psi[k, :1], y[k, :1])
    assert np.allclose(recursive_least_squares(Psi[:200, :1], y[:200, :1])[-1], rls.theta)


def test_rls_keep_returns_exactly_the_full_history_at_those_rows():
    """Issue 13: the decimated history (``keep``) is the full one at those rows, bit for bit,
    on both paths (vector error, scalar error) and with rows weighted out."""
    rng = np.random.default_rng(3)
    Psi = rng.normal(size=(300, 2, 4))
    y = rng.normal(size=(300, 2))
    w = np.ones(y.shape)
    w[10:40] = 0.0
    keep = np.array([0, 5, 11, 39, 40, 150, 299])
    for P, Y, W in ((Psi, y, w), (Psi[:, :1], y[:, :1], w[:, :1])):
        full = recursive_least_squares(P, Y, W)
        kept = recursive_least_squares(P, Y, W, keep=keep)
        assert kept.shape == (len(keep), 4)
        assert np.array_equal(kept, full[keep])
    with pytest.raises(ValueError, match="keep must be increasing"):
        recursive_least_squares(Psi, y, keep=np.array([5, 3]))
    with pytest.raises(ValueError, match="keep must be increasing"):
        recursive_least_squares(Psi, y, keep=np.array([300]))


def test_interval_integrals_in_chunks_equal_the_whole(monkeypatch):
    """Issue 13: integrating the intervals chunk by chunk (bounded memory) gives the same bits
    as all at once, with a common interval and with each interval's own length."""
    from hil.model import regressors

    rng = np.random.default_rng(4)
    t = np.cumsum(0.0025 + 1e-4 * rng.random(1001))
    q = np.column_stack([np.sin(1.3 * t), 0.6 * np.cos(2.1 * t)])
    q[400:420, 1] = q[400, 1]  # a stuck stretch: its flags must survive the chunking
    v = regressors.central_difference(q, 0.0025)
    for h, chunk in [(h, c) for h in (0.0025, np.diff(t)) for c in (64, 256)]:
        monkeypatch.setattr(regressors, "INTERVAL_CHUNK", 10**9)
        whole = regressors.interval_integrals(q, v, h)
        monkeypatch.setattr(regressors, "INTERVAL_CHUNK", chunk)  # a power of two, as shipped
        chunked = regressors.interval_integrals(q, v, h)
        assert chunked.stuck.any()
        for f in ("k", "R", "friction_work", "stuck"):
            assert np.array_equal(getattr(chunked, f), getattr(whole, f)), f


def _sliding_joint(t: np.ndarray, tau: np.ndarray, inertia: float, viscous: float, coulomb: float):
    """A joint I q̈ = τ_k − b q̇ − F sliding forward under torques held over each interval,
    solved exactly (an exponential per interval): q, q̇ at the samples."""
    q, v = np.zeros(len(t)), np.zeros(len(t))
    v[0] = 5.0
    for k in range(len(t) - 1):
        h, lag = t[k + 1] - t[k], inertia / viscous
        v_end, decay = (tau[k] - coulomb) / viscous, np.exp(-(t[k + 1] - t[k]) / lag)
        v[k + 1] = v_end + (v[k] - v_end) * decay
        q[k + 1] = q[k] + v_end * h + (v[k] - v_end) * lag * (1 - decay)
    return q, v


@pytest.mark.parametrize(("stamps", "half_window", "left"), [("equal", 1, 0.1),
                         ("unequal", 1, 0.1), ("unequal", 3, 0.5)])  # fmt: skip
def test_held_torque_momentum_bias_removes_the_corner_error(stamps, half_window, left):
    """The ur5e's joint 6 (I = 2.6e-4 kg m², b = 0.02 N m s, F = 0.08 N m) sliding under held
    sines and 4 mN m quantization steps: the momentum balance over each interval, with the
    velocities of the exact discretization, misses by a quarter of the torque's second
    difference (2.5 mN m RMS; a false `unexplained` structure on the effect-free ur5e run).
    With the bias moved to the torque side the residual falls to a tenth (three-point) or half
    (local quadratic, whose own curvature error is larger); on equal intervals b = h/4 Δτ."""
    from hil.model import regressors

    rng = np.random.default_rng(3)
    h, n, inertia, viscous, coulomb = 0.0025, 2000, 2.6e-4, 0.02, 0.08
    t = np.arange(n) * h if stamps == "equal" else np.cumsum(h * (1 + 0.2 * rng.random(n)))
    tau = 0.3 + 0.1 * np.sin(35 * t) + 0.06 * np.sin(24 * t) + 0.004 * np.round(rng.normal(size=n))
    q, v = _sliding_joint(t, tau, inertia, viscous, coulomb)
    assert v.min() > 0  # sliding throughout: no stick, no reversal
    times = None if stamps == "equal" else t
    vh = regressors.sample_velocities(q[:, None], h, times, half_window)[:, 0]
    bias = regressors.held_torque_momentum_bias(tau[:, None], h, times, half_window)[:, 0]
    dt = np.diff(t)
    rows = slice(half_window, n - half_window - 1)
    model = inertia * np.diff(vh) / dt + viscous * np.diff(q) / dt + coulomb
    before = np.sqrt(np.mean((tau[:-1] - model)[rows] ** 2))
    after = np.sqrt(np.mean((tau[:-1] + np.diff(bias) / dt - model)[rows] ** 2))
    assert before > 2e-3 and after < left * before, (before, after)
    if stamps == "equal":
        np.testing.assert_allclose(bias[1:-1], h / 4 * (tau[1:-1] - tau[:-2]), atol=1e-12)


def test_weighted_least_squares_balances_channels():
    """Channel 2 has 100× less noise: WLS uses it, plain LS is dominated by channel 1."""
    rng = np.random.default_rng(2)
    theta = np.array([1.0, -2.0])
    Psi = rng.normal(size=(2000, 2, 2))
    y = np.einsum("kmp,p->km", Psi, theta)
    y[:, 0] += rng.normal(size=2000) * 1.0
    y[:, 1] += rng.normal(size=2000) * 0.01
    err_ls = np.linalg.norm(least_squares(Psi, y) - theta)
    err_wls = np.linalg.norm(weighted_least_squares(Psi, y) - theta)
    assert err_wls < 0.2 * err_ls


def test_weighted_least_squares_on_fewer_rows_than_its_window():
    """130 rows, window 200 (a 5 s recording's fit part): the noise window shrinks to the rows
    (np.convolve's "same" mode would return 200 values and fail to broadcast)."""
    rng = np.random.default_rng(3)
    theta = np.array([1.0, -2.0])
    Psi = rng.normal(size=(130, 2, 2))
    y = np.einsum("kmp,p->km", Psi, theta) + rng.normal(size=(130, 2)) * 0.01
    assert np.allclose(weighted_least_squares(Psi, y, window=200), theta, atol=0.01)


def test_rls_rejects_bad_settings():
    with pytest.raises(ValueError, match="forgetting"):
        RecursiveLeastSquares(3, forgetting=1.5)
    with pytest.raises(ValueError, match="P\\(0\\)"):
        RecursiveLeastSquares(3, p0=0)


# --- online RLS -------------------------------------------------------------------------------


@pytest.mark.parametrize("discretization", ["exact", "paper"])
def test_online_rls_equals_batch_rls(recordings, discretization):
    rec = recordings["default"]
    n = 1200
    online = OnlineIdentifier(rec.period_s, discretization=discretization)
    for q, tau in zip(rec.q[:n], rec.tau[:n], strict=True):
        online.push(q, tau)
    for scheme in SCHEMES:
        reg = build_regression(scheme, rec.q[:n], rec.tau[:n], rec.period_s, 50.0, discretization)
        batch = recursive_least_squares(reg.Psi, reg.y, reg.weights)[-1]
        assert online.streams[scheme].rows == len(reg.y)
        assert np.allclose(online.theta[scheme], batch, rtol=1e-7, atol=1e-9), scheme
    assert online.cost_per_sample_s() > 0


# --- bad input --------------------------------------------------------------------------------


def test_bad_input_is_refused_with_a_clear_error():
    q = np.zeros((100, 2))
    with pytest.raises(ValueError, match="unknown scheme"):
        build_regression("energy", q, q, 0.0025)
    with pytest.raises(ValueError, match="at least 8"):
        build_regression("filtered_power", q[:5], q[:5], 0.0025)
    bad = q.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="finite"):
        build_regression("filtered_dynamic", bad, q, 0.0025)
    with pytest.raises(ValueError, match="lambda"):
        build_regression("filtered_dynamic", q, q, 0.0025, lam=-1)
    with pytest.raises(ValueError, match="discretization"):
        build_regression("filtered_dynamic", q, q, 0.0025, discretization="tustin")
    with pytest.raises(ValueError, match="shape"):
        build_regression("filtered_dynamic", q, q[:, :1], 0.0025)


# --- CLI --------------------------------------------------------------------------------------


def _hil(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "hil.cli", *args], capture_output=True, text=True, timeout=300
    )


def test_cli_identify_from_recordings(recordings, tmp_path):
    rec, held = recordings["default"], recordings["held_out"]
    out = tmp_path / "id"
    proc = _hil("identify", "--from", str(rec.path), "--validate", str(held.path),
                "--out", str(out), "--discretization", "both", "--json")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    table = doc["discretizations"]["exact"]["table_ii"]
    assert [row["parameter"] for row in table] == [f"theta{i}" for i in range(1, 10)]
    fd = doc["discretizations"]["exact"]["schemes"]["filtered_dynamic"]
    assert max(abs(e) for e in fd["relative_error"][:3]) < 0.02
    assert set(fd["validation"]) == {"fit", "held_out"}
    assert all(0 <= x < 0.2 for x in fd["validation"]["held_out"]["position_nrmse"])
    params = load_params(out / "params.json")
    assert params.scheme == "filtered_dynamic"
    assert np.allclose(params.theta, fd["theta"])
    assert load_params(out / "params-paper.json", scheme="filtered_power").theta.shape == (9,)
    # identify.json holds the same θ: read as a parameter file (issue 29 item 2b)
    from_report = load_params(out / "identify.json")
    assert from_report.scheme == "filtered_dynamic"
    assert np.array_equal(from_report.theta, params.theta)
    assert np.array_equal(
        load_params(out / "identify.json", scheme="filtered_power").theta,
        load_params(out / "params.json", scheme="filtered_power").theta,
    )
    proc = _hil("diagnose", str(held.path), "--robot", "cicese", "--params",
                str(out / "identify.json"), "--json", "--no-plots")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["summary"]
    for png in ("theta-exact-filtered_power.png", "validation-paper-supplied_energy.png"):
        assert (out / png).stat().st_size > 10_000


def test_cli_identify_over_the_bench_with_online_rls(tmp_path):
    """End to end over a bench: short excitation, online RLS during the run equals the batch."""
    out = tmp_path / "bench"
    proc = _hil("identify", "--bench", "virtual-inprocess", "--duration", "2", "--out", str(out),
                "--validation-experiment", "none", "--no-plot", "--json")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    assert doc["rows"] == 800
    assert max(doc["online"]["max_relative_difference_to_batch_rls"].values()) < 1e-6
    assert (out / "fit" / "signals.csv").is_file() and (out / "params.json").is_file()


def test_cli_identify_errors_are_one_line(tmp_path):
    proc = _hil("identify", "--from", str(tmp_path / "missing"), "--json")
    assert proc.returncode == 2
    assert proc.stdout == ""
    assert proc.stderr.count("\n") == 1 and "missing" in proc.stderr
    proc = _hil("identify", "--from", str(tmp_path), "--schemes", "foo")
    assert proc.returncode == 2 and "unknown scheme" in proc.stderr


def test_cli_identify_from_a_recording_with_a_gap_fits_each_segment_never_across(
    recordings, tmp_path
):
    """400 rows cut out of the 10 s run (a realtime run's stall looks the same on its real
    times): `hil identify --from` fits the two segments' rows together, none across the gap, and
    validates each segment from its own start; bridging the gap as if the rows were adjacent
    spoils θ."""
    rec = recordings["default"]
    keep = np.r_[0:1200, 1600 : len(rec)]
    path = tmp_path / "gap.csv"
    with path.open("w") as f:
        f.write("t,q1,q2,tau1,tau2\n")
        for k in keep:
            f.write(",".join(repr(float(x)) for x in (rec.t[k], *rec.q[k], *rec.tau[k])) + "\n")
    out = tmp_path / "id"
    proc = _hil("identify", "--from", str(path), "--out", str(out), "--no-plot", "--json",
                "--validation-experiment", "none")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "2 segments between gaps" in proc.stderr
    doc = json.loads(proc.stdout)
    fd = doc["discretizations"]["exact"]["schemes"]["filtered_dynamic"]
    assert max(abs(e) for e in fd["relative_error"][:5]) < 0.02
    assert all(0 <= x < 0.2 for x in fd["validation"]["fit"]["position_nrmse"])
    # the same rows with the gap bridged (one segment of k·h rows): far off
    bridged = identify(rec.q[keep], rec.tau[keep], rec.period_s, schemes=["filtered_dynamic"])
    err = np.abs(rel_err(bridged["filtered_dynamic"].theta)[:5])
    assert err.max() > 5 * max(abs(e) for e in fd["relative_error"][:5])
