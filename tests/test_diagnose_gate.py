"""The diagnosis's simulation gate (issue 12, "Never a confident wrong answer"): a finding must
improve the held-out simulated motion, judged beyond noise (docs/diagnosis.md, 4b).

The gate's statistic is :func:`hil.diagnose.gates.worse_beyond_noise`: a rise of the held-out
simulated-position NRMSE is a worsening only beyond the relative tolerance plus the
simulation's sensitivity to the model's own held-out torque error. With a bare 2 % relative
test, four true blind-set terms and a closed-loop gain were dropped for rises of 0.07-0.53
points on fits at 0.1-0.3 %.
"""

from __future__ import annotations

import math

import pytest
from diagnose_cases import diagnose_capturing_gate, make_recording

from drivers.recording import read_signals
from hil.diagnose.findings import Finding
from hil.diagnose.gates import SIMULATION_TOLERANCE, worse_beyond_noise
from hil.diagnose.heldout import before_after
from hil.diagnose.interpret import cogging_at_true_angle
from hil.diagnose.pipeline import diagnose
from hil.model.params import robot_params

REFERENCE = robot_params("cicese").theta


@pytest.fixture(scope="module")
def gate_inputs(tmp_path_factory):
    """The default robot over `diagnosis` (joint 1's asymmetry), diagnosed; the gate's inputs
    and the with/without fits it compares."""
    rec = make_recording(tmp_path_factory.mktemp("gate") / "rec", "diagnosis", None)
    doc, args = diagnose_capturing_gate(read_signals(rec), REFERENCE)
    prob, accepted, findings, nominal_theta, se, shaft = args
    fit, arrays = before_after(prob, accepted, findings, nominal_theta, True, se, shaft, True)
    return doc, fit, arrays


@pytest.mark.slow
def test_noise_level_rise_is_kept_and_a_real_worsening_is_not(gate_inputs):
    """On the default robot the model with joint 1's asymmetry simulates held-out motion at a
    few tenths of a percent; moving its torque by its own held-out torque error moves that
    simulation by the sensitivity. A 0.1-point rise on that near-perfect fit is within it
    (kept); a 50 % rise of the nominal model's error, far above the noise, is a worsening
    (dropped). With the bare relative test the first was a worsening too."""
    doc, fit, arrays = gate_inputs
    assert [f["effect"] for f in doc["findings"]] == ["coulomb_asymmetry", "torque_offset"]
    near = fit.after.position_nrmse
    far = fit.before.position_nrmse
    noise = arrays["simulation"]["position_sensitivity"]
    for j in (0, 1):
        assert near[j] < 0.005, near  # a near-perfect fit
        assert 0 < noise[j] < 0.5 * far[j], (noise, far)
        # noise-level: 0.1 point on a near-perfect fit, which the bare relative test dropped
        assert near[j] + 0.001 > (1 + SIMULATION_TOLERANCE) * near[j]
    assert not any(worse_beyond_noise(near[j] + 0.001, near[j], noise[j]) for j in (0, 1))
    # a genuine worsening: half again the nominal model's error (a few percent)
    assert all(worse_beyond_noise(1.5 * far[j], far[j], noise[j]) for j in (0, 1))


def test_worse_beyond_noise_arithmetic():
    # the closed-loop gain on joint 1: joint 2's 0.13 % → 0.26 % at a 0.2 % sensitivity
    assert not worse_beyond_noise(0.0026, 0.0013, 0.002)
    # the same rise where the simulation is sharp (no sensitivity): a worsening
    assert worse_beyond_noise(0.0026, 0.0013, 0.0)
    # within the relative tolerance alone: not a worsening
    assert not worse_beyond_noise(0.1015, 0.1, 0.0)
    # 50 % on a 10 % fit, sensitivity 0.2 %: a worsening
    assert worse_beyond_noise(0.15, 0.10, 0.002)
    # a poor fit (a real arm: position 20 %, sensitivity 70 %): the allowance is bounded, so
    # the joint a finding is about may not get worse beyond the noise floor ...
    assert worse_beyond_noise(0.25, 0.20, 0.70, own_joint=True)
    assert not worse_beyond_noise(0.2065, 0.20, 0.70, own_joint=True)
    # ... and another joint not beyond twice its error
    assert not worse_beyond_noise(0.35, 0.20, 0.70)
    assert worse_beyond_noise(0.45, 0.20, 0.70)


