"""Golden check of the shipped commands (issue 29: behaviour unchanged by a refactoring).

Runs a fixed set of the commands a user runs (``hil diagnose`` on the recordings in tests/data and
on simulated ones of the 2-DOF and a URDF arm, ``hil identify`` on the cicese virtual arm, a URDF
arm and a DFKI file, ``hil demo --quick``) into one directory, then compares two such directories:
every JSON document (files and the commands' ``--json`` stdout) value by value apart from times,
CPU figures and paths, every text report line by line with paths replaced, every recording
(signals.csv) byte for byte.

    python tests/benchmarks/golden_outputs.py run OUT_BEFORE      # on the old tree
    python tests/benchmarks/golden_outputs.py run OUT_AFTER       # on the new tree
    python tests/benchmarks/golden_outputs.py compare OUT_BEFORE OUT_AFTER

``compare`` prints each difference and the count; exit status 1 when there is any. Two runs of
the same tree give 0 differences (what is ignored below was found that way: wall-clock and CPU
times, run directories, host facts).
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DFKI = "tests/data/dfki/design_A.0__20220815__sys_id__trajectory_00.csv"
PENDULUM = "tests/data/dfki-pendulum/control_method_ilqr__data_measured.csv"

# (name, command; {OUT} is the output directory, each writes --out OUT/name)
COMMANDS: list[tuple[str, list[str]]] = [
    (name, cmd.split())
    for name, cmd in (
        ("diag-dfki-a0", f"hil diagnose {DFKI} --format dfki --robot dfki-a0"),
        (
            "diag-dfki-pendulum",
            f"hil diagnose {PENDULUM} --robot dfki-pendulum "
            "--columns t=time,q1=position,tau1=torque",
        ),
        (
            "sim-cicese",
            "virtual-robot simulate --robot cicese --experiment diagnosis --effects stribeck "
            "--duration 14 --no-plot",
        ),
        ("diag-cicese", "hil diagnose {OUT}/sim-cicese --robot cicese"),
        (
            "sim-cicese-payload",
            "virtual-robot simulate --robot cicese --experiment diagnosis --effects payload "
            "--duration 14 --no-plot",
        ),
        ("diag-cicese-payload", "hil diagnose {OUT}/sim-cicese-payload --robot cicese"),
        (
            "sim-cicese3",
            "virtual-robot simulate --robot cicese3 --experiment cicese3-excitation "
            "--effects joint3-gain --duration 12 --no-plot",
        ),
        ("diag-cicese3", "hil diagnose {OUT}/sim-cicese3 --robot cicese3"),
        (
            "id-cicese",
            "hil identify --bench virtual-inprocess --duration 4 --seed 1 "
            "--validation-experiment none --no-plot",
        ),
        (
            "id-cicese-terms",
            "hil identify --from {OUT}/sim-cicese/signals.csv --robot cicese "
            "--terms rotor_inertia --no-plot",
        ),
        (
            "id-cicese3",
            "hil identify --from {OUT}/sim-cicese3/signals.csv --robot cicese3 --no-plot",
        ),
        ("id-dfki-a0", f"hil identify --from {DFKI} --format dfki --robot dfki-a0 --no-plot"),
        (
            "diag-cicese-params",
            "hil diagnose {OUT}/sim-cicese-payload --robot cicese "
            "--params {OUT}/id-cicese-terms/identify.json",
        ),
        ("demo", "hil demo --quick"),
    )
]
NO_PLOTS = {"hil diagnose": "--no-plots", "hil identify": ""}

# keys whose values are wall-clock or CPU times, or facts of the process that ran: not compared
# (two runs of the same tree differ in these and nothing else; paths are compared, normalized)
IGNORED_KEY = re.compile(
    r"^(wall_time_s|cpu_time_s|cpu_s|realtime_factor|timing_s|started_unix|finished_unix|"
    r"start_ticks|pid|host|cost_per_cycle_us)$"
)
TIME_TEXT = re.compile(
    r"\d{4}-\d\d-\d\dT\d\d[:\d.]*\S*|\d+(\.\d+)? ?(s|ms) (of )?CPU|\bin \d+(\.\d+)? s\b"
    r"|\d+(\.\d+)?x real ?time|\d+ µs per cycle"
    r"|ddbench-\d+-\d+|/dev/pts/\d+"  # the bench channel: process and object id, pty
)
ROOT_FILE = "root.txt"


def run(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / ROOT_FILE).write_text(str(ROOT))  # the tree that ran: its paths are normalized
    bin_dir = Path(sys.executable).parent
    for name, cmd in COMMANDS:
        args = [a.replace("{OUT}", str(out)) for a in cmd]
        args[0] = str(bin_dir / args[0])
        head = " ".join(cmd[:2])
        if head in NO_PLOTS and NO_PLOTS[head] and "--no-plot" not in args:
            args.append(NO_PLOTS[head])
        args += ["--out", str(out / name), "--overwrite"]
        if head in ("hil diagnose", "hil identify", "hil demo"):  # the document on stdout
            json_run = subprocess.run(
                [*args, "--json"], cwd=ROOT, capture_output=True, text=True, check=False
            )
            (out / f"{name}.stdout.json").write_text(json_run.stdout)
            (out / f"{name}.status").write_text(f"{json_run.returncode}\n")
            if head == "hil demo":  # the same run twice costs 40 s: its files are the same
                print(f"{name}: exit {json_run.returncode}", flush=True)
                continue
        proc = subprocess.run(args, cwd=ROOT, capture_output=True, text=True, check=False)
        (out / f"{name}.stdout.txt").write_text(proc.stdout)
        (out / f"{name}.stderr").write_text(proc.stderr)  # progress lines: read, not compared
        (out / f"{name}.text-status").write_text(f"{proc.returncode}\n")
        print(f"{name}: exit {proc.returncode}", flush=True)


def _normal_text(text: str, base: Path) -> str:
    root = (base / ROOT_FILE).read_text() if (base / ROOT_FILE).exists() else str(ROOT)
    text = text.replace(str(base), "<OUT>").replace(root, "<ROOT>")
    text = re.sub(r"/work/wt/[^/\s]+", "<ROOT>", text)
    return TIME_TEXT.sub("<TIME>", text)


def _compare_json(a: object, b: object, where: str, diffs: list[str], bases: tuple[Path, Path]):
    if isinstance(a, dict) and isinstance(b, dict):
        for key in sorted(set(a) | set(b)):
            if IGNORED_KEY.search(str(key)):
                continue
            if key not in a or key not in b:
                diffs.append(f"{where}.{key}: only in {'after' if key in b else 'before'}")
                continue
            _compare_json(a[key], b[key], f"{where}.{key}", diffs, bases)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            diffs.append(f"{where}: length {len(a)} != {len(b)}")
            return
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _compare_json(x, y, f"{where}[{i}]", diffs, bases)
    elif isinstance(a, str) and isinstance(b, str):
        if _normal_text(a, bases[0]) != _normal_text(b, bases[1]):
            diffs.append(f"{where}: {a[:120]!r} != {b[:120]!r}")
    elif a != b and not (a != a and b != b):  # NaN equals NaN here
        diffs.append(f"{where}: {a!r} != {b!r}")


def compare(before: Path, after: Path) -> list[str]:
    diffs: list[str] = []
    files = sorted(
        p.relative_to(before)
        for p in before.rglob("*")
        if p.is_file()
        and p.suffix in (".json", ".txt", ".csv", ".status", ".text-status")
        and p.name != ROOT_FILE
    )
    after_files = {
        p.relative_to(after)
        for p in after.rglob("*")
        if p.is_file()
        and p.suffix in (".json", ".txt", ".csv", ".status", ".text-status")
        and p.name != ROOT_FILE
    }
    for rel in sorted(after_files - set(files)):
        diffs.append(f"{rel}: only in after")
    for rel in files:
        a, b = before / rel, after / rel
        if not b.exists():
            diffs.append(f"{rel}: missing after")
            continue
        if rel.suffix == ".csv":
            if a.read_bytes() != b.read_bytes():
                diffs.append(f"{rel}: bytes differ")
        elif rel.suffix == ".json":
            try:
                ja, jb = json.loads(a.read_text() or "null"), json.loads(b.read_text() or "null")
            except json.JSONDecodeError as exc:
                diffs.append(f"{rel}: not JSON ({exc})")
                continue
            _compare_json(ja, jb, str(rel), diffs, (before, after))
        else:
            la = _normal_text(a.read_text(), before).splitlines()
            lb = _normal_text(b.read_text(), after).splitlines()
            if la != lb:
                first = next(
                    (i for i, (x, y) in enumerate(zip(la, lb, strict=False)) if x != y),
                    min(len(la), len(lb)),
                )
                x, y = la[first : first + 1], lb[first : first + 1]
                diffs.append(f"{rel}: line {first + 1}: {x!r} != {y!r}")
    return diffs


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    sub.add_parser("run").add_argument("out", type=Path)
    cmp_ = sub.add_parser("compare")
    cmp_.add_argument("before", type=Path)
    cmp_.add_argument("after", type=Path)
    args = parser.parse_args()
    if args.cmd == "run":
        run(args.out.resolve())
        return 0
    diffs = compare(args.before.resolve(), args.after.resolve())
    for d in diffs:
        print(d)
    print(f"golden: {len(diffs)} differences")
    return 1 if diffs else 0


if __name__ == "__main__":
    raise SystemExit(main())
