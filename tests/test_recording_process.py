"""Every recording carries its writer's process stamp, so a killed writer reads as ``died``.

RecordingWriter stamps meta.json itself (drivers.process.process_stamp), so the recordings of
``virtual-robot simulate`` have it as ``hil`` runs do (issue 13).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from drivers.process import run_status
from drivers.recording import RecordingWriter


def _meta(out: Path) -> dict:
    return json.loads((out / "meta.json").read_text())


def test_writer_stamps_its_process(tmp_path: Path) -> None:
    with RecordingWriter(tmp_path, {"period_s": 0.0025}) as rec:
        running = _meta(tmp_path)
        assert running["process"]["pid"] == os.getpid()
        assert run_status(running) == "running"
        rec.write([0.0, 0.0, 0.0, 0.0, 0.0])
    done = _meta(tmp_path)
    assert done["status"] == "complete" and run_status(done) == "complete"
    assert done["process"] == running["process"]


def test_killed_simulate_reads_as_died(tmp_path: Path) -> None:
    out = tmp_path / "sim"
    # a long simulation, killed (SIGKILL: nothing runs after it) once its meta.json is written
    proc = subprocess.Popen(
        [sys.executable, "-m", "virtual_robot.cli", "simulate", "--duration", "600",
         "--out", str(out), "--no-plot", "-q"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        while not (out / "signals.csv").is_file():
            assert proc.poll() is None, proc.communicate()[1]
            assert time.monotonic() < deadline, "simulate wrote no recording within 60 s"
            time.sleep(0.05)
        meta = _meta(out)
        assert meta["process"]["pid"] == proc.pid
        assert run_status(meta) == "running"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    meta = _meta(out)
    assert meta["status"] == "running"  # what the file says: nobody closed it
    assert run_status(meta) == "died"


def test_large_recording_says_what_reading_does(tmp_path: Path, monkeypatch, capsys) -> None:
    """A large recording (here: any, with the threshold at 1 byte) says it is being read, how
    big it is, and how many rows it took how long."""
    import argparse
    import math

    import hil.cli_options as options

    with RecordingWriter(tmp_path, {"period_s": 0.01}) as rec:
        for k in range(50):
            rec.write([k * 0.01, math.sin(k / 5), math.cos(k / 7), 0.1, -0.2])
    monkeypatch.setattr(options, "LARGE_RECORDING_BYTES", 1)
    got = options.read_recording(argparse.Namespace(), tmp_path, command="identify")
    err = capsys.readouterr().err
    assert len(got) == 50
    assert f"hil identify: reading {tmp_path / 'signals.csv'} (0 MB) ..." in err
    assert "hil identify: read 50 rows of signals.csv in " in err
    monkeypatch.setattr(options, "LARGE_RECORDING_BYTES", 50_000_000)
    options.read_recording(argparse.Namespace(), tmp_path, command="identify")
    assert "reading" not in capsys.readouterr().err  # small files stay quiet


_FREED_PROBE = """
import ctypes
import numpy as np
from drivers.process import release_freed_heap
def rss():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096
libc = ctypes.CDLL(None)
if not hasattr(libc, "mallopt"):
    print("unsupported")
    raise SystemExit
# glibc's state after a long analysis, set outright (left to itself it depends on what the
# process freed before): the mmap threshold grown to 32 MB, the heap's top trimmed only
# beyond twice that
libc.mallopt(-3, 32 << 20)  # M_MMAP_THRESHOLD
libc.mallopt(-1, 64 << 20)  # M_TRIM_THRESHOLD
middle = np.ones(2_000_000)  # 16 MB, from the heap
after = np.ones(1000)  # a small block behind it
middle[:] = 2.0
before = rss()
del middle
kept = before - rss()  # glibc leaves a freed block in the middle of the heap resident
if not release_freed_heap():
    print("unsupported")
    raise SystemExit
print(kept, before - rss())
"""


def test_freed_heap_goes_back_to_the_system() -> None:
    """drivers.process.release_freed_heap: a 16 MB array freed on the heap stays resident (glibc
    with the thresholds a long analysis leaves it) until the heap is trimmed. Skipped where
    there is no /proc or no mallopt and malloc_trim (not glibc)."""
    if not Path("/proc/self/statm").exists():
        pytest.skip("no /proc/self/statm to read the resident size from")
    root = Path(__file__).resolve().parents[1]
    out = subprocess.run(
        [sys.executable, "-c", _FREED_PROBE],
        cwd=root, capture_output=True, text=True, check=True, timeout=120,
    ).stdout.split()  # fmt: skip
    if out == ["unsupported"]:
        pytest.skip("the C library has no malloc_trim (not glibc)")
    kept, returned = (int(x) for x in out)
    assert kept < 4e6  # what the trim is for
    assert returned > 12e6
