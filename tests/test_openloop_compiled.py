"""The open-loop simulation's compiled sub-step (hil/model/compiled_openloop.py,
openloop_slide.c; issue 13): the same bits as the Python step on every row, stick–slip, model
terms and stretched periods included, and the fallback to the Python step when it is forced or
cannot be built (one line saying why, never a traceback)."""

from __future__ import annotations

import logging
import os
import shutil

import numpy as np
import pytest
from fake_compiler import failing_compiler

import hil.model.compiled_openloop as compiled
from drivers.native_build import CACHE_ENV
from hil.model.closed_form import ArmModel
from hil.model.compiled_openloop import KERNEL_ENV, kernel_status
from hil.model.openloop import simulate_open_loop, simulate_open_loop_chunks
from hil.model.params import robot_params
from profiles.experiment import load_experiment

H = 0.0025
needs_compiler = pytest.mark.skipif(
    shutil.which(os.environ.get("CC", "cc")) is None,
    reason="no C compiler: the compiled open-loop step cannot be built here",
)


def torques(experiment: str, rows: int, scale: float = 1.0) -> np.ndarray:
    return scale * load_experiment(experiment).torque_table(np.arange(rows) * H)


def both(monkeypatch, run):
    """``run()`` with the Python step and with the compiled one (which must be the one run)."""
    results = {}
    for kernel in ("python", "compiled"):
        monkeypatch.setenv(KERNEL_ENV, kernel)
        assert kernel_status().kernel == kernel
        results[kernel] = run()
    return results["python"], results["compiled"]


def assert_same_bits(py, cc) -> None:
    for field in ("t", "q", "dq", "stuck", "stick_events", "breakaways"):
        a, b = getattr(py, field), getattr(cc, field)
        assert a.shape == b.shape and a.tobytes() == b.tobytes(), field
    assert py.substeps == cc.substeps


@needs_compiler
@pytest.mark.parametrize(
    "name, experiment, rows, scale, kwargs",
    [
        # joints swing, reverse and stick again and again (Coulomb levels of the profile)
        ("stick-slip", "reyes-kelly", 3000, 1.0, {}),
        ("asymmetric-coulomb", "reyes-kelly", 1500, 1.0,
         {"coulomb_positive": (7.17, 1.734), "coulomb_negative": (8.049, 1.734)}),
        # fast motion, both joints sliding nearly throughout: the compiled rows dominate
        ("moving-start-3-substeps", "validation-multisine", 2000, 1.0,
         {"q0": (0.3, -0.2), "dq0": (0.5, -0.1), "steps_per_period": 3}),
        ("joint2-frictionless", "reyes-kelly", 1500, 1.0,
         {"coulomb_positive": (7.17, 0.0), "coulomb_negative": (8.049, 0.0)}),
        ("weak-torques-mostly-stuck", "reyes-kelly", 1500, 0.4, {}),
    ],
)  # fmt: skip
def test_compiled_step_gives_the_python_steps_bits(monkeypatch, name, experiment, rows, scale,
                                                   kwargs):  # fmt: skip
    theta = robot_params().theta
    tau = torques(experiment, rows, scale)
    py, cc = both(monkeypatch, lambda: simulate_open_loop(theta, tau, H, **kwargs))
    assert_same_bits(py, cc)
    if name != "joint2-frictionless":
        assert py.stick_events.sum() > 0 or py.stuck.any()  # stick–slip exercised


