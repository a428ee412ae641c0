"""The compiled RK4 step of the n-joint plant (virtual_robot/compiled_step.py, rk4_aba.cpp):
the same trajectory as the Python step, the fallback to the Python step when it is forced or
cannot be built (one line saying why, never a traceback), and `virtual-robot simulate` saying
which step ran (issue 14's speed target)."""

from __future__ import annotations

import json
import os
import shutil
import stat

import numpy as np
import pytest
from fake_compiler import failing_compiler

from profiles.robot import load_urdf_robot
from virtual_robot.cli import main as vr_main
from virtual_robot.compiled_step import CACHE_ENV, KERNEL_ENV, kernel_status
from virtual_robot.urdf_plant import UrdfPlant, UrdfPlantParams

needs_compiler = pytest.mark.skipif(
    shutil.which(os.environ.get("CXX", "g++")) is None,
    reason="no C++ compiler: the compiled plant step cannot be built here",
)
SIM = ["simulate", "--robot", "cicese3", "--experiment", "cicese3-excitation", "--no-plot"]


def falling_panda(rows: int = 400) -> UrdfPlant:
    """The Panda of the speed benchmark for 1 s: open loop from q = 0 under sines of 2 to 8 Nm,
    falling and swinging at up to tens of rad/s, its joints sticking and breaking away."""
    plant = UrdfPlant(UrdfPlantParams.from_profile(load_urdf_robot("panda")))
    h, j = 0.0025, np.arange(7)
    for k in range(rows):
        plant.command((2.0 + j) * np.sin((10.0 + 3 * j) * k * h + 0.1 * j))
        plant.advance_to((k + 1) * h)
    return plant


@needs_compiler
def test_compiled_step_is_the_python_step(monkeypatch):
    """A run far from the frozen reference's (fast, many velocity reversals): the compiled and
    the Python step give the same states (bit for bit here: same operations, same library ABA;
    the bound is 1e-9 rad), the same steps and stick events, and the same energy books."""
    plants = {}
    for kernel in ("python", "compiled"):
        monkeypatch.setenv(KERNEL_ENV, kernel)
        plants[kernel] = falling_panda()
        assert plants[kernel].kernel.kernel == kernel
    py, cc = plants["python"], plants["compiled"]
    assert py.stick_events > 3 and (py.steps, py.stick_events) == (cc.steps, cc.stick_events)
    assert np.abs(py.dq).max() > 5.0  # it does move fast
    assert np.abs(py.q - cc.q).max() <= 1e-9 and np.abs(py.dq - cc.dq).max() <= 1e-9
    assert cc.work_in_J == pytest.approx(py.work_in_J, rel=1e-12)
    assert cc.dissipated_J == pytest.approx(py.dissipated_J, rel=1e-12)


@needs_compiler
def test_periods_in_one_kernel_call_are_command_and_advance_to(monkeypatch):
    """UrdfPlant.advance_periods (ddb_run_periods: many control periods per call, the stick
    events and breakaways handled in the kernel) gives the states of command() + advance_to()
    per period bit for bit, the same steps and stick events, energy books to round-off (the
    work products are summed in joint order there), and stops after the first period ending
    out of its bounds, with that period's row written."""
    monkeypatch.setenv(KERNEL_ENV, "compiled")
    robot = load_urdf_robot("panda")
    h, j, rows = 0.0025, np.arange(7), 400
    k = np.arange(rows)[:, None]
    torques = np.ascontiguousarray((2.0 + j) * np.sin((10.0 + 3 * j) * k * h + 0.1 * j))
    one_by_one = UrdfPlant(UrdfPlantParams.from_profile(robot))
    q_rows, dq_rows = np.empty((rows, 7)), np.empty((rows, 7))
    for i in range(rows):
        one_by_one.command(torques[i])
        one_by_one.advance_to((i + 1) * h)
        q_rows[i], dq_rows[i] = one_by_one.q, one_by_one.dq
    wide = (np.full(7, np.inf), np.full(7, np.inf))
    batched = UrdfPlant(UrdfPlantParams.from_profile(robot))
    q_out, dq_out = np.zeros((rows, 7)), np.zeros((rows, 7))
    half = rows // 2  # two calls, as a recording's blocks
    assert batched.advance_periods(torques[:half], 1, h, wide, q_out, dq_out) == (half, True)
    assert batched.advance_periods(
        torques[half:], half + 1, h, wide, q_out[half:], dq_out[half:]
    ) == (rows - half, True)
    a, b = one_by_one, batched
    assert a.stick_events > 3 and (a.steps, a.stick_events, a.t) == (b.steps, b.stick_events, b.t)
    assert np.array_equal(q_out, q_rows) and np.array_equal(dq_out, dq_rows)
    assert np.array_equal(a.q, b.q) and np.array_equal(a.dq, b.dq)
    assert b.work_in_J == pytest.approx(a.work_in_J, rel=1e-12)
    assert b.dissipated_J == pytest.approx(a.dissipated_J, rel=1e-12)
    # bounds: it stops after the first period whose |q̇| passes 3 rad/s on some joint
    slow = (np.full(7, 3.0), np.full(7, np.inf))
    first_fast = int(np.argmax((np.abs(dq_rows) > 3.0).any(axis=1)))
    assert 0 < first_fast < rows
    bounded = UrdfPlant(UrdfPlantParams.from_profile(robot))
    q_out[:] = 0.0
    assert bounded.advance_periods(torques, 1, h, slow, q_out, dq_out) == (first_fast + 1, False)
    assert np.array_equal(q_out[: first_fast + 1], q_rows[: first_fast + 1])
    assert bounded.t == (first_fast + 1) * h
    monkeypatch.setenv(KERNEL_ENV, "python")  # without the kernel: nothing done, says so
    python_step = UrdfPlant(UrdfPlantParams.from_profile(robot))
    assert python_step.advance_periods(torques, 1, h, wide, q_out, dq_out) == (0, True)


