"""Concealed-effect recordings for testing and calibrating the mismatch diagnosis (issue 7).

A pure helper for tests and benchmarks (no test functions here):

* :func:`make_recording` runs an experiment offline on the virtual robot (virtual_robot.simulate)
  with an effects profile written from a dict, and writes a standard recording whose meta.json
  does not name the effects (the diagnosis must find them, as on a real arm).
* :data:`CASES` is a catalogue of named cases, one per effect of the diagnosis vocabulary and
  joint, plus null cases, each with its effects dict and its truth in the diagnosis vocabulary.
* :func:`case` builds a case for any magnitudes, :func:`combine` merges effects of several cases
  (tests/benchmarks/make_diagnose_set.py uses them for a blind-like set).
* :func:`diagnose_capturing_gate` diagnoses a recording and captures its simulation gate's
  inputs, optionally with another gate in its place (tests/test_diagnose_gate.py,
  tests/benchmarks/closed_loop_bias.py).

The default robot has a direction-dependent Coulomb friction on joint 1 (7.17 / 8.049 Nm, Table I).
Every case here starts from a ``coulomb`` table that makes friction symmetric (the mean levels
[7.6095, 1.734] Nm both ways), so the only concealed physics is the case's, unless a case says it
keeps the default asymmetry (then its truth lists ``coulomb_asymmetry`` on joint 1 too).

Vocabulary → effects profile (docs/effects.md); magnitudes of the truth, per effect:

| effect | effects table | truth magnitude |
|---|---|---|
| coulomb_asymmetry | coulomb (joint's levels) | positive_Nm, negative_Nm |
| torque_offset | torque_offset | offset_Nm |
| stribeck | stribeck (other joint: ratio 1) | breakaway_ratio, velocity_rad_s |
| cogging | cogging (other joint: amplitude 0) | periods_per_rev, amplitude_Nm |
| actuator_lag | amplifier_lag | time_constant_s |
| transport_delay | transport_delay (both joints: joint None) | delay_s |
| angle_offset | encoder_offset | offset_rad |
| torque_gain | torque_gain_error | relative |
"""

from __future__ import annotations

import dataclasses
import json
import math
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drivers.recording import META, Recording, write_json_atomic
from hil.diagnose import pipeline
from hil.diagnose.candidates import VOCABULARY as DIAGNOSIS_VOCABULARY
from hil.model.closed_form import TERMS as MODEL_TERMS
from profiles.effects import load_effects
from profiles.experiment import ExperimentProfile, load_experiment
from profiles.robot import load_robot
from virtual_robot.simulate import simulate

SYMMETRIC_COULOMB_NM = [7.6095, 1.734]  # mean of Table I's 7.17 / 8.049 Nm; joint 2 1.734 Nm
DEFAULT_POSITIVE_NM = [7.17, 1.734]  # the default robot's levels (profiles/robots/cicese.toml)
DEFAULT_NEGATIVE_NM = [8.049, 1.734]
# meta.json keys that would give the concealed effects away
CONCEALED_META_KEYS = ("effects", "effects_profile", "effects_enabled")

# The effect names `hil diagnose` reports that the virtual robot can conceal. The model terms
# (rotor_inertia, com_offset: hil.model.closed_form.TERMS) are the arm's structure, not effects
# of the world's 2-DOF plant; tests/test_diagnose_terms.py records them with the host simulator.
VOCABULARY = tuple(e for e in DIAGNOSIS_VOCABULARY if e not in MODEL_TERMS)
# The size that tests/benchmarks scale (0.5x-2x): the other keys are kept.
SIZE_KEY = {
    "coulomb_asymmetry": "half_difference_Nm",  # derived: scale (negative - positive) / 2
    "torque_offset": "offset_Nm",
    "stribeck": "breakaway_ratio",  # scales ratio - 1
    "cogging": "amplitude_Nm",
    "actuator_lag": "time_constant_s",
    "transport_delay": "delay_s",
    "angle_offset": "offset_rad",
    "torque_gain": "relative",
}


@dataclass(frozen=True)
class Truth:
    """One concealed effect in the diagnosis vocabulary: name, joint 1|2 (None: both), size."""

    effect: str
    joint: int | None
    magnitude: dict[str, float]

    def as_dict(self) -> dict[str, Any]:
        return {"effect": self.effect, "joint": self.joint, "magnitude": dict(self.magnitude)}


@dataclass(frozen=True)
class Case:
    """Effects dict (tables as in docs/effects.md) and the truth the diagnosis should report."""

    name: str
    effects: dict[str, dict[str, Any]]
    truth: tuple[Truth, ...] = ()
    note: str = ""

    @property
    def is_null(self) -> bool:
        return not self.truth

    def truth_dicts(self) -> list[dict[str, Any]]:
        return [t.as_dict() for t in self.truth]


