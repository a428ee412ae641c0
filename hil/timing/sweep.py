"""`hil jitter --sweep VAR=LEVELS`: what latency, jitter and lost frames do to control and
identification.

At each level of the swept timing fault, and for several seeds where the fault is random, a
point runs, in LOCKSTEP with the fault imposed in simulated time by the virtual robot
(virtual_robot/timing_faults.py; deterministic, and faster than real time):

* the control comparison (:func:`hil.control.tracking.compare_schemes`, the khosla-kanade-tracking
  experiment, the schemes of ``--scheme``): max and RMS tracking errors per joint;
* the identification (:func:`hil.identify.cli.run_identify`, the reyes-kelly excitation, the
  three schemes, exact discretization): the relative error of θ̂1..θ̂9 to the robot profile.

Swept variables (robot side; in lockstep a host-side delay of the same size is the same
experiment): ``latency`` (s; fixed, so deterministic: one run per level whatever ``--seeds``),
``jitter`` (s, the scale of ``--jitter-distribution``), ``drop`` (probability that a command
frame is lost). Levels: ``START:STOP:N`` (N evenly spaced, units on either end: s, ms, us, %),
or a comma list.

The zero-fault lockstep run is the baseline. Points are independent and run on an executor
(hil/bench/executors.py: a local process pool by default, serial with ``--executor serial``, a Dask
cluster with ``--executor dask`` or ``--executor tcp://HOST:8786``, docs/scaling.md); the
sweep's JSON is the same on each, up to its wall times and the executor's description
(:func:`reproducible`). A point whose worker died twice is listed in ``lost_points`` with its
parameters; the others are kept. Output in ``--out``: ``sweep.json`` (every point and mean ± std
over seeds), ``sweep-tracking.png``, ``sweep-parameters.png``, and one directory per point.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import re
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drivers.recording import write_json_atomic
from hil.bench.executors import add_executor_arguments, executor_from_args
from hil.bench.jobs import Executor, Outcome
from hil.cli_options import EXIT_FAILED, EXIT_OK, prepare_out_dir, print_document, say

VARIABLES = {
    "latency": "s",
    "jitter": "s",
    "drop": "probability",
}
DISTRIBUTIONS = ("normal", "uniform", "exponential")
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6}
DEFAULT_SCHEMES = ("ct",)
DEFAULT_CONTROL_EXPERIMENT = "khosla-kanade-tracking"
DEFAULT_IDENTIFY_EXPERIMENT = "reyes-kelly"
SWEEP_JSON = "sweep.json"


# ---- arguments --------------------------------------------------------------------------------
def add_sweep_arguments(p: argparse.ArgumentParser) -> None:
    """The sweep's options, on `hil jitter`'s parser (call after its own options: ``--bench``,
    ``--out``, ``--json``, and ``--seed``/``--effects`` if it has them, are shared)."""
    g = p.add_argument_group("studies (--sweep; docs/jitter.md)")
    g.add_argument(
        "--sweep",
        default=None,
        metavar="VAR=LEVELS",
        help="sweep a timing fault in lockstep: latency=0:2ms:9, jitter=0:1ms:5, drop=0:5%%:6 "
        "(or a comma list); runs the control comparison and the identification at each level",
    )
    g.add_argument(
        "--scheme",
        action="append",
        default=None,
        help="controller(s) of the sweep's control comparison (repeat or comma list; default ct)",
    )
    g.add_argument("--seeds", type=int, default=3, help="seeds per level of a random fault")
    g.add_argument(
        "--jitter-distribution",
        choices=DISTRIBUTIONS,
        default="normal",
        help="distribution of a jitter sweep (normal: half-normal |N(0, scale)|)",
    )
    add_executor_arguments(g)
    g.add_argument(
        "--study-duration",
        type=float,
        default=None,
        help="seconds of each control and identification run (default: the experiments' own)",
    )
    g.add_argument("--no-identify", action="store_true", help="sweep the control comparison only")
    options = p._option_string_actions  # shared options `hil jitter` may not have
    if "--seed" not in options:
        g.add_argument("--seed", type=int, default=None, help="first seed (default 0)")
    if "--effects" not in options:
        g.add_argument("--effects", default=None, help="virtual bench: effects profile")


def parse_sweep(spec: str) -> tuple[str, list[float]]:
    """``VAR=START:STOP:N`` or ``VAR=a,b,c`` -> (variable, levels in SI units)."""
    var, sep, text = spec.partition("=")
    var = var.strip().replace("-", "_")
    if not sep or var not in VARIABLES:
        raise ValueError(
            f"--sweep {spec!r}: expected VAR=LEVELS with VAR one of {', '.join(VARIABLES)}"
        )
    kind = VARIABLES[var]
    parts = text.split(":")
    try:
        if len(parts) == 3:
            stop, unit = _number(parts[1], kind, None)
            start, _ = _number(parts[0], kind, unit)
            n = int(parts[2])
            if n < 1:
                raise ValueError("N must be >= 1")
            levels = np.linspace(start, stop, n).tolist() if n > 1 else [start]
        elif len(parts) == 1:
            values = [v for v in text.split(",") if v.strip()]
            unit = _number(values[-1], kind, None)[1] if values else None
            levels = [_number(v, kind, unit)[0] for v in values]
        else:
            raise ValueError("use START:STOP:N or a comma list")
    except (ValueError, IndexError) as exc:
        raise ValueError(f"--sweep {spec!r}: {exc}") from None
    if not levels:
        raise ValueError(f"--sweep {spec!r}: no levels")
    for v in levels:  # at most 1 s of delay, or probability 1
        if not (math.isfinite(v) and 0.0 <= v <= 1.0):
            what = "a probability in [0, 1]" if kind == "probability" else "a delay in [0, 1 s]"
            raise ValueError(f"--sweep {spec!r}: level {v:g} is not {what}")
    return var, [float(v) for v in levels]


def _number(text: str, kind: str, default_unit: str | None) -> tuple[float, str | None]:
    m = re.fullmatch(r"\s*([-+0-9.eE]+)\s*([a-zµ%]*)\s*", text)
    if not m:
        raise ValueError(f"{text!r} is not a number with an optional unit")
    value, unit = float(m.group(1)), m.group(2) or default_unit
    if kind == "probability":
        if unit in (None, ""):
            return value, unit
        if unit == "%":
            return value / 100.0, unit
        raise ValueError(f"unit {unit!r}: a drop rate takes none or %")
    if unit in (None, ""):
        return value, unit  # seconds
    if unit not in TIME_UNITS:
        raise ValueError(f"unit {unit!r}: expected one of {', '.join(TIME_UNITS)}")
    return value * TIME_UNITS[unit], unit


def _schemes(values: list[str] | None) -> tuple[str, ...]:
    from hil.control.controllers import SCHEMES

    if not values:
        return DEFAULT_SCHEMES
    out = tuple(s.strip() for v in values for s in v.split(",") if s.strip())
    bad = [s for s in out if s not in SCHEMES]
    if bad or not out:
        raise ValueError(f"--scheme {', '.join(bad)}: expected some of {', '.join(SCHEMES)}")
    return out


# ---- one point --------------------------------------------------------------------------------
@dataclass(frozen=True)
class PointSpec:
    """Everything one point needs (picklable: it crosses to a worker process)."""

    variable: str
    level: float  # SI: s or probability; 0 with baseline=True
    seed: int
    bench: str
    base_effects: str | None
    schemes: tuple[str, ...]
    distribution: str
    out_dir: str
    identify: bool
    duration_s: float | None
    baseline: bool = False


def point_faults(spec: PointSpec) -> dict[str, Any] | None:
    """The ``[timing_faults]`` table of a point (None: no fault, the baseline)."""
    if spec.baseline or spec.level <= 0:
        return None
    robot: dict[str, Any]
    if spec.variable == "latency":
        robot = {"latency_s": spec.level}
    elif spec.variable == "jitter":
        robot = {"jitter": {"distribution": spec.distribution, "scale_s": spec.level}}
    else:
        robot = {"drop_probability": spec.level}
    return {"seed": spec.seed, "robot": robot}


def write_point_effects(spec: PointSpec, out: Path) -> str | None:
    """The point's effects profile: the base effects with the point's timing faults."""
    from profiles.loader import load_toml
    from profiles.timing_faults import to_toml

    faults = point_faults(spec)
    if faults is None:
        return spec.base_effects
    data = dict(load_toml("effects", spec.base_effects)[0]) if spec.base_effects else {}
    data["name"] = f"{data.get('name', 'none')}+{spec.variable}"
    data["description"] = f"sweep point: {spec.variable} = {spec.level!r}, seed {spec.seed}"
    data["timing_faults"] = faults
    path = out / "effects.toml"
    path.write_text(to_toml(data))
    return str(path)


def run_point(spec: PointSpec) -> dict[str, Any]:
    """One point: control comparison and identification in lockstep with the fault imposed.
    Its progress and messages go to ``point.log`` in its directory."""
    out = Path(spec.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    with (
        open(out / "point.log", "w") as log,
        contextlib.redirect_stderr(log),
    ):
        effects = write_point_effects(spec, out)
        result: dict[str, Any] = {
            "variable": spec.variable,
            "level": spec.level,
            "seed": spec.seed,
            "baseline": spec.baseline,
            "out_dir": str(out),
            "effects": effects,
            "timing_faults": point_faults(spec),
            "control": _control(spec, effects, out / "control"),
        }
        if spec.identify:
            try:
                result["identify"] = _identify(spec, effects, out / "identify")
            except (RuntimeError, ValueError, OSError) as exc:  # e.g. a drive's watchdog fault
                result["identify_failure"] = str(exc)
                print(f"identification failed: {exc}", file=sys.stderr)
    result["wall_time_s"] = time.perf_counter() - started
    write_json_atomic(out / "point.json", result)
    return result


def _control(spec: PointSpec, effects: str | None, out: Path) -> dict[str, Any]:
    from hil.control.tracking import compare_schemes

    doc = compare_schemes(
        spec.bench,
        out,
        duration_s=spec.duration_s,
        schemes=spec.schemes,
        experiment=DEFAULT_CONTROL_EXPERIMENT,
        mode="lockstep",
        effects=effects,
        seed=spec.seed,
        plot=False,
        progress=False,
    )
    runs = next(iter(doc["results"].values()))  # the profile's θ
    keys = (
        "max_position_error_rad",
        "rms_position_error_rad",
        "max_velocity_error_rad_s",
        "rms_velocity_error_rad_s",
    )
    return {
        s: {"status": r["status"], "reason": r["reason"], **{k: r.get(k) for k in keys}}
        for s, r in runs.items()
    }


def _identify(spec: PointSpec, effects: str | None, out: Path) -> dict[str, Any]:
    """The excitation over the bench (no online RLS: the batch result is the same), then the
    identification from its recording."""
    from hil.bench.run import run_experiment
    from hil.identify import cli as identify_cli

    fit = out / "fit"
    run = run_experiment(
        spec.bench,
        DEFAULT_IDENTIFY_EXPERIMENT,
        fit,
        duration_s=spec.duration_s,
        mode="lockstep",
        effects=effects,
        seed=spec.seed,
        plot=False,
        progress=False,
    )
    if run["status"] != "complete":
        raise RuntimeError(f"excitation run {run['status']}: {run['reason']}")
    argv = ["--from", str(fit), "--out", str(out), "--no-plot", "--json"]
    report, _ = identify_cli.run_identify(identify_cli.parse_args(argv))
    schemes = report["discretizations"]["exact"]["schemes"]
    return {
        s: {
            "relative_error": r["relative_error"],
            "max_abs_relative_error": float(np.max(np.abs(r["relative_error"]))),
        }
        for s, r in schemes.items()
    }


# ---- the sweep --------------------------------------------------------------------------------
def plan(args: argparse.Namespace) -> tuple[str, list[float], list[int], list[PointSpec]]:
    """The sweep's points (the baseline first), checked before anything runs."""
    from profiles.bench import load_bench

    variable, levels = parse_sweep(args.sweep)
    schemes = _schemes(getattr(args, "scheme", None))
    if args.seeds < 1:
        raise ValueError(f"--seeds must be >= 1, got {args.seeds}")
    duration = getattr(args, "study_duration", None)
    if duration is not None and not duration > 0:
        raise ValueError(f"--study-duration must be > 0 s, got {duration}")
    bench_name = getattr(args, "bench", None) or "virtual-slcan"
    bench = load_bench(bench_name)
    if not bench.virtual:
        raise ValueError(f"bench {bench.name} is not virtual: a sweep runs on the virtual robot")
    if bench.timing_faults is not None and bench.timing_faults.active:
        raise ValueError(
            f"bench {bench.name} has [timing_faults]: a sweep imposes its own; use a bench "
            "without them"
        )
    first = getattr(args, "seed", None) or 0
    random_fault = variable != "latency"  # a fixed latency gives the same run for every seed
    seeds = [first + i for i in range(args.seeds)] if random_fault else [first]
    out = Path(getattr(args, "out", None) or f"runs/sweep-{variable}")
    effects = getattr(args, "effects", None) or bench.effects
    if effects is not None:
        from profiles.effects import load_effects

        own = load_effects(effects).timing_faults
        if own is not None and own.active:
            raise ValueError(
                f"effects {effects} has [timing_faults]: a sweep imposes its own; use effects "
                "without them"
            )
    common = {
        "variable": variable,
        "bench": bench_name,
        "base_effects": effects,
        "schemes": schemes,
        "distribution": getattr(args, "jitter_distribution", "normal"),
        "identify": not getattr(args, "no_identify", False),
        "duration_s": duration,
    }
    points = [PointSpec(level=0.0, seed=first, out_dir=str(out / "baseline"), baseline=True,
                        **common)]  # fmt: skip
    for i, level in enumerate(levels):
        if level <= 0:
            continue  # no fault: the baseline
        for seed in seeds:
            name = f"{variable}-{i:02d}-seed{seed}"
            points.append(
                PointSpec(level=level, seed=seed, out_dir=str(out / "points" / name), **common)
            )
    return variable, levels, seeds, points


