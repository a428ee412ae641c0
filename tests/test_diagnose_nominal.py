"""Diagnosis against the model the user has (hil/diagnose/drift/, hil/diagnose/effects):
the profile's θ, ``--params`` of any arm, ``--reference`` recordings; drift patterns with their
sizes, uncertainty and held-out proof; nulls give nothing.

The virtual cicese arm's recordings are made by tests/diagnose_cases.py (open loop, the
``diagnosis`` experiment: multisine then slow moves); the URDF arm's (cicese3) by the virtual
plant with the effect written into the recording (tests/urdf_effect_recordings.py)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from diagnose_cases import make_recording
from realdata import realdata
from urdf_effect_recordings import with_effect, with_payload

from hil.cli import main as hil_main
from hil.diagnose.columns import moving_average
from hil.diagnose.effects import REGISTRY, Effect, SimInput, register
from hil.diagnose.effects.base import on_joint
from virtual_robot.cli import main as vr_main

# one worker runs the whole module under `pytest -n` (`--dist loadgroup`): its module
# fixtures are built once, not once per worker
pytestmark = pytest.mark.xdist_group("diagnose_nominal")

WITHIN = 0.35  # the size tolerance
GAIN = 0.07
ANGLE = 0.06


@pytest.fixture(scope="module")
def arm(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("nominal")
    gain = {"torque_gain_error": {"relative": [GAIN, 0.0]}}
    return {
        "gain": make_recording(root / "gain", "diagnosis", gain),
        "angle": make_recording(
            root / "angle", "diagnosis", {"encoder_offset": {"offset_rad": [ANGLE, 0.0]}}
        ),
        "null_a": make_recording(root / "null_a", "diagnosis", {}, seed=1),
        "null_b": make_recording(root / "null_b", "diagnosis", {}, seed=2),
        "gain_b": make_recording(root / "gain_b", "diagnosis", gain, seed=2),
        "payload": make_recording(
            root / "payload",
            "diagnosis",
            {"payload": {"mass_kg": 1.5, "distance_m": 0.25, "inertia_kgm2": 0.0}},
        ),
    }


def _diagnose(capsys, *args: str) -> dict:
    capsys.readouterr()
    assert hil_main(["diagnose", *args, "--json", "--no-plots"]) == 0
    return json.loads(capsys.readouterr().out)


def _drift(doc: dict) -> list[tuple[str, int | None]]:
    return [(f["effect"], f["joint"]) for f in doc["nominal"]["findings"]]


def _one(doc: dict, effect: str) -> dict:
    """The drift finding ``effect`` (against the nominal model), also in the findings: as
    itself, or beside the refit's finding of the same physics on the same joint."""
    found = [f for f in doc["nominal"]["findings"] if f["effect"] == effect]
    assert len(found) == 1, doc["summary"]
    listed = [
        {k: v for k, v in g.get("against_nominal", g).items() if k != "refit_findings"}
        for g in doc["findings"]
    ]
    assert found[0] in listed, doc["findings"]
    return found[0]


def test_concealed_gain_on_joint_1_is_found_against_the_profile(arm, capsys):
    doc = _diagnose(capsys, str(arm["gain"]), "--robot", "cicese")
    assert doc["nominal"]["source"] == "profile" and doc["nominal"]["used"]
    f = _one(doc, "torque_gain")
    assert f["joint"] == 1
    g = f["estimate"]["gain"]
    assert abs(g - (1 + GAIN)) <= WITHIN * GAIN, f
    assert abs(g - (1 + GAIN)) <= 0.05 * GAIN, f  # much better than the issue asks
    assert f["estimate"]["gain_se"] < abs(g - 1) / 2
    # its held-out proof and the model it was judged against are in the document
    assert f["evidence"]["against"] == "profile"
    assert f["evidence"]["blocks_improved"] > 0.8 * f["evidence"]["blocks"]
    assert "torque gain on joint 1" in doc["summary"]
    # nothing else on joint 2, which nothing changed
    assert ("torque_gain", 2) not in _drift(doc)


