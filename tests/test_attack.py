"""The issue-31 attack battery (tests/attack/attack.py) as a slow test: its quick subset (hostile
files, options and profiles, signals at random moments, hub junk and floods, concurrent runs and
attaches) must end without a traceback, a lost run, invalid JSON or a robot a --clear-faults
rerun cannot recover. The whole battery: ``python tests/attack/attack.py`` (docs/faults.md)."""

from __future__ import annotations

import subprocess
import sys

import pytest
from cli_run import ROOT


@pytest.mark.slow
def test_the_quick_attack_battery_finds_nothing():
    proc = subprocess.run(
        [sys.executable, str(ROOT / "tests" / "attack" / "attack.py"), "--quick"],
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
        cwd=ROOT,
    )
    assert proc.returncode == 0, proc.stderr[-6000:]
    assert "attempts in" in proc.stderr and " 0 failed" in proc.stderr, proc.stderr[-2000:]
