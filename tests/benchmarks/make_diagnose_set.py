"""Write a blind-like set of concealed-effect recordings for the mismatch diagnosis (issue 7).

About 30 recordings made offline on the virtual robot (tests/diagnose_cases.py), one directory each,
plus ``truth.json`` with what every recording conceals. The set has:
  * single effects of the diagnosis vocabulary on joint 1 or 2 (transport delay: both), with
    magnitudes 0.5x-2x the catalogue (log-uniform), cogging at 48-144 periods/rev and a random
    phase, Stribeck velocities of 0.05-0.15 rad/s;
  * pairs of effects (two effects, or one effect on both joints);
  * the default robot (joint 1's direction-dependent Coulomb friction), alone and with an effect;
  * null recordings (symmetric Coulomb friction: the 9-parameter model is exact).
over the excitations reyes-kelly, validation-multisine, optimal-fourier and diagnosis, some of them
with every sine's phase shifted at random (``seed`` in truth.json: another excitation of the same
spectrum). Everything follows from ``--seed``. The recordings' meta.json do not name the effects.

    .venv/bin/python tests/benchmarks/make_diagnose_set.py [--out /tmp/diagnose_set] [--seed 0]
        [--executor serial|process|dask|tcp://HOST:8786] [--workers N] [--only K]

The recordings are independent jobs on an executor (hil/bench/executors.py; serial by default): the
set is the same, byte for byte, on any of them. ``--only K`` makes the first K of the plan. On a
Dask cluster each worker needs ddbench and this checkout's tests/ at the same path, and writes
to ``--out`` (a shared file system, or truth.json alone is on this machine: docs/scaling.md).

Prints one JSON summary on stdout (directory, count, wall time); progress on stderr as each
recording is made. A recording that fails (or whose worker died twice) is listed under
``failed`` in truth.json and the summary, with its parameters, and the exit status is 1. The
directory is replaced if it holds a truth.json from an earlier run, and refused otherwise if not
empty.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # tests/, for diagnose_cases

import diagnose_cases as dc

from hil.bench.executors import add_executor_arguments, executor_from_args

TESTS_DIR = str(Path(__file__).resolve().parent.parent)

EXPERIMENTS = ("reyes-kelly", "validation-multisine", "optimal-fourier", "diagnosis")
COGGING_PERIODS = (48.0, 72.0, 96.0, 120.0, 144.0)
# same joint, confounded in sliding: kept out of the pairs (the truth would be ambiguous)
CONFOUNDED = {"coulomb_asymmetry", "torque_offset"}


def _joints(effect: str) -> tuple[int | None, ...]:
    return tuple(dc.CATALOGUE[effect])


def random_part(
    rng: np.random.Generator, effect: str, joint: int | None
) -> tuple[str, int | None, dict[str, float]]:
    """One effect on ``joint`` with a random magnitude around the catalogue's."""
    base = dc.CATALOGUE[effect][joint]
    factor = float(math.exp(rng.uniform(math.log(0.5), math.log(2.0))))
    magnitude = dc.scale_magnitude(effect, base, factor)
    if effect == "cogging":
        magnitude["periods_per_rev"] = float(rng.choice(COGGING_PERIODS))
        magnitude["phase_rad"] = float(rng.uniform(0.0, 2 * math.pi))
    if effect == "stribeck":
        magnitude["velocity_rad_s"] = float(rng.uniform(0.05, 0.15))
    return effect, joint, {k: round(v, 6) for k, v in magnitude.items()}


def plan_set(seed: int) -> list[dict[str, Any]]:
    """The recordings to make: case, experiment and phase seed of each."""
    rng = np.random.default_rng(seed)
    plan: list[dict[str, Any]] = []

    def add(case: dc.Case, experiment: str | None = None) -> None:
        k = len(plan)
        experiment = experiment or EXPERIMENTS[k % len(EXPERIMENTS)]
        # other excitations of the same spectra: random phases on a third of the multisines
        phase_seed = (
            int(rng.integers(1, 10_000))
            if experiment != "diagnosis" and rng.random() < 1 / 3
            else None
        )
        plan.append({"case": case, "experiment": experiment, "seed": phase_seed})

    # single effects: every effect twice (both joints where it has two)
    for effect in dc.VOCABULARY:
        joints = _joints(effect)
        for i in range(2):
            joint = joints[i % len(joints)]
            part = random_part(rng, effect, joint)
            suffix = "" if joint is None else f"_j{joint}"
            add(dc.case(f"{effect}{suffix}", [part]))
    # pairs
    pairs = 0
    while pairs < 7:
        e1, e2 = (str(e) for e in rng.choice(dc.VOCABULARY, size=2, replace=True))
        j1 = _joints(e1)[int(rng.integers(len(_joints(e1))))]
        j2 = _joints(e2)[int(rng.integers(len(_joints(e2))))]
        if (e1, j1) == (e2, j2) or ({e1, e2} == CONFOUNDED and j1 == j2):
            continue
        parts = [random_part(rng, e1, j1), random_part(rng, e2, j2)]
        name = "+".join(f"{e}{'' if j is None else f'_j{j}'}" for e, j, _ in parts)
        add(dc.case(name, parts))
        pairs += 1
    # the default robot, alone and with one more effect
    add(dc.case("default_robot", [], keep_default_asymmetry=True), "diagnosis")
    extra = random_part(rng, "angle_offset", 2)
    add(dc.case("default_robot+angle_offset_j2", [extra], keep_default_asymmetry=True))
    # nulls: every excitation once, and a phase-shifted one
    for experiment in EXPERIMENTS:
        plan.append({"case": dc.CASES["null"], "experiment": experiment, "seed": None})
    plan.append({"case": dc.CASES["null"], "experiment": "reyes-kelly", "seed": 7})
    plan.append({"case": dc.CASES["null"], "experiment": "validation-multisine", "seed": 11})
    return plan


