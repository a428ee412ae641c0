"""Run `hil diagnose` over a set of concealed-effect recordings and score it against the truth.

    python tests/benchmarks/make_diagnose_set.py --out /tmp/diagnose_set
    python tests/benchmarks/score_diagnose_set.py /tmp/diagnose_set [--jobs 2]

A truth effect counts as named when a finding has its effect and joint (a truth on both joints,
joint null, also accepts a finding on either joint) and, for the magnitude, when the finding's size
is within 25 % of the truth's. A null recording passes when it has no findings. Findings that
match no truth are listed as extra (a confounded partner of a named truth is not extra; a
partner with no joint, the model term com_offset, is one on either joint, and so are the
per-joint lags confounded with a delay found on both joints).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

SIZE = {
    "coulomb_asymmetry": lambda m: m["negative_Nm"] - m["positive_Nm"],
    "torque_offset": lambda m: m["offset_Nm"],
    "stribeck": lambda m: m["breakaway_ratio"] - 1.0,
    "cogging": lambda m: m["amplitude_Nm"],
    "actuator_lag": lambda m: m["time_constant_s"],
    "transport_delay": lambda m: m["delay_s"],
    "angle_offset": lambda m: m["offset_rad"],
    "torque_gain": lambda m: m["relative"],
}
FINDING_SIZE = {
    "coulomb_asymmetry": lambda e: e["negative_Nm"] - e["positive_Nm"],
    "torque_offset": lambda e: e["offset_Nm"],
    "stribeck": lambda e: (e.get("breakaway_ratio") or 1.0) - 1.0,
    "cogging": lambda e: e["amplitude_Nm"],
    "actuator_lag": lambda e: e["time_constant_s"],
    "transport_delay": lambda e: e["delay_s"],
    "angle_offset": lambda e: e["offset_rad"],
    "torque_gain": lambda e: e["relative"],
}
# Sizes a finding cannot give (an effect outside the vocabulary, found as a structure only).
UNSIZED = {"unexplained"}
WITHIN = 0.25  # a size counts when within this fraction of the truth's


def _diagnose(path: str) -> tuple[str, dict, float]:
    from drivers.recording import read_signals
    from hil.diagnose.pipeline import diagnose
    from hil.model.params import robot_params

    t0 = time.perf_counter()
    doc = diagnose([read_signals(path)], robot_params("cicese").theta).document
    return path, doc, time.perf_counter() - t0


def _joint_ok(truth_joint, finding_joint) -> bool:
    return truth_joint is None or finding_joint == truth_joint


def _same_joints(partner_joint, named_joint) -> bool:
    """Whether a confounded partner sits where the named finding does: a finding with no joint
    spans both (a model term such as com_offset, or one transport delay on both joints, whose
    confounded lags are reported per joint), so it meets a partner on either joint."""
    return partner_joint is None or named_joint is None or partner_joint == named_joint


def score(
    entry: dict,
    doc: dict,
    *,
    within: float = WITHIN,
    aliases: dict[str, tuple[str, ...]] | None = None,
    truth_size: dict | None = None,
    finding_size: dict | None = None,
) -> dict:
    """Which truths of ``entry`` the findings of ``doc`` name, size (within ``within`` of the
    truth) or miss, and which findings are extra. ``aliases``: truth effect -> the finding
    effects that name it (default: its own name); ``truth_size`` / ``finding_size``: more size
    rules over :data:`SIZE` / :data:`FINDING_SIZE` (a finding in :data:`UNSIZED` names a truth
    without a size: sized when the truth has no size rule of that finding's effect)."""
    findings = doc["findings"]
    aliases = aliases or {}
    size_of_truth = {**SIZE, **(truth_size or {})}
    size_of_finding = {**FINDING_SIZE, **(finding_size or {})}
    named, sized, missed = [], [], []
    used = set()
    for t in entry["truth"]:
        names = aliases.get(t["effect"], (t["effect"],))
        hits = [
            i
            for i, f in enumerate(findings)
            if f["effect"] in names and _joint_ok(t["joint"], f["joint"])
        ]
        if not hits:
            missed.append(f"{t['effect']}:{t['joint']}")
            continue
        named.append(f"{t['effect']}:{t['joint']}")
        used.update(hits)
        for i in hits:
            used.update(
                k
                for k, g in enumerate(findings)
                if g["effect"] in findings[i].get("confounded_with", [])
                and _same_joints(g["joint"], findings[i]["joint"])
            )
        want = size_of_truth[t["effect"]](t["magnitude"])
        got = [
            size_of_finding[findings[i]["effect"]](findings[i]["estimate"])
            for i in hits
            if findings[i]["effect"] not in UNSIZED
        ]
        if not got:  # named only as a structure the vocabulary lacks
            sized.append((f"{t['effect']}:{t['joint']}", round(want, 5), None, True))
            continue
        best = min(got, key=lambda g: abs(g - want))
        ok = abs(best - want) <= within * abs(want)
        if t["effect"] == "cogging":
            ok = ok and any(
                findings[i]["estimate"]["periods_per_rev"] == t["magnitude"]["periods_per_rev"]
                for i in hits
            )
        sized.append((f"{t['effect']}:{t['joint']}", round(want, 5), round(best, 5), ok))
    extra = [f"{f['effect']}:{f['joint']}" for i, f in enumerate(findings) if i not in used]
    return {"named": named, "missed": missed, "sized": sized, "extra": extra}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("set_dir", type=Path)
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    truth = json.loads((args.set_dir / "truth.json").read_text())["recordings"]
    paths = [str(args.set_dir / e["recording"]) for e in truth]
    with ProcessPoolExecutor(args.jobs) as pool:
        results = {p: (doc, dt) for p, doc, dt in pool.map(_diagnose, paths)}
    totals = {"truths": 0, "named": 0, "sized": 0, "null": 0, "null_clean": 0, "extra": 0}
    for e, p in zip(truth, paths, strict=True):
        doc, dt = results[p]
        s = score(e, doc)
        totals["truths"] += len(e["truth"])
        totals["named"] += len(s["named"])
        totals["sized"] += sum(1 for x in s["sized"] if x[3])
        totals["extra"] += len(s["extra"])
        if e["null"]:
            totals["null"] += 1
            totals["null_clean"] += not doc["findings"]
        flag = (
            "ok " if not s["missed"] and all(x[3] for x in s["sized"]) and not s["extra"] else "BAD"
        )
        print(
            f"{flag} {e['recording']} {e['experiment']:20s} {e['case']:34s} "
            f"missed={s['missed']} extra={s['extra']} "
            f"sizes={[(n, w, g) for n, w, g, ok in s['sized'] if not ok]} "
            f"({dt:.1f}s)"
        )
    print(json.dumps(totals))
    return 0


if __name__ == "__main__":
    sys.exit(main())
