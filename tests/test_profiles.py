"""Tests for the profile loaders (profiles/*.py) and the TOML files shipped with them."""

from __future__ import annotations

import dataclasses
import math
import re
import subprocess
import sys
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from drivers.recording import read_signals
from profiles import ProfileError, available
from profiles.drive import DriveProfile, load_drive
from profiles.effects import EffectsProfile, load_effects
from profiles.experiment import ExperimentProfile, JointExcitation, Sine, load_experiment
from profiles.robot import (
    RobotProfile,
    UrdfRobotProfile,
    load_any_robot,
    load_robot,
    load_urdf_robot,
)
from profiles.tracking import TrackingProfile, load_tracking
from virtual_robot.simulate import simulate

PROFILES_DIR = Path(__file__).resolve().parent.parent / "profiles"


# --- a tiny TOML writer (tomli_w is not a dependency) -------------------------------------------


def _toml_string(s: str) -> str:
    out = ['"']
    for ch in s:
        if ch in '"\\':
            out.append("\\" + ch)
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return _toml_string(v)
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_toml_string(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"cannot write {type(v).__name__} as TOML")


def dumps_toml(doc: dict[str, Any]) -> str:
    """Every key on its own line, every table inline: valid TOML 1.0, readable by tomllib."""
    return "".join(f"{_toml_string(k)} = {_toml_value(v)}\n" for k, v in doc.items())


def shipped(kind: str, name: str) -> dict[str, Any]:
    with open(PROFILES_DIR / kind / f"{name}.toml", "rb") as f:
        return tomllib.load(f)


def write(tmp_path: Path, doc: dict[str, Any], name: str = "bad.toml") -> Path:
    path = tmp_path / name
    path.write_text(dumps_toml(doc), encoding="utf-8")
    return path


def assert_one_line_error(
    exc: pytest.ExceptionInfo[ProfileError], path: Path | str, field: str | None
) -> str:
    msg = str(exc.value)
    assert "\n" not in msg and "\r" not in msg, msg
    assert str(path) in msg, msg
    if field is not None:
        assert exc.value.field == field
        assert f"'{field}'" in msg, msg
    return msg


def test_toml_writer_round_trips_shipped_profiles():
    for kind in ("robots", "drives", "effects", "experiments"):
        for name in available(kind):
            doc = shipped(kind, name)
            assert tomllib.loads(dumps_toml(doc)) == doc


# --- every shipped profile loads ----------------------------------------------------------------

LOADERS = {
    # arms described by a URDF only (panda) load with load_urdf_robot
    "robots": (
        lambda name: (load_robot if _is_planar(name) else load_urdf_robot)(name),
        (RobotProfile, UrdfRobotProfile),
    ),
    "drives": (load_drive, DriveProfile),
    "effects": (load_effects, EffectsProfile),
    "experiments": (
        lambda name: (load_tracking if _is_tracking(name) else load_experiment)(name),
        (ExperimentProfile, TrackingProfile),
    ),
}


def _is_planar(name: str | Path) -> bool:
    path = name if isinstance(name, Path) else PROFILES_DIR / "robots" / f"{name}.toml"
    return "link1" in tomllib.loads(path.read_text())


def _is_tracking(name: str | Path) -> bool:
    """Closed-loop tracking experiments (`hil control`) load with profiles.tracking."""
    path = name if isinstance(name, Path) else PROFILES_DIR / "experiments" / f"{name}.toml"
    return tomllib.loads(path.read_text()).get("kind") == "tracking"


@pytest.mark.parametrize("kind", sorted(LOADERS))
def test_every_shipped_profile_loads(kind):
    names = available(kind)
    assert names, f"no shipped {kind}"
    load, cls = LOADERS[kind]
    for name in names:
        profile = load(name)
        assert isinstance(profile, cls)
        assert Path(profile.source).stem == name
        # a path to the same file loads the same profile
        by_path = load(PROFILES_DIR / kind / f"{name}.toml")
        assert dataclasses.replace(by_path, source=profile.source) == profile


def test_shipped_names():
    assert "cicese" in available("robots")
    assert {"dm1200a", "dm1015b"} <= set(available("drives"))
    assert "reyes-kelly" in available("experiments")
    assert "none" in available("effects")
    with pytest.raises(ValueError):
        available("spaceships")