@needs_compiler
def test_compiled_step_with_model_terms_and_real_sample_times(monkeypatch):
    """Rotor inertia and a centre-of-mass offset (the θ2⊥, θ4⊥, θ5⊥ branch) over stretched
    periods (a realtime recording's intervals), in chunks that cut through stick events."""
    model = ArmModel(("rotor_inertia", "com_offset"))
    base = robot_params().theta
    theta = np.concatenate([base, [0.004, 0.01, -0.3, 0.05]])  # θ_rotor, θ2⊥, θ4⊥, θ5⊥
    assert model.n_params == len(theta)
    rows = 2500
    tau = torques("reyes-kelly", rows)
    rng = np.random.default_rng(13)
    intervals = H * (1.0 + 0.2 * rng.uniform(-1.0, 1.0, rows - 1))
    py, cc = both(
        monkeypatch,
        lambda: simulate_open_loop(theta, tau, H, intervals_s=intervals, model=model),
    )
    assert_same_bits(py, cc)
    assert py.stick_events.sum() > 0

    def chunked():
        parts = list(simulate_open_loop_chunks(base, tau, H, chunk=97, intervals_s=intervals))
        return np.concatenate([p.q for p in parts]), np.concatenate([p.dq for p in parts])

    (pq, pdq), (cq, cdq) = both(monkeypatch, chunked)
    assert pq.tobytes() == cq.tobytes() and pdq.tobytes() == cdq.tobytes()


@needs_compiler
def test_compiled_step_runs_most_rows(monkeypatch):
    """The compiled step takes the rows in every stick mode, the Python step only those in
    which the mode changes: counted through the slider's calls, on a run that sticks often."""
    monkeypatch.setenv(KERNEL_ENV, "compiled")
    taken: dict[tuple[bool, bool], int] = {}
    real_run = compiled.Slider.run

    def counting(self, row, rows, state, stuck, levels, direction):
        out = real_run(self, row, rows, state, stuck, levels, direction)
        taken[stuck] = taken.get(stuck, 0) + out[0]
        return out

    monkeypatch.setattr(compiled.Slider, "run", counting)
    sim = simulate_open_loop(robot_params().theta, torques("reyes-kelly", 4000, 0.3), H)
    events = int(sim.stick_events.sum() + sim.breakaways.sum())
    assert events > 20 and sim.stuck[:-1].any(axis=1).sum() > 4 * events
    assert sum(taken.values()) >= len(sim.q) - 1 - events  # at most a row per event in Python
    stuck_rows = sim.stuck[:-1].any(axis=1).sum()
    assert sum(n for mode, n in taken.items() if any(mode)) >= stuck_rows - events


def test_python_step_forced(monkeypatch):
    monkeypatch.setenv(KERNEL_ENV, "python")
    assert kernel_status().reason == f"{KERNEL_ENV}=python" and not compiled.compiled()
    monkeypatch.setenv(KERNEL_ENV, "fortran")
    with pytest.raises(ValueError, match=KERNEL_ENV):
        kernel_status()


def test_broken_build_falls_back_in_one_line(tmp_path, monkeypatch, caplog):
    """A compiler that fails: the Python step runs, one warning line says why, the failure is
    remembered (the compiler is not run again); with DDBENCH_OPENLOOP_KERNEL=compiled it is a
    one-line ValueError. No compiler at all: the same fallback."""
    broken, calls = failing_compiler(
        tmp_path, "openloop_slide.c:1:10: fatal error: math.h: No such file"
    )
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "cache"))
    monkeypatch.setenv("CC", str(broken))
    monkeypatch.setenv(KERNEL_ENV, "auto")
    theta, tau = robot_params().theta, torques("reyes-kelly", 200)
    with caplog.at_level(logging.WARNING):
        for _ in range(2):
            status = kernel_status()
            assert status.kernel == "python" and "math.h" in status.reason
            assert "\n" not in status.reason
            assert len(simulate_open_loop(theta, tau, H).q) == 200
    assert calls.read_text().count("run") == 1  # remembered beside the library
    monkeypatch.setenv(KERNEL_ENV, "compiled")
    with pytest.raises(ValueError, match=r"math\.h") as err:
        kernel_status()
    assert "\n" not in str(err.value)
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    monkeypatch.setenv(KERNEL_ENV, "auto")
    status = kernel_status()
    assert status.kernel == "python" and "no C compiler" in status.reason
