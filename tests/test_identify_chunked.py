"""Identification in bounded memory (issue 13): every estimate and validation number computed
from rows in chunks equals the one computed from all rows at once.

The recording is 3 s of eqs. (31)-(32) (1200 rows, stick-slip included); chunks of 97 or 256
rows make it many chunks long, and chunks of 37 rows are shorter than the weighted refit's
moving window (200 rows), so its look-ahead spans several chunks.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from drivers.recording import read_signals
from hil.identify.schemes import identify, validate, validate_many
from hil.model.estimators import (
    LeastSquaresRows,
    RecursiveLeastSquares,
    RecursiveLeastSquaresRows,
    ResidualLevel,
    WeightedRefit,
    least_squares,
    recursive_least_squares,
    weighted_least_squares,
)
from hil.model.metrics import NrmseAccumulator, nrmse
from hil.model.openloop import simulate_open_loop, simulate_open_loop_chunks
from hil.model.params import robot_params
from hil.model.regressors import SCHEMES, build_regression, iter_regression
from profiles.experiment import load_experiment
from profiles.robot import load_robot
from virtual_robot.simulate import simulate

WHOLE = 10**9  # a chunk longer than any recording here: all rows at once


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    d = tmp_path_factory.mktemp("chunked")
    simulate(
        load_robot("cicese"),
        load_experiment("reyes-kelly"),
        d,
        duration_s=3.0,
        plot=False,
    )
    return read_signals(d)


def relative(a: np.ndarray, b: np.ndarray) -> float:
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape
    scale = np.maximum(np.abs(b), 1e-300)
    return float(np.max(np.abs(a - b) / scale)) if a.size else 0.0


def chunks_of(n: int, size: int):
    return [slice(i, min(i + size, n)) for i in range(0, n, size)]


@pytest.mark.parametrize("discretization", ["exact", "paper", "irregular"])
@pytest.mark.parametrize("scheme", SCHEMES)
def test_rows_in_chunks_are_the_whole_recordings(rec, scheme, discretization) -> None:
    t = None
    disc = discretization
    if discretization == "irregular":  # real time stamps: intervals of 0.9 h to 1.1 h
        rng = np.random.default_rng(3)
        t = np.cumsum(np.r_[0.0, rec.period_s * rng.uniform(0.9, 1.1, len(rec) - 1)])
        disc = "exact"
    whole = build_regression(scheme, rec.q, rec.tau, rec.period_s, 50.0, disc, t=t)
    parts = list(iter_regression(scheme, rec.q, rec.tau, rec.period_s, 50.0, disc, t=t, chunk=256))
    assert len(parts) >= 4
    for f in ("t", "y", "Psi", "weights"):
        joined = np.concatenate([getattr(c, f) for c in parts])
        assert relative(joined, getattr(whole, f)) < 1e-12, f
    if scheme == "filtered_dynamic" and discretization == "exact":
        # the stick memory crosses chunk borders: some rows are excluded, and the same ones
        assert 0 < np.sum(whole.weights == 0) < whole.weights.size


@pytest.mark.parametrize("discretization", ["exact", "paper"])
@pytest.mark.parametrize("scheme", SCHEMES)
def test_identify_in_chunks_equals_all_at_once(rec, scheme, discretization) -> None:
    args = (rec.q, rec.tau, rec.period_s)
    whole = identify(*args, schemes=[scheme], discretization=discretization, chunk=WHOLE)[scheme]
    parts = identify(*args, schemes=[scheme], discretization=discretization, chunk=97)[scheme]
    for f in ("theta_rls", "theta_ls", "theta_wls", "history", "history_t"):
        assert relative(getattr(parts, f), getattr(whole, f)) < 1e-9, f
    assert (parts.rows, parts.rows_excluded) == (whole.rows, whole.rows_excluded)


def test_estimators_over_chunks_equal_the_whole_regression(rec) -> None:
    """The in-memory estimators are the chunked ones over one chunk; chunks shorter than the
    weighted refit's window (37 < 200 rows) still give the same fit."""
    reg = build_regression("filtered_dynamic", rec.q, rec.tau, rec.period_s, 50.0, "exact")
    K, m, p = reg.Psi.shape
    pieces = chunks_of(K, 37)
    ls = LeastSquaresRows(p)
    for s in pieces:
        ls.add(reg.Psi[s], reg.y[s], reg.weights[s])
    theta_ls = least_squares(reg.Psi, reg.y, reg.weights)
    assert relative(ls.solve(), theta_ls) < 1e-9
    # the old lstsq on the scaled rows (what least squares was before issue 13)
    sw = np.sqrt(reg.weights.reshape(-1))
    A = reg.Psi.reshape(K * m, p) * sw[:, None]
    scale = np.linalg.norm(A, axis=0)
    ref = np.linalg.lstsq(A / scale, reg.y.reshape(-1) * sw, rcond=None)[0] / scale
    assert relative(theta_ls, ref) < 1e-9

    level = ResidualLevel(theta_ls, m)
    for s in pieces:
        level.add(reg.Psi[s], reg.y[s], reg.weights[s])
    refit = WeightedRefit(theta_ls, level.level(), K)
    for s in pieces:
        refit.add(reg.Psi[s], reg.y[s], reg.weights[s])
    assert relative(refit.solve(), weighted_least_squares(reg.Psi, reg.y, reg.weights)) < 1e-9

    keep = np.array([0, 5, 36, 37, 500, K - 1])
    rls = RecursiveLeastSquaresRows(p, m, K, keep=keep)
    for s in pieces:
        rls.add(reg.Psi[s], reg.y[s], reg.weights[s])
    whole = recursive_least_squares(reg.Psi, reg.y, reg.weights)
    np.testing.assert_array_equal(rls.history, whole[keep])  # the same loop: bit for bit