@pytest.mark.parametrize("name", available("robots"))
def test_robot_drives_are_shipped(name):
    robot = load_any_robot(name)
    for drive in robot.drives or ():
        assert drive.partition("@")[0] in available("drives")
    drives = [load_drive(d) for d in robot.drives or ()]
    # every drive at its own node id and unit address (one bus, one multi-drop line)
    assert len({d.node_id for d in drives}) == len(drives)
    assert len({d.unit_address for d in drives}) == len(drives)


def test_drive_at_an_address_is_the_shipped_drive_there():
    at5 = load_drive("dm1015b@5")
    assert (at5.node_id, at5.unit_address) == (5, 5)
    shipped_drive = load_drive("dm1015b")
    assert shipped_drive.node_id != 5
    assert at5 == dataclasses.replace(shipped_drive, node_id=5, unit_address=5)


@pytest.mark.parametrize("name", ["dm1015b@0", "dm1015b@128", "dm1015b@x", "dm1015b@"])
def test_drive_address_out_of_range_is_a_one_line_error(name):
    with pytest.raises(ProfileError) as exc:
        load_drive(name)
    assert "\n" not in str(exc.value) and "1..127" in str(exc.value)


def test_experiments_have_one_excitation_per_joint():
    # the 2-DOF arm's experiments, and those of the n-joint arms named by their first word
    # (cicese3-excitation: profiles/robots/cicese3.toml, 3 joints; ur5e-excitation: 6)
    for name in (n for n in available("experiments") if not _is_tracking(n)):
        exp = load_experiment(name)
        arm = name.split("-")[0]
        n = load_urdf_robot(arm).n_joints if arm in ("cicese3", "ur5e") else 2
        assert exp.n_joints == len(exp.joints) == len(exp.initial_q_rad) == n, name
        assert exp.torque_table([0.0, 0.1]).shape == (2, n)


# --- θ of the CICESE arm against Reyes & Kelly Table II ("measured") ----------------------------

# (value, decimals printed in the table)
TABLE_II = [
    (2.351, 3),
    (0.084, 3),
    (0.102, 3),
    (38.465, 3),
    (1.825, 3),
    (2.288, 3),
    (0.175, 3),
    ((7.17 + 8.049) / 2, None),
    (1.734, 3),
]


def test_cicese_theta_matches_table_ii():
    theta = load_robot("cicese").theta()
    assert theta.shape == (9,)
    for i, (ref, decimals) in enumerate(TABLE_II):
        half_unit = 0.5 * 10.0**-decimals if decimals is not None else 0.0
        # within the table's rounding, or 0.2 % of the value
        assert theta[i] == pytest.approx(ref, rel=2e-3, abs=half_unit), f"θ{i + 1}"
    assert abs(theta[4] / 1.825 - 1.0) < 2e-3  # θ5 within 0.2 %
    assert theta[7] == pytest.approx(7.6095, abs=1e-12)
    assert theta[8] == 1.734


# --- bad input: one defect per file, one-line errors naming file and field ----------------------


def test_missing_field(tmp_path):
    doc = shipped("robots", "cicese")
    del doc["link1"]["mass_kg"]
    path = write(tmp_path, doc)
    with pytest.raises(ProfileError) as exc:
        load_robot(path)
    assert "missing" in assert_one_line_error(exc, path, "link1.mass_kg")


def test_wrong_type(tmp_path):
    doc = shipped("robots", "cicese")
    doc["link1"]["mass_kg"] = "heavy"
    path = write(tmp_path, doc)
    with pytest.raises(ProfileError) as exc:
        load_robot(path)
    msg = assert_one_line_error(exc, path, "link1.mass_kg")
    assert "number" in msg and "heavy" in msg


def test_negative_mass(tmp_path):
    doc = shipped("robots", "cicese")
    doc["link2"]["mass_kg"] = -1.0
    path = write(tmp_path, doc)
    with pytest.raises(ProfileError) as exc:
        load_robot(path)
    assert "-1.0" in assert_one_line_error(exc, path, "link2.mass_kg")


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_non_finite_number(tmp_path, value):
    doc = shipped("robots", "cicese")
    doc["gravity_m_s2"] = value
    path = write(tmp_path, doc)
    with pytest.raises(ProfileError) as exc:
        load_robot(path)
    assert "finite" in assert_one_line_error(exc, path, "gravity_m_s2")


