"""Run the ``hil`` command line in a subprocess, as a user would, and compare what it recorded
(shared by the test modules)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

# The emulated guest of `make test-vcan` runs Python 5-50x slower than the host (software CPU
# emulation on a shared machine). Its tests check that the paths over vcan work end to end, so
# they run copies of the shipped benches with generous timeouts (bench_copy); the timing figures
# are `make bench`'s, on the host.
SLOW_GUEST = {"timeout_s = 2.0": "timeout_s = 60.0"}


def bench_copy(name: str, where: Path, changes: dict[str, str]) -> Path:
    """The shipped bench ``name`` with each ``changes`` key (which must be there) replaced."""
    from profiles import resolve

    text = resolve("benches", name).read_text()
    for old, new in changes.items():
        assert old in text, (name, old)
        text = text.replace(old, new)
    path = where / f"{name}.toml"
    path.write_text(text)
    return path


def hil(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """``python -m hil.cli ARGS``: output captured as text, never raising on a non-zero exit
    (the tests read the status); ``timeout`` bounds a hang."""
    return subprocess.run(
        [sys.executable, "-m", "hil.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


def wait_rows(
    out: Path, rows: int, proc: subprocess.Popen | None = None, timeout: float = 60.0
) -> dict:
    """Wait until the run writing ``out`` has its robot announced and ``rows`` rows on disk;
    its meta. ``proc``, the run's process: ending early fails with its stderr."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:  # ended early: say why
            _, err = proc.communicate()
            log = out / "virtual-robot.log"
            robot = log.read_text()[-500:] if log.is_file() else ""
            raise AssertionError(f"hil exited {proc.returncode} early: {err}\n{robot}")
        try:
            meta = json.loads((out / "meta.json").read_text())
            csv = out / "signals.csv"
            if meta.get("channel") and csv.read_text().count("\n") > rows:
                return meta
        except (FileNotFoundError, json.JSONDecodeError):
            pass
        time.sleep(0.05)
    raise AssertionError(f"fewer than {rows} rows after {timeout} s")


def start_hil(*args: str, module: str = "hil.entry") -> subprocess.Popen:
    """``hil ARGS`` started through the console entry point (hil.entry: the exit signals
    installed as for a user), or as ``python -m MODULE``, output captured as text; the caller
    waits for it or kills it."""
    return subprocess.Popen(
        [sys.executable, "-m", module, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )


def finish_all(procs: Sequence[subprocess.Popen], timeout: float) -> list[tuple[int, str, str]]:
    """Wait for each process in turn (each killed if it outlives ``timeout``): its exit status,
    stdout and stderr."""
    results = []
    for proc in procs:
        try:
            stdout, stderr = proc.communicate(timeout=timeout)
        finally:
            proc.kill()
        results.append((proc.returncode, stdout, stderr))
    return results


def run_with_robot_paused(
    args: Sequence[str], out: Path, pause_s: float, *, after_rows: int = 100, timeout: float = 60
) -> subprocess.CompletedProcess:
    """``hil ARGS --out OUT`` (a realtime run); once it has ``after_rows`` rows its virtual robot
    is stopped (SIGSTOP) for ``pause_s`` and continued: a scheduling stall of the robot as an
    ordinary desktop makes one. The finished run's status and output (it is killed if it
    outlives ``timeout``, and the robot is always continued)."""
    proc = start_hil(*args, "--out", str(out))
    try:
        pid = wait_rows(out, after_rows, proc)["channel"]["pid"]
        os.kill(pid, signal.SIGSTOP)
        try:
            time.sleep(pause_s)
        finally:
            os.kill(pid, signal.SIGCONT)
        stdout, stderr = proc.communicate(timeout=timeout)
    finally:
        proc.kill()
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)


def assert_same_recording(rec: Any, reference: Any) -> None:
    """``rec`` (a :class:`drivers.recording.Recording`, e.g. of a lockstep `hil run`) has the
    sample times, angles and torques of ``reference`` (e.g. `virtual-robot simulate`'s) bit for
    bit, not just close; a difference in q is reported by its size."""
    assert np.array_equal(rec.t, reference.t)
    assert np.array_equal(rec.q, reference.q), np.max(np.abs(rec.q - reference.q))
    assert np.array_equal(rec.tau, reference.tau)


def run_module(module: str, *args: str, timeout: float = 120) -> None:
    """``python -m MODULE ARGS``, which must exit 0 (else its stderr is the failure)."""
    proc = subprocess.run(
        [sys.executable, "-m", module, *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr


def simulate_cli(
    robot: str, experiment_toml: str, where: Path, *, timeout: float = 120
) -> tuple[Any, np.ndarray]:
    """`virtual-robot simulate --robot ROBOT` of the open-loop experiment ``experiment_toml`` (a
    profile's text, written to ``where/experiment.toml``) into ``where/s``: its recording and the
    experiment's torque of each of its rows (rows × joints), what a client sends to redo it."""
    from drivers.recording import read_signals
    from profiles.experiment import load_experiment

    experiment = where / "experiment.toml"
    experiment.write_text(experiment_toml)
    args = [
        "--robot",
        robot,
        "--experiment",
        str(experiment),
        "--no-plot",
        "--out",
        str(where / "s"),
    ]
    run_module("virtual_robot.cli", "simulate", *args, timeout=timeout)
    rec = read_signals(where / "s")
    exp = load_experiment(experiment)
    rows = exp.torque_rows(exp.period_s, len(rec.t))
    return rec, np.array([rows[k] for k in range(len(rec.t))])


def assert_hil_run_equals_simulate(
    bench: str, robot: str, experiment_toml: str, where: Path, *, rows: int, timeout: float = 120
) -> Any:
    """`hil run --bench BENCH` (lockstep) and `virtual-robot simulate --robot ROBOT`
    (:func:`simulate_cli`) of the open-loop experiment ``experiment_toml``, both into ``where``
    (``h``, ``s``): ``rows`` rows each, the same q and τ bit for bit
    (:func:`assert_same_recording`); the host's recording."""
    from drivers.recording import read_signals

    offline, _ = simulate_cli(robot, experiment_toml, where, timeout=timeout)
    ex = ["--experiment", str(where / "experiment.toml"), "--no-plot"]
    run_module("hil.cli", "run", "--bench", bench, *ex, "--out", str(where / "h"), timeout=timeout)
    host = read_signals(where / "h")
    assert len(host.t) == len(offline.t) == rows
    assert_same_recording(host, offline)
    return host
