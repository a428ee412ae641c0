"""Both arm models declare hil.model.protocol.ArmDynamics: analyses ask the model, not its class."""

from __future__ import annotations

import numpy as np
import pytest

from hil.model import ArmDynamics, ArmModel, UrdfArmModel


def _urdf_model() -> UrdfArmModel:
    return UrdfArmModel.from_profile("cicese")


@pytest.fixture(scope="module")
def models():
    return [ArmModel(()), ArmModel(("rotor_inertia",)), _urdf_model()]


def test_both_models_satisfy_the_protocol(models):
    for model in models:
        assert isinstance(model, ArmDynamics), type(model).__name__


def test_rigid_count_splits_rigid_from_friction(models):
    closed, rotor, urdf = models
    assert closed.rigid_count == 5 and rotor.rigid_count == 5
    assert urdf.rigid_count == urdf.n_params - urdf.n_friction
    # the rigid parameters come before every friction column
    for model in models:
        assert min(model.friction_columns) >= model.rigid_count


def test_words_and_refusals(models):
    closed, rotor, urdf = models
    assert closed.display_name == "9-parameter"
    assert rotor.display_name == "10-parameter (rotor_inertia)"
    assert "base-parameter" in urdf.display_name and "2 joints" in urdf.display_name
    assert closed.refused_terms == {} and "com_offset" in urdf.refused_terms
    assert "rotor_inertia" not in rotor.missing_terms and "rotor_inertia" in closed.missing_terms
    assert urdf.missing_terms == ()
    assert closed.closed_form and not urdf.closed_form


def test_torques_through_the_protocol_agree_with_the_regressor(models):
    rng = np.random.default_rng(0)
    q, dq, ddq = rng.normal(size=(3, 5, 2))
    for model in models:
        theta = np.abs(rng.normal(size=model.n_params)) if model.closed_form else model.base_theta()
        tau = model.torque(theta, q, dq, ddq)
        assert tau.shape == (5, 2) and np.all(np.isfinite(tau))