def summarize(variable: str, levels: list[float], results: list[dict[str, Any]]) -> dict[str, Any]:
    """Mean, std, min and max over seeds of every metric, per level (level 0 = baseline)."""
    baseline = next(r for r in results if r["baseline"])
    by_level: list[list[dict[str, Any]]] = []
    for level in levels:
        here = [r for r in results if not r["baseline"] and r["level"] == level]
        by_level.append(here if level > 0 else [baseline])

    def stats(values: list[Any]) -> dict[str, Any]:
        a = np.asarray([v for v in values if v is not None], dtype=float)
        if a.size == 0:
            return {"mean": None, "std": None, "min": None, "max": None, "n": 0}
        return {
            "mean": a.mean(axis=0).tolist(),
            "std": a.std(axis=0).tolist(),
            "min": a.min(axis=0).tolist(),
            "max": a.max(axis=0).tolist(),
            "n": int(a.shape[0]),
        }

    control: dict[str, Any] = {}
    for scheme in baseline["control"]:
        control[scheme] = {}
        for key in ("max_position_error_rad", "rms_position_error_rad",
                    "max_velocity_error_rad_s", "rms_velocity_error_rad_s"):  # fmt: skip
            control[scheme][key] = [  # failed runs (a watchdog fault, say) are not counted
                stats([_complete(r["control"][scheme]).get(key) for r in rs]) for rs in by_level
            ]
            control[scheme][key + "_baseline"] = baseline["control"][scheme].get(key)
    identify: dict[str, Any] = {}
    for scheme in baseline.get("identify", {}):
        identify[scheme] = {
            key: [
                stats([r["identify"][scheme][key] for r in rs if "identify" in r])
                for rs in by_level
            ]
            for key in ("max_abs_relative_error", "relative_error")
        }
        identify[scheme]["max_abs_relative_error_baseline"] = baseline["identify"][scheme][
            "max_abs_relative_error"
        ]
    return {"control": control, "identify": identify, "degradation": degradation(levels, control)}