def test_integer_too_large_for_a_float(tmp_path):
    doc = shipped("robots", "cicese")
    doc["link1"]["com_m"] = 10**400  # tomllib reads integers of any size
    path = write(tmp_path, doc)
    with pytest.raises(ProfileError) as exc:
        load_robot(path)
    assert_one_line_error(exc, path, "link1.com_m")


def test_boolean_is_not_a_number(tmp_path):
    doc = shipped("robots", "cicese")
    doc["link1"]["mass_kg"] = True
    path = write(tmp_path, doc)
    with pytest.raises(ProfileError) as exc:
        load_robot(path)
    assert_one_line_error(exc, path, "link1.mass_kg")


def test_unknown_effect(tmp_path):
    doc = shipped("effects", "stribeck")
    doc["frobnicate"] = {"gain": 2.0}
    path = write(tmp_path, doc)
    with pytest.raises(ProfileError) as exc:
        load_effects(path)
    msg = assert_one_line_error(exc, path, "frobnicate")
    assert "unknown effect" in msg and "stribeck" in msg


def test_unknown_field_in_table(tmp_path):
    doc = shipped("robots", "cicese")
    doc["link1"]["colour"] = "red"
    path = write(tmp_path, doc)
    with pytest.raises(ProfileError) as exc:
        load_robot(path)
    assert "unknown field" in assert_one_line_error(exc, path, "link1.colour")


def test_unknown_field_in_effect_table(tmp_path):
    doc = shipped("effects", "stribeck")
    doc["stribeck"]["breakaway"] = 1.2
    path = write(tmp_path, doc)
    with pytest.raises(ProfileError) as exc:
        load_effects(path)
    assert_one_line_error(exc, path, "stribeck.breakaway")


def test_unknown_top_level_field(tmp_path):
    doc = shipped("drives", "dm1200a")
    doc["nodeid"] = 3
    path = write(tmp_path, doc)
    with pytest.raises(ProfileError) as exc:
        load_drive(path)
    assert_one_line_error(exc, path, "nodeid")


def test_list_of_wrong_length(tmp_path):
    doc = shipped("robots", "cicese")
    doc["friction"]["viscous_Nms"] = [1.0]
    path = write(tmp_path, doc)
    with pytest.raises(ProfileError) as exc:
        load_robot(path)
    assert "list of 2" in assert_one_line_error(exc, path, "friction.viscous_Nms")


def test_bad_list_element(tmp_path):
    doc = shipped("robots", "cicese")
    doc["friction"]["coulomb_negative_Nm"] = [8.049, -0.5]
    path = write(tmp_path, doc)
    with pytest.raises(ProfileError) as exc:
        load_robot(path)
    assert_one_line_error(exc, path, "friction.coulomb_negative_Nm[1]")


def test_invalid_toml_syntax(tmp_path):
    path = tmp_path / "broken.toml"
    text = (PROFILES_DIR / "robots" / "cicese.toml").read_text(encoding="utf-8")
    path.write_text(text.replace("mass_kg = 23.902", "mass_kg = = 23.902"), encoding="utf-8")
    with pytest.raises(ProfileError) as exc:
        load_robot(path)
    assert "not valid TOML" in assert_one_line_error(exc, path, None)
    assert exc.value.field is None


@pytest.mark.parametrize(
    "text",
    [
        b'name = "x"\ndescription = "\xff\xfe"\n',  # not UTF-8
        b"gravity_m_s2 = 1" + b"0" * 5000 + b"\n",  # more digits than int() converts
        b"gravity_m_s2 = " + b"[" * 5000 + b"]" * 5000 + b"\n",  # deeper than the recursion limit
    ],
    ids=["not-utf8", "5000-digit-integer", "deep-array"],
)
def test_toml_that_tomllib_chokes_on(tmp_path, text):
    path = tmp_path / "odd.toml"
    path.write_bytes(text)
    with pytest.raises(ProfileError) as exc:
        load_robot(path)
    assert "not valid TOML" in assert_one_line_error(exc, path, None)


