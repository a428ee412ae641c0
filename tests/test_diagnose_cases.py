"""The concealed-effect generator (tests/diagnose_cases.py) makes what its truth says."""

from __future__ import annotations

import json

import diagnose_cases as dc
import numpy as np
import pytest

from drivers.recording import read_signals
from profiles.effects import parse_effects
from profiles.robot import load_robot
from virtual_robot.plant import Plant, PlantParams


def test_catalogue_covers_the_vocabulary_on_both_joints():
    named = {(t.effect, t.joint) for c in dc.CASES.values() if len(c.truth) == 1 for t in c.truth}
    for effect in dc.VOCABULARY:
        joints = {None} if effect == "transport_delay" else {1, 2}
        assert {(effect, j) for j in joints} <= named, effect
    assert {"null", "null_payload"} <= set(dc.NULL_CASES)


@pytest.mark.parametrize("name", sorted(dc.CASES))
def test_each_case_is_the_physics_its_truth_names(name):
    case = dc.CASES[name]
    params = PlantParams.from_profiles(
        load_robot("cicese"), parse_effects(case.effects, f"<{name}>")
    )
    truth = {(t.effect, t.joint): t.magnitude for t in case.truth}
    # friction is symmetric unless the truth says otherwise
    for joint in (1, 2):
        m = truth.get(("coulomb_asymmetry", joint))
        pos, neg = params.coulomb_positive_Nm[joint - 1], params.coulomb_negative_Nm[joint - 1]
        if m is None:
            assert pos == neg == dc.SYMMETRIC_COULOMB_NM[joint - 1], (joint, pos, neg)
        else:
            assert (pos, neg) == (m["positive_Nm"], m["negative_Nm"])
    for (effect, joint), m in truth.items():
        i = None if joint is None else joint - 1
        other = None if joint is None else 1 - i
        if effect == "torque_offset":
            assert (
                params.torque_offset_Nm[i] == m["offset_Nm"] and not params.torque_offset_Nm[other]
            )
        elif effect == "torque_gain":
            assert params.torque_gain_error[i] == m["relative"]
        elif effect == "actuator_lag":
            assert params.amplifier_lag_s[i] == m["time_constant_s"]
        elif effect == "angle_offset":
            assert params.encoder_offset_rad[i] == m["offset_rad"]
        elif effect == "transport_delay":
            assert params.transport_delay_s == m["delay_s"]
        elif effect == "cogging":
            assert params.cogging_periods_per_rev[i] == m["periods_per_rev"]
            assert params.cogging_amplitude_Nm[i] == m["amplitude_Nm"]
            assert params.cogging_amplitude_Nm[other] == 0.0
        elif effect == "stribeck":
            assert params.stribeck_velocity_rad_s is not None
            assert params.stribeck_velocity_rad_s[i] == m["velocity_rad_s"]
            ratio = params.breakaway_positive_Nm[i] / params.coulomb_positive_Nm[i]
            assert ratio == pytest.approx(m["breakaway_ratio"])
            assert params.breakaway_positive_Nm[other] == params.coulomb_positive_Nm[other]
    if not case.truth:
        assert set(case.effects) <= {"coulomb", "payload"}


def test_velocity_squared_drag_adds_c_v_squared_to_the_sliding_friction():
    case = dc.OUT_OF_VOCABULARY["drag_j1"]
    params = PlantParams.from_profiles(load_robot("cicese"), parse_effects(case.effects, "<d>"))
    assert params.drag_Nms2 == (1.5, 0.0)
    plant = Plant(params)
    coulomb = dc.SYMMETRIC_COULOMB_NM
    # τ_drag = −c q̇|q̇|: magnitude c q̇² on top of the Coulomb level, none at rest, none on joint 2
    assert plant._friction_level(0, 1.0, 2.0) == pytest.approx(coulomb[0] + 1.5 * 4.0)
    assert plant._friction_level(0, -1.0, 2.0) == pytest.approx(coulomb[0] + 1.5 * 4.0)
    assert plant._friction_level(0, 1.0, 0.0) == pytest.approx(coulomb[0])
    assert plant._friction_level(1, 1.0, 2.0) == pytest.approx(coulomb[1])


def test_drag_slows_joint_1_under_the_same_commands(tmp_path):
    drag = read_signals(
        dc.make_recording(
            tmp_path / "d", "reyes-kelly", dc.OUT_OF_VOCABULARY["drag_j1"].effects, 1.0
        )
    )
    null = read_signals(
        dc.make_recording(tmp_path / "n", "reyes-kelly", dc.CASES["null"].effects, 1.0)
    )
    assert np.array_equal(drag.tau, null.tau)  # open loop
    assert np.abs(np.diff(drag.q[:, 0])).sum() < np.abs(np.diff(null.q[:, 0])).sum()


def test_scale_magnitude():
    asym = dc.scale_magnitude("coulomb_asymmetry", {"positive_Nm": 7.0, "negative_Nm": 8.0}, 2.0)
    assert asym == pytest.approx({"positive_Nm": 6.5, "negative_Nm": 8.5})
    strib = {"breakaway_ratio": 1.3, "velocity_rad_s": 0.1}
    assert dc.scale_magnitude("stribeck", strib, 0.5) == pytest.approx(
        {"breakaway_ratio": 1.15, "velocity_rad_s": 0.1}
    )
    cog = {"periods_per_rev": 96.0, "amplitude_Nm": 0.2}
    assert dc.scale_magnitude("cogging", cog, 1.5) == pytest.approx(
        {"periods_per_rev": 96.0, "amplitude_Nm": 0.3}
    )


def test_make_recording_conceals_the_effects(tmp_path):
    rec_dir = dc.make_recording(
        tmp_path / "cog", "reyes-kelly", dc.CASES["cogging_j1"].effects, 1.0
    )
    null_dir = dc.make_recording(tmp_path / "null", "reyes-kelly", dc.CASES["null"].effects, 1.0)
    meta = json.loads((rec_dir / "meta.json").read_text())
    assert not set(dc.CONCEALED_META_KEYS) & set(meta) and meta["seed"] is None
    assert sorted(p.name for p in rec_dir.iterdir()) == ["meta.json", "signals.csv"]
    rec, null = read_signals(rec_dir), read_signals(null_dir)
    assert rec.q.shape == (400, 2) and np.array_equal(rec.tau, null.tau)  # open loop
    assert np.abs(rec.q - null.q).max() > 1e-3  # the cogging moved the arm


def test_seed_shifts_the_phases_only(tmp_path):
    a = read_signals(dc.make_recording(tmp_path / "a", "reyes-kelly", None, 0.5, seed=3))
    b = read_signals(dc.make_recording(tmp_path / "b", "reyes-kelly", None, 0.5, seed=3))
    c = read_signals(dc.make_recording(tmp_path / "c", "reyes-kelly", None, 0.5))
    assert np.array_equal(a.q, b.q) and not np.array_equal(a.tau, c.tau)
    assert json.loads((tmp_path / "a" / "meta.json").read_text())["seed"] == 3
    # same spectrum: the same peak torque bound, other values
    assert np.abs(a.tau).max() < 68 + 9 + 29 + 0.2


def test_bad_effects_are_rejected(tmp_path):
    with pytest.raises(ValueError, match="joint must be 1 or 2"):
        dc.case("x", [("cogging", 3, {"periods_per_rev": 1.0, "amplitude_Nm": 1.0})])
    with pytest.raises(ValueError, match="unknown effect"):
        dc.case("x", [("backlash", 1, {})])
    with pytest.raises(ValueError, match="must be a table"):
        dc.effects_toml({"coulomb": 1.0})