def test_encoder_offset_on_joint_1_is_named_with_its_angle(arm, capsys):
    doc = _diagnose(capsys, str(arm["angle"]), "--robot", "cicese")
    f = _one(doc, "encoder_offset")
    assert f["joint"] == 1
    assert abs(f["estimate"]["offset_rad"] - ANGLE) <= WITHIN * ANGLE, f
    # not a centre-of-mass offset (nor the refit's angle offset beside it)
    effects = {g["effect"] for g in doc["findings"]}
    assert "com_offset" not in effects and "angle_offset" not in effects, doc["summary"]


def test_planar_payload_on_link_2_found_with_its_mass_and_distance(arm, capsys):
    doc = _diagnose(capsys, str(arm["payload"]), "--robot", "cicese")
    f = _one(doc, "payload")
    assert abs(f["estimate"]["mass_kg"] - 1.5) <= WITHIN * 1.5, f
    assert abs(f["estimate"]["centre_m"][0] - 0.25) <= WITHIN * 0.25, f
    assert ("torque_gain", 1) not in _drift(doc) and ("torque_gain", 2) not in _drift(doc)


def test_reference_null_pair_gives_no_finding_and_a_gain_since_then_is_found(arm, capsys):
    doc = _diagnose(
        capsys, str(arm["null_b"]), "--robot", "cicese", "--reference", str(arm["null_a"])
    )
    assert doc["nominal"]["source"] == "reference" and doc["nominal"]["used"]
    assert doc["findings"] == [], doc["summary"]
    # joint 1's direction-dependent Coulomb friction is in both: the reference keeps it
    assert ("torque_offset", 1) in [(b["effect"], b["joint"]) for b in doc["nominal"]["baseline"]]
    assert "Nothing changed" in doc["summary"]
    doc = _diagnose(
        capsys, str(arm["gain_b"]), "--robot", "cicese", "--reference", str(arm["null_a"])
    )
    assert _drift(doc) == [("torque_gain", 1)], doc["summary"]
    g = doc["nominal"]["findings"][0]["estimate"]["gain"]
    assert abs(g - (1 + GAIN)) <= WITHIN * GAIN
    # one reference of another motion (the phases differ): the finding says what it was not
    # weighed against, in the report's words too
    evidence = doc["nominal"]["findings"][0]["evidence"]
    assert "one reference of another motion" in evidence["spread"]
    assert evidence["spread"] in evidence["words"]


def test_the_nominal_model_options_and_refit(arm, capsys, tmp_path):
    doc = _diagnose(capsys, str(arm["gain"]), "--robot", "cicese", "--refit")
    assert doc["nominal"] == {
        "source": "refit",
        "used": False,
        "decision": "--refit: judged against θ refitted from the recordings alone",
    }
    capsys.readouterr()
    code = hil_main(
        ["diagnose", str(arm["gain"]), "--params", "x.json", "--reference", str(arm["null_a"])]
    )
    assert code != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "give one nominal model" in err[0]