def test_unknown_field_with_a_newline_in_its_name(tmp_path):
    doc = shipped("robots", "cicese")
    doc["link1"]["col\nour"] = 1.0
    path = write(tmp_path, doc)
    with pytest.raises(ProfileError) as exc:
        load_robot(path)
    msg = str(exc.value)
    assert "\n" not in msg and str(path) in msg and "link1.col" in msg


def test_nonexistent_file(tmp_path):
    path = tmp_path / "no-such-robot.toml"
    with pytest.raises(ProfileError) as exc:
        load_robot(path)
    assert "no such profile file" in assert_one_line_error(exc, path, None)
    path = tmp_path / "subdir" / "robot"
    with pytest.raises(ProfileError) as exc:
        load_robot(path)
    assert_one_line_error(exc, path, None)


@pytest.mark.parametrize(
    "kind,load",
    [
        ("robots", load_robot),
        ("drives", load_drive),
        ("effects", load_effects),
        ("experiments", load_experiment),
    ],
)
def test_unknown_shipped_name(kind, load):
    with pytest.raises(ProfileError) as exc:
        load("no-such-profile")
    msg = assert_one_line_error(exc, f"{kind}/no-such-profile", None)
    for name in available(kind):
        assert name in msg


def test_experiment_with_one_joint(tmp_path):
    # one excitation per joint of some arm: one joint loads, and is refused (one line) when
    # run on the 2-DOF arm; none at all is refused at load
    doc = shipped("experiments", "reyes-kelly")
    doc["joints"] = doc["joints"][:1]
    doc["initial_q_rad"] = [0.1]
    path = write(tmp_path, doc)
    one = load_experiment(path)
    assert one.n_joints == 1 and one.initial_q_rad == (0.1,)
    with pytest.raises(ValueError, match="drives 1 joint") as exc:
        one.check_joints(2, "cicese")
    assert "\n" not in str(exc.value)
    doc["joints"] = []
    path = write(tmp_path, doc)
    with pytest.raises(ProfileError) as exc:
        load_experiment(path)
    assert "1 to 64 entries" in assert_one_line_error(exc, path, "joints")


def test_experiment_unknown_kind(tmp_path):
    doc = shipped("experiments", "reyes-kelly")
    doc["kind"] = "closed_loop"
    path = write(tmp_path, doc)
    with pytest.raises(ProfileError) as exc:
        load_experiment(path)
    assert_one_line_error(exc, path, "kind")


def test_experiment_bad_sine(tmp_path):
    doc = shipped("experiments", "reyes-kelly")
    doc["joints"][1]["sines"][0]["omega_rad_s"] = "fast"
    path = write(tmp_path, doc)
    with pytest.raises(ProfileError) as exc:
        load_experiment(path)
    assert_one_line_error(exc, path, "joints[1].sines[0].omega_rad_s")


# --- sine windows and piecewise-linear points (profiles/experiment.py) ---------------------------


def test_sine_window_has_raised_cosine_ramps():
    s = Sine(2.0, 0.0, math.pi / 2, start_s=1.0, stop_s=3.0, ramp_s=0.5)  # 2 sin(π/2) = 2 Nm
    joint = JointExcitation(0.0, 1.0, (s,))
    t = np.array([0.0, 0.999, 1.0, 1.125, 1.25, 1.5, 2.0, 2.5, 2.75, 2.999, 3.0, 5.0])
    expected = 2.0 * np.array(
        [0, 0, 0, 0.5 * (1 - math.cos(math.pi / 4)), 0.5, 1, 1, 1, 0.5, None, 0, 0], dtype=float
    )
    tau = joint.torque(t)
    mask = ~np.isnan(expected)
    np.testing.assert_allclose(tau[mask], expected[mask], atol=1e-12)
    assert 0 < tau[9] < 1e-4  # just inside the window: the ramp ends smoothly at 0
    assert joint.torque(1.25) == pytest.approx(1.0)  # scalar in, scalar out
    gate = JointExcitation(0.0, 1.0, (Sine(1.0, 0.0, math.pi / 2, stop_s=2.0),))
    assert gate.torque(1.999) == 1.0 and gate.torque(2.0) == 0.0  # no ramp: a gate [start, stop)


