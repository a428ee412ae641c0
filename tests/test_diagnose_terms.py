"""The model terms in the diagnosis (issue 12): ``rotor_inertia`` and ``com_offset`` are found
with their size when the nominal model lacks them, and not again when it has them.

The virtual robot's 2-DOF plant has neither term, so the recordings whose truth has them are
made with the host's open-loop simulator (hil.model.openloop, which simulates any
``ArmModel``): the commanded torques of a virtual-robot `diagnosis` run (multisine, then slow
moves; symmetric Coulomb friction) drive the CICESE arm with the term added, and the positions
are quantised to the virtual robot's encoder step.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from diagnose_cases import CASES, make_recording
from realdata import realdata

from drivers.recording import read_signals
from hil.cli import main as hil_main
from hil.diagnose.candidates import candidates
from hil.diagnose.columns import model_term_columns, noise_model, recording_rows
from hil.diagnose.pipeline import diagnose
from hil.model.closed_form import ArmModel
from hil.model.openloop import simulate_open_loop
from hil.model.params import robot_params

THETA = robot_params("cicese").theta
WITHIN = 0.05  # relative: the recordings are the model plus quantisation, nothing else
# Truths of the size real arms have: a rotor term of 20 % of θ3 (the DFKI A.0's is 14 %), link
# centres of mass 30 % of θ2's lever and 5-10 % of the gravity terms across the links.
TERMS_TRUTH = {
    "rotor_inertia": [0.2 * THETA[2]],
    "com_offset": [0.3 * THETA[1], 0.05 * THETA[3], 0.1 * THETA[4]],
}
DFKI_FILE = (
    Path(__file__).parent / "data" / "dfki" / "design_A.0__20220815__sys_id__trajectory_00.csv"
)


@pytest.fixture(scope="module")
def torque_source(tmp_path_factory):
    """A virtual-robot `diagnosis` run with the model exact (symmetric Coulomb friction)."""
    out = tmp_path_factory.mktemp("source")
    return read_signals(make_recording(out / "rec", "diagnosis", CASES["null"].effects))


def _with_term(source, term: str, out: Path) -> Path:
    """The source's torques on the CICESE arm with ``term`` (TERMS_TRUTH), as a CSV."""
    t, tau = source.t, source.tau
    model = ArmModel((term,))
    sim = simulate_open_loop(np.r_[THETA, TERMS_TRUTH[term]], tau, t[1] - t[0], model=model)
    quantum = noise_model(source.q, t).quantum_rad
    q = np.round(sim.q / np.asarray(quantum)) * np.asarray(quantum)
    path = out / f"{term}.csv"
    np.savetxt(
        path, np.c_[t, q, tau], delimiter=",", header="t,q1,q2,tau1,tau2", comments="", fmt="%.10g"
    )
    return path


def test_candidate_columns_are_the_models_own_columns(torque_source):
    """A model term's candidate columns are exactly the columns ``ArmModel(terms)`` appends to
    Ψ, built over the same intervals and through the same filter."""
    q, tau, h = torque_source.q[:2000], torque_source.tau[:2000], torque_source.period_s
    rows = recording_rows(q, tau, h)
    for term in ("rotor_inertia", "com_offset"):
        full = recording_rows(q, tau, h, model=ArmModel((term,)))
        np.testing.assert_allclose(full.Psi[:, :, :9], rows.Psi, rtol=0, atol=1e-12)
        np.testing.assert_allclose(model_term_columns(rows, term), full.Psi[:, :, 9:], atol=1e-12)
    keys = {c.key for c in candidates(THETA)}
    assert {"rotor_inertia", "com_offset"} <= keys
    keys = {c.key for c in candidates(THETA, model=ArmModel(("rotor_inertia",)))}
    assert "rotor_inertia" not in keys and "com_offset" in keys