def test_a_new_effect_is_one_registered_class(arm, capsys, tmp_path):
    """An effect registered from here (a cubic drag c q̇³ on joint 2, not in the
    registry) is tested, found with its size and reported, with nothing else changed."""
    c = 0.05  # Nm s³

    class Drag(Effect):
        name = "test_drag"

        def variants(self, ctx):
            return [1]

        def columns(self, ctx, joint, at):
            def build(r):
                v = r.v_mean[:, joint : joint + 1]
                return moving_average(-on_joint(v**3, joint, ctx.n_joints), r.window)

            return ctx.stack(build)

        def estimate(self, ctx, joint, beta, se, at):
            return {"drag_Nms2": float(beta[0]), "se": float(se[0])}, float(beta[0]), float(se[0])

        def words(self, e):
            return f"a drag of {e['drag_Nms2']:.3g} Nm s²"

        def simulation(self, ctx, joint, e):
            return SimInput()

    src = arm["null_b"] / "signals.csv"
    rows = list(csv.reader(src.open()))
    head, data = rows[0], np.array(rows[1:], float)
    t, q2, tau2 = (head.index(k) for k in ("t", "q2", "tau2"))
    v = np.gradient(data[:, q2], data[:, t])
    data[:, tau2] -= c * v**3  # τ_shaft = τ + c q̇³: the recorded τ is that less
    out = tmp_path / "drag.csv"
    with out.open("w", newline="") as fh:
        csv.writer(fh).writerows([head, *data.tolist()])
    register(Drag())
    try:
        doc = _diagnose(capsys, str(out), "--robot", "cicese", "--reference", str(arm["null_a"]))
    finally:
        REGISTRY.pop("test_drag")
    assert _drift(doc) == [("test_drag", 2)], doc["summary"]
    f = doc["nominal"]["findings"][0]
    assert abs(f["estimate"]["drag_Nms2"] - c) <= WITHIN * c
    assert "a drag of" in f["evidence"]["words"]


DFKI_A0 = (
    Path(__file__).parent / "data" / "dfki" / "design_A.0__20220815__sys_id__trajectory_00.csv"
)


@pytest.mark.parametrize("nominal", ["reference", "params"])
def test_gain_written_into_the_shipped_dfki_file_is_found_against_its_original(
    capsys, tmp_path, nominal
):
    """A 5 % torque gain on joint 2 of a real A.0 recording (τ_con2 / 1.05), judged against
    ``--reference`` the unmodified file, or ``--params`` of `hil identify` of it (which names
    and fingerprints the file, and the diagnosis compares with that file): found on joint 2
    with its size, though the model's own error (tens of % NRMSE) leaves only 27 of 40 blocks
    better, which a sign test over blocks does not accept; the unmodified file against
    itself: nothing. Against the identified θ alone the gain was missed: its estimator's rows
    and filter differ from the diagnosis's by more than 5 %."""
    g = 1.05
    rows = list(csv.reader(DFKI_A0.open()))
    col = rows[0].index("tau_con2")
    for r in rows[1:]:
        r[col] = repr(float(r[col]) / g)
    rec = tmp_path / "gain.csv"
    with rec.open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    args = ["--reference", str(DFKI_A0), "--format", "dfki", "--robot", "dfki-a0"]
    if nominal == "params":
        assert hil_main(["identify", "--from", str(DFKI_A0), *args[2:], "--out",
                         str(tmp_path / "id"), "--no-plot", "-q"]) == 0  # fmt: skip
        args[:2] = ["--params", str(tmp_path / "id" / "params.json")]
    doc = _diagnose(capsys, str(rec), *args)
    assert _drift(doc) == [("torque_gain", 2)], doc["summary"]
    if nominal == "params":
        assert "re-identified from the recording it was identified from" in doc["nominal"]["why"]
    found = doc["nominal"]["findings"][0]["estimate"]["gain"]
    assert abs(found - g) <= WITHIN * (g - 1), found
    # the same motion: the paired difference, no spread over motions to weigh
    assert "spread" not in doc["nominal"]["findings"][0]["evidence"]
    if nominal == "reference":  # (with --params the same comparison, once its file is found)
        doc = _diagnose(capsys, str(DFKI_A0), *args)
        assert _drift(doc) == [], doc["summary"]