def test_unwindowed_sines_are_bit_identical_to_the_plain_formula():
    exp = load_experiment("reyes-kelly")
    t = np.arange(4000) * 0.0025
    j = exp.joints[0]
    plain = j.step_Nm * (1 - np.exp(-j.step_rate_per_s * t))
    for s in j.sines:
        plain = plain + s.amplitude_Nm * np.sin(s.omega_rad_s * t + s.phase_rad)
    assert np.array_equal(exp.torque_table(t)[:, 0], plain)


def test_points_are_linear_between_and_held_outside():
    joint = JointExcitation(
        0.0, 1.0, (), offset_Nm=1.0, points=((2.0, 0.0), (4.0, 10.0), (5.0, -2.0))
    )
    t = np.array([0.0, 2.0, 3.0, 4.0, 4.5, 5.0, 9.0])
    np.testing.assert_allclose(joint.torque(t), 1.0 + np.array([0, 0, 5, 10, 4, -2, -2]))
    assert joint.peak_Nm() == 11.0


def _with_joint_keys(tmp_path, **keys):
    doc = shipped("experiments", "reyes-kelly")
    doc["joints"][1].update(keys)
    return write(tmp_path, doc)


def test_points_load_from_toml(tmp_path):
    path = _with_joint_keys(tmp_path, points=[[0, 0], [1.5, 2.0], [3, -1]])
    joint = load_experiment(path).joints[1]
    assert joint.points == ((0.0, 0.0), (1.5, 2.0), (3.0, -1.0))
    assert joint.torque(0.75) == pytest.approx(
        load_experiment("reyes-kelly").joints[1].torque(0.75) + 1
    )


@pytest.mark.parametrize(
    ("sine", "field", "message"),
    [
        ({"stop_s": 2.0, "start_s": 2.0}, "stop_s", "must be > start_s"),
        ({"stop_s": 1.0, "start_s": 3.0}, "stop_s", "must be > start_s"),
        ({"start_s": -1.0}, "start_s", ">= 0"),
        ({"stop_s": 2.0, "ramp_s": 1.5}, "ramp_s", "half the window"),
        ({"ramp_s": -0.1}, "ramp_s", ">= 0"),
        ({"stop_s": math.inf}, "stop_s", "finite"),
        ({"stop_s": "later"}, "stop_s", "must be a number"),
        ({"window": 1.0}, "window", "unknown field"),
    ],
)
def test_bad_sine_window_is_a_one_line_error(tmp_path, sine, field, message):
    doc = shipped("experiments", "reyes-kelly")
    doc["joints"][0]["sines"][1].update(sine)
    path = write(tmp_path, doc)
    with pytest.raises(ProfileError) as exc:
        load_experiment(path)
    assert message in assert_one_line_error(exc, path, f"joints[0].sines[1].{field}")


@pytest.mark.parametrize(
    ("points", "field", "message"),
    [
        ([[0.0, 1.0]], "points", "at least 2"),
        ("ramp", "points", "at least 2"),
        ([[0.0, 1.0], [1.0]], "points[1]", "pair"),
        ([[0.0, 1.0], 5.0], "points[1]", "pair"),
        ([[0.0, 1.0], [1.0, 2.0, 3.0]], "points[1]", "pair"),
        ([[1.0, 1.0], [1.0, 2.0]], "points[1]", "times must increase"),
        ([[2.0, 1.0], [1.0, 2.0]], "points[1]", "times must increase"),
        ([[-1.0, 1.0], [1.0, 2.0]], "points[0].t", ">= 0"),
        ([[0.0, 1.0], [1.0, math.nan]], "points[1].tau", "finite"),
        ([[0.0, "x"], [1.0, 2.0]], "points[0].tau", "must be a number"),
    ],
)
def test_bad_points_are_a_one_line_error(tmp_path, points, field, message):
    path = _with_joint_keys(tmp_path, points=points)
    with pytest.raises(ProfileError) as exc:
        load_experiment(path)
    assert message in assert_one_line_error(exc, path, f"joints[1].{field}")


# --- the shipped diagnosis excitation (profiles/experiments/diagnosis.toml) ----------------------


