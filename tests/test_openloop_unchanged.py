"""hil.model.openloop's integrator is one scheme with and without effects, and unchanged.

The rigid model and the diagnosis's effects used to run in two copies of the stick–slip integrator
(hil/model/openloop.py and openloop_effects.py, issue 15); they are now one,
hil.model.openloop_core.integrate. REFERENCE holds the results of the two old copies (commit
4f21f7c) on fixed cases, captured before the merge: the merged integrator reproduces them to the
last bit on this machine (checked against the old code over full runs of all shipped experiments);
the tolerance below only allows for another libm.
"""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from hil.model.openloop import OpenLoopExtras, simulate_open_loop
from hil.model.openloop_core import Friction, TorquePath, integrate
from hil.model.openloop_effects import EffectsTorquePath, integrate_with_extras
from hil.model.params import robot_params
from profiles.experiment import load_experiment

H = 0.0025

# name: (experiment, rows, simulate_open_loop keywords, OpenLoopExtras keywords or None)
CASES = {
    # name: (experiment, rows, simulate_open_loop keywords, OpenLoopExtras keywords or None)
    "rigid_asymmetric_coulomb": (
        "reyes-kelly",
        800,
        {"coulomb_positive": (7.17, 1.734), "coulomb_negative": (8.049, 1.734)},
        None,
    ),
    "rigid_moving_start_3_substeps": (
        "validation-multisine",
        600,
        {"q0": (0.3, -0.2), "dq0": (0.5, -0.1), "steps_per_period": 3},
        None,
    ),
    "rigid_joint2_without_coulomb": (
        "reyes-kelly",
        600,
        {"coulomb_positive": (7.17, 0.0), "coulomb_negative": (8.049, 0.0)},
        None,
    ),
    "gain_offset_whole_period_delay": (
        "validation-multisine",
        600,
        {},
        {"torque_gain": (0.06, -0.06), "torque_offset_Nm": (1.0, 0.15), "transport_delay_s": 0.005},
    ),
    "lag_fractional_delay_settled_start": (
        "diagnosis",
        800,
        {},
        {
            "actuator_lag_s": (0.003, 0.002),
            "transport_delay_s": 0.0061,
            "initial_command_Nm": (2.0, -0.5),
            "torque_gain": (0.03, 0.0),
        },
    ),
    "cogging_stribeck_angle_offset": (
        "reyes-kelly",
        800,
        {"q0": (0.01, 0.02)},
        {
            "cogging_periods_per_rev": (120.0, 96.0),
            "cogging_amplitude_Nm": (1.5, 0.15),
            "cogging_phase_rad": (0.3, 0.5),
            "stribeck_breakaway_ratio": (1.35, 1.25),
            "stribeck_velocity_rad_s": (0.08, 0.10),
            "angle_offset_rad": (0.01, 0.02),
        },
    ),
    "all_effects_with_chattering": (  # row 1693: a lagged break-away chatters (8 stick events)
        "diagnosis",
        1800,
        {"q0": (0.01, 0.02), "coulomb_positive": (7.17, 1.6), "coulomb_negative": (8.049, 1.9)},
        {
            "torque_offset_Nm": (0.5, 0.1),
            "torque_gain": (0.03, -0.02),
            "actuator_lag_s": (0.002, 0.001),
            "transport_delay_s": 0.0011,
            "cogging_periods_per_rev": (120.0, 96.0),
            "cogging_amplitude_Nm": (1.0, 0.1),
            "stribeck_breakaway_ratio": (1.2, 1.1),
            "stribeck_velocity_rad_s": (0.1, 0.1),
            "stribeck_exponent": 1.5,
            "angle_offset_rad": (0.01, 0.02),
        },
    ),
}

