"""Benchmark: peak memory and time of `hil identify --from` on a long 2-DOF recording (issue 13).

Simulates ``--seconds`` of the default experiment with `virtual-robot simulate` (400 Hz rows,
a physical recording: identification and open-loop validation run end to end), then runs
`hil identify --from` on it in a fresh process under ``/usr/bin/time`` and prints its peak RSS,
the bytes per recording row, the wall time and the CPU time (user + system) per row. Target
(issue 13): a 700 MB CSV (10 M rows) identified in < 4 GB; exit 1 if the peak RSS is over it.

    python tests/benchmarks/bench_identify_memory.py --seconds 60 --tile-mb 7 --stages  # make bench
    python tests/benchmarks/bench_identify_memory.py --seconds 850   # 340 000 rows
    python tests/benchmarks/bench_identify_memory.py --seconds 60 --tile-mb 700   # make bench-big

``--stages``: also the CPU time of each stage per row, in this process on the same file
(reading; each scheme's rows built once; each scheme's RLS over them; one validation's
open-loop simulation, with the compiled sub-step and with the Python one): where a long
recording's time goes.

``--tile-mb MB`` makes a long file quickly (simulating 700 MB, 10 M rows, outright takes the
better part of an hour): one settled stretch of the simulated run repeated until signals.csv
holds MB megabytes, t rewritten as k·h. The stretch joins onto itself: the excitation of eqs.
(31)-(32) has frequencies 12, 16, 20, 26 rad/s, all multiples of 2 rad/s, so it repeats every
π s, and 11π s is 13 823.0 samples of 2.5 ms; from t = 25 s on (the steps' e^{-0.8 t} gone) the
arm follows that period, its state at t and t + 11π s a few encoder counts apart (≲ 2e-4 rad).
So copies of [25 s, 25 s + 11π s) meet with jumps of that size, and the file identifies like
a long physical run (``--seconds`` must then be ≥ 60).

The command's progress lines (every 30 s) pass through on stderr. The recording is kept in
``--dir`` (default: a temporary directory, removed at the end).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=850.0, help="simulated duration")
    p.add_argument("--dir", default=None, help="where to write (default: a temporary dir)")
    p.add_argument("--tile-mb", type=float, default=None, help="repeat the run to this size")
    p.add_argument(
        "--command", default="identify", choices=("identify", "diagnose"), help="what to measure"
    )
    p.add_argument("--stages", action="store_true", help="also CPU per row of each stage")
    args = p.parse_args()
    if not args.seconds > 0:
        p.error(f"--seconds must be > 0, got {args.seconds}")
    with tempfile.TemporaryDirectory(prefix="bench-idmem-") as tmp:
        run = Path(args.dir or tmp) / f"sim-{args.seconds:g}s"
        subprocess.run(
            [sys.executable, "-m", "virtual_robot.cli", "simulate", "--duration",
             str(args.seconds), "--out", str(run), "--no-plot", "-q"],
            check=True, capture_output=True,
        )  # fmt: skip
        if args.tile_mb is not None:
            tile(run, args.tile_mb * 1e6)
        with open(run / "signals.csv") as f:
            rows = sum(1 for _ in f) - 1
        t0 = time.perf_counter()
        # the command's progress lines pass through on stderr (a 700 MB run takes a while);
        # time's figures go to a file, the JSON on stdout is not needed
        measured = Path(tmp) / "time.txt"
        proc = subprocess.run(
            ["/usr/bin/time", "-o", str(measured), "-f", "%M %U %S", sys.executable, "-m",
             "hil.cli", *command(args, run, tmp)],
            stdout=subprocess.DEVNULL, check=False,
        )  # fmt: skip
        seconds = time.perf_counter() - t0
        if proc.returncode != 0:
            return 1
        kb, user, system = measured.read_text().strip().splitlines()[-1].split()
        peak, cpu = int(kb) * 1024, float(user) + float(system)
        size = (run / "signals.csv").stat().st_size
        print(
            f"hil {args.command} ({rows} rows, {size / 1e6:.0f} MB CSV): {seconds:.0f} s wall, "
            f"{cpu:.0f} s CPU ({cpu / rows * 1e6:.0f} µs a row), peak RSS {peak / 1e6:.0f} MB "
            f"({peak / rows:.0f} B a row; target < {TARGET_RSS_BYTES / 1e9:.0f} GB)"
        )
        if args.stages:
            stages(run)
    return 0 if peak < TARGET_RSS_BYTES else 1


TARGET_RSS_BYTES = 4e9  # issue 13: a 700 MB CSV identified in under 4 GB


def stages(run: Path) -> None:
    """CPU time per row of each stage of `hil identify --from run` (see the module doc)."""
    from drivers.recording import read_signals
    from hil.identify.schemes import initial_velocity
    from hil.model.compiled_openloop import KERNEL_ENV, kernel_status
    from hil.model.estimators import RecursiveLeastSquaresRows
    from hil.model.openloop import simulate_open_loop_chunks
    from hil.model.params import robot_params
    from hil.model.regressors import SCHEMES, iter_regression

    def line(name: str, start: float, n: int) -> None:
        print(f"  {name:46s} {(time.process_time() - start) / n * 1e6:6.1f} µs CPU a row")

    start = time.process_time()
    rec = read_signals(run)
    q, tau, h = rec.q, rec.tau, rec.period_s
    line("read (t, q, tau)", start, len(q))
    for scheme in SCHEMES:
        start = time.process_time()
        chunks = list(iter_regression(scheme, q[:100_000], tau[:100_000], h))  # bounded
        n = sum(len(c.t) for c in chunks)
        line(f"{scheme}: rows (built once)", start, n)
        start = time.process_time()
        rls = RecursiveLeastSquaresRows(chunks[0].Psi.shape[-1], chunks[0].y.shape[1], n, keep=[])
        for c in chunks:
            rls.add(c.Psi, c.y, c.weights)
        line(f"{scheme}: recursive least squares", start, n)
    dq0 = initial_velocity(rec)
    for kernel in ("compiled", "python"):  # hil.model.compiled_openloop's step, then Python's
        os.environ[KERNEL_ENV] = kernel
        if kernel_status().kernel != kernel:
            continue  # no compiler: the Python step's line alone
        start = time.process_time()
        for _ in simulate_open_loop_chunks(robot_params("cicese").theta, tau[:100_000], h,
                                           q0=q[0], dq0=dq0):  # fmt: skip
            pass
        line(f"validation: open-loop simulation ({kernel})", start, min(len(q), 100_000))


def command(args: argparse.Namespace, run: Path, tmp: str) -> list[str]:
    out = str(Path(args.dir or tmp) / args.command)
    if args.command == "diagnose":
        return ["diagnose", str(run), "--out", out, "--overwrite", "--no-plots", "--json"]
    return ["identify", "--from", str(run), "--out", out, "--overwrite", "--no-plot", "--json",
            "--progress-every", "30"]  # fmt: skip


# A stretch of whole excitation periods (11π s) once the arm has settled (from 25 s): see the
# module docstring.
TILE_FIRST_ROW = 10_000
TILE_ROWS = 13_823


def tile(run: Path, size_bytes: float) -> None:
    """Repeat rows TILE_FIRST_ROW.. of TILE_ROWS of run/signals.csv until the file holds
    ``size_bytes``, t rewritten as k·h; meta.json's rows and duration follow."""
    csv_path = run / "signals.csv"
    lines = csv_path.read_text().splitlines()
    if len(lines) < 1 + TILE_FIRST_ROW + TILE_ROWS:
        raise SystemExit("--tile-mb needs a run of at least 60 s (--seconds 60)")
    meta = json.loads((run / "meta.json").read_text())
    h = float(meta["period_s"])
    block_rows = lines[1 + TILE_FIRST_ROW : 1 + TILE_FIRST_ROW + TILE_ROWS]
    body = [line.split(",", 1)[1] for line in block_rows]
    tmp = csv_path.with_suffix(".tiled")
    written = 0
    k = 0
    with open(tmp, "w") as f:
        f.write(lines[0] + "\n")
        while written < size_bytes:
            block = "".join(f"{round((k + i) * h, 9)!r},{row}\n" for i, row in enumerate(body))
            f.write(block)
            written += len(block)
            k += len(body)
    tmp.replace(csv_path)
    meta["rows"], meta["duration_s"] = k, k * h
    (run / "meta.json").write_text(json.dumps(meta, indent=2))


if __name__ == "__main__":
    sys.exit(main())
