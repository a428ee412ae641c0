"""The blind-like set's scorer (tests/benchmarks/score_diagnose_set.py): which findings count
as named, sized and extra."""

from __future__ import annotations

import importlib.util
from pathlib import Path

SCRIPT = Path(__file__).parent / "benchmarks" / "score_diagnose_set.py"
_spec = importlib.util.spec_from_file_location("score_diagnose_set", SCRIPT)
assert _spec is not None and _spec.loader is not None
scorer = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(scorer)

ANGLE_J2 = {"effect": "angle_offset", "joint": 2, "magnitude": {"offset_rad": 0.02}}
COM = {
    "effect": "com_offset",
    "joint": None,  # a model term: no joint of its own
    "estimate": {"theta2_perp_kgm2": 0.001, "theta4_perp_Nm": 0.2, "theta5_perp_Nm": 0.03},
}


def angle_found(confounded: bool) -> list[dict]:
    found = {"effect": "angle_offset", "joint": 2, "estimate": {"offset_rad": 0.021}}
    if not confounded:
        return [found]
    return [
        {**found, "confounded_with": ["com_offset"]},
        {**COM, "confounded_with": ["angle_offset"]},
    ]


def test_a_model_term_confounded_with_a_named_truth_is_not_extra():
    """rec-25 of every blind set: the angle offset on joint 2 is found, with `com_offset` (the
    same gravity torque, θ4 sin(q1 + δ) = θ4 cos δ sin q1 + θ4 sin δ cos q1) as its confounded
    alternative. The alternative has no joint, and was counted as an extra finding."""
    entry = {"truth": [ANGLE_J2]}
    plain = scorer.score(entry, {"findings": angle_found(confounded=False)})
    both = scorer.score(entry, {"findings": angle_found(confounded=True)})
    assert both == plain  # named, sized, no extra: the alternative changes nothing
    assert both["named"] == ["angle_offset:2"] and both["extra"] == []
    assert both["sized"][0][3]


def test_a_model_term_standing_alone_is_extra():
    """Where the plant has no centre of mass off the axes and `com_offset` is nobody's
    confounded alternative, it is a false finding."""
    assert scorer.score({"truth": []}, {"findings": [COM]})["extra"] == ["com_offset:None"]
    with_truth = scorer.score({"truth": [ANGLE_J2]}, {"findings": [*angle_found(False), COM]})
    assert with_truth["extra"] == ["com_offset:None"]


DELAY_BOTH = {"effect": "transport_delay", "joint": None, "magnitude": {"delay_s": 0.004}}


def delay_found(confounded: bool) -> list[dict]:
    """One delay on both joints (joint null, as report.classify_rate gives it) and, when the
    data cannot tell it from a lag, the lags it is confounded with, one per joint."""
    est = {"delay_s": 0.0042, "per_joint_s": [0.0041, 0.0043]}
    if not confounded:
        return [{"effect": "transport_delay", "joint": None, "estimate": est}]
    lags = [
        {
            "effect": "actuator_lag",
            "joint": j,
            "estimate": {"time_constant_s": 0.004},
            "confounded_with": ["transport_delay"],
        }
        for j in (1, 2)
    ]
    delay = {
        "effect": "transport_delay",
        "joint": None,
        "estimate": est,
        "confounded_with": ["actuator_lag"],
    }
    return [delay, *lags]


def test_lags_confounded_with_a_delay_on_both_joints_are_partners_not_extra():
    """Blind set 0 (rec-11, rec-17): the delay on both joints was found with a lag on each joint
    as its confounded alternative, and the scorer counted the lags as two extra findings (the
    delay has no joint, so no lag sat on "its" joint)."""
    entry = {"truth": [DELAY_BOTH]}
    plain = scorer.score(entry, {"findings": delay_found(confounded=False)})
    both = scorer.score(entry, {"findings": delay_found(confounded=True)})
    assert both == plain
    assert both["named"] == ["transport_delay:None"] and both["extra"] == []
    assert both["sized"][0][3]


def test_a_lag_beside_a_delay_without_confounding_is_extra():
    """A lag the report does not call the delay's alternative is a finding of its own."""
    lag = {"effect": "actuator_lag", "joint": 1, "estimate": {"time_constant_s": 0.004}}
    doc = {"findings": [*delay_found(confounded=False), lag]}
    assert scorer.score({"truth": [DELAY_BOTH]}, doc)["extra"] == ["actuator_lag:1"]
