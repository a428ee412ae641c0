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
