"""Run the ``hil`` command line in a subprocess, as a user would (shared by the test modules)."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path


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