# Realistic magnitudes per effect and joint (truth vocabulary). Joint None: one for both joints.
CATALOGUE: dict[str, dict[int | None, dict[str, float]]] = {
    # Table I's asymmetry on joint 1; about ±11 % on joint 2
    "coulomb_asymmetry": {
        1: {"positive_Nm": 7.17, "negative_Nm": 8.049},
        2: {"positive_Nm": 1.55, "negative_Nm": 1.92},
    },
    # amplifier zero errors: 0.5 % of the 200 Nm rating, 1 % of the 15 Nm rating
    "torque_offset": {1: {"offset_Nm": 1.0}, 2: {"offset_Nm": 0.15}},
    # the shipped `stribeck` profile: F_s / F_c and v_s
    "stribeck": {
        1: {"breakaway_ratio": 1.35, "velocity_rad_s": 0.08},
        2: {"breakaway_ratio": 1.25, "velocity_rad_s": 0.10},
    },
    # direct-drive ripple: 0.75 % of 200 Nm at 120 periods/rev; 1 % of 15 Nm at 96
    "cogging": {
        1: {"periods_per_rev": 120.0, "amplitude_Nm": 1.5},
        2: {"periods_per_rev": 96.0, "amplitude_Nm": 0.15},
    },
    # a slow current loop (~50 Hz bandwidth)
    "actuator_lag": {1: {"time_constant_s": 0.003}, 2: {"time_constant_s": 0.003}},
    # one control period of command latency (acts on both joints)
    "transport_delay": {None: {"delay_s": 0.0025}},
    # encoder zero errors of about 1-2 degrees
    "angle_offset": {1: {"offset_rad": 0.02}, 2: {"offset_rad": -0.04}},
    # torque-constant errors of ±6 %
    "torque_gain": {1: {"relative": 0.06}, 2: {"relative": -0.06}},
}


def symmetric_base() -> dict[str, dict[str, Any]]:
    """The effects dict that only makes friction symmetric: the model is then exact."""
    return {
        "coulomb": {
            "positive_Nm": list(SYMMETRIC_COULOMB_NM),
            "negative_Nm": list(SYMMETRIC_COULOMB_NM),
        }
    }


def _set(table: dict[str, Any], key: str, joint: int, value: float, fill: float) -> None:
    pair = list(table.get(key, [fill, fill]))
    pair[joint - 1] = value
    table[key] = pair


def add_effect(
    effects: dict[str, dict[str, Any]], effect: str, joint: int | None, magnitude: dict[str, float]
) -> None:
    """Add one vocabulary effect to an effects dict in place (per-joint tables are merged)."""
    m = magnitude
    if effect == "transport_delay":
        if joint is not None:
            raise ValueError("transport_delay acts on both joints: joint must be None")
        effects["transport_delay"] = {"delay_s": float(m["delay_s"])}
        return
    if joint not in (1, 2):
        raise ValueError(f"{effect}: joint must be 1 or 2, got {joint!r}")
    if effect == "coulomb_asymmetry":
        t = effects.setdefault("coulomb", symmetric_base()["coulomb"])
        _set(t, "positive_Nm", joint, float(m["positive_Nm"]), 0.0)
        _set(t, "negative_Nm", joint, float(m["negative_Nm"]), 0.0)
    elif effect == "torque_offset":
        _set(effects.setdefault("torque_offset", {}), "offset_Nm", joint, m["offset_Nm"], 0.0)
    elif effect == "stribeck":
        t = effects.setdefault("stribeck", {"exponent": 2.0})
        _set(t, "breakaway_ratio", joint, float(m["breakaway_ratio"]), 1.0)  # 1: none
        _set(t, "velocity_rad_s", joint, float(m["velocity_rad_s"]), 0.1)
    elif effect == "cogging":
        t = effects.setdefault("cogging", {})
        _set(t, "periods_per_rev", joint, float(m["periods_per_rev"]), 0.0)
        _set(t, "amplitude_Nm", joint, float(m["amplitude_Nm"]), 0.0)
        _set(t, "phase_rad", joint, float(m.get("phase_rad", 0.0)), 0.0)
    elif effect == "actuator_lag":
        t = effects.setdefault("amplifier_lag", {})
        _set(t, "time_constant_s", joint, float(m["time_constant_s"]), 0.0)
    elif effect == "angle_offset":
        t = effects.setdefault("encoder_offset", {})
        _set(t, "offset_rad", joint, float(m["offset_rad"]), 0.0)
    elif effect == "torque_gain":
        t = effects.setdefault("torque_gain_error", {})
        _set(t, "relative", joint, float(m["relative"]), 0.0)
    else:
        raise ValueError(f"unknown effect {effect!r}; one of {', '.join(VOCABULARY)}")