def test_host_simulator_with_terms_is_the_models_forward_dynamics():
    """Without Coulomb friction the stick-slip integrator with the terms is plain RK4 of
    ArmModel.forward_dynamics (M, C, g with the rotor term and the centre-of-mass offset)."""
    model = ArmModel(("rotor_inertia", "com_offset"))
    theta = np.r_[THETA, TERMS_TRUTH["rotor_inertia"], TERMS_TRUTH["com_offset"]]
    theta[7:9] = 0.0
    h, n, sub = 0.0025, 200, 5
    t = np.arange(n) * h
    tau = np.c_[60 * np.sin(3 * t), 4 * np.cos(5 * t)]
    sim = simulate_open_loop(theta, tau, h, q0=(0.3, -0.2), model=model, steps_per_period=sub)
    q, v, out = np.array([0.3, -0.2]), np.zeros(2), [np.array([0.3, -0.2])]
    dt = h / sub
    for k in range(n - 1):
        for _ in range(sub):

            def f(qq, vv, k=k):
                return model.forward_dynamics(theta, qq, vv, tau[k])

            a1 = f(q, v)
            a2 = f(q + dt / 2 * v, v + dt / 2 * a1)
            a3 = f(q + dt / 2 * (v + dt / 2 * a1), v + dt / 2 * a2)
            a4 = f(q + dt * (v + dt / 2 * a2), v + dt * a3)
            q, v = q + dt * v + dt**2 / 6 * (a1 + a2 + a3), v + dt / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
        out.append(q)
    assert np.ptp(sim.q, axis=0).min() > 0.5  # it moved
    np.testing.assert_allclose(sim.q, np.array(out), atol=1e-9)
    # not positive definite with the term: refused with the reason
    bad = theta.copy()
    bad[9] = -theta[2] - 0.01
    with pytest.raises(ValueError, match="M22"):
        simulate_open_loop(bad, tau, h, model=model)


@pytest.mark.parametrize("term", ["rotor_inertia", "com_offset"])
def test_missing_model_term_is_found_with_its_size_and_not_again(term, torque_source, tmp_path):
    """The 9-parameter diagnosis of an arm that has the term names it, with its size, and the
    held-out torque and simulated motion improve; the diagnosis whose nominal model has the
    term finds nothing (and does not offer it)."""
    path = _with_term(torque_source, term, tmp_path)
    assert hil_main(["diagnose", str(path), "--json", "--no-plots"]) == 0
    rec = read_signals(path)
    doc = diagnose([rec], THETA).document
    found = [f for f in doc["findings"] if f["effect"] == term]
    assert len(found) == 1, doc["summary"]
    assert {f["effect"] for f in doc["findings"]} == {term}, doc["summary"]
    est = list(found[0]["estimate"].values())[: len(TERMS_TRUTH[term])]
    np.testing.assert_allclose(est, TERMS_TRUTH[term], rtol=WITHIN)
    before, after = doc["fit"]["before"], doc["fit"]["after"]
    joints = [1] if term == "rotor_inertia" else [0, 1]
    for j in joints:
        assert after["torque_nrmse"][j] < before["torque_nrmse"][j]
        assert after["position_nrmse"][j] < before["position_nrmse"][j]
    with_term = ArmModel((term,))
    doc = diagnose([rec], np.r_[THETA, TERMS_TRUTH[term]], model=with_term).document
    assert doc["findings"] == [], doc["summary"]
    assert term not in doc["candidates_tested"]
    assert doc["nominal_model"]["terms"] == [term]
    np.testing.assert_allclose(doc["nominal_theta"][9:], TERMS_TRUTH[term], rtol=WITHIN)


