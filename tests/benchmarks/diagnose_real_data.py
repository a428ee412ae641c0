"""`hil diagnose` on every shipped DFKI double-pendulum recording: the table of
docs/real-data-diagnosis.md.

    python tests/benchmarks/diagnose_real_data.py [--records DIR] [--out DIR]

Each recording is diagnosed alone (its last 25 % held out), with `--format dfki` and the robot
profile of its design (dfki-a0, dfki-c0), exactly as
`hil diagnose FILE --format dfki --robot dfki-a0 --json` does; the documents are written to
``--out`` (default: a temporary directory) and one table row per recording is printed:
nominal fit physical or not, findings, not-findings, held-out torque and simulated-position
NRMSE before → after, and the noise model's windows. Slow: about a minute per recording on a
loaded machine.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from realdata import realdata  # tests/realdata.py

RECORDS = realdata("dfki-double-pendulum") / "records"


def _pct(x: float | None) -> str:
    return "–" if x is None else f"{100 * x:.1f}"


def row(name: str, doc: dict) -> str:
    fit = doc["fit"]
    b, a = fit["before"], fit["after"]
    torque = f"{_pct(b['torque_nrmse'][0])} / {_pct(b['torque_nrmse'][1])}"
    if doc["findings"]:
        torque += f" → {_pct(a['torque_nrmse'][0])} / {_pct(a['torque_nrmse'][1])}"
    pos_b, pos_a = b["position_nrmse"], a["position_nrmse"]
    sim = f"{_pct(pos_b[0])} / {_pct(pos_b[1])}" if pos_b else "not simulated"
    if doc["findings"] and pos_a:
        sim += f" → {_pct(pos_a[0])} / {_pct(pos_a[1])}"
    found = ", ".join(f"{f['effect']} j{f['joint'] or '1+2'}" for f in doc["findings"]) or "none"
    nominal = (
        "yes"
        if doc["physical"]["nominal_consistent"]
        else ("no: " + "; ".join(doc["physical"]["nominal_violations"]))
    )
    rejected = ", ".join(doc.get("not_findings", {})) or "–"
    noise = doc["noise"][0] or {}
    half, window_s = noise.get("velocity_half_window", "?"), noise.get("filter_window_s", 0)
    windows = f"{half} / {1000 * window_s:.0f} ms"
    return f"| {name} | {nominal} | {found} | {rejected} | {torque} | {sim} | {windows} |"


HEADER = (
    "| recording | nominal fit physical | findings | not findings (reason in the report) "
    "| held-out torque NRMSE % j1 / j2 | held-out simulated position % | velocity half-window / "
    "filter |\n|---|---|---|---|---|---|---|"
)


def diagnose_to(target: Path, recordings: list[Path], robot: str) -> str | None:
    """`hil diagnose RECORDINGS --format dfki --robot ROBOT --json`, its document written to
    ``target``; the last line of its error when it fails, else None."""
    argv = [sys.executable, "-m", "hil.cli", "diagnose", *map(str, recordings), "--format",
            "dfki", "--robot", robot, "--json", "--no-plots"]  # fmt: skip
    done = subprocess.run(argv, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        return done.stderr.strip().splitlines()[-1]
    target.write_text(done.stdout)
    return None


def table_arguments(doc: str, prefix: str) -> tuple[argparse.Namespace, Path]:
    """The options of a real-data table script (--records, --out, --table-only) and its
    output directory (--out, or a new temporary one named ``prefix``...)."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--records", type=Path, default=RECORDS)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--table-only", action="store_true", help="format the documents in --out")
    args = ap.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix=prefix))
    out.mkdir(parents=True, exist_ok=True)
    return args, out


def main() -> int:
    args, out = table_arguments(__doc__, "ddbench-dfki-diagnosis-")
    files = sorted(args.records.glob("*.csv"))
    print(HEADER)
    for f in files:
        target = out / f"{f.stem}.json"
        if not args.table_only:
            robot = "dfki-a0" if f.name.startswith("design_A") else "dfki-c0"
            error = diagnose_to(target, [f], robot)
            if error:
                print(f"| {f.stem} | fails: `{error}` |||||")
                continue
        if target.exists() and target.stat().st_size:
            print(row(f.stem, json.loads(target.read_text())))
    return 0


if __name__ == "__main__":
    sys.exit(main())
