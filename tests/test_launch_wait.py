"""How long `hil run` waits for the virtual robot it started (hil/bench/launch.py, StartWait):
a robot still working on its start is waited for past READY_TIMEOUT_S (a cold start in the
emulated guest of `make test-vcan` on a loaded machine takes minutes), one that does no work
is given up after READY_TIMEOUT_S, and READY_MAX_S bounds the whole wait."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Iterator

import pytest

import hil.bench.launch as launch


@pytest.fixture
def child() -> Iterator[list[subprocess.Popen]]:
    procs: list[subprocess.Popen] = []
    yield procs
    for proc in procs:
        proc.kill()
        proc.wait()


def _wait(proc: subprocess.Popen) -> tuple[float, str]:
    wait = launch.StartWait(proc.pid)
    while wait.more():
        time.sleep(0.02)
    return time.monotonic() - wait.started, wait.why()


def test_a_process_that_works_is_waited_for_and_one_that_idles_is_not(child, monkeypatch):
    monkeypatch.setattr(launch, "READY_TIMEOUT_S", 0.4)
    monkeypatch.setattr(launch, "READY_MAX_S", 30.0)
    # busy for 2 s (a slow start), then idle: waited for through its work, given up after
    busy = "import time\nend = time.monotonic() + 2.0\nwhile time.monotonic() < end: pass\n"
    child.append(subprocess.Popen([sys.executable, "-c", busy + "time.sleep(60)"]))
    waited, why = _wait(child[-1])
    assert 2.0 <= waited < 10.0, waited
    assert "no CPU used" in why, why
    # idle from the start (after the interpreter's own start-up): about two timeouts
    child.append(subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"]))
    waited, why = _wait(child[-1])
    assert waited < 2.0, waited


def test_the_whole_wait_is_bounded(child, monkeypatch):
    monkeypatch.setattr(launch, "READY_TIMEOUT_S", 0.2)
    monkeypatch.setattr(launch, "READY_MAX_S", 1.0)
    child.append(subprocess.Popen([sys.executable, "-c", "while True: pass"]))
    waited, why = _wait(child[-1])
    assert 1.0 <= waited < 3.0, waited
    assert why.startswith("still starting after"), why