def test_shipped_dfki_profile_diagnoses_with_its_rotor_term(capsys):
    """`--robot dfki-a0` (terms = rotor_inertia): the nominal model is the profile's 10
    parameters, and rotor_inertia is not a candidate again."""
    argv = ["diagnose", str(DFKI_FILE), "--format", "dfki", "--robot", "dfki-a0", "--json"]
    assert hil_main([*argv, "--no-plots"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["nominal_model"]["terms"] == ["rotor_inertia"]
    assert len(doc["nominal_theta"]) == 10
    assert "rotor_inertia" not in doc["candidates_tested"]
    assert not any(f["effect"] == "rotor_inertia" for f in doc["findings"])
    # the refit of this recording holds θ6, θ8 at zero (least squares puts them below): the
    # 10-parameter model's own coefficients
    assert set(doc["physical"]["held_at_zero"]) == {"theta6", "theta8"}, doc["physical"]
    # a joint's held-out torque NRMSE that cannot be scored (too few held-out rows) is n/a in
    # the text report, with the reason said once
    from hil.diagnose.cli import format_report

    assert None not in doc["fit"]["before"]["torque_nrmse"], doc["fit"]
    assert "torque n/a:" not in format_report(doc)
    doc["fit"]["after"]["torque_nrmse"][1] = None
    text = format_report(doc)
    assert text.count("torque n/a: fewer than 50 usable held-out rows") == 1, text


def test_params_with_model_terms_set_the_nominal_model(torque_source, tmp_path, capsys):
    """`hil diagnose --params FILE` with `model_terms` (as `hil identify` writes them): the
    nominal model is the file's, so the rotor term it has is no finding."""
    path = _with_term(torque_source, "rotor_inertia", tmp_path)
    params = tmp_path / "params.json"
    theta = np.r_[THETA, TERMS_TRUTH["rotor_inertia"]].tolist()
    params.write_text(json.dumps({"model_terms": ["rotor_inertia"], "theta": theta}))
    argv = ["diagnose", str(path), "--params", str(params), "--json", "--no-plots"]
    assert hil_main(argv) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["nominal_model"]["terms"] == ["rotor_inertia"]
    assert doc["findings"] == [], doc["summary"]
    assert "rotor_inertia" not in doc["candidates_tested"]
    # a θ that does not fit the model is a one-line error
    params.write_text(json.dumps({"model_terms": ["rotor_inertia"], "theta": theta[:9]}))
    assert hil_main(argv) != 0
    assert "theta" in capsys.readouterr().err


SHARED_DFKI = realdata("dfki-double-pendulum")


def test_dfki_rotor_inertia_found_without_it(capsys):
    """DFKI A.0 trajectory 04 fitted, 05 held out (docs/real-data-diagnosis.md, "The model
    terms"): with the profile variant without the rotor term, `rotor_inertia` is found and
    lowers the held-out torque and simulated position of both joints on the other recording
    (with the shipped profile, the term in the nominal model, it is no candidate:
    test_shipped_dfki_profile_diagnoses_with_its_rotor_term)."""
    records = SHARED_DFKI / "records"
    pair = [records / f"design_A.0__20220815__sys_id__trajectory_0{i}.csv" for i in (4, 5)]
    if not all(p.is_file() for p in pair):
        pytest.skip(f"DFKI recordings not present at {SHARED_DFKI} (../shared/realdata)")
    rigid = Path(__file__).parent / "data" / "dfki" / "dfki-a0-rigid.toml"
    argv = ["diagnose", *map(str, pair), "--format", "dfki", "--robot", str(rigid), "--json"]
    assert hil_main([*argv, "--no-plots"]) == 0
    doc = json.loads(capsys.readouterr().out)
    found = [f for f in doc["findings"] if f["effect"] == "rotor_inertia"]
    assert found, doc["summary"]
    # the owners' 42 Ir = 0.0032 kg m² (datasheet Ir: 0.0026); the identification ≈ 0.0055
    assert 0.002 < found[0]["estimate"]["theta_rotor_kgm2"] < 0.008
    before, after = doc["fit"]["before"], doc["fit"]["after"]
    for key in ("torque_nrmse", "position_nrmse"):
        for j in (0, 1):
            assert after[key][j] < before[key][j], (key, before, after)


def test_residual_bursts_are_timed_from_the_recordings_start():
    """A recording stamped in Unix time (an .npz log's 1.66e9 s) with a torque burst 5–6 s in:
    the burst's window is reported in seconds from the recording's first sample (it was
    reported at 1660000005 s), the origin stated, and the burst note says so."""
    from hil.diagnose.locate import TIME_ORIGIN, locate
    from hil.diagnose.problem import build_problem
    from hil.diagnose.report import burst_notes

    h = 0.002
    t = np.arange(5000) * h
    q = np.stack([0.8 * np.sin(1.3 * t), 0.6 * np.sin(2.1 * t + 0.4)], axis=1)
    tau = np.stack([0.5 * np.sin(1.3 * t + 0.2), 0.2 * np.cos(2.1 * t)], axis=1)
    tau += 0.002 * np.random.default_rng(0).standard_normal(tau.shape)
    burst = (t >= 5.0) & (t < 6.0)
    tau[burst, 0] += 0.5 * np.sin(2 * np.pi * 7 * t[burst])
    prob, theta = build_problem([(q, tau, h, 1.66e9 + t)])
    where = locate(prob, theta).document
    assert where["time_origin"] == TIME_ORIGIN
    windows = where["joints"][0]["time_windows"]
    assert windows and 4.0 <= windows[0]["t_s"][0] <= windows[0]["t_s"][1] <= 7.0, windows
    notes = burst_notes(where)
    assert notes and "from the start" in notes[0] and "1660000" not in notes[0], notes
