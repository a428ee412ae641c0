"""The refit's candidate kinds (hil/diagnose/kinds/, issue 29): each kind answers for itself, and
a kind registered from outside the package is tested, selected and reported like the shipped
ones."""

from __future__ import annotations

import csv
import json
from typing import ClassVar

import numpy as np
import pytest
from diagnose_cases import CASES, make_recording

from hil.cli import main as hil_main
from hil.diagnose.candidates import Candidate
from hil.diagnose.columns import RecordingRows, moving_average
from hil.diagnose.finding import Finding, rounded
from hil.diagnose.kinds import KINDS, CandidateKind, Library, TermFit, kind_of
from hil.model.closed_form import TERMS

SHIPPED = ("offset", "gain", "cogging", "stribeck", "rate", "angle", *TERMS)


def test_every_shipped_kind_and_model_term_is_registered():
    assert set(SHIPPED) <= set(KINDS)
    assert all(kind_of(t).model_term for t in TERMS)
    assert [k for k in SHIPPED if kind_of(k).is_gain] == ["gain"]
    assert [k for k in SHIPPED if kind_of(k).is_rate] == ["rate"]


def test_a_kind_carries_its_width_joints_and_floor():
    assert [kind_of(k).width for k in SHIPPED] == [1, 1, 2, 1, 2, 1, 1, 3]
    assert kind_of("angle").joints(1) == [0, 1] and kind_of("offset").joints(1) == [1]
    assert kind_of("cogging").large_enough(np.array([0.006, 0.008]), np.zeros(9))  # 0.01 Nm
    assert not kind_of("rate").large_enough(np.array([-1e-3, 0.0]), np.zeros(9))  # a lead
    assert kind_of("offset").large_enough(np.array([-0.03]), np.zeros(9))


FREQUENCY_HZ = 0.43  # not one of the reyes-kelly excitation's frequencies
FREQUENCIES_HZ = (0.17, FREQUENCY_HZ, 0.71)  # the toy's variants
AMPLITUDE_NM = 0.25
NAME = "test_time_sine"


def time_sine_columns(rows: RecordingRows, joint: int, frequency_hz: float) -> np.ndarray:
    """A sin(2π f t + φ) added to the shaft torque of ``joint``: X = −F[sin 2πft, cos 2πft],
    the torque held over each interval at its first sample's value."""
    phase = 2 * np.pi * frequency_hz * rows.t
    raw = np.stack([np.sin(phase), np.cos(phase)], axis=1)
    out = np.zeros((rows.rows, rows.n_joints, 2))
    out[:, joint, :] = -moving_average(raw, rows.window)
    return out


class TimeSine(CandidateKind):
    """A torque that oscillates in time, whatever the arm does (a toy: a mains hum)."""

    name = NAME
    width = 2
    practical_floor = 0.01  # Nm amplitude
    words: ClassVar[dict[str, str]] = {
        NAME: "a torque of {amplitude_Nm:.3g} Nm oscillating at {frequency_hz:.3g} Hz"
    }

    def size(self, coef: np.ndarray) -> float:
        return float(np.hypot(*coef))

    def candidates(self, joint: int, library: Library) -> list[Candidate]:
        return [Candidate(NAME, joint, FREQUENCIES_HZ, lambda r, f: time_sine_columns(r, joint, f))]

    def findings(self, fit: TermFit) -> list[Finding]:
        estimate = {
            "amplitude_Nm": rounded(self.size(fit.coef)),
            "frequency_hz": float(fit.variant),
        }
        return [Finding(NAME, fit.joint + 1, estimate, {})]


def test_a_kind_registered_here_is_selected_and_reported(monkeypatch, capsys, tmp_path):
    """A toy kind (a torque oscillating in time, written into joint 2's torque of a recording
    with nothing else to find) registered from here, its candidates on every joint its own: the
    diagnosis selects it on joint 2, sizes it and reports it in words, with nothing else changed."""
    rec = make_recording(tmp_path / "rec", "reyes-kelly", CASES["null"].effects, duration_s=10.0)
    src = rec / "signals.csv"
    rows = list(csv.reader(src.open()))
    head, data = rows[0], np.array(rows[1:], float)
    t, tau2 = head.index("t"), head.index("tau2")
    # τ_shaft = τ + A sin(2π f t): the recorded τ is that less
    data[:, tau2] -= AMPLITUDE_NM * np.sin(2 * np.pi * FREQUENCY_HZ * data[:, t])
    with src.open("w", newline="") as fh:
        csv.writer(fh).writerows([head, *data.tolist()])

    monkeypatch.setitem(KINDS, NAME, TimeSine())  # the kind's one file: this class
    capsys.readouterr()
    assert hil_main(["diagnose", str(rec), "--robot", "cicese", "--json", "--no-plots"]) == 0
    doc = json.loads(capsys.readouterr().out)
    found = [f for f in doc["findings"] if f["effect"] == NAME]
    assert [(f["joint"], f["estimate"]["frequency_hz"]) for f in found] == [(2, FREQUENCY_HZ)]
    assert found[0]["estimate"]["amplitude_Nm"] == pytest.approx(AMPLITUDE_NM, rel=0.25)
    assert "oscillating at 0.43 Hz" in doc["summary"]