def test_diagnosis_experiment_shape_and_limits():
    exp = load_experiment("diagnosis")
    assert exp.kind == "open_loop_torque" and exp.period_s == 0.0025 and exp.duration_s == 20.0
    t = np.arange(8000) * exp.period_s
    tau = exp.torque_table(t)
    assert np.all(np.abs(tau).max(axis=0) < 0.8 * np.array([200.0, 15.0]))  # drive limits
    fast, slow = t < 9.5, t >= 10.0
    for j in exp.joints:
        assert all(s.stop_s == 9.5 and s.ramp_s == 1.0 for s in j.sines)  # multisine, faded out
        assert j.points[0] == (9.5, 0.0) and j.points[-1][0] == 20.0  # slow part after it
    assert np.all(np.abs(tau[fast]).max(axis=0) > [100.0, 10.0])  # rich, fast excitation
    # slow: gravity-balance torques, no jumps (joint 1 < 30 Nm/s, joint 2 < 5 Nm/s)
    rate = np.abs(np.diff(tau[slow], axis=0)).max(axis=0) / exp.period_s
    assert np.all(rate < [30.0, 5.0]), rate


def test_diagnosis_experiment_moves_slowly_both_ways_with_holds(tmp_path):
    """On the exact model (symmetric Coulomb friction), through the drives and encoders."""
    simulate(
        load_robot("cicese"),
        load_experiment("diagnosis"),
        tmp_path,
        effects=load_effects("symmetric-coulomb"),
        plot=False,
    )
    rec = read_signals(tmp_path)
    slow = rec.t >= 10.0
    step = np.diff(rec.q, axis=0, prepend=rec.q[:1])
    still = (step == 0)[slow]
    dq = step[slow] / rec.period_s
    # measured (20 s, 8000 rows): still 23 % / 22 %, |q̇| < 0.3 rad/s 93 % / 77 %, max
    # 0.36 / 0.43 rad/s, q1 in [-0.45, 0.71], q2 in [-0.67, 0.35] rad
    assert np.all((still.mean(axis=0) > 0.15) & (still.mean(axis=0) < 0.35))
    assert np.all((np.abs(dq) < 0.3).mean(axis=0) > 0.7)
    assert np.all(np.abs(dq).max(axis=0) < 0.6)
    assert np.all((dq > 0.05).mean(axis=0) > 0.25) and np.all((dq < -0.05).mean(axis=0) > 0.2)
    assert np.all(np.ptp(rec.q[slow], axis=0) > 0.9)
    assert np.ptp(rec.q[~slow, 0]) > 2.0 and np.ptp(rec.q[~slow, 1]) > 3.0  # the fast part


@pytest.mark.parametrize("node_id", [200, 0, 128])
def test_drive_node_id_out_of_range(tmp_path, node_id):
    doc = shipped("drives", "dm1200a")
    doc["node_id"] = node_id
    path = write(tmp_path, doc)
    with pytest.raises(ProfileError) as exc:
        load_drive(path)
    assert str(node_id) in assert_one_line_error(exc, path, "node_id")


def test_drive_node_id_float(tmp_path):
    doc = shipped("drives", "dm1200a")
    doc["node_id"] = 1.0
    path = write(tmp_path, doc)
    with pytest.raises(ProfileError) as exc:
        load_drive(path)
    assert "integer" in assert_one_line_error(exc, path, "node_id")


def test_table_replaced_by_scalar(tmp_path):
    doc = shipped("robots", "cicese")
    doc["link2"] = 3.88
    path = write(tmp_path, doc)
    with pytest.raises(ProfileError) as exc:
        load_robot(path)
    assert "table" in assert_one_line_error(exc, path, "link2")


def test_profile_error_is_a_value_error():
    assert issubclass(ProfileError, ValueError)


# --- the CLI turns profile errors into one line on stderr, exit code 2 --------------------------


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "virtual_robot.cli", *args],
        capture_output=True,
        text=True,
        timeout=60,
    )


def assert_cli_error(proc: subprocess.CompletedProcess[str], *needles: str) -> str:
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1, proc.stderr
    assert re.match(r"virtual-robot (simulate|serve): error:", lines[0]), lines[0]
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


def test_cli_negative_mass_robot(tmp_path):
    doc = shipped("robots", "cicese")
    doc["link2"]["mass_kg"] = -1.0
    bad = write(tmp_path, doc)
    out = tmp_path / "run"
    proc = run_cli("simulate", "--robot", str(bad), "--out", str(out), "--no-plot")
    assert_cli_error(proc, str(bad), "link2.mass_kg")
    assert not (out / "signals.csv").exists()


