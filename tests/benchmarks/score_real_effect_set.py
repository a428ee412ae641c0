"""Run `hil diagnose` over a set of effects concealed in real recordings and score it
(issue 26, "Proof").

    python tests/benchmarks/make_real_effect_set.py --out /tmp/real_set
    python tests/benchmarks/score_real_effect_set.py /tmp/real_set [--json FILE] [--jobs 1]
        [--nominal auto|reference|params|profile] [--only case-03,case-10]

Each case's modified recording is diagnosed against the unmodified one's model:
``--reference reference.csv`` where `hil diagnose --help` offers it; else ``--params`` from
`hil identify --from reference.csv` (params.json of a 2-DOF arm, identify.json of a URDF arm;
the diagnosis finds the fingerprinted reference.csv again and compares with it); ``--nominal
profile``: the robot profile. The unmodified recording is diagnosed the same way: its findings
are the baseline, what the real arm already gives.

A case passes when its effect is named on its joint (a truth on no joint, a delay or a
payload: on any) with a size within 35 % (score_diagnose_set.score; a cogging finding must
have the truth's periods), and no finding appears that the baseline lacks; a null passes when
no finding appears that the baseline lacks. A transport delay is also named by an
``actuator_lag`` (the same shaft torque to first order, sized by its time constant); the
out-of-vocabulary drag by an ``unexplained`` structure on its joint (no size to score). Prints a
table and the totals per robot (DFKI x/10, the 7-joint arm x/5); ``--json`` writes them.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))  # tests/benchmarks

from score_diagnose_set import score

from profiles.robot import describes_urdf_only

WITHIN = 0.35  # the size tolerance on real recordings
ALIASES = {
    "transport_delay": ("transport_delay", "actuator_lag"),
    "velocity_squared_drag": ("velocity_squared_drag", "unexplained"),
    # the drift stage's name for an encoder zero offset (hil/diagnose/effects/encoder.py)
    "angle_offset": ("angle_offset", "encoder_offset"),
}
TRUTH_SIZE = {
    "payload": lambda m: m["mass_kg"],
    "velocity_squared_drag": lambda m: m["coefficient_Nms2"],
}
FINDING_SIZE = {
    "encoder_offset": lambda e: e["offset_rad"],
    "payload": lambda e: e["mass_kg"],
    "velocity_squared_drag": lambda e: e["coefficient_Nms2"],
}


def hil(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hil", *args], capture_output=True, text=True)


def offers_reference() -> bool:
    """Whether this tree's `hil diagnose` takes ``--reference`` (issue 26, item 1)."""
    return "--reference" in hil("diagnose", "--help").stdout


def _json(proc: subprocess.CompletedProcess, what: str) -> dict[str, Any]:
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["no message"])[-1]
        raise RuntimeError(f"{what}: exit {proc.returncode}: {last}")
    return json.loads(proc.stdout)


def nominal_args(case_dir: Path, entry: dict, mode: str, work: Path) -> tuple[str, list[str]]:
    """The nominal model's options for this case: (what was used, options)."""
    reference = case_dir / "reference.csv"
    if mode == "reference":
        return "reference", ["--reference", str(reference)]
    robot = entry["diagnose_args"][entry["diagnose_args"].index("--robot") + 1]
    if mode == "params":
        out = work / f"{entry['case']}-identify"
        _json(hil("identify", "--from", str(reference), *entry["diagnose_args"], "--out",
                  str(out), "--overwrite", "--no-plot", "--json"),
              f"{entry['case']}: hil identify")  # fmt: skip
        document = "identify.json" if describes_urdf_only(robot) else "params.json"
        return "params", ["--params", str(out / document)]
    return "profile", []


def diagnose_case(set_dir: Path, entry: dict, mode: str, work: Path) -> dict[str, Any]:
    case_dir = set_dir / entry["case"]
    started = time.perf_counter()
    try:
        used, extra = nominal_args(case_dir, entry, mode, work)
        run = [*entry["diagnose_args"], *extra, "--no-plots", "--json"]
        doc = _json(hil("diagnose", str(case_dir / "recording.csv"), *run), "diagnose")
        base = _json(hil("diagnose", str(case_dir / "reference.csv"), *run), "baseline")
    except (RuntimeError, json.JSONDecodeError) as exc:
        return {"error": str(exc), "seconds": time.perf_counter() - started}
    return {"nominal": used, "doc": doc, "baseline": base,
            "seconds": time.perf_counter() - started}  # fmt: skip


