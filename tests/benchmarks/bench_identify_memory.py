"""Benchmark: peak memory of `hil identify --from` on a long 2-DOF recording (issue 13).

Simulates ``--seconds`` of the default experiment with `virtual-robot simulate` (400 Hz rows,
a physical recording: identification and open-loop validation run end to end), then runs
`hil identify --from` on it in a fresh process under ``/usr/bin/time`` and prints its peak RSS,
the bytes per recording row, and the wall time.

    python tests/benchmarks/bench_identify_memory.py --seconds 850   # 340 000 rows, ~1.5 min
    python tests/benchmarks/bench_identify_memory.py --seconds 120 --tile-mb 700 --dir /tmp/x

``--tile-mb MB`` makes a long file quickly (simulating 700 MB, 10 M rows, outright takes the
better part of an hour): one settled stretch of the simulated run repeated until signals.csv
holds MB megabytes, t rewritten as k·h. The stretch joins onto itself: the excitation of eqs.
(31)-(32) has frequencies 12, 16, 20, 26 rad/s, all multiples of 2 rad/s, so it repeats every
π s, and 11π s is 13 823.0 samples of 2.5 ms; from t = 25 s on (the steps' e^{-0.8 t} gone) the
arm follows that period, its state at t and t + 11π s a few encoder counts apart (≲ 2e-4 rad).
So copies of [25 s, 25 s + 11π s) meet with jumps of that size, and the file identifies like
a long physical run (``--seconds`` must then be ≥ 60).

The recording is kept in ``--dir`` (default: a temporary directory, removed at the end).
"""

from __future__ import annotations

import argparse
import json
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
        proc = subprocess.run(
            ["/usr/bin/time", "-f", "%M", sys.executable, "-m", "hil.cli",
             *command(args, run, tmp)],
            capture_output=True, text=True, check=False,
        )  # fmt: skip
        seconds = time.perf_counter() - t0
        if proc.returncode != 0:
            print(proc.stderr.strip(), file=sys.stderr)
            return 1
        peak = int(proc.stderr.strip().splitlines()[-1]) * 1024
        size = (run / "signals.csv").stat().st_size
        print(
            f"hil {args.command} ({rows} rows, {size / 1e6:.0f} MB CSV): {seconds:.0f} s, "
            f"peak RSS {peak / 1e6:.0f} MB ({peak / rows:.0f} B a row)"
        )
    return 0


def command(args: argparse.Namespace, run: Path, tmp: str) -> list[str]:
    out = str(Path(args.dir or tmp) / args.command)
    if args.command == "diagnose":
        return ["diagnose", str(run), "--out", out, "--overwrite", "--no-plots", "--json"]
    return ["identify", "--from", str(run), "--out", out, "--overwrite", "--no-plot", "--json"]


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