def test_weighted_refit_window_matches_the_whole_arrays_moving_mean() -> None:
    """The variance each row gets is np.convolve(r², window, "same") of all rows, zeros beyond
    both ends, whatever the chunking: a fit whose weights depend on it tells."""
    rng = np.random.default_rng(0)
    K, p = 450, 3
    Psi = rng.normal(size=(K, 1, p))
    noise = np.where(np.arange(K) < 200, 0.01, 1.0) * rng.normal(size=K)  # two noise levels
    y = Psi[:, :, 0] + noise[:, None]
    theta0 = least_squares(Psi, y)
    r2 = (y[:, 0] - Psi[:, 0] @ theta0) ** 2
    var = np.maximum(np.convolve(r2, np.ones(200) / 200, "same"), 1e-6 * r2.mean() + 1e-300)
    expected = least_squares(Psi, y, 1.0 / var[:, None])
    for size in (1, 37, 99, 100, 450):
        level = ResidualLevel(theta0, 1)
        level.add(Psi, y)
        refit = WeightedRefit(theta0, level.level(), K)
        for s in chunks_of(K, size):
            refit.add(Psi[s], y[s])
        assert relative(refit.solve(), expected) < 1e-9, size


def test_validation_in_chunks_equals_all_at_once(rec) -> None:
    theta = robot_params("cicese").theta
    whole = validate(theta, rec, chunk=WHOLE)
    parts = validate(theta, rec, chunk=97)
    for key in ("position_nrmse", "position_max_error_rad", "torque_nrmse"):
        assert relative(parts[key], whole[key]) < 1e-9, key
    np.testing.assert_array_equal(parts["simulated_q"], whole["simulated_q"])
    sim = simulate_open_loop(theta, rec.tau, rec.period_s, q0=rec.q[0])
    pieces = list(simulate_open_loop_chunks(theta, rec.tau, rec.period_s, q0=rec.q[0], chunk=97))
    np.testing.assert_array_equal(np.concatenate([c.q for c in pieces]), sim.q)
    assert pieces[-1].substeps == sim.substeps


def test_validation_of_several_thetas_shares_the_rows_and_changes_no_bit(rec) -> None:
    """`hil identify` validates every scheme's θ and the profile's in one call: the torque rows
    built once for all, each θ's simulation its own; every number as validate() gives it for
    that θ alone, bit for bit, chunked or not (and the θ do differ in their results)."""
    fits = identify(rec.q, rec.tau, rec.period_s, chunk=256)
    thetas = [fits[s].theta for s in SCHEMES] + [robot_params("cicese").theta]
    for chunk in (97, WHOLE):
        together = validate_many(thetas, rec, chunk=chunk, stages=list("abcd"))
        for theta, shared in zip(thetas, together, strict=True):
            alone = validate(theta, rec, chunk=chunk)
            assert shared.keys() == alone.keys()
            for key, value in alone.items():
                assert np.asarray(shared[key]).tobytes() == np.asarray(value).tobytes(), key
        assert len({tuple(v["torque_nrmse"]) for v in together}) == len(thetas)
    with pytest.raises(ValueError, match="stage names"):
        validate_many(thetas, rec, stages=["only one"])