def scale_magnitude(effect: str, magnitude: dict[str, float], factor: float) -> dict[str, float]:
    """The magnitude with its size (SIZE_KEY) scaled by ``factor``; other keys kept."""
    m = dict(magnitude)
    if effect == "coulomb_asymmetry":
        mean = 0.5 * (m["positive_Nm"] + m["negative_Nm"])
        half = 0.5 * (m["negative_Nm"] - m["positive_Nm"])
        m["positive_Nm"], m["negative_Nm"] = mean - factor * half, mean + factor * half
    elif effect == "stribeck":
        m["breakaway_ratio"] = 1.0 + factor * (m["breakaway_ratio"] - 1.0)
    else:
        key = SIZE_KEY[effect]
        m[key] = factor * m[key]
    return m


def case(
    name: str,
    parts: list[tuple[str, int | None, dict[str, float]]],
    *,
    keep_default_asymmetry: bool = False,
    note: str = "",
) -> Case:
    """A case with the effects ``parts`` = [(effect, joint, magnitude), ...] on the symmetric base.

    ``keep_default_asymmetry``: no base ``coulomb`` table, so joint 1 keeps the robot's
    7.17 / 8.049 Nm (added to the truth as coulomb_asymmetry on joint 1).
    """
    effects: dict[str, dict[str, Any]] = {} if keep_default_asymmetry else symmetric_base()
    truth = []
    if keep_default_asymmetry:
        if any(p[0] == "coulomb_asymmetry" for p in parts):
            raise ValueError("keep_default_asymmetry with a coulomb_asymmetry part: choose one")
        effects["coulomb"] = {
            "positive_Nm": list(DEFAULT_POSITIVE_NM),
            "negative_Nm": list(DEFAULT_NEGATIVE_NM),
        }
        truth.append(
            Truth(
                "coulomb_asymmetry",
                1,
                {"positive_Nm": DEFAULT_POSITIVE_NM[0], "negative_Nm": DEFAULT_NEGATIVE_NM[0]},
            )
        )
    for effect, joint, magnitude in parts:
        add_effect(effects, effect, joint, magnitude)
        truth.append(Truth(effect, joint, dict(magnitude)))
    if keep_default_asymmetry:
        del effects["coulomb"]  # the robot profile's own levels: nothing written
    return Case(name, effects, tuple(truth), note)


def combine(name: str, *cases: Case, note: str = "") -> Case:
    """One case with the effects and truths of several (per-joint tables merged)."""
    parts = [(t.effect, t.joint, t.magnitude) for c in cases for t in c.truth]
    return case(name, parts, note=note)


def _catalogue_cases() -> dict[str, Case]:
    cases: dict[str, Case] = {}
    for effect in VOCABULARY:
        for joint, magnitude in CATALOGUE[effect].items():
            suffix = "" if joint is None else f"_j{joint}"
            cases[effect + suffix] = case(effect + suffix, [(effect, joint, magnitude)])
    cases["transport_delay_short"] = case(
        "transport_delay_short", [("transport_delay", None, {"delay_s": 0.00125})]
    )
    # null: the model is exact (symmetric Coulomb friction, nothing else)
    cases["null"] = case("null", [])
    # null for a diagnosis that refits θ: a payload changes θ1..θ5, not the model's structure
    cases["null_payload"] = Case(
        "null_payload",
        {
            **symmetric_base(),
            "payload": {"mass_kg": 1.5, "distance_m": 0.25, "inertia_kgm2": 0.002},
        },
        (),
        note="null only if the diagnosis refits θ (the payload changes θ1..θ5, not the structure)",
    )
    # the default robot as shipped: Table I's direction-dependent Coulomb friction on joint 1
    cases["default_robot"] = case("default_robot", [], keep_default_asymmetry=True)
    cases["default_robot_cogging_j2"] = case(
        "default_robot_cogging_j2",
        [("cogging", 2, CATALOGUE["cogging"][2])],
        keep_default_asymmetry=True,
    )
    return cases


CASES: dict[str, Case] = _catalogue_cases()
NULL_CASES = tuple(name for name, c in CASES.items() if c.is_null)

