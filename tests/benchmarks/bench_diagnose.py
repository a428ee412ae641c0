"""Benchmark: `hil diagnose` on a 20 s recording at 400 Hz (target: under 30 s on this machine),
and with ``--long`` on a 10-minute recording at 1 kHz (target: under 60 s and 1 GB).

    python tests/benchmarks/bench_diagnose.py [--repeat 3] [--long [--long-minutes 10]
        [--long-recording RUN_DIR]]

Records the diagnosis excitation on the default virtual robot (joint 1's direction-dependent
Coulomb friction) and on the null robot (symmetric friction), then times the whole diagnosis
(nominal fit, 12 candidates with blocked cross-validation, refit, before/after simulations), the
same call `hil diagnose` makes, without plots. ``--long`` simulates the validation multisine at
1 kHz for 10 minutes (about a minute) and diagnoses it in a child process, whose peak resident
memory (ru_maxrss) is reported with its wall and CPU time. The long case's time target is
judged on the child's CPU time: on this shared machine its wall time measures the neighbours
(5–10× the CPU time at load 10–20); on an idle machine the two are alike.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from diagnose_cases import CASES, make_recording

from drivers.recording import read_signals
from hil.diagnose.pipeline import diagnose
from hil.model.params import robot_params

TARGET_S = 30.0
LONG_TARGET_S, LONG_TARGET_BYTES = 60.0, 1e9


def long_case(minutes: float, recording: str | None = None) -> None:
    """Diagnose ``minutes`` of the validation multisine at 1 kHz in a child process
    (``recording``: a run directory, made there and kept when it holds no recording yet, so that
    reruns diagnose the same one instead of simulating it again). The child runs with one BLAS
    thread, as every ``hil`` command does (drivers.process.limit_blas_threads)."""
    from profiles.experiment import load_experiment

    text = Path(load_experiment("validation-multisine").source).read_text()
    text = text.replace("period_s = 0.0025", "period_s = 0.001")
    text = text.replace("duration_s = 10.0", f"duration_s = {60 * minutes:g}")
    with tempfile.TemporaryDirectory() as tmp:
        toml = Path(tmp) / "multisine-1khz.toml"
        toml.write_text(text)
        if recording is None:
            path = make_recording(Path(tmp) / "long", toml, None)
        elif not (Path(recording) / "signals.csv").exists():
            path = make_recording(Path(recording), toml, None)
        else:
            path = Path(recording)
        code = (
            "from drivers.process import limit_blas_threads; limit_blas_threads(); "
            "import sys, time; from drivers.recording import read_signals; "
            "from hil.diagnose.pipeline import diagnose; "
            "from hil.model.params import robot_params; "
            "rec = read_signals(sys.argv[1]); t = time.perf_counter(); "
            "doc = diagnose([rec], robot_params('cicese').theta).document; "
            "print(len(rec), round(time.perf_counter() - t, 1), "
            "','.join(f\"{f['effect']}:{f['joint']}\" for f in doc['findings']) or 'none')"
        )
        root = Path(__file__).resolve().parents[2]
        load_before = os.getloadavg()[0]
        out = subprocess.run(
            [sys.executable, "-c", code, str(path)],
            cwd=root,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.split()
        usage = resource.getrusage(resource.RUSAGE_CHILDREN)
        rows, wall, found = int(out[0]), float(out[1]), out[2]
        peak = usage.ru_maxrss * 1024
        cpu = usage.ru_utime + usage.ru_stime
        print(
            f"diagnose, {minutes:g} min at 1 kHz: {rows} rows: {wall:.1f} s wall, "
            f"{cpu:.1f} s CPU, peak RSS {peak / 1e6:.0f} MB; "
            f"targets < {LONG_TARGET_S:.0f} s CPU "
            f"{'met' if cpu < LONG_TARGET_S else 'MISSED'}, < 1 GB "
            f"{'met' if peak < LONG_TARGET_BYTES else 'MISSED'}; findings: {found}; "
            f"load average {load_before:.1f} → {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs"
        )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="runs per case, at least 1")
    ap.add_argument("--long", action="store_true", help="also the 10-minute 1 kHz case")
    ap.add_argument("--long-minutes", type=float, default=10.0)
    ap.add_argument(
        "--long-recording",
        default=None,
        help="run directory of the long recording: made there once and kept, then reused",
    )
    args = ap.parse_args()
    if args.repeat < 1:
        ap.error(f"--repeat must be at least 1, got {args.repeat}")
    if args.long:
        long_case(args.long_minutes, args.long_recording)
    reference = robot_params("cicese").theta
    with tempfile.TemporaryDirectory() as tmp:
        for name, effects in (("default robot", None), ("null", CASES["null"].effects)):
            path = make_recording(Path(tmp) / name.replace(" ", "_"), "diagnosis", effects)
            rec = read_signals(path)
            times, cpu = [], []
            for _ in range(args.repeat):
                t0, c0 = time.perf_counter(), time.process_time()
                doc = diagnose([rec], reference).document
                times.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
            found = ", ".join(f"{f['effect']}:{f['joint']}" for f in doc["findings"]) or "none"
            med = statistics.median(times)
            print(
                f"diagnose, {name}: {len(rec)} rows ({len(rec) * rec.period_s:.0f} s at "
                f"{1 / rec.period_s:.0f} Hz): median {med:.1f} s of {args.repeat} "
                f"(min {min(times):.1f}, max {max(times):.1f}; median CPU "
                f"{statistics.median(cpu):.1f} s); target < {TARGET_S:.0f} s "
                f"{'met' if med < TARGET_S else 'MISSED'}; findings: {found}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
