"""`virtual-robot simulate` and `hil demo` end to end: recording format, determinism, drives."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from drivers.recording import read_signals
from profiles.experiment import load_experiment
from profiles.robot import load_robot
from virtual_robot.simulate import simulate

H = 0.0025


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "virtual_robot.cli", *args],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )


def test_cli_simulate_writes_the_recording(tmp_path):
    out = tmp_path / "run"
    proc = run_cli(
        "simulate",
        "--robot",
        "cicese",
        "--experiment",
        "reyes-kelly",
        "--duration",
        "1",
        "--out",
        str(out),
        "--json",
    )
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)  # --json: one JSON document and nothing else on stdout
    assert summary["rows"] == 400
    assert Path(summary["plot"]).is_file() and Path(summary["plot"]).stat().st_size > 10_000
    rec = read_signals(out)
    assert list(rec.columns)[:5] == ["t", "q1", "q2", "tau1", "tau2"]
    assert len(rec) == 400 and not rec.dropped_partial_row
    assert np.array_equal(rec.t, np.arange(400) * H)  # row k is t = k·h exactly
    meta = json.loads((out / "meta.json").read_text())
    assert meta["status"] == "complete" and meta["period_s"] == H and meta["rows"] == 400
    assert meta["robot"] == "cicese" and meta["experiment"] == "reyes-kelly"

    # tau is what the drive applies: eqs. (31)-(32) quantized to per-mille of rated torque
    exp = load_experiment("reyes-kelly")
    ideal = exp.torque_table(rec.t)
    steps = np.array([200.0 / 1000, 15.0 / 1000])
    assert np.all(np.abs(rec.tau - ideal) <= steps / 2 + 1e-12)
    assert np.allclose(rec.tau / steps, np.round(rec.tau / steps), atol=1e-9)
    # q is an encoder reading: whole counts of 1,024,000 and 655,360 per rev, read at the centre
    # of the count (drivers.units.position_to_rad)
    counts = rec.q / (2 * math.pi / np.array([1_024_000, 655_360])) - 0.5
    assert np.allclose(counts, np.round(counts), atol=1e-6)
    # from rest at q = 0 (count 0, read as ½ count), and the arm actually moves
    assert tuple(rec.q[0]) == (math.pi / 1_024_000, math.pi / 655_360)
    assert np.ptp(rec.q[:, 0]) > 0.2 and np.ptp(rec.q[:, 1]) > 0.2
    # statusword: operation enabled (x01x 0111) all along
    assert np.all((rec.columns["status1"].astype(int) & 0x6F) == 0x27)


def test_same_inputs_same_recording(tmp_path):
    robot, exp = load_robot("cicese"), load_experiment("reyes-kelly")
    simulate(robot, exp, tmp_path / "a", duration_s=0.5, plot=False)
    simulate(robot, exp, tmp_path / "b", duration_s=0.5, plot=False)
    assert (tmp_path / "a/signals.csv").read_bytes() == (tmp_path / "b/signals.csv").read_bytes()


def test_two_dof_and_n_joint_simulations_end_alike(tmp_path):
    """The 2-DOF closed-form plant and the n-joint URDF plant share the run's ending
    (virtual_robot.offline.run_open_loop): the same status columns, the same totals in
    meta.json (the 2-DOF run lacked the CPU time), the same plot."""
    from profiles.robot import load_urdf_robot

    runs = {
        "cicese": (load_robot("cicese"), load_experiment("reyes-kelly")),
        "cicese3": (load_urdf_robot("cicese3"), load_experiment("cicese3-excitation")),
    }
    totals = {"wall_time_s", "cpu_time_s", "realtime_factor", "plant_steps", "stick_events"}
    for name, (robot, experiment) in runs.items():
        result = simulate(robot, experiment, tmp_path / name, duration_s=0.1)
        meta = json.loads((tmp_path / name / "meta.json").read_text())
        n = robot.n_joints if name == "cicese3" else 2
        assert meta["columns"][-n:] == [f"status{j}" for j in range(1, n + 1)]
        assert totals <= set(meta) and meta["faults"] == [] and meta["rows"] == 40, name
        assert meta["cpu_time_s"] > 0 and meta["plant_steps"] == result.plant_steps
        assert result.plot == tmp_path / name / "positions.png" and result.plot.is_file()


def test_effects_change_the_world_not_the_commands(tmp_path):
    out_a, out_b = tmp_path / "a", tmp_path / "b"
    assert run_cli("simulate", "--duration", "2", "--out", str(out_a), "--no-plot").returncode == 0
    proc = run_cli(
        "simulate", "--duration", "2", "--out", str(out_b), "--no-plot", "--effects", "payload"
    )
    assert proc.returncode == 0, proc.stderr
    a, b = read_signals(out_a), read_signals(out_b)
    assert np.array_equal(a.tau, b.tau)  # open loop: same commands
    assert np.max(np.abs(a.q - b.q)) > 0.01  # a heavier link 2 moves differently
    assert json.loads((out_b / "meta.json").read_text())["effects_enabled"] == ["payload"]


def _experiment_file(tmp_path: Path, step1: float, step2: float, duration: float = 1.0) -> Path:
    path = tmp_path / "exp.toml"
    path.write_text(f"""