# Physics outside the vocabulary: the diagnosis may call it `unexplained` or say nothing, but must
# not name a vocabulary effect for it (issue 12). Not in CASES: their truth has no vocabulary name.
OUT_OF_VOCABULARY: dict[str, Case] = {
    # a velocity-squared drag τ = −c q̇|q̇| on joint 1: 1.5 Nm at 1 rad/s, ~12 Nm at its 2.8 rad/s
    # (95th percentile of |q̇1| on the diagnosis excitation), against Coulomb 7.6 Nm
    "drag_j1": Case(
        "drag_j1",
        {**symmetric_base(), "velocity_squared_drag": {"coefficient_Nms2": [1.5, 0.0]}},
        note="velocity-squared drag on joint 1: out of vocabulary (unexplained)",
    ),
}


# ---- recordings ----------------------------------------------------------------------------


def effects_toml(effects: dict[str, dict[str, Any]], name: str = "concealed") -> str:
    """An effects profile (docs/effects.md) from a dict of tables of numbers / number pairs."""
    lines = [f'name = "{name}"']
    for table, values in effects.items():
        if not isinstance(values, dict):
            raise ValueError(f"effects[{table!r}] must be a table (dict), got {values!r}")
        lines.append(f"\n[{table}]")
        for key, value in values.items():
            if isinstance(value, list | tuple):
                text = "[" + ", ".join(repr(float(v)) for v in value) + "]"
            else:
                text = repr(float(value))
            lines.append(f"{key} = {text}")
    return "\n".join(lines) + "\n"


def _randomised_phases(experiment: ExperimentProfile, seed: int) -> ExperimentProfile:
    """The experiment with every sine's phase shifted by a uniform random angle (seeded)."""
    rng = np.random.default_rng(seed)
    joints = []
    for j in experiment.joints:
        sines = tuple(
            dataclasses.replace(s, phase_rad=s.phase_rad + float(rng.uniform(0.0, 2 * math.pi)))
            for s in j.sines
        )
        joints.append(dataclasses.replace(j, sines=sines))
    return dataclasses.replace(experiment, joints=(joints[0], joints[1]))


def make_recording(
    out_dir: str | Path,
    experiment: str | Path | ExperimentProfile,
    effects: dict[str, dict[str, Any]] | None,
    duration_s: float | None = None,
    seed: int | None = None,
) -> Path:
    """Simulate ``experiment`` on the virtual cicese arm with ``effects`` and record to out_dir.

    ``effects``: tables as in docs/effects.md (e.g. ``CASES["cogging_j1"].effects``); None runs
    the default robot (joint 1 keeps its direction-dependent Coulomb friction). ``seed``: shift
    every sine's phase by a seeded random angle (another excitation of the same spectrum, e.g. a
    held-out recording); None keeps the experiment as it is. The effects profile is written to a
    temporary file outside ``out_dir`` and deleted; meta.json keeps no trace of it (its effects
    keys are removed), so the recording conceals the effects as a real arm's would.
    Returns ``out_dir`` (signals.csv and meta.json). Offline, deterministic, no plot.
    """
    exp = experiment if isinstance(experiment, ExperimentProfile) else load_experiment(experiment)
    if seed is not None:
        exp = _randomised_phases(exp, seed)
    out = Path(out_dir)
    with tempfile.TemporaryDirectory(prefix="ddbench-effects-") as tmp:
        if effects is None:
            profile = None
        else:
            path = Path(tmp) / "concealed.toml"
            path.write_text(effects_toml(effects), encoding="utf-8")
            profile = load_effects(path)
        simulate(
            load_robot("cicese"),
            exp,
            out,
            effects=profile,
            duration_s=duration_s,
            plot=False,
        )
    meta_path = out / META
    meta = json.loads(meta_path.read_text(encoding="utf-8"))
    for key in CONCEALED_META_KEYS:
        meta.pop(key, None)
    meta["seed"] = seed
    write_json_atomic(meta_path, meta)
    return out


def diagnose_capturing_gate(
    rec: Recording, reference: np.ndarray, gate: Callable[..., Any] | None = None
) -> tuple[dict[str, Any], tuple]:
    """``diagnose([rec], reference)`` with ``gate`` (called with the simulation gate's arguments;
    None: the gate itself) in place of :func:`hil.diagnose.gates.simulation_gate`. The
    diagnosis document and the gate's inputs ``(prob, accepted, findings, nominal_theta, se,
    shaft)``."""
    real_gate = pipeline.simulation_gate
    use = gate or real_gate
    captured: dict[str, tuple] = {}

    def capture(prob, accepted, findings, nominal_theta, say, se=None, shaft=None, **kw):
        captured["args"] = (prob, list(accepted), list(findings), nominal_theta, se, shaft)
        return use(prob, accepted, findings, nominal_theta, say, se, shaft, **kw)

    pipeline.simulation_gate = capture
    try:
        doc = pipeline.diagnose([rec], reference).document
    finally:
        pipeline.simulation_gate = real_gate
    return doc, captured["args"]