@needs_compiler
def test_stick_events_in_the_kernel_are_the_python_steps(monkeypatch):
    """1.5 s of the shipped ur5e excitation (joints stuck while others stick, break away and
    stick again): the kernel's periods with their stick events in one call (ddb_run_periods)
    give every period's state of the Python step (command() + advance_to(), scipy's brentq,
    Pinocchio's reduced models) bit for bit, the same steps, stick events and final stick
    mode, and the energy books to round-off."""
    from profiles.experiment import load_experiment

    experiment = load_experiment("ur5e-excitation")
    robot, h, rows = load_urdf_robot("ur5e"), experiment.period_s, 600
    torques = np.ascontiguousarray(experiment.torque_rows(h, rows), dtype=float)
    monkeypatch.setenv(KERNEL_ENV, "python")
    python = UrdfPlant(UrdfPlantParams.from_profile(robot), q0=experiment.initial_q_rad)
    q_rows, dq_rows = np.empty((rows, 6)), np.empty((rows, 6))
    stuck_while_another_sticks = 0
    for i in range(rows):
        python.command(torques[i])
        events = python.stick_events
        stuck_before = python._n_stuck
        python.advance_to((i + 1) * h)
        stuck_while_another_sticks += python.stick_events > events and stuck_before > 0
        q_rows[i], dq_rows[i] = python.q, python.dq
    monkeypatch.setenv(KERNEL_ENV, "compiled")
    kernel = UrdfPlant(UrdfPlantParams.from_profile(robot), q0=experiment.initial_q_rad)
    wide = (np.full(6, np.inf), np.full(6, np.inf))
    q_out, dq_out = np.zeros((rows, 6)), np.zeros((rows, 6))
    assert kernel.advance_periods(torques, 1, h, wide, q_out, dq_out) == (rows, True)
    assert python.stick_events > 30 and stuck_while_another_sticks > 5
    assert (kernel.steps, kernel.stick_events, kernel.t) == (python.steps, python.stick_events,
                                                             python.t)  # fmt: skip
    assert np.array_equal(q_out, q_rows) and np.array_equal(dq_out, dq_rows)
    assert np.array_equal(kernel.stuck, python.stuck)
    assert np.array_equal(kernel.slip_dir, python.slip_dir)
    assert kernel.work_in_J == pytest.approx(python.work_in_J, rel=1e-12)
    assert kernel.dissipated_J == pytest.approx(python.dissipated_J, rel=1e-12)