def test_cogging_phase_moves_to_the_true_angle_with_an_angle_offset():
    """The cogging columns are on the recorded angle q = q_true + δ: A sin(n q + φ_rec) =
    A sin(n q_true + φ_rec + n δ). The simulator and the arm put cogging at the true angle."""
    est = {"periods_per_rev": 96, "amplitude_Nm": 0.08, "phase_rad": -2.386}
    cog = Finding("cogging", 2, est, {})
    ang = Finding("angle_offset", 2, {"offset_rad": -0.02708}, {})
    other = Finding("angle_offset", 1, {"offset_rad": 0.5}, {})
    out = cogging_at_true_angle([cog, ang, other])
    want = math.remainder(-2.386 + 96 * -0.02708, math.tau)
    assert out[0].estimate["phase_rad"] == pytest.approx(want, abs=1e-3)  # 4 significant digits
    assert out[1:] == [ang, other]
    # no offset on its joint: unchanged; only the ``fresh`` ones move
    assert cogging_at_true_angle([cog, other]) == [cog, other]
    assert cogging_at_true_angle([cog, ang], fresh={1}) == [cog, ang]


@pytest.mark.slow
def test_true_terms_kept_where_another_joint_moves_at_noise_level(tmp_path):
    """Blind set 11 rec-19 (issue 12): a 3.2 % gain on joint 1 and joint 2's Coulomb asymmetry
    on `optimal-fourier`. The asymmetry takes joint 2's held-out simulated position from
    3.3 % to 0.2 %; joint 1's moved 0.24 % → 0.31 %, and the bare relative test dropped the
    asymmetry for it."""
    effects = {
        "coulomb": {"positive_Nm": [7.6095, 1.638029], "negative_Nm": [7.6095, 1.831971]},
        "torque_gain_error": {"relative": [0.032362, 0.0]},
    }
    rec = make_recording(tmp_path / "rec", "optimal-fourier", effects)
    doc, args = diagnose_capturing_gate(read_signals(rec), REFERENCE)
    found = {(f["effect"], f["joint"]): f["estimate"] for f in doc["findings"]}
    assert ("torque_gain", 1) in found and ("coulomb_asymmetry", 2) in found, doc["not_findings"]
    assert found[("coulomb_asymmetry", 2)]["difference_Nm"] == pytest.approx(0.194, rel=0.25)
    assert found[("torque_gain", 1)]["relative"] == pytest.approx(0.0324, rel=0.25)
    _a_diverging_refit_loses_its_last_term(args)


def _a_diverging_refit_loses_its_last_term(args):
    """The same gate inputs, the refit's held-out simulation made to leave the finite range
    (NaN rows, as :func:`hil.model.openloop_core.integrate_chunks` gives them) whenever the last
    accepted term is in it: that term goes, with the reason, and the others are judged as
    before (a closed-form simulation that diverged used to raise, and NaN positions would
    have read as "nothing to simulate" and kept every term)."""
    import numpy as np

    import hil.diagnose.gates as gates

    prob, accepted, findings, nominal_theta, se, shaft = args
    last = accepted[-1]
    real = gates.before_after

    def diverging(prob, acc, *rest, **kw):
        fit, arrays = real(prob, acc, *rest, **kw)
        after = arrays["simulation"].get("after")
        if after is not None and any(a is last for a in acc):
            arrays["simulation"]["after"] = np.where(
                np.arange(len(after))[:, None] > 5, np.nan, after
            )
        return fit, arrays

    gates.before_after = diverging
    try:
        result = gates.simulation_gate(
            prob, accepted, findings, nominal_theta, lambda _: None, se, shaft
        )
    finally:
        gates.before_after = real
    group = gates.RATE_TERM if last.cand.spec.is_rate else last.cand.key
    assert result.dropped.get(group) == "with it the refit's held-out simulation diverges", (
        result.dropped
    )
    assert all(a is not last for a in result.accepted)


@pytest.mark.slow
def test_cogging_next_to_an_angle_offset_is_found(tmp_path):
    """Blind set 0 rec-21: cogging 0.08 Nm × 96/rev on joint 2 next to a −27.5 mrad encoder
    offset there, `reyes-kelly`. Simulated at the recorded angle's phase it made the held-out
    motion worse than no cogging (0.75 % → 1.46 % on joint 2) and was dropped."""
    effects = {
        "coulomb": {"positive_Nm": [7.6095, 1.734], "negative_Nm": [7.6095, 1.734]},
        "encoder_offset": {"offset_rad": [0.0, -0.027535]},
        "cogging": {
            "periods_per_rev": [0.0, 96.0],
            "amplitude_Nm": [0.0, 0.080609],
            "phase_rad": [0.0, 1.247294],
        },
    }
    rec = make_recording(tmp_path / "rec", "reyes-kelly", effects)
    doc = diagnose([read_signals(rec)], REFERENCE).document
    cog = [f for f in doc["findings"] if f["effect"] == "cogging"]
    assert [(f["joint"], f["estimate"]["periods_per_rev"]) for f in cog] == [(2, 96)]
    est = cog[0]["estimate"]
    assert est["amplitude_Nm"] == pytest.approx(0.0806, rel=0.1)
    assert abs(math.remainder(est["phase_rad"] - 1.247294, math.tau)) < 0.2