def test_validation_plot_points_are_bounded(rec, monkeypatch) -> None:
    import hil.identify.schemes as schemes

    theta = robot_params("cicese").theta
    full = simulate_open_loop(
        theta, rec.tau, rec.period_s, q0=rec.q[0], dq0=schemes.initial_velocity(rec)
    )
    monkeypatch.setattr(schemes, "PLOT_POINTS", 100)
    for chunk in (97, WHOLE):
        few = schemes.validate(theta, rec, chunk=chunk)
        rows = few["simulated_rows"]
        assert len(rows) <= 100 and rows[-1] >= len(rec) - 13
        np.testing.assert_array_equal(few["simulated_q"], full.q[rows])


def test_nrmse_accumulated_over_chunks() -> None:
    rng = np.random.default_rng(1)
    y = rng.normal(size=(1000, 2)) * [1.0, 1e-3] + [5.0, 1e3]  # far-off means: cancellation
    y_hat = y + rng.normal(size=(1000, 2)) * 0.1
    acc = NrmseAccumulator()
    for s in chunks_of(1000, 77):
        acc.add(y[s], y_hat[s])
    assert relative(acc.result(), nrmse(y, y_hat)) < 1e-9
    one = NrmseAccumulator()
    one.add(y, y_hat)
    np.testing.assert_array_equal(one.result(), nrmse(y, y_hat))
    const = NrmseAccumulator()
    for s in chunks_of(10, 3):
        const.add(np.ones(10)[s], np.zeros(10)[s])
    assert np.isnan(const.result())


def test_identify_memory_does_not_grow_with_the_rows(rec) -> None:
    """Beyond the recording itself, identification and validation hold O(chunk) memory: four
    times the rows cost less than 200 B a row more at their peak (tracemalloc; the whole
    regression was about 1 KB a row before issue 13). Not a speed or size target (those are
    in tests/benchmarks/bench_identify_memory.py): a structural check that no pass keeps all
    rows."""
    import dataclasses
    import tracemalloc

    def peak(copies: int) -> int:
        q = np.concatenate([rec.q] * copies)  # joins jump: harmless for a memory count
        tau = np.concatenate([rec.tau] * copies)
        longer = dataclasses.replace(
            rec,
            columns={
                "t": np.arange(len(q)) * rec.period_s,
                "q1": q[:, 0].copy(),
                "q2": q[:, 1].copy(),
                "tau1": tau[:, 0].copy(),
                "tau2": tau[:, 1].copy(),
            },
        )
        tracemalloc.start()
        tracemalloc.reset_peak()
        base = tracemalloc.get_traced_memory()[0]
        res = identify(q, tau, rec.period_s, schemes=["filtered_dynamic"], chunk=256)
        assert res["filtered_dynamic"].rows == len(q) - 3
        validate(robot_params("cicese").theta, longer, chunk=256)
        top = tracemalloc.get_traced_memory()[1] - base
        tracemalloc.stop()
        return top

    short, long = peak(1), peak(4)
    added_rows = 3 * len(rec)
    assert (long - short) / added_rows < 200, (short, long)


def test_vector_rls_over_chunks_is_the_online_update_bit_for_bit() -> None:
    """The chunk loop of RecursiveLeastSquaresRows for vector errors (issue 13: its per-row cost
    was most of a long recording's identification) does the floating-point operations of
    RecursiveLeastSquares.update, the online identifier's step, in the same order: θ̂(k) and P
    equal to the last bit, with rows of weight 0, partial weights and chunks of odd lengths."""
    m = 2
    rng = np.random.default_rng(m)
    K, p = 1500, 9
    Psi = rng.normal(size=(K, m, p)) * np.array([1, 0.1, 0.1, 40, 2, 2, 0.2, 7, 1])
    y = rng.normal(size=(K, m)) * 10
    w = (rng.random((K, m)) > 0.1).astype(float)
    w[::7] = 0.0
    w[5::11, 0] = 0.3
    online = RecursiveLeastSquares(p)
    expected = np.array([online.update(Psi[k], y[k], w[k]).copy() for k in range(K)])
    rows = RecursiveLeastSquaresRows(p, m, K)
    for a in range(0, K, 97):
        rows.add(Psi[a : a + 97], y[a : a + 97], w[a : a + 97])
    np.testing.assert_array_equal(rows.history, expected)
    np.testing.assert_array_equal(rows.rls.P, online.P)
    assert rows.rls.updates == online.updates