def _complete(run: dict[str, Any]) -> dict[str, Any]:
    return run if run.get("status") == "complete" else {}


def degradation(levels: list[float], control: dict[str, Any]) -> dict[str, Any]:
    """Per scheme and joint: max position error relative to the baseline at each level, and
    the first level where it grew by 10 %, 50 % and 100 %."""
    out: dict[str, Any] = {}
    for scheme, metrics in control.items():
        base = metrics["max_position_error_rad_baseline"]
        means = [s["mean"] for s in metrics["max_position_error_rad"]]
        if base is None or any(m is None for m in means):
            continue
        ratio = [[m[j] / base[j] if base[j] > 0 else None for j in range(2)] for m in means]
        first: dict[str, list[float | None]] = {}
        for pct in (10, 50, 100):
            first[f"+{pct}%"] = [
                next(
                    (lv for lv, r in zip(levels, ratio, strict=True)
                     if r[j] is not None and r[j] >= 1 + pct / 100),
                    None,
                )
                for j in range(2)
            ]  # fmt: skip
        out[scheme] = {"ratio_to_baseline": ratio, "first_level_above": first}
    return out


def sweep(
    args: argparse.Namespace, executor: Executor | None = None, progress: bool = True
) -> dict[str, Any]:
    """Plan, run (on ``executor``, default from ``--executor``/``--workers``), summarize, plot;
    returns sweep.json's document. Progress on stderr as each point finishes, in the order
    they finish; the document lists the points in the plan's order whatever the executor."""
    variable, levels, seeds, points = plan(args)
    if executor is None:
        executor = executor_from_args(args)
    out = Path(points[0].out_dir).parent
    prepare_out_dir(out, getattr(args, "overwrite", False))
    out.mkdir(parents=True, exist_ok=True)
    if progress:
        say(
            "jitter",
            f"sweep {variable} over {len(levels)} levels x {len(seeds)} seed(s): "
            f"{len(points)} points on {executor.describe()} -> {out}",
        )
        where = executor.describe()
        if not out.is_absolute() and where.get("scheduler", "LocalCluster") != "LocalCluster":
            say(
                "jitter",
                f"--out {out} is relative: each Dask worker writes its points "
                "under its own working directory (docs/scaling.md)",
            )
    started = time.perf_counter()
    outcomes: list[Outcome[PointSpec, dict[str, Any]] | None] = [None] * len(points)
    for k, outcome in enumerate(executor.run(run_point, points)):
        outcomes[outcome.index] = outcome
        if progress:
            _print_progress(variable, k + 1, len(points), outcome)
    wall = time.perf_counter() - started
    results = [o.result for o in outcomes if o is not None and o.ok]
    lost = [
        {"point": asdict(o.item), "error": o.error, "attempts": o.attempts}
        for o in outcomes
        if o is not None and not o.ok
    ]
    failed = [
        f"{r['out_dir']}: {s} {c['status']} ({c['reason']})"
        for r in results
        for s, c in r["control"].items()
        if c["status"] != "complete"
    ] + [
        f"{r['out_dir']}: identification {r['identify_failure']}"
        for r in results
        if "identify_failure" in r
    ] + [f"{x['point']['out_dir']}: point lost: {x['error']}" for x in lost]  # fmt: skip
    baseline_ok = any(r["baseline"] for r in results)
    # a run that fails at a fault level (a drive's watchdog, say) is a finding, listed in
    # "failures" and left out of the statistics; the sweep fails if its baseline did, and is
    # incomplete if a point was lost (its worker died, or it raised)
    if not baseline_ok or any(f.startswith(points[0].out_dir + ":") for f in failed):
        status = "failed"
    elif lost:
        status = "incomplete"
    else:
        status = "complete"
    doc: dict[str, Any] = {
        "kind": "hil jitter sweep",
        "variable": variable,
        "unit": VARIABLES[variable],
        "levels": levels,
        "seeds": seeds,
        "deterministic": variable == "latency",
        "side": "robot (lockstep: a host-side delay of the same size is the same experiment)",
        "mode": "lockstep",
        "bench": points[0].bench,
        "effects": points[0].base_effects,
        "schemes": list(points[0].schemes),
        "jitter_distribution": points[0].distribution if variable == "jitter" else None,
        "study_duration_s": points[0].duration_s,
        "executor": executor.describe(),
        "points_run": len(points),
        "wall_time_s": wall,
        "status": status,
        "failures": failed,
        "lost_points": lost,
        "out_dir": str(out),
        **(
            summarize(variable, levels, results)
            if baseline_ok
            else {"control": {}, "identify": {}, "degradation": {}}
        ),
        "points": [
            asdict(p) | ({"result": o.result} if o is not None and o.ok else {"result": None})
            for p, o in zip(points, outcomes, strict=True)
        ],
        "plots": [],
    }
    if not getattr(args, "no_plot", False) and baseline_ok:
        from hil.timing.sweep_plots import plot_sweep

        doc["plots"] = [str(p) for p in plot_sweep(doc, out)]
    write_json_atomic(out / SWEEP_JSON, doc)
    return doc