def test_cli_unknown_effect(tmp_path):
    doc = shipped("effects", "none")
    doc["frobnicate"] = {"gain": 1.0}
    bad = write(tmp_path, doc)
    proc = run_cli("simulate", "--effects", str(bad), "--out", str(tmp_path / "run"), "--no-plot")
    assert_cli_error(proc, str(bad), "frobnicate")


def test_cli_unknown_experiment_name(tmp_path):
    proc = run_cli(
        "simulate",
        "--experiment",
        "no-such-experiment",
        "--out",
        str(tmp_path / "run"),
        "--no-plot",
    )
    line = assert_cli_error(proc, "experiments/no-such-experiment")
    for name in available("experiments"):
        assert name in line


def test_cli_negative_duration(tmp_path):
    proc = run_cli("simulate", "--duration", "-1", "--out", str(tmp_path / "run"), "--no-plot")
    assert_cli_error(proc, "--duration")


# --- fuzz: any one leaf of the robot profile replaced by anything -------------------------------


def _leaf_paths(value: Any, prefix: tuple = ()) -> list[tuple]:
    paths: list[tuple] = []
    if isinstance(value, dict):
        for k, v in value.items():
            paths.extend(_leaf_paths(v, (*prefix, k)))
    else:
        paths.append(prefix)
        if isinstance(value, list):
            for i, v in enumerate(value):
                paths.extend(_leaf_paths(v, (*prefix, i)))
    return paths


def _replaced(doc: Any, path: tuple, new: Any) -> Any:
    if not path:
        return new
    head, rest = path[0], path[1:]
    if isinstance(doc, dict):
        return {k: (_replaced(v, rest, new) if k == head else v) for k, v in doc.items()}
    return [(_replaced(v, rest, new) if i == head else v) for i, v in enumerate(doc)]


CICESE = shipped("robots", "cicese")
CICESE_LEAVES = _leaf_paths(CICESE)

scalars = (
    st.text(max_size=12)
    | st.integers()
    | st.integers(-(10**400), 10**400)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.booleans()
)
values = st.recursive(
    scalars,
    lambda children: (
        st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=6), children, max_size=3)
    ),
    max_leaves=8,
)


@settings(max_examples=100, deadline=None)
@given(path=st.sampled_from(CICESE_LEAVES), new=values)
@example(path=("link1", "mass_kg"), new=math.nan)
@example(path=("link1", "mass_kg"), new=-math.inf)
@example(path=("link2", "com_m"), new=10**400)
@example(path=("friction", "viscous_Nms"), new={"a\nb": 1})
@example(path=("joints", "drives", 0), new=["dm1200a"])
@example(path=("name",), new='\x00\x7f"\\\n')
def test_fuzzed_robot_profile_loads_or_raises_profile_error(tmp_path_factory, path, new):
    doc = _replaced(CICESE, path, new)
    text = dumps_toml(doc)
    assert repr(tomllib.loads(text)) == repr(doc)  # the writer is faithful (nan-safe comparison)
    file = tmp_path_factory.mktemp("fuzz") / "robot.toml"
    file.write_text(text, encoding="utf-8")
    try:
        robot = load_robot(file)
    except ProfileError as exc:
        msg = str(exc)
        assert "\n" not in msg and "\r" not in msg, msg
        assert str(file) in msg
    else:
        assert isinstance(robot, RobotProfile)


@settings(max_examples=60, deadline=None)
@given(
    points=values, sine=st.dictionaries(st.sampled_from(["start_s", "stop_s", "ramp_s"]), values)
)
def test_fuzzed_points_and_windows_load_or_raise_profile_error(tmp_path_factory, points, sine):
    doc = shipped("experiments", "reyes-kelly")
    doc["joints"][0]["points"] = points
    doc["joints"][1]["sines"][0].update(sine)
    file = tmp_path_factory.mktemp("fuzz") / "experiment.toml"
    file.write_text(dumps_toml(doc), encoding="utf-8")
    try:
        exp = load_experiment(file)
    except ProfileError as exc:
        assert "\n" not in str(exc) and str(file) in str(exc)
    else:
        assert np.all(np.isfinite(exp.torque_table(np.linspace(0.0, 12.0, 97))))