def _key(f: dict) -> str:
    return f"{f['effect']}:{f['joint']}"


def score_case(entry: dict, result: dict) -> dict[str, Any]:
    """The case's verdict from its diagnosis and its baseline's."""
    if "error" in result:
        return {"pass": False, "error": result["error"], "named": [], "missed": [], "extra": []}
    s = score(entry, result["doc"], within=WITHIN, aliases=ALIASES, truth_size=TRUTH_SIZE,
              finding_size=FINDING_SIZE)  # fmt: skip
    baseline = {_key(f) for f in result["baseline"]["findings"]}
    extra = [e for e in s["extra"] if e not in baseline]
    sized_ok = all(x[3] for x in s["sized"])
    ok = not extra and (entry["null"] or (not s["missed"] and sized_ok))
    return {"pass": ok, "named": s["named"], "missed": s["missed"], "sized": s["sized"],
            "extra": extra, "baseline": sorted(baseline), "nominal": result["nominal"]}  # fmt: skip


def _size(truth: list[dict]) -> str:
    return "" if not truth else f"{truth[0]['size']:.4g}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("set_dir", type=Path)
    ap.add_argument("--json", type=Path, default=None, help="write the scores here")
    ap.add_argument("--jobs", type=int, default=1, help="cases diagnosed at once")
    ap.add_argument("--nominal", choices=("auto", "reference", "params", "profile"),
                    default="auto", help="the nominal model (auto: --reference if offered, "
                    "else --params, else the profile)")  # fmt: skip
    ap.add_argument(
        "--only", default=None, help="comma-separated case names to score (default: every case)"
    )
    args = ap.parse_args(argv)
    cases = json.loads((args.set_dir / "truth.json").read_text(encoding="utf-8"))["cases"]
    if args.only:
        wanted = set(args.only.split(","))
        unknown = wanted - {e["case"] for e in cases}
        if unknown:
            ap.error(f"--only: no case named {', '.join(sorted(unknown))} in {args.set_dir}")
        cases = [e for e in cases if e["case"] in wanted]
    mode = args.nominal
    if mode == "auto":
        mode = "reference" if offers_reference() else "params"
    with (
        tempfile.TemporaryDirectory(prefix="score_real_") as tmp,
        ThreadPoolExecutor(args.jobs) as pool,
    ):
        results = list(pool.map(lambda e: diagnose_case(args.set_dir, e, mode, Path(tmp)), cases))
    rows, totals = [], {}
    print(f"{'':4s} {'case':8s} {'robot':8s} {'effect':22s} {'joint':5s} {'truth':>9s} "
          f"{'found':>9s} {'nominal':9s} extra / missed")  # fmt: skip
    for entry, result in zip(cases, results, strict=True):
        s = score_case(entry, result)
        t = totals.setdefault(entry["robot"], {"cases": 0, "passed": 0, "null": 0,
                                               "null_clean": 0, "extra": 0})  # fmt: skip
        t["cases"] += 1
        t["passed"] += s["pass"]
        t["extra"] += len(s["extra"])
        if entry["null"]:
            t["null"] += 1
            t["null_clean"] += s["pass"]
        joint = "" if not entry["truth"] else str(entry["truth"][0]["joint"] or "all")
        found = next((x[2] for x in s.get("sized", []) if x[2] is not None), None)
        print(f"{'ok ' if s['pass'] else 'BAD'}  {entry['case']:8s} {entry['robot']:8s} "
              f"{entry['effect']:22s} {joint:5s} {_size(entry['truth']):>9s} "
              f"{'' if found is None else f'{found:.4g}':>9s} {s.get('nominal', '-'):9s} "
              f"{s['extra']} / {s['missed']} {s.get('error', '')}")  # fmt: skip
        rows.append({"case": entry["case"], "robot": entry["robot"], "effect": entry["effect"],
                     "recording": entry["recording"], "truth": entry["truth"], **s,
                     "seconds": round(result["seconds"], 1)})  # fmt: skip
    for robot, t in totals.items():
        print(f"{robot}: {t['passed']}/{t['cases']} passed, nulls {t['null_clean']}/{t['null']} "
              f"clean, {t['extra']} extra finding(s) beyond the baseline")  # fmt: skip
    if args.json:
        args.json.write_text(json.dumps({"nominal": mode, "totals": totals, "cases": rows},
                                        indent=1) + "\n", encoding="utf-8")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