def reduced_params(model, stuck: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Pinocchio's own reduced model (the Python step's locked arm) as rows of
    CompiledArm.locked_params: joint placement (rotation row major, translation), mass,
    lever, rotational inertia (xx, xy, yy, xz, yz, zz)."""
    import pinocchio as pin

    reduced = pin.buildReducedModel(model, [int(j) + 1 for j in stuck], q)
    rows = []
    for placement, inertia in zip(reduced.jointPlacements[1:], reduced.inertias[1:], strict=True):
        i = inertia.inertia
        symmetric = (i[0, 0], i[0, 1], i[1, 1], i[0, 2], i[1, 2], i[2, 2])
        rows.append(
            [*placement.rotation.ravel(), *placement.translation, inertia.mass, *inertia.lever,
             *symmetric]
        )  # fmt: skip
    return np.array(rows).reshape(-1, 22)


@needs_compiler
@pytest.mark.parametrize("robot_name", ["panda", "ur5e"])
def test_a_locked_arm_refreshed_in_place_is_pinocchios_reduced_model(monkeypatch, robot_name):
    """The kernel builds one locked arm per stuck set and, when that set sticks again at other
    positions, recomputes only what q_S enters (rk4_aba.cpp, refresh_locked): its placements
    and inertias equal Pinocchio's buildReducedModel at those positions bit for bit, for stuck
    sets with neighbouring, separated and end joints and every joint; its accelerations and
    RK4 step equal those of a locked arm built fresh, and the Python step's ABA on the
    reduced model."""
    monkeypatch.setenv(KERNEL_ENV, "compiled")
    import pinocchio as pin

    from virtual_robot.compiled_step import CompiledArm

    plant = UrdfPlant(UrdfPlantParams.from_profile(load_urdf_robot(robot_name)))
    p, n = plant.params, plant.n_joints
    b = np.asarray(p.viscous_Nms)
    rng = np.random.default_rng(3)
    kept = CompiledArm(p.urdf, p.gravity_m_s2, p.armature_kgm2)
    sets = [np.array(s) for s in ([1, 3], [2], [1, 2], [0], [n - 1], [0, 2, 4], [1, 2, n - 1])]
    sets.append(np.arange(n))  # all stuck: nothing moves
    refreshed = 0
    for _ in range(4):  # each set locked again at new positions three times
        for stuck in sets:
            q, v, c = rng.uniform(-3.0, 3.0, (3, n))
            v[stuck] = 0.0
            locked = kept.locked(stuck, q)
            free = np.setdiff1d(np.arange(n), stuck)
            if free.size == 0:
                assert kept.locked_params(locked).size == 0
                assert np.array_equal(kept.accelerations(locked, q, v, c, b), np.zeros(n))
                continue
            assert np.array_equal(kept.locked_params(locked), reduced_params(plant.model, stuck, q))
            refreshed += 1
            fresh = CompiledArm(p.urdf, p.gravity_m_s2, p.armature_kgm2)
            built = fresh.locked(stuck, q)
            a_k = kept.accelerations(locked, q, v, c, b)
            assert np.array_equal(a_k, fresh.accelerations(built, q, v, c, b))
            assert np.all(a_k[stuck] == 0.0)
            step_k, step_f = (
                kept.step(locked, q, v, c, b, 5e-4),
                fresh.step(built, q, v, c, b, 5e-4),
            )
            assert all(np.array_equal(x, y) for x, y in zip(step_k, step_f, strict=True))
            reduced = pin.buildReducedModel(plant.model, [int(j) + 1 for j in stuck], q)
            reduced.armature = plant.model.armature[free]
            a_py = pin.aba(reduced, reduced.createData(), q[free], v[free], (c - b * v)[free])
            assert np.array_equal(a_k[free], a_py)
    assert refreshed == 4 * (len(sets) - 1)


@needs_compiler
def test_stick_located_in_the_kernel_as_by_scipys_brent(monkeypatch):
    """The kernel's stick location (ddb_locate: scipy's brentq ported, on the kernel's RK4 flow
    map) gives the time, the joint and the state of the Python step's (scipy's brentq on the
    Python RK4), bit for bit (the viscous work to round-off), at every stick event of a fast
    Panda run and of 1.5 s of the shipped ur5e excitation (joints stuck while others stick).
    The offline simulation's periods locate in the kernel too (ddb_run_periods); this is the
    path of command() + advance_to()."""
    monkeypatch.setenv(KERNEL_ENV, "compiled")
    located = UrdfPlant.locate
    compared = []

    def both(plant, dt, crossed, end):
        kernel = located(plant, dt, crossed, end)
        compiled, plant._compiled = plant._compiled, None  # the Python step's
        try:
            python = located(plant, dt, crossed, end)
        finally:
            plant._compiled = compiled
        (s_k, joint_k, (q_k, v_k, work_k)), (s_p, joint_p, (q_p, v_p, work_p)) = kernel, python
        assert (s_k, joint_k) == (s_p, joint_p)
        assert np.array_equal(q_k, q_p) and np.array_equal(v_k, v_p)
        # ∫bᵀq̇² dt: Eigen's dot product beside numpy's, which may sum in another order (the
        # energy books only; the compiled step's work was the kernel's before too)
        assert work_k == pytest.approx(work_p, rel=1e-14, abs=1e-300)
        compared.append((kernel[0] < dt, len(crossed), plant._n_stuck))
        return kernel

    monkeypatch.setattr(UrdfPlant, "locate", both)
    falling_panda()
    from profiles.experiment import load_experiment

    experiment = load_experiment("ur5e-excitation")
    ur5e = UrdfPlant(
        UrdfPlantParams.from_profile(load_urdf_robot("ur5e")), q0=experiment.initial_q_rad
    )
    h = experiment.period_s
    for k, row in enumerate(experiment.torque_rows(h, 600)):
        ur5e.command(row)
        ur5e.advance_to((k + 1) * h)
    assert len(compared) > 20
    assert any(inside for inside, _, _ in compared)  # zeros inside the step, not only at ends
    assert any(stuck for _, _, stuck in compared)  # and with joints locked


def test_python_step_forced(monkeypatch, tmp_path, capsys):
    monkeypatch.setenv(KERNEL_ENV, "python")
    plant = UrdfPlant(UrdfPlantParams.from_profile(load_urdf_robot("cicese3")))
    assert plant.kernel.kernel == "python" and plant._compiled is None
    assert vr_main([*SIM, "--duration", "0.1", "--out", str(tmp_path / "s"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["plant_kernel"] == {"kernel": "python", "reason": f"{KERNEL_ENV}=python"}
    meta = json.loads((tmp_path / "s" / "meta.json").read_text())
    assert meta["integrator"]["kernel"]["kernel"] == "python"
    monkeypatch.setenv(KERNEL_ENV, "fortran")
    assert vr_main([*SIM, "--duration", "0.1", "--out", str(tmp_path / "t")]) == 2
    err = capsys.readouterr().err.strip()
    assert KERNEL_ENV in err and len(err.splitlines()) == 1, err


@needs_compiler
def test_simulate_says_the_compiled_step_ran(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv(KERNEL_ENV, raising=False)
    assert vr_main([*SIM, "--duration", "0.1", "--out", str(tmp_path / "s")]) == 0
    assert "plant step: compiled" in capsys.readouterr().out.splitlines()


def test_broken_build_falls_back_in_one_line(tmp_path, capsys, monkeypatch):
    """A compiler that fails, and none at all: the plant runs its Python step, `simulate`
    says why in one line and exits 0; the failure is remembered (the compiler is not run
    again for the same source); with DDBENCH_PLANT_KERNEL=compiled it is a one-line error."""
    broken, calls = failing_compiler(
        tmp_path, "rk4_aba.cpp:1:10: fatal error: Eigen/Core: No such file"
    )
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "cache"))
    monkeypatch.setenv("CXX", str(broken))
    monkeypatch.delenv(KERNEL_ENV, raising=False)
    for attempt in range(2):
        out = tmp_path / f"s{attempt}"
        assert vr_main([*SIM, "--duration", "0.1", "--out", str(out), "--json"]) == 0
        captured = capsys.readouterr()
        kernel = json.loads(captured.out)["plant_kernel"]
        assert kernel["kernel"] == "python"
        assert "failed" in kernel["reason"] and "Eigen/Core" in kernel["reason"]
        assert "\n" not in kernel["reason"] and "Traceback" not in captured.err
        assert (out / "signals.csv").exists()
    assert calls.read_text().count("run") == 1  # remembered beside the library
    monkeypatch.setenv(KERNEL_ENV, "compiled")
    assert vr_main([*SIM, "--duration", "0.1", "--out", str(tmp_path / "no")]) == 2
    err = capsys.readouterr().err.strip()
    assert "Eigen/Core" in err and len(err.splitlines()) == 1, err
    monkeypatch.setenv("CXX", str(tmp_path / "no-such-compiler"))
    monkeypatch.setenv(KERNEL_ENV, "auto")
    status = kernel_status()
    assert status.kernel == "python" and "no C++ compiler" in status.reason


def test_cached_library_is_used_without_a_compiler(tmp_path, monkeypatch):
    """A library built once stays in use when the compiler is gone later (a machine whose
    build tools were removed, a container built from a cached image): its key (source,
    compiler name, flags, Pinocchio version) matches, so nothing needs compiling."""
    monkeypatch.delenv(KERNEL_ENV, raising=False)
    real = kernel_status()
    if real.kernel != "compiled":
        pytest.skip(f"no compiled step to reuse here: {real.reason}")
    compiler = tmp_path / "bin" / "c++"  # a compiler that "builds" by copying the real one
    compiler.parent.mkdir()
    compiler.write_text(f'#!/bin/sh\nfor a; do [ "$p" = -o ] && out="$a"; p="$a"; done\n'
                        f'cp "{real.library}" "$out"\n')  # fmt: skip
    compiler.chmod(compiler.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "cache"))
    monkeypatch.setenv("CXX", str(compiler))
    built = kernel_status()
    assert built.kernel == "compiled", built.reason
    compiler.unlink()  # the compiler is gone; the cached library is not
    status = kernel_status()
    assert status.kernel == "compiled", status.reason
    assert status.library == built.library
    (tmp_path / "cache" / os.path.basename(built.library)).unlink()  # and without it: why not
    status = kernel_status()
    assert status.kernel == "python" and "no C++ compiler" in status.reason