def _prepare(out: Path) -> None:
    if out.exists():
        if (out / "truth.json").is_file():
            shutil.rmtree(out)
        elif any(out.iterdir()):
            raise SystemExit(f"make_diagnose_set: {out} is not empty and holds no truth.json")
    out.mkdir(parents=True, exist_ok=True)


def make_one(job: dict[str, Any]) -> float:
    """One recording of the set (a job of the executor, maybe on another machine's worker);
    returns its wall time."""
    if job["tests_dir"] not in sys.path:  # a Dask worker that did not start from this script
        sys.path.insert(0, job["tests_dir"])
    import diagnose_cases

    t0 = time.perf_counter()
    diagnose_cases.make_recording(
        job["out_dir"], job["experiment"], job["effects"], seed=job["seed"]
    )
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="/tmp/diagnose_set", help="directory of the set")
    parser.add_argument("--seed", type=int, default=0, help="seed of the set's random choices")
    parser.add_argument("--only", type=int, default=None, help="make the first K recordings")
    add_executor_arguments(parser, default="serial")
    args = parser.parse_args(argv)
    executor = executor_from_args(args, default="serial")
    out = Path(args.out)
    _prepare(out)
    plan = plan_set(args.seed)[: args.only]
    entries = []
    jobs = []
    for k, item in enumerate(plan):
        case: dc.Case = item["case"]
        name = f"rec-{k + 1:02d}"
        jobs.append({"recording": name, "out_dir": str(out / name), "tests_dir": TESTS_DIR,
                     "experiment": item["experiment"], "effects": case.effects,
                     "seed": item["seed"]})  # fmt: skip
        entries.append(
            {
                "recording": name,
                "experiment": item["experiment"],
                "phase_seed": item["seed"],
                "case": case.name,
                "null": case.is_null,
                "truth": case.truth_dicts(),
                "effects": case.effects,
                "note": case.note,
            }
        )
    print(f"make_diagnose_set: {len(jobs)} recordings on {executor.describe()} -> {out}",
          file=sys.stderr)  # fmt: skip
    started = time.perf_counter()
    failed: list[dict[str, Any]] = []
    for k, outcome in enumerate(executor.run(make_one, jobs)):
        job, what = outcome.item, f"{entries[outcome.index]['case']}"
        if outcome.ok:
            print(f"make_diagnose_set: {k + 1}/{len(jobs)} {job['recording']} "
                  f"{job['experiment']:20s} {what} ({outcome.result:.2f} s)",
                  file=sys.stderr)  # fmt: skip
            continue
        print(f"make_diagnose_set: {k + 1}/{len(jobs)} {job['recording']} FAILED after "
              f"{outcome.attempts} attempt(s): {outcome.error}", file=sys.stderr)  # fmt: skip
        failed.append({**entries[outcome.index], "error": outcome.error,
                       "attempts": outcome.attempts})  # fmt: skip
    wall = time.perf_counter() - started
    lost = {f["recording"] for f in failed}
    truth = {
        "generated_by": "tests/benchmarks/make_diagnose_set.py",
        "seed": args.seed,
        "vocabulary": list(dc.VOCABULARY),
        "recordings": [e for e in entries if e["recording"] not in lost],
    }
    if failed:
        truth["failed"] = sorted(failed, key=lambda f: f["recording"])
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n", encoding="utf-8")
    summary = {
        "out_dir": str(out),
        "recordings": len(truth["recordings"]),
        "null": sum(e["null"] for e in truth["recordings"]),
        "failed": [f["recording"] for f in truth.get("failed", [])],
        "executor": executor.describe(),
        "wall_time_s": round(wall, 2),
    }
    print(json.dumps(summary))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