def _print_progress(
    variable: str, k: int, n: int, outcome: Outcome[PointSpec, dict[str, Any]]
) -> None:
    spec = outcome.item
    what = "baseline" if spec.baseline else f"{variable} {_fmt_level(variable, spec.level)}"
    if outcome.ok:
        r = outcome.result or {}
        again = f", attempt {outcome.attempts}" if outcome.attempts > 1 else ""
        say(
            "jitter",
            f"point {k}/{n} ({what}, seed {spec.seed}) in "
            f"{r.get('wall_time_s', float('nan')):.1f} s{again}",
        )
        return
    say(
        "jitter",
        f"point {k}/{n} ({what}, seed {spec.seed}) LOST after "
        f"{outcome.attempts} attempt(s): {outcome.error} [{spec.out_dir}]",
    )
    if outcome.detail and not outcome.error.startswith("KilledWorker"):  # type: ignore[union-attr]
        print(outcome.detail.rstrip(), file=sys.stderr)


RUN_KEYS = ("wall_time_s", "executor")  # what differs between two runs of the same sweep


def reproducible(doc: Any) -> Any:
    """``doc`` without :data:`RUN_KEYS` at any depth: equal, as JSON, for the same sweep (its
    seeds, levels, bench and --out) on any executor, since every point runs in lockstep."""
    if isinstance(doc, dict):
        return {k: reproducible(v) for k, v in doc.items() if k not in RUN_KEYS}
    if isinstance(doc, list):
        return [reproducible(v) for v in doc]
    return doc