def test_real_dfki_pair_of_the_same_arm_gives_no_change(capsys):
    """Two sys_id recordings of design A.0 on one day: nothing changed, nothing found (or the
    honest "cannot tell" of a pattern the reverse comparison or the gates did not confirm)."""
    records = realdata("dfki-double-pendulum") / "records"
    a = records / "design_A.0__20220815__sys_id__trajectory_04.csv"
    b = records / "design_A.0__20220815__sys_id__trajectory_05.csv"
    if not (a.is_file() and b.is_file()):
        pytest.skip(f"DFKI recordings not found under {records}")
    doc = _diagnose(capsys, str(b), "--reference", str(a), "--format", "dfki", "--robot", "dfki-a0")
    assert doc["nominal"]["source"] == "reference"
    assert _drift(doc) == [], doc["summary"]


def test_a_drift_term_the_training_recording_cannot_determine_is_dropped_not_fatal(capsys):
    """DFKI C.0 trajectory 04 drives joint 2 only, 05 joint 1 only. Against the profile a joint-1
    torque gain is accepted on both; the simulation gate fits it on 04 alone, where joint 1's
    torque is 0, reads about -100 %, and its held-out simulation on 05 leaves every finite
    angle. That ended the diagnosis in `math domain error`; the term is now not a finding, with
    that reason, and the report is written."""
    records = realdata("dfki-double-pendulum") / "records"
    a = records / "design_C.0__20220914__sys_id__trajectory_04.csv"
    b = records / "design_C.0__20220914__sys_id__trajectory_05.csv"
    if not (a.is_file() and b.is_file()):
        pytest.skip(f"DFKI recordings not found under {records}")
    doc = _diagnose(capsys, str(a), str(b), "--format", "dfki", "--robot", "dfki-c0")
    assert (
        doc["nominal"]["not_findings"]["torque_gain:1"]
        == "with it the held-out simulation diverges"
    )
    assert _drift(doc) == [], doc["summary"]
    positions = doc["nominal"]["held_out_position_nrmse"]
    assert all(x is None or np.isfinite(x) for side in positions.values() for x in side or [])


def test_a_pattern_with_which_no_arm_is_physical_is_refused():
    """The drift patterns θ's own check cannot judge: a drag below zero (no arm is fed energy
    by its speed) against a model with no drag, and a load taken off that leaves link 2 of the
    profile no rigid body (its mass gone, or its inertia about its centre below zero)."""
    from hil.diagnose.cli import arm_geometry
    from hil.diagnose.effects.base import Context
    from hil.model.closed_form import ArmModel
    from hil.model.urdf import UrdfArmModel
    from profiles.robot import load_robot

    drag = REGISTRY["velocity_squared_drag"]
    assert "below zero" in drag.unphysical(None, 0, {"coefficient_Nms2": -0.01}, "profile")
    assert "below zero" in drag.unphysical(None, 0, {"coefficient_Nms2": -0.01}, "params")
    # since reference recordings whose own drag θ₀ absorbed: less drag is physics
    assert drag.unphysical(None, 0, {"coefficient_Nms2": -0.01}, "reference") is None
    assert drag.unphysical(None, 0, {"coefficient_Nms2": 0.01}, "profile") is None

    payload = REGISTRY["payload"]
    c0 = load_robot("dfki-c0")  # link 2: 0.598 kg, m2 lc2 = 0.164 kg m, 0.0535 kg m² at joint 2
    model = ArmModel(c0.terms)
    ctx = Context(
        [], model, c0.theta(), np.zeros((0, 2, model.n_params)), geometry=arm_geometry("dfki-c0")
    )

    def planar(m: float, lp: float, source: str = "profile") -> str | None:
        return payload.unphysical(ctx, None, {"mass_kg": m, "centre_m": [lp]}, source)

    # C.0 trajectory 03 against its profile, trained on 75 % of its rows: 0.62 kg taken off
    assert "more than its 0.598 kg" in planar(-0.624, 0.244)
    # mass taken off at joint 2 leaves link 2's first moment (0.164 kg m) on too little mass
    assert "too little to carry" in planar(-0.3, 0.0)
    assert planar(-0.1, 0.244) is None and planar(0.55, 0.244) is None
    assert planar(-0.55, 0.244, "params") is None  # a fitted θ₀'s masses are not the profile's
    no_link2 = Context(
        [], model, c0.theta(), ctx.Psi_raw, geometry={"link1_m": 0.2, "gravity_m_s2": 9.81}
    )
    assert (
        payload.unphysical(no_link2, None, {"mass_kg": -0.7, "centre_m": [0.244]}, "profile")
        is None
    )

    arm3 = UrdfArmModel.from_profile("cicese3")
    ctx3 = Context([], arm3, arm3.base_theta(), np.zeros((0, 3, arm3.n_params)))
    last = float(arm3.standard_theta[10 * 2])
    gone = {"mass_kg": -(last + 0.1), "centre_m": [0.0, 0.0, 0.0]}
    assert "mass" in payload.unphysical(ctx3, None, gone, "profile")
    assert (
        payload.unphysical(
            ctx3, None, {"mass_kg": -0.01 * last, "centre_m": [0.0, 0.0, 0.0]}, "profile"
        )
        is None
    )