# per case: q and dq at rows N//3, 2N//3, N−1; (stuck samples, stick events, break-aways per
# joint, sub-steps), from the code before the merge
REFERENCE = {
    "rigid_asymmetric_coulomb": {
        "q": [
            [0.43370179275077353, 0.2475793277481037],
            [0.36235490369423323, -0.05301338507435307],
            [0.5554620471717537, 0.3041611701368252],
        ],
        "dq": [
            [-0.2938034653717425, 0.6783590632101396],
            [2.0895850403608662, -0.20701231073772897],
            [-0.800329447764746, 0.22976216841040706],
        ],
        "counts": ([1, 28], [9, 16], [10, 17], 3995),
    },
    "rigid_moving_start_3_substeps": {
        "q": [
            [0.3292174534914324, -0.05878103762723963],
            [-0.46495213842280836, -0.24031946348422195],
            [-0.38486118794693686, -1.400150970595834],
        ],
        "dq": [
            [-4.587285394091205, 2.625729588109488],
            [-2.629647688174299, 2.6312367169480853],
            [1.2620411864172163, 2.342923449380496],
        ],
        "counts": ([0, 6], [4, 9], [4, 9], 1797),
    },
    "rigid_joint2_without_coulomb": {
        "q": [
            [0.2541578668938087, 0.7558925820274094],
            [0.3860033940550239, 0.0757663027741616],
            [0.6047256425142016, -0.2832539169343209],
        ],
        "dq": [
            [1.1951944888110562, -6.044772189854313],
            [2.108626132111731, -7.972597659453111],
            [-0.8087125932112335, 0.3234758820017832],
        ],
        "counts": ([2, 0], [7, 0], [8, 0], 2995),
    },
    "gain_offset_whole_period_delay": {
        "q": [
            [0.33658095088673196, -0.047584092935020965],
            [-0.31427093927898525, -0.08371714507195746],
            [-0.455777159006259, -1.3036945246754306],
        ],
        "dq": [
            [-3.901215158517638, 3.6392730301604037],
            [-2.9575396758254184, 2.608192040574596],
            [1.243137960643744, 2.1642900451019997],
        ],
        "counts": ([3, 15], [4, 8], [5, 9], 2995),
    },
    "lag_fractional_delay_settled_start": {
        "q": [
            [0.04028741757650164, -0.008790236873312818],
            [0.6204327145122839, -0.331824106935946],
            [1.0660365622992973, -0.8825154681574375],
        ],
        "dq": [
            [0.9368843014617889, 0.2879400396818328],
            [4.326514537744872, -8.112451995598455],
            [1.4242500374743414, -10.091302636763682],
        ],
        "counts": ([122, 216], [5, 6], [6, 7], 4794),
    },
    "cogging_stribeck_angle_offset": {
        "q": [
            [0.4270423552208169, 0.27423534850343595],
            [0.36473090852317575, -0.03949965810884254],
            [0.5544985413025694, 0.32606546331845854],
        ],
        "dq": [
            [-0.30637332092009417, 0.6418253398322871],
            [2.1138637704587038, -0.179492935759369],
            [-0.8001904994579172, 0.07508249775391306],
        ],
        "counts": ([2, 39], [9, 15], [10, 16], 3995),
    },
    "all_effects_with_chattering": {
        "q": [
            [1.2801932059047958, -0.8775104988099727],
            [0.694742389474514, -1.5049682082874383],
            [-0.2443788099562893, -1.1438660576715347],
        ],
        "dq": [
            [0.6766345135358482, 1.8768655143835955],
            [1.4774305087218078, -3.9742188232285267],
            [-1.3947305677678892, 1.1114603074772076],
        ],
        "counts": ([125, 250], [14, 23], [15, 24], 10794),
    },
}


@pytest.fixture(scope="module")
def theta() -> np.ndarray:
    return robot_params().theta


def run_case(theta: np.ndarray, name: str):
    experiment, rows, kwargs, extras = CASES[name]
    tau = load_experiment(experiment).torque_table(np.arange(rows) * H)
    ex = None if extras is None else OpenLoopExtras(**extras)
    return simulate_open_loop(theta, tau, H, extras=ex, **kwargs)


@pytest.mark.parametrize("name", list(CASES))
def test_results_match_the_code_before_the_merge(theta, name):
    sim = run_case(theta, name)
    n = len(sim.q)
    rows = [n // 3, 2 * n // 3, n - 1]
    ref = REFERENCE[name]
    np.testing.assert_allclose(sim.q[rows], ref["q"], rtol=0, atol=1e-10)
    np.testing.assert_allclose(sim.dq[rows], ref["dq"], rtol=0, atol=1e-8)
    stuck_samples, stick_events, breakaways, substeps = ref["counts"]
    assert sim.stuck.sum(axis=0).tolist() == stuck_samples
    assert sim.stick_events.tolist() == stick_events
    assert sim.breakaways.tolist() == breakaways
    assert sim.substeps == substeps


def test_the_effects_path_with_no_effect_is_the_rigid_integration_bit_for_bit(theta):
    """Through EffectsTorquePath (delay 0, no lag, gain 0, offset 0) and plain Coulomb friction
    the one integrator gives exactly what the identity path gives: the effects add terms, not a
    second scheme."""
    tau = load_experiment("reyes-kelly").torque_table(np.arange(1200) * H)
    pos, neg = (7.17, 1.734), (8.049, 1.734)
    start = (0.0, 0.0, 0.0, 0.0)
    rigid = integrate(theta, tau, H, 5, start, Friction(pos, neg))
    same = integrate_with_extras(theta, tau, H, 5, start, pos, neg, OpenLoopExtras())
    for field in ("q", "dq", "stuck", "stick_events", "breakaways"):
        assert np.array_equal(getattr(rigid, field), getattr(same, field)), field
    assert rigid.substeps == same.substeps
    assert rigid.stick_events.sum() > 20  # stick–slip exercised
    assert TorquePath().applied((1.5, -2.0), 0.001) == ((1.5, -2.0), (1.5, -2.0))
    # a lag is a state carried from step to step: the path moves it only when told to settle
    lagged = EffectsTorquePath(OpenLoopExtras(actuator_lag_s=(0.002, 0.0)))
    (mean1, mean2), end = lagged.applied((1.0, 1.0), 0.002)
    assert 0.0 < mean1 < end[0] < 1.0 and mean2 == end[1] == 1.0 and lagged.lag == (0.0, 0.0)


def test_the_core_sits_below_the_simulator_modules():
    """openloop_core imports from hil only its compiled sub-step (which imports nothing of hil),
    openloop_effects only the core: no cycle."""
    here = Path(__file__).resolve().parents[1] / "hil" / "model"

    def hil_imports(module: str) -> set[str]:
        tree = ast.parse((here / f"{module}.py").read_text())
        return {
            node.module
            for node in ast.walk(tree)
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("hil")
        }

    assert hil_imports("openloop_core") == {"hil.model.compiled_openloop"}
    assert hil_imports("compiled_openloop") == set()
    assert hil_imports("openloop_effects") == {"hil.model.openloop_core"}