def _fmt_level(variable: str, level: float) -> str:
    return f"{level:.3g}" if VARIABLES[variable] == "probability" else f"{level * 1e3:.3g} ms"


def format_sweep(doc: dict[str, Any]) -> str:
    """The sweep as a table: tracking errors (and parameter errors) per level."""
    var = doc["variable"]
    lines = [
        f"sweep of {var}, imposed by the virtual robot in lockstep over {doc['bench']}, "
        f"{len(doc['seeds'])} seed(s) per level (mean ± std over seeds)",
    ]
    for scheme, m in doc["control"].items():
        lines.append(f"  {scheme.upper()} tracking error, max / RMS position [mrad], joint 1 | 2")
        for level, mx, rms in zip(
            doc["levels"], m["max_position_error_rad"], m["rms_position_error_rad"], strict=True
        ):
            if mx["mean"] is None or rms["mean"] is None:
                cells = "every run failed"
            else:
                expected = 1 if level <= 0 else len(doc["seeds"])  # level 0: the baseline
                runs = f"  ({mx['n']} of {expected} runs)" if mx["n"] < expected else ""
                cells = (
                    " | ".join(
                        f"{1e3 * mx['mean'][j]:7.3f}±{1e3 * mx['std'][j]:.3f} / "
                        f"{1e3 * rms['mean'][j]:6.3f}"
                        for j in range(2)
                    )
                    + runs
                )
            lines.append(f"    {_fmt_level(var, level):>10}  {cells}")
    for scheme, m in doc["identify"].items():
        cells = ", ".join(
            f"{_fmt_level(var, lv)}: "
            + ("failed" if s["mean"] is None else f"{100 * s['mean']:.1f}%")
            for lv, s in zip(doc["levels"], m["max_abs_relative_error"], strict=True)
        )
        lines.append(f"  identification {scheme}, worst |relative error| of θ: {cells}")
    lines.append(f"sweep.json: {Path(doc['out_dir']) / SWEEP_JSON}")
    if doc["plots"]:
        lines.append("plots:      " + ", ".join(doc["plots"]))
    lines.append(f"{doc['points_run']} points in {doc['wall_time_s']:.1f} s on {doc['executor']}")
    if doc["failures"]:
        lines.append("failed: " + "; ".join(doc["failures"]))
    return "\n".join(lines)


def run_sweep(args: argparse.Namespace) -> int:
    """`hil jitter --sweep`: exit status 0 when every point completed. An executor that cannot
    run here (:class:`hil.bench.jobs.ExecutorUnavailableError`) is a usage error (exit status 2)."""
    if getattr(args, "out", None) is None:  # a new runs/sweep-VARIABLE/<stamp> for this sweep
        variable = parse_sweep(args.sweep)[0]
        args.out = str(prepare_out_dir(None, False, default=f"sweep-{variable}", command="jitter"))
    doc = sweep(args, executor_from_args(args), progress=True)
    print_document(args, doc, lambda: format_sweep(doc))
    return EXIT_OK if doc["status"] == "complete" else EXIT_FAILED