name = "custom"
kind = "open_loop_torque"
period_s = 0.0025
duration_s = {duration}
[[joints]]
step_Nm = {step1}
step_rate_per_s = 1000.0
[[joints]]
step_Nm = {step2}
step_rate_per_s = 1000.0
""")
    return path


def test_torque_saturates_at_the_drive_limit_and_is_flagged(tmp_path):
    exp = _experiment_file(tmp_path, 250.0, -20.0, duration=0.1)  # 200 Nm overspeeds by 0.15 s
    proc = run_cli("simulate", "--experiment", str(exp), "--out", str(tmp_path / "r"), "--no-plot")
    assert proc.returncode == 0, proc.stderr
    rec = read_signals(tmp_path / "r")
    late = rec.t > 0.01
    assert np.all(rec.tau[late, 0] == 200.0) and np.all(rec.tau[late, 1] == -15.0)
    for col in ("status1", "status2"):
        assert np.all(rec.columns[col][late].astype(int) & 0x0800)  # bit 11: internal limit


def test_overspeed_faults_the_drive_zeroes_torque_and_keeps_the_recording(tmp_path):
    # 15 Nm on the elbow against 1.7 Nm Coulomb + 0.175 Nm·s viscous: it spins up past 25 rad/s
    exp = _experiment_file(tmp_path, 0.0, 15.0, duration=3.0)
    proc = run_cli("simulate", "--experiment", str(exp), "--out", str(tmp_path / "r"), "--no-plot")
    assert proc.returncode == 0, proc.stderr
    assert "fault 0x8400" in proc.stderr and "Traceback" not in proc.stderr
    rec = read_signals(tmp_path / "r")
    meta = json.loads((tmp_path / "r/meta.json").read_text())
    assert meta["faults"][0]["error_code"] == "0x8400" and meta["faults"][0]["drive"] == "DM1015-B"
    t_fault = meta["faults"][0]["t"]
    assert np.all(rec.tau[rec.t > t_fault, 1] == 0.0)
    assert (int(rec.columns["status2"][-1]) & 0x4F) == 0x08  # fault state
    assert len(rec) == 1200


def test_duration_is_validated():
    proc = run_cli("simulate", "--duration", "-1", "--out", "/tmp/never-written")
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "duration" in proc.stderr


def _check_demo_summary(
    summary: dict, excitation_s: float, tracking_s: float, plots: bool = True
) -> None:
    """What every `hil demo` does, full or --quick: the HIL run bit-identical to the offline
    simulation, θ identified and validated, the four controllers with both parameter sets, and
    joint 1's direction-dependent Coulomb friction found; each step's plots written, or (with
    ``plots`` False, `--no-plot`) none."""
    rows = round(excitation_s / H)
    assert summary["hil_run_equals_simulate"] is True
    assert len(read_signals(summary["simulate"]["out_dir"])) == rows
    assert len(read_signals(summary["hil_run"]["out_dir"])) == rows
    assert Path(summary["hil_run"]["traffic_log"]).name == "bus.log"
    assert Path(summary["hil_run"]["plot"]).is_file() if plots else not summary["hil_run"]["plot"]
    # identification (issue 4) and the control comparison (issue 5) are part of the demo
    exact = summary["identify"]["discretizations"]["exact"]["schemes"]
    assert abs(exact["filtered_dynamic"]["relative_error"][0]) < 0.02
    assert set(exact["filtered_dynamic"]["validation"]) == {"fit", "held_out"}
    assert Path(summary["identify"]["params_files"][0]).is_file()
    labels = [ps["label"] for ps in summary["control"]["parameter_sets"]]
    assert labels[-1] == "identified" and len(labels) == 2
    for label in labels:
        runs = summary["control"]["results"][label]
        assert sorted(runs) == ["ct", "fed", "pd", "rfed"]
        assert all(r["status"] == "complete" for r in runs.values())
        assert all(len(read_signals(r["out_dir"])) == round(tracking_s / H) for r in runs.values())
    # ... and the mismatch diagnosis (issue 7): joint 1's direction-dependent Coulomb friction
    found = {(f["effect"], f["joint"]) for f in summary["diagnose"]["findings"]}
    assert ("coulomb_asymmetry", 1) in found
    # judged against the profile's nominal model, as `hil diagnose RUN --robot cicese` does
    nominal = summary["diagnose"]["nominal"]
    assert nominal["source"] == "profile" and nominal["used"] is True
    assert any(f["joint"] == 1 for f in nominal["findings"])
    if plots:
        assert summary["identify"]["discretizations"]["exact"]["plots"]
        assert summary["diagnose"]["plots"] and all(
            Path(p).is_file() for p in summary["diagnose"]["plots"]
        )
    else:
        assert not summary["diagnose"].get("plots")
        assert not list(Path(summary["hil_run"]["out_dir"]).parent.rglob("*.png"))


def test_hil_demo_quick_runs_every_step_of_the_main_job(tmp_path, capsys):
    """`hil demo --quick`, in process: every step of the demo and its outputs on shorter runs
    (4 s of excitation, 3 s of tracking, 14 s of diagnosis; hil.cli.DEMO_QUICK), without its
    plots (`--no-plot`: each step's plots are tested with its command). The full demo, plots
    and all: test_hil_demo_runs_the_main_job_end_to_end (slow)."""
    from hil.cli import DEMO_QUICK
    from hil.cli import main as hil_main

    status = hil_main(["demo", "--quick", "--no-plot", "--out", str(tmp_path), "--json"])
    out = capsys.readouterr()
    assert status == 0, out.err
    summary = json.loads(out.out)
    assert summary["quick"] is True
    _check_demo_summary(summary, DEMO_QUICK.excitation_s, DEMO_QUICK.tracking_s, plots=False)
    assert "4 s of the Reyes & Kelly" in out.err and "14 s of the diagnosis" in out.err
    assert "the profile's nominal model" in out.err
    # the summary and each step's document against their schemas (docs/schemas.md)
    jsonschema = pytest.importorskip("jsonschema", reason="the test extra's jsonschema is missing")
    schemas = Path(__file__).resolve().parent.parent / "docs" / "schemas"
    steps = [
        (None, "demo"),
        ("hil_run", "run"),
        ("simulate", "simulate"),
        ("identify", "identify"),
        ("control", "compare"),
        ("diagnose", "diagnosis"),
    ]
    for key, name in steps:
        schema = json.loads((schemas / f"{name}.schema.json").read_text(encoding="utf-8"))
        jsonschema.validate(summary if key is None else summary[key], schema)


@pytest.mark.slow
def test_hil_demo_runs_the_main_job_end_to_end(tmp_path):
    """`make demo` as a user runs it (its own process, the profiles' full lengths). The same
    steps are checked in `make test` by test_hil_demo_quick_runs_every_step_of_the_main_job."""
    from hil.cli import DEMO_FULL

    proc = subprocess.run(
        [sys.executable, "-m", "hil.cli", "demo", "--out", str(tmp_path), "--json"],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["quick"] is False
    assert DEMO_FULL.excitation_s == 10.0  # the 4000 rows of eqs. (31)-(32) at h = 2.5 ms
    _check_demo_summary(summary, DEMO_FULL.excitation_s, DEMO_FULL.tracking_s)


@pytest.mark.parametrize("module", ["hil", "drivers"])
def test_host_side_never_imports_the_plant(module):
    """docs/design.md: hil and drivers never import virtual_robot (the plant is the world)."""
    root = Path(__file__).resolve().parent.parent / module
    for path in root.rglob("*.py"):
        text = path.read_text()
        assert not re.search(r"^\s*(import|from)\s+virtual_robot", text, re.M), path
        dynamic = re.findall(r"import_module\(\s*[\"']virtual_robot[.\w]*", text)
        if path.name == "launch.py":  # the in-process bench starts serve() in a thread
            assert all(d.endswith("virtual_robot.serve") for d in dynamic), dynamic
        else:
            assert not dynamic, path


def _held_and_row_by_row(tmp_path, monkeypatch, robot, experiment, duration_s):
    """The recording with the held rows (virtual_robot.offline._held_rows) and with the drive
    models row by row, and how many rows the held path wrote."""
    import virtual_robot.offline as offline

    held_rows = []
    held = offline._held_rows

    def spy(*args, **kwargs):
        out = held(*args, **kwargs)
        held_rows.append(out[0])
        return out

    monkeypatch.setattr(offline, "_held_rows", spy)
    simulate(robot, experiment, tmp_path / "held", duration_s=duration_s, plot=False)
    monkeypatch.setattr(offline, "_rows_can_be_held", lambda *_: False)
    simulate(robot, experiment, tmp_path / "rows", duration_s=duration_s, plot=False)
    metas = [json.loads((tmp_path / d / "meta.json").read_text()) for d in ("held", "rows")]
    return (
        *((tmp_path / d / "signals.csv").read_bytes() for d in ("held", "rows")),
        held_rows,
        metas,
    )


@pytest.mark.parametrize("kernel", ["auto", "python"])
@pytest.mark.parametrize("case", ["cicese3", "cicese3 overspeed"])
def test_held_rows_are_the_drive_models_rows(tmp_path, monkeypatch, case, kernel):
    """The offline simulation's block path (drives' arithmetic on arrays while every drive
    applies torque; the compiled kernel's periods in one call, ddb_run_periods, or one
    period at a time with the Python step) writes the recording the drive models write row by
    row, byte for byte, the fault and the rows after it included (there it hands over to the
    drive models)."""
    from dataclasses import replace

    from profiles.robot import load_urdf_robot
    from virtual_robot.compiled_step import KERNEL_ENV

    monkeypatch.setenv(KERNEL_ENV, kernel)
    robot, experiment = load_urdf_robot("cicese3"), load_experiment("cicese3-excitation")
    duration, fault = (1.0 if kernel == "auto" else 0.4), False
    if case == "cicese3 overspeed":  # 3 x the torques: joint 3 passes its 25 rad/s
        experiment = replace(experiment, joints=tuple(
            replace(j, sines=tuple(replace(s, amplitude_Nm=3 * s.amplitude_Nm) for s in j.sines))
            for j in experiment.joints
        ))  # fmt: skip
        duration, fault = 3.0, True
    held, rows, held_rows, (meta_held, meta_rows) = _held_and_row_by_row(
        tmp_path, monkeypatch, robot, experiment, duration
    )
    assert held == rows
    assert meta_held["faults"] == meta_rows["faults"]
    assert meta_held["plant_steps"] == meta_rows["plant_steps"]
    assert meta_held["stick_events"] == meta_rows["stick_events"] > 0
    assert meta_held["integrator"]["kernel"]["kernel"] == (
        "compiled" if kernel == "auto" else kernel
    )
    n_rows = round(duration / H)
    if not fault:
        assert meta_held["faults"] == [] and held_rows == [n_rows]
    else:  # held up to the sample where the drive faulted, row by row from there
        assert meta_held["faults"], case
        assert held_rows == [round(meta_held["faults"][0]["t"] / H)]
        assert 0 < held_rows[0] < n_rows


def test_two_dof_rows_stay_row_by_row(tmp_path, monkeypatch):
    """The 2-DOF plant has no many-period call: its rows go through the drive models."""
    import virtual_robot.offline as offline

    calls = []
    monkeypatch.setattr(offline, "_held_rows", lambda *a: calls.append(a))
    simulate(load_robot("cicese"), load_experiment("reyes-kelly"), tmp_path, duration_s=0.1,
             plot=False)  # fmt: skip
    assert calls == [] and len(read_signals(tmp_path)) == 40
