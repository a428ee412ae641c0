"""The URDF torque scheme near friction steps (hil.identify.urdf): which rows lie near a stick
or a reversal, which joints' equations the data say to leave out there, and the per-parameter
uncertainty that turns an undetermined parameter into "not identifiable"."""

from __future__ import annotations

import numpy as np

from hil.identify.urdf import (
    IDENTIFIED_MAX_RELATIVE_SE,
    FilteredRows,
    friction_step_samples,
    leave_out_friction_steps,
    parameter_uncertainty,
)
from hil.model.estimators import BlockNormalEquations

RNG = np.random.default_rng(7)


def test_samples_near_a_reversal_or_a_stick_are_marked_within_the_margin():
    t = np.arange(0.0, 1.0, 0.001)
    dq = np.stack([np.sin(2 * np.pi * t), np.ones_like(t)], axis=1)  # reverses at t = 0.5
    stuck = np.zeros_like(dq, dtype=bool)
    stuck[800:820, 1] = True  # joint 2 sticks for 20 ms
    near = friction_step_samples(t, stuck, dq, margin_s=0.03)
    expect1 = np.abs(t - 0.5) <= 0.03 + 1e-9
    assert np.count_nonzero(near[:, 0] != expect1) <= 1  # the crossing lies between two samples
    assert near[771:849, 1].all() and not near[:769, 1].any() and not near[851:, 1].any()


def _rows(near: np.ndarray, residual_scale_near: np.ndarray) -> tuple[FilteredRows, np.ndarray]:
    K, n, p = len(near), near.shape[1], 3
    Y = RNG.normal(size=(K, n, p))
    theta = np.array([1.0, -2.0, 0.5])
    noise = RNG.normal(size=(K, n)) * np.where(near, residual_scale_near, 1.0) * 0.01
    tau = np.einsum("knp,p->kn", Y, theta) + noise
    return FilteredRows(np.arange(K) * 0.025, tau, Y, near, np.ones((K, n))), theta


def test_only_joints_whose_residual_grows_near_steps_are_left_out():
    near = RNG.random((2000, 3)) < 0.3
    near[:, 2] = RNG.random(2000) < 0.97  # joint 3: hardly a row away from its steps
    rows, theta = _rows(near, np.array([8.0, 1.0, 8.0]))
    left_out, ratio = leave_out_friction_steps(rows, theta)
    assert left_out.tolist() == [True, False, False], ratio
    assert ratio[0] > 5 and 0.8 < ratio[1] < 1.25 and np.isnan(ratio[2])
    weights = rows.leaving_out(left_out).weights
    assert np.array_equal(weights[:, 0] == 0, near[:, 0]) and np.all(weights[:, 1:] == 1)


def test_a_parameter_the_rows_do_not_determine_is_not_identified():
    """Two columns almost alike: their difference is barely in the data, so each one's
    blocked-bootstrap SE exceeds half its size; a clean column stays identified."""
    K = 4000
    t = np.arange(K) * 0.01
    a = RNG.normal(size=K)
    Y = np.stack([a, a + 1e-4 * RNG.normal(size=K), RNG.normal(size=K)], axis=1)[:, None, :]
    theta = np.array([0.3, 0.2, 1.0])
    y = (Y @ theta) + 0.05 * RNG.normal(size=(K, 1))
    blocks = BlockNormalEquations(3, 1, 0.5)
    blocks.add(t, y, Y, np.ones((K, 1)))
    fit = np.linalg.lstsq(Y[:, 0, :], y[:, 0], rcond=None)[0]
    u = parameter_uncertainty(blocks, fit)
    assert u.identified.tolist() == [False, False, True], (fit, u.se_block)
    assert np.all(u.se_block[:2] > IDENTIFIED_MAX_RELATIVE_SE * np.abs(fit[:2]))
    assert u.blocks == 80 and u.as_json()["identified"] == [False, False, True]
