"""The screen of a drift pattern's many starting points (issue 26, performance): a cogging's
periods fitted all at once from one pass over their columns (hil.diagnose.drift.fit.Fit.screen)
keep the starts the one-by-one fits rank best, and the refinement ends at the same period,
against a profile and block-paired against a reference's rerun of the motion."""

from __future__ import annotations

import numpy as np
import pytest

import hil.diagnose.drift.fit as drift_fit
from hil.diagnose.drift.fit import make_fit, same_motion
from hil.diagnose.drift.terms import Term
from hil.diagnose.effects import REGISTRY
from hil.diagnose.problem import build_problem
from hil.diagnose.stats import block_stats, cross_validate, full_fit_sse
from hil.model.closed_form import ArmModel

THETA = np.array([0.36, 0.068, 0.036, 38.0, 1.8, 0.175, 0.02, 1.1, 0.6])  # 9 parameters


def _recording(rng: np.random.Generator, cogging_nm: float) -> tuple[np.ndarray, ...]:
    """6 s at 1 kHz of a multisine on both joints, the model's torque with a 23-period
    cogging of ``cogging_nm`` on joint 1 and sensor noise."""
    model, h = ArmModel(()), 1e-3
    t = np.arange(6_000) * h
    freq = 2 * np.pi * np.array([[0.71, 1.37, 1.93], [0.89, 1.43, 2.11]])[:, :, None]
    amp = np.array([[0.9, 0.5, 0.3], [0.8, 0.4, 0.3]])[:, :, None]
    phase = freq * t + 1.0  # (joint, sine, sample)
    q = (amp * np.sin(phase)).sum(axis=1).T
    dq = (amp * freq * np.cos(phase)).sum(axis=1).T
    ddq = -(amp * freq**2 * np.sin(phase)).sum(axis=1).T
    tau = model.torque(THETA, q, dq, ddq)
    tau[:, 0] -= cogging_nm * np.sin(23 * q[:, 0] + 0.7)
    tau += rng.normal(0, 0.02, tau.shape)
    q = q + rng.normal(0, 1e-5, q.shape)
    return q, tau, h


def _loop_errors(fit, terms, only, starts) -> np.ndarray:
    """The in-sample error refine compares starts by, each start built and fitted alone."""
    out = []
    for s in starts:
        only.at = s
        fit.build(only)
        out.append(float(fit.judged_cv(terms).sse.sum()))
    return np.array(out)


def test_full_fit_sse_is_cross_validations_full_data_error():
    rng = np.random.default_rng(1)
    K, n, p = 600, 2, 4
    Z, y = rng.normal(size=(K, n, p)), rng.normal(size=(K, n))
    w = (rng.uniform(size=(K, n)) > 0.1).astype(float)
    blocks = np.repeat(np.arange(6), K // 6)
    cv = cross_validate(block_stats(Z, y, w, blocks))
    G = np.einsum("kn,knp,knq->pq", w, Z, Z)
    r = np.einsum("kn,knp,kn->p", w, Z, y)
    got = full_fit_sse(G[None], r[None], float(np.sum(w * y * y)))
    np.testing.assert_allclose(got[0], cv.sse.sum(), rtol=1e-10)


@pytest.mark.parametrize("against", ["profile", "reference"])
def test_screen_keeps_the_best_starts_and_refine_ends_at_the_same_period(against, monkeypatch):
    rng = np.random.default_rng(7)
    model = ArmModel(())
    prob, _ = build_problem([_recording(rng, 0.05)], model)
    fit = make_fit(prob, model, THETA)
    if against == "reference":
        ref, _ = build_problem([_recording(rng, 0.0)], model)
        fit.reference = make_fit(ref, model, THETA)
        fit.paired = same_motion(prob, ref)
        assert fit.paired
    cogging = REGISTRY["cogging"]
    gain = fit.build(Term(REGISTRY["torque_gain"], 1, None))  # another term beside it
    only = fit.build(Term(cogging, 0, cogging.start(fit.ctx, 0)))
    starts = cogging.starts(fit.ctx, 0)
    assert len(starts) > 100
    kept = fit.screen([gain, only], only, starts)
    errors = _loop_errors(fit, [gain, only], only, starts)
    best = sorted(np.argsort(errors, kind="stable")[: drift_fit.SCREEN_KEPT])
    assert kept == [starts[i] for i in best]
    assert kept[int(np.argmin(errors[best]))] == 23.0

    def refined(screen: bool) -> Term:
        if not screen:  # every start fitted one by one
            monkeypatch.setattr(drift_fit, "SCREEN_KEPT", len(starts))
        term = fit.build(Term(cogging, 0, cogging.start(fit.ctx, 0)))
        fit.refine([gain, term], only=term)
        monkeypatch.undo()
        return term

    with_screen, without = refined(True), refined(False)
    assert with_screen.at == without.at == 23.0
    np.testing.assert_array_equal(with_screen.cols, without.cols)
