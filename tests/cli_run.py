"""Run the ``hil`` command line in a subprocess, as a user would (shared by the test modules)."""

from __future__ import annotations

import subprocess
import sys


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
