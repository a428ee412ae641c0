"""Does the diagnosis find the DFKI arms' reflected rotor inertia by itself? The table of
docs/real-data-diagnosis.md, "The model terms".

    python tests/benchmarks/diagnose_real_terms.py [--records DIR] [--out DIR] [--table-only]

For each design (A.0, C.0), consecutive system-identification trajectories are diagnosed in
pairs, the first fitted and the second held out (`hil diagnose A B --format dfki --robot R`),
once with the profile variant WITHOUT the rotor term (tests/data/dfki/dfki-*-rigid.toml: then
`rotor_inertia` is a candidate) and once with the shipped profile (terms = rotor_inertia: the
term is in the nominal model). One row per run: whether the nominal fit is physical, the
first-round evidence of the `rotor_inertia` and `com_offset` candidates (held-out error
reduction, blocks improved, sign-test p), findings, why a candidate was not a finding, and the
held-out torque NRMSE. Slow: tens of seconds per pair on a loaded machine.
"""

from __future__ import annotations

import itertools
import json
import sys
from pathlib import Path

from diagnose_real_data import _pct, diagnose_to, table_arguments  # this directory: run as a script

RIGID = Path(__file__).resolve().parents[1] / "data" / "dfki"
DESIGNS = {"A.0": ("design_A.0__20220815__sys_id__trajectory_0", "a0"),
           "C.0": ("design_C.0__20220914__sys_id__trajectory_0", "c0")}  # fmt: skip


def _evidence(doc: dict, key: str) -> str:
    ev = doc["candidates_tested"].get(key)
    if ev is None:
        return "in the model" if key in doc.get("nominal_model", {}).get("terms", []) else "–"
    return (
        f"{100 * ev['held_out_error_reduction']:+.1f} %, {ev['blocks_improved']}/{ev['blocks']}, "
        f"p {ev['sign_test_p']:.2g}"
    )


def row(pair: str, profile: str, doc: dict) -> str:
    fit = doc["fit"]
    b, a = fit["before"]["torque_nrmse"], fit["after"]["torque_nrmse"]
    torque = f"{_pct(b[0])} / {_pct(b[1])}"
    if doc["findings"]:
        torque += f" → {_pct(a[0])} / {_pct(a[1])}"
    found = ", ".join(f"{f['effect']} j{f['joint'] or '1+2'}" for f in doc["findings"]) or "none"
    nominal = "yes" if doc["physical"]["nominal_consistent"] else "no"
    why = "; ".join(
        f"{k}: {v}" for k, v in doc.get("not_findings", {}).items() if k in ("rotor_inertia",)
    )
    return (
        f"| {pair} | {profile} | {nominal} | {_evidence(doc, 'rotor_inertia')} | "
        f"{_evidence(doc, 'com_offset')} | {found} | {why or '–'} | {torque} |"
    )


HEADER = (
    "| fit → held out | profile | nominal fit physical | rotor_inertia (first round: reduction, "
    "blocks, p) | com_offset | findings | rotor_inertia not a finding because | held-out torque "
    "NRMSE % j1 / j2 |\n|---|---|---|---|---|---|---|---|"
)


def main() -> int:
    args, out = table_arguments(__doc__, "ddbench-dfki-terms-")
    print(HEADER)
    for design, (stem, short) in DESIGNS.items():
        files = sorted(args.records.glob(stem + "*.csv"))
        for first, second in itertools.pairwise(files):
            pair = f"{design} {first.stem[-2:]} → {second.stem[-2:]}"
            for profile in (str(RIGID / f"dfki-{short}-rigid.toml"), f"dfki-{short}"):
                name = Path(profile).stem
                target = out / f"{first.stem}__{second.stem[-2:]}__{name}.json"
                if not args.table_only:
                    error = diagnose_to(target, [first, second], profile)
                    if error:
                        print(f"| {pair} | {name} | fails: `{error}` ||||||")
                        continue
                if target.exists() and target.stat().st_size:
                    print(row(pair, name, json.loads(target.read_text())), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
