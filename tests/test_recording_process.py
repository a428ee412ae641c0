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
