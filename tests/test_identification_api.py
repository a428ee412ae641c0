"""One identification API (issue 29 item 3): ``identify(model, recording, scheme, ...)`` returns
an ``Identification`` for every arm and engine, the same numbers as the engine it calls, one
uncertainty type and one JSON layout; options an engine has not are refused in one line; the
``identifications`` layout reads back as a parameter file, as do older identify.json layouts."""

from __future__ import annotations

import json

import numpy as np
import pytest

from drivers.recording import read_signals
from hil.identify import Identification, identify
from hil.identify.schemes import Uncertainty, identify_model
from hil.identify.schemes import identify as identify_schemes
from hil.model.closed_form import ArmModel
from hil.model.params import ParamsError, load_params
from hil.model.urdf import UrdfArmModel
from profiles.experiment import load_experiment
from profiles.robot import load_robot
from virtual_robot.simulate import simulate

LAYOUT = {
    "model", "terms", "scheme", "discretization", "estimator", "lambda_rad_s", "method", "names",
    "units", "theta", "theta_least_squares", "rows", "uncertainty", "physical_consistency",
    "usable", "failed_reason",
}  # fmt: skip


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    """4 s of eqs. (31)-(32) on the CICESE arm (offline simulation, ~0.1 s)."""
    out = tmp_path_factory.mktemp("rk")
    simulate(load_robot("cicese"), load_experiment("reyes-kelly"), out, duration_s=4.0, plot=False)
    return read_signals(out)


def test_paper_estimators_are_the_table_ii_engine(rec):
    for disc in ("exact", "paper"):
        ident = identify(ArmModel(), rec, "filtered_power", discretization=disc, estimator="wls")
        engine = identify_schemes(
            rec.q, rec.tau, rec.period_s, schemes=["filtered_power"], discretization=disc,
            estimator="wls",
        )["filtered_power"]  # fmt: skip
        assert isinstance(ident, Identification) and ident.discretization == disc
        assert np.array_equal(ident.theta, engine.theta) and ident.uncertainty is None
        assert ident.lam == 50.0 and ident.rows == engine.rows
        doc = ident.to_json()
        assert set(doc) == LAYOUT and doc["model"] == "closed_form" and len(doc["theta"]) == 9
        json.dumps(doc, allow_nan=False)  # strict JSON


def test_bounded_estimator_is_the_model_path(rec):
    model = ArmModel(("rotor_inertia",))
    ident = identify(model, rec, lam=40.0)
    engine = identify_model(rec.t, rec.q, rec.tau, model, lam=40.0)
    assert np.array_equal(ident.theta, engine.theta) and ident.estimator == "bounded"
    assert isinstance(ident.uncertainty, Uncertainty)
    assert np.array_equal(ident.uncertainty.se_block, engine.se_block)
    doc = ident.to_json()
    assert doc["terms"] == ["rotor_inertia"] and doc["names"][-1] == "theta_rotor"
    assert len(doc["uncertainty"]["se_blocked_bootstrap"]) == model.n_params


def test_urdf_arm_base_parameters_with_the_same_layout(rec):
    model = UrdfArmModel.from_profile("cicese")
    ident = identify(model, rec, "filtered_dynamic", cutoff_hz=5.0)
    assert ident.theta.shape == (model.n_params,) and ident.consistency["consistent"]
    assert ident.usable and isinstance(ident.uncertainty, Uncertainty)
    doc = ident.to_json()
    assert set(doc) == LAYOUT and doc["model"] == "urdf" and doc["names"] == list(model.names)
    # friction ≥ 0 whatever least squares says: where it says less, θ is the bounded fit
    friction = ident.theta[list(model.friction_columns)]
    assert np.all(friction >= 0), friction
    if ident.theta_least_squares is not None:
        assert "bounded to friction >= 0" in ident.method


def test_a_command_s_verdict_fails_an_identification(rec):
    ident = identify(ArmModel(), rec, estimator="ls")
    assert ident.usable and ident.failing(None) is ident
    failed = ident.failing("failed held-out validation: joint 2")
    assert not failed.usable and failed.to_json()["failed_reason"].endswith("joint 2")
    assert failed.failing("another reason").failed_reason == failed.failed_reason


@pytest.mark.parametrize(
    ("model", "options", "message"),
    [
        (ArmModel(), {"scheme": "kalman"}, "unknown scheme 'kalman'"),
        (ArmModel(), {"discretization": "paper"}, "the paper's discretization is the 9-param"),
        (ArmModel(("rotor_inertia",)), {"estimator": "rls"}, "the paper's estimators fit"),
        (ArmModel(), {"estimator": "magic"}, "unknown estimator 'magic'"),
    ],
)
def test_options_an_engine_has_not_are_refused_in_one_line(rec, model, options, message):
    with pytest.raises(ValueError, match=message) as err:
        identify(model, rec, **options)
    assert "\n" not in str(err.value)


def test_urdf_arm_refuses_the_recursive_estimators(rec):
    with pytest.raises(ValueError, match="fitted by the 'bounded' estimator only"):
        identify(UrdfArmModel.from_profile("cicese"), rec, estimator="rls")


def test_identify_json_layouts_read_as_parameter_files(rec, tmp_path):
    """The ``identifications`` layout, and the two 2-DOF layouts of older files (Table II's
    ``discretizations``, the model path's ``identification``), give the same θ; a FAILED
    selection is refused with its reason."""
    ident = identify(ArmModel(), rec, estimator="rls")
    selection = {"scheme": "filtered_dynamic", "discretization": "exact", "usable": True}
    docs = {
        "one layout": {"identifications": [ident.to_json()], "selection": selection},
        "table ii": {
            "discretizations": {"exact": {"schemes": {"filtered_dynamic": ident.to_json()}}},
            "selection": selection,
        },
        "model path": {"identification": ident.to_json(), "selection": selection},
    }
    for name, doc in docs.items():
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(doc))
        params = load_params(path)
        assert params.scheme == "filtered_dynamic", name
        assert np.array_equal(params.theta, ident.theta), name
    failed = ident.failing("torque prediction no better than its mean on joint 1")
    path = tmp_path / "failed.json"
    path.write_text(json.dumps({"identifications": [failed.to_json()], "selection": selection}))
    with pytest.raises(ParamsError, match=r"FAILED, not parameters \(torque prediction"):
        load_params(path)
