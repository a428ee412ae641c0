"""Benchmark: reading a large recording (drivers/recording/ read_signals) in bounded memory.

Generates a CSV of this bench's format (t = k·h at 1 kHz, q1, q2, tau1, tau2 and the realtime
timing columns, every value a float repr as the writer writes it) of about ``--mb`` megabytes,
then reads it in a fresh process and prints the wall time and that process's peak RSS (the
memory a `hil` command spends on reading), against the file's size. With ``--identify`` it
also runs `hil identify --from` on it in a fresh process and prints its peak RSS (issue 13:
a 700 MB CSV must be identified in under 4 GB).

    python tests/benchmarks/bench_read.py --mb 100            # default; about 1 minute
    python tests/benchmarks/bench_read.py --mb 700 --identify # only on a quiet machine

The generated file is kept in ``--dir`` (default: a temporary directory, removed at the end).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

H = 0.001
COLUMNS = ("t", "q1", "q2", "tau1", "tau2", "status1", "status2", "deadline_s", "sync_sent_s",
           "feedback_s")  # fmt: skip

READ_CHILD = """
import json, resource, sys, time
from drivers.recording import read_signals
t0 = time.perf_counter()
rec = read_signals(sys.argv[1], extra_columns=sys.argv[2] == "all")
dt = time.perf_counter() - t0
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps({"rows": len(rec), "columns": len(rec.columns), "seconds": dt, "peak_rss": peak}))
"""


def generate(path: Path, megabytes: float) -> int:
    """Write ~``megabytes`` MB of rows (meta.json with period_s beside it); returns the rows."""
    path.mkdir(parents=True, exist_ok=True)
    target = megabytes * 1e6
    rows = 0
    with open(path / "signals.csv", "w") as f:
        f.write(",".join(COLUMNS) + "\n")
        written = 0
        block: list[str] = []
        while written < target:
            k = rows
            t = k * H
            q1 = 0.5 * math.sin(2 * math.pi * 0.7 * t)
            q2 = 0.8 * math.sin(2 * math.pi * 1.1 * t)
            line = ",".join(
                (repr(t), repr(q1), repr(q2), repr(5 * math.cos(2 * math.pi * 0.9 * t)),
                 repr(math.sin(2 * math.pi * 1.3 * t)), "1079", "1079", repr(100.0 + t),
                 repr(100.0 + t + 1.3e-5), repr(100.0 + t + 4.1e-4))
            )  # fmt: skip
            block.append(line)
            written += len(line) + 1
            rows += 1
            if len(block) == 10000:
                f.write("\n".join(block) + "\n")
                block = []
        if block:
            f.write("\n".join(block) + "\n")
    meta = {"period_s": H, "robot": "cicese", "status": "complete", "rows": rows}
    (path / "meta.json").write_text(json.dumps(meta))
    return rows


def read_in_child(path: Path, columns: str) -> dict:
    proc = subprocess.run(
        [sys.executable, "-c", READ_CHILD, str(path), columns],
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(proc.stdout)


def identify_in_child(path: Path, out: Path) -> dict:
    t0 = time.perf_counter()
    proc = subprocess.run(
        ["/usr/bin/time", "-f", "%M", sys.executable, "-m", "hil.cli", "identify", "--from",
         str(path), "--out", str(out), "--overwrite", "--no-plot", "--json"],
        capture_output=True,
        text=True,
        check=False,
    )  # fmt: skip
    peak_kb = int(proc.stderr.strip().splitlines()[-1])
    return {
        "exit": proc.returncode,
        "seconds": time.perf_counter() - t0,
        "peak_rss": peak_kb * 1024,
        "error": None if proc.returncode == 0 else proc.stderr.strip().splitlines()[-2:],
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--mb", type=float, default=100.0, help="size of the generated CSV in MB")
    p.add_argument("--dir", default=None, help="where to write it (default: a temporary dir)")
    p.add_argument("--identify", action="store_true", help="also time `hil identify --from`")
    args = p.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-read-") as tmp:
        run = Path(args.dir or tmp) / f"read-{args.mb:g}mb"
        t0 = time.perf_counter()
        rows = generate(run, args.mb)
        size = (run / "signals.csv").stat().st_size
        print(
            f"generated {run / 'signals.csv'}: {size / 1e6:.0f} MB, {rows} rows x "
            f"{len(COLUMNS)} columns in {time.perf_counter() - t0:.0f} s"
        )
        for columns in ("all", "base"):
            r = read_in_child(run, columns)
            print(
                f"read_signals ({columns} columns kept: {r['columns']}): {r['seconds']:.1f} s, "
                f"{size / 1e6 / r['seconds']:.0f} MB/s, peak RSS {r['peak_rss'] / 1e6:.0f} MB "
                f"({r['peak_rss'] / size:.2f} x the file)"
            )
        if args.identify:
            r = identify_in_child(run, Path(args.dir or tmp) / "identify")
            print(
                f"hil identify --from: exit {r['exit']}, {r['seconds']:.0f} s, peak RSS "
                f"{r['peak_rss'] / 1e9:.2f} GB" + (f"; {r['error']}" if r["error"] else "")
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