def test_real_c0_trajectory_03_against_its_profile_names_no_unphysical_drift(capsys):
    """DFKI C.0 trajectory 03 against the dfki-c0 profile fitted a point mass of −0.55 kg on
    link 2 (0.598 kg) and a v·|v| drag below zero on joint 1: neither an arm can have. They
    are refused with the reason, and the profile, without them, does not describe the
    recording: the tool says it cannot tell rather than name a change."""
    records = realdata("dfki-double-pendulum") / "records"
    rec = records / "design_C.0__20220914__sys_id__trajectory_03.csv"
    if not rec.is_file():
        pytest.skip(f"DFKI recordings not found under {records}")
    doc = _diagnose(capsys, str(rec), "--format", "dfki", "--robot", "dfki-c0")
    refused = doc["nominal"]["not_findings"]
    assert "link 2" in refused["payload"] and "not physical" in refused["payload"], refused
    assert "below zero" in refused["velocity_squared_drag:1"], refused
    assert _drift(doc) == [], doc["summary"]
    assert not doc["findings"], doc["summary"]


# --- an arm described by a URDF (slow: the n-joint plant and Pinocchio's regressors) ----------


@pytest.fixture(scope="module")
def cicese3(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("nominal-urdf")
    args = ["simulate", "--robot", "cicese3", "--experiment", "cicese3-excitation"]
    assert vr_main([*args, "--duration", "6", "--out", str(root / "null"), "--no-plot"]) == 0
    return {
        "null": root / "null",
        "gain": with_effect(root / "null", root / "gain3", "gain", 3, GAIN),
        "payload": with_payload(root / "null", root / "payload", "cicese3", 0.5, (0.1, 0.0, 0.0)),
    }


@pytest.mark.slow
def test_urdf_payload_on_the_last_body_found_with_its_mass(cicese3, capsys):
    doc = _diagnose(capsys, str(cicese3["payload"]), "--robot", "cicese3")
    f = _one(doc, "payload")
    assert abs(f["estimate"]["mass_kg"] - 0.5) <= WITHIN * 0.5, f
    assert abs(f["estimate"]["centre_m"][0] - 0.1) <= WITHIN * 0.1, f
    assert _drift(doc) == [("payload", None)], doc["summary"]


@pytest.mark.slow
def test_urdf_params_from_hil_identify_is_the_nominal_model(cicese3, capsys, tmp_path):
    assert hil_main(
        ["identify", "--robot", "cicese3", "--from", str(cicese3["null"]), "--out", str(tmp_path)]
    ) in (0, 1)
    params = str(tmp_path / "identify.json")
    doc = _diagnose(capsys, str(cicese3["gain"]), "--robot", "cicese3", "--params", params)
    # identify.json fingerprints the null run: found, the model re-identified from it
    assert doc["nominal"]["source"] == "reference" and params in doc["nominal"]["why"]
    assert _drift(doc) == [("torque_gain", 3)], doc["summary"]
    g = doc["nominal"]["findings"][0]["estimate"]["gain"]
    assert abs(g - (1 + GAIN)) <= WITHIN * GAIN
    doc = _diagnose(capsys, str(cicese3["null"]), "--robot", "cicese3", "--params", params)
    assert _drift(doc) == [], doc["summary"]


def test_a_gain_column_that_explains_the_whole_torque_has_no_finite_size():
    """β = 1 − 1/g of the gain column at or beyond 1 has no finite positive gain: its size is
    unbounded (and no finding: :func:`hil.diagnose.drift.judge.size_gates`), not a clamped 0.99
    read as a gain of 100 (the "gain size 99" seen on DFKI C.0 joint 2); below 1 the size is
    g − 1."""
    gain = REGISTRY["torque_gain"]
    for b in (1.0, 3.0):
        est, size, se = gain.estimate(None, 1, np.array([b]), np.array([0.01]), None)
        assert np.isinf(size) and np.isinf(se), (b, size)
    assert gain.estimate(None, 1, np.array([0.995]), np.array([0.0]), None)[1] == pytest.approx(199)
    est, size, se = gain.estimate(None, 1, np.array([0.5]), np.array([0.01]), None)
    assert est["gain"] == pytest.approx(2.0) and size == pytest.approx(1.0)
    assert se == pytest.approx(0.04)


def test_reference_diagnosis_builds_each_recordings_rows_once(arm, capsys, monkeypatch):
    """``--reference``: the judge reuses the rows the diagnosis built (issue 26, the Panda
    pair's CPU time): one regressor per recording and per reference, and the same document as
    when the judge builds its own."""
    import hil.diagnose.cli as cli
    import hil.diagnose.problem as problem

    args = (str(arm["gain_b"]), "--robot", "cicese", "--reference", str(arm["null_a"]))
    built = []
    real_rows = problem.recording_rows
    monkeypatch.setattr(
        problem, "recording_rows", lambda *a, **k: built.append(1) or real_rows(*a, **k)
    )
    doc = _diagnose(capsys, *args)
    assert len(built) == 2  # the recording's and the reference's
    real_judge = cli.judge
    monkeypatch.setattr(cli, "judge", lambda *a, rows=None, **k: real_judge(*a, **k))
    again = _diagnose(capsys, *args)
    assert len(built) == 2 + 3  # the judge built the recording's rows again
    for d in (doc, again):
        d.pop("timing_s", None)
        d["nominal"].pop("timing_s", None)
    assert json.dumps(doc, sort_keys=True) == json.dumps(again, sort_keys=True)


def test_the_references_encoder_rows_are_built_once(arm, capsys, monkeypatch):
    """``--reference``: the encoder rows of the reference's rows, built while its model is
    identified, are reused when the reference is judged against the same θ (issue 26, the
    Panda pair's CPU time): each recording's rows, joint and θ built once. (The reference's
    own departures are set aside here, as when it shows none, so that θ stays the one the
    rows were built at.)"""
    import importlib

    import hil.diagnose.effects.encoder as encoder

    judge = importlib.import_module("hil.diagnose.drift.judge")  # the package names a function so
    built = []
    real_coefficients, real_select = encoder._coefficients, judge.select_terms

    def counted(r, theta, joint, base):
        built.append((id(r), hash(theta.tobytes()), joint))
        return real_coefficients(r, theta, joint, base)

    def reference_shows_nothing(fit, cands, say, **kw):
        accepted, seen = real_select(fit, cands, say, **kw)
        return ([], seen) if not kw else (accepted, seen)

    monkeypatch.setattr(encoder, "_coefficients", counted)
    monkeypatch.setattr(judge, "select_terms", reference_shows_nothing)
    doc = _diagnose(
        capsys, str(arm["angle"]), "--robot", "cicese", "--reference", str(arm["null_a"])
    )
    assert ("encoder_offset", 1) in _drift(doc), doc["summary"]
    assert len({b[0] for b in built}) == 2  # the recording's rows and the reference's
    assert len(built) == len(set(built)), built


def test_refit_findings_on_joints_a_change_reaches_are_set_aside():
    """Against references, the refit of the recording alone (θ free, no vocabulary of changes)
    takes a change as whatever it can name: an encoder angle on DFKI A.0's joint 2 became a lag
    and a delay on joint 1 beside it. A refit finding on a joint the change found reaches is
    set aside (``within_change``) and said in the summary; one on another joint stays, and of
    the same physics found by both the drift's is listed, the refit's beside it."""
    from hil.diagnose.cli import merge_drift
    from hil.diagnose.drift.terms import DriftResult
    from hil.diagnose.findings import Finding

    def refit(effect: str, joint: int) -> dict:
        return {"effect": effect, "joint": joint, "estimate": {}, "evidence": {}}

    doc = {
        "findings": [refit("actuator_lag", 1), refit("stribeck", 3), refit("torque_gain", 2)],
        "summary": "Refit.",
    }
    encoder = Finding("encoder_offset", 2, {"offset_rad": 0.05}, {"joints": [1, 2], "words": "e"})
    gain = Finding("torque_gain", 2, {"gain": 0.9}, {"joints": [2], "words": "g"})
    drift = DriftResult(
        {"source": "reference", "why": "w", "decision": "d", "baseline": []}, [encoder, gain]
    )
    merge_drift(doc, drift)
    names = [(f["effect"], f["joint"]) for f in doc["findings"]]
    assert names == [("stribeck", 3), ("encoder_offset", 2), ("torque_gain", 2)], names
    # the drift's gain is listed (the change), the refit's beside it
    assert doc["findings"][2]["estimate"] == {"gain": 0.9}
    assert doc["findings"][2]["refit_findings"] == [refit("torque_gain", 2)]
    assert [f["effect"] for f in drift.document["within_change"]] == ["actuator_lag"]
    assert "actuator lag on joint 1" in doc["summary"]
    # where joint 2's rows share θ columns with joint 3's, the refit moves joint 3 as well
    doc = {"findings": [refit("stribeck", 3), refit("unexplained", 4)], "summary": "Refit."}
    drift = DriftResult(
        {"source": "reference", "why": "w", "decision": "d", "baseline": []},
        [gain],
        shares={2: {2, 3}, 3: {2, 3}, 4: {4}},
    )
    merge_drift(doc, drift)
    assert [(f["effect"], f["joint"]) for f in doc["findings"]] == [
        ("unexplained", 4),
        ("torque_gain", 2),
    ]
    assert [f["effect"] for f in drift.document["within_change"]] == ["stribeck"]
    # nothing changed: the refit's findings all stay
    doc = {"findings": [refit("actuator_lag", 1)], "summary": "Refit."}
    merge_drift(doc, DriftResult({"source": "reference", "why": "w", "decision": "d",
                                  "baseline": []}, []))  # fmt: skip
    assert [f["effect"] for f in doc["findings"]] == ["actuator_lag"]
    # against a profile the refit's findings answer what the model leaves out: all stay, the
    # drift's reading beside the one of the same physics
    doc = {"findings": [refit("actuator_lag", 1), refit("torque_gain", 2)], "summary": "Refit."}
    merge_drift(doc, DriftResult({"source": "profile", "why": "w", "decision": "d",
                                  "baseline": []}, [encoder, gain]))  # fmt: skip
    names = [(f["effect"], f["joint"]) for f in doc["findings"]]
    assert names == [("actuator_lag", 1), ("torque_gain", 2), ("encoder_offset", 2)], names
    assert doc["findings"][1]["against_nominal"]["estimate"] == {"gain": 0.9}
