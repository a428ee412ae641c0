"""Never a finding below what the data can resolve (issue 26, item 4): a lag or delay shorter
than a quarter of the sample interval is not a finding; its rate term is dropped with the
reason."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from hil.diagnose import interpret as interpret_stage
from hil.diagnose.findings import RESOLVABLE_INTERVALS, Finding, unresolved_rate_terms
from hil.diagnose.kinds import kind_of

H = 0.0015  # the 1.5 ms samples of the DFKI pair


def _prob(h: float = H) -> SimpleNamespace:
    return SimpleNamespace(rows=[SimpleNamespace(h=h)])


def _rate(joint: int) -> SimpleNamespace:
    cand = SimpleNamespace(kind="rate", spec=kind_of("rate"), key=f"rate:{joint}", joint=joint - 1)
    return SimpleNamespace(cand=cand)


def test_a_lag_under_a_quarter_interval_is_unresolved():
    lag = Finding("actuator_lag", 1, {"time_constant_s": 5e-5}, {})
    slow = Finding("actuator_lag", 2, {"time_constant_s": 0.003}, {})
    out = unresolved_rate_terms(_prob(), [lag, slow])
    assert list(out) == ["rate:1"] and "sample interval" in out["rate:1"]
    edge = Finding("transport_delay", 2, {"delay_s": RESOLVABLE_INTERVALS * H * 1.01}, {})
    assert unresolved_rate_terms(_prob(), [edge]) == {}


def test_a_delay_on_all_joints_is_judged_per_joint():
    both = Finding(
        "transport_delay",
        None,
        {"delay_s": 3e-4, "per_joint_s": [2e-4, 0.004]},
        {"joints_tested": [1, 2]},
    )
    assert list(unresolved_rate_terms(_prob(), [both])) == ["rate:1"]


@pytest.mark.parametrize("seconds, kept", [(5e-5, False), (0.002, True)])
def test_interpret_with_rate_drops_an_unresolved_lag(monkeypatch, seconds, kept):
    """The issue's 50 µs "lag" on 1.5 ms samples: interpreted with its rate term it is a
    finding; the guard drops the term, says why, and interprets the rest again."""
    shaft = np.zeros((4, 2))

    def interpret(prob, accepted, library, reference):
        if any(a.cand.kind == "rate" for a in accepted):
            lag = Finding("actuator_lag", 1, {"time_constant_s": seconds}, {}, term="rate")
            return [lag], [], shaft
        return [], [], None

    monkeypatch.setattr(interpret_stage, "interpret", interpret)
    monkeypatch.setattr(interpret_stage, "reselect_on_shaft", lambda prob, acc, *a: acc)
    rejected: dict[str, str] = {}
    accepted, findings, _, out_shaft = interpret_stage.interpret_with_rate(
        _prob(), [_rate(1)], [], np.zeros(9), rejected
    )
    assert bool(findings) == kept and bool(accepted) == kept
    assert (out_shaft is not None) == kept
    assert ("rate:1" in rejected) != kept