def test_progress_is_told_every_pass_to_its_end(rec) -> None:
    """identify() and validate() tell how far each pass is after every chunk of rows: per
    scheme least squares, RLS, the weighted refit, then validation's simulation and torque
    rows, each counting up to its total (what `hil identify` prints on a long recording)."""
    calls: list[tuple[str, int, int]] = []
    identify(rec.q, rec.tau, rec.period_s, schemes=["filtered_dynamic", "supplied_energy"],
             chunk=256, progress=lambda *a: calls.append(a))  # fmt: skip
    validate(robot_params("cicese").theta, rec, chunk=256, progress=lambda *a: calls.append(a))
    stages = list(dict.fromkeys(stage for stage, _, _ in calls))
    assert stages == [
        "filtered_dynamic: least squares",
        "filtered_dynamic: recursive least squares",
        "filtered_dynamic: weighted least squares",
        "supplied_energy: least squares",
        "supplied_energy: recursive least squares",
        "supplied_energy: weighted least squares",
        "validation: open-loop simulation",
        "validation: torque prediction",
    ]
    for stage in stages:
        done = [d for s, d, _ in calls if s == stage]
        total = {t for s, _, t in calls if s == stage}
        assert len(done) > 2 and done == sorted(done) and len(total) == 1, stage
        # each pass ends at its total (least squares: rows against samples, 3 fewer)
        assert 0 <= total.pop() - done[-1] <= 3, stage


def test_hil_identify_progress_on_stderr_only(rec, tmp_path) -> None:
    """A long recording's stages say how far they are on stderr (here every chunk:
    --progress-every 0), stdout stays one JSON document; -q silences them."""
    from cli_run import hil

    argv = ["identify", "--from", str(rec.path), "--no-plot", "--json", "--overwrite"]
    loud = hil(*argv, "--out", str(tmp_path / "a"), "--progress-every", "0")
    assert loud.returncode == 0, loud.stderr
    json.loads(loud.stdout)
    lines = [x for x in loud.stderr.splitlines() if " rows (" in x]
    assert any("filtered_power: recursive least squares:" in x for x in lines), loud.stderr
    assert any(x.endswith("rows (100 %)") and "open-loop simulation" in x for x in lines)
    quiet = hil(*argv, "--out", str(tmp_path / "b"), "--progress-every", "0", "-q")
    assert quiet.returncode == 0, quiet.stderr
    assert " rows (" not in quiet.stderr
    assert json.loads(quiet.stdout)["rows"] == json.loads(loud.stdout)["rows"]


def test_least_squares_rows_are_svd_least_squares_where_it_matters():
    """The corrected semi-normal equations (hil.model.estimators.least_squares_rows) give the
    SVD least squares of tall rows whose columns differ by six orders of magnitude to 1e-10,
    a column zero on every row exactly 0, where the columns are dependent (the normal matrix
    singular) the SVD's minimum-norm solution to 1e-10, and where they are nearly but not
    exactly dependent the SVD's answer itself."""
    from hil.model.estimators import least_squares_rows

    rng = np.random.default_rng(7)
    A = rng.normal(size=(20_000, 12)) * np.logspace(-3, 3, 12)
    A[:, 4] = 0.0
    b = A @ rng.normal(size=12) + rng.normal(size=20_000)
    expected = np.linalg.lstsq(A, b, rcond=None)[0]
    expected[4] = 0.0  # lstsq's is 1e-13 of either sign
    got = least_squares_rows(A, b)
    assert got[4] == 0.0
    np.testing.assert_allclose(got, expected, rtol=1e-10, atol=0)
    A[:, 5] = A[:, 6]  # dependent: no unique θ
    A[:, 8] = -3.0 * A[:, 2]  # dependent columns of other scales
    got = least_squares_rows(A, b)
    expected = np.where(np.arange(12) == 4, 0.0, np.linalg.lstsq(A, b, rcond=None)[0])
    assert got[4] == 0.0
    np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-12)
    assert got[5] == pytest.approx(got[6], rel=1e-10)  # the minimum norm splits them evenly
    A[:, 5] += 1e-6 * rng.normal(size=20_000) * np.abs(A[:, 6]).mean()  # nearly dependent
    np.testing.assert_array_equal(
        least_squares_rows(A, b),
        np.where(np.arange(12) == 4, 0.0, np.linalg.lstsq(A, b, rcond=None)[0]),
    )
