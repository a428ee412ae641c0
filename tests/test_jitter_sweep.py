"""`hil jitter --sweep` (issue 6, part B): level parsing, executors, a small sweep end to end."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import pytest

from hil.bench.executors import LocalProcessExecutor, SerialExecutor, make_executor
from hil.timing.sweep import (
    PointSpec,
    add_sweep_arguments,
    parse_sweep,
    point_faults,
    summarize,
    sweep,
)


def args_for(argv: list[str]) -> argparse.Namespace:
    """The sweep's options as `hil jitter` gives them (its --bench, --out, --json first)."""
    p = argparse.ArgumentParser()
    p.add_argument("--bench", default="virtual-slcan")
    p.add_argument("--out", default=None)
    p.add_argument("--no-plot", action="store_true")
    p.add_argument("--json", action="store_true")
    add_sweep_arguments(p)
    return p.parse_args(argv)


@pytest.mark.parametrize(
    ("spec", "variable", "levels"),
    [
        ("latency=0:2ms:9", "latency", [i * 0.25e-3 for i in range(9)]),
        ("latency=0ms:2ms:3", "latency", [0.0, 1e-3, 2e-3]),
        ("jitter=100us:300us:3", "jitter", [1e-4, 2e-4, 3e-4]),
        ("drop=0:5%:6", "drop", [0.0, 0.01, 0.02, 0.03, 0.04, 0.05]),
        ("drop=0,0.1,0.2", "drop", [0.0, 0.1, 0.2]),
        ("latency=0.5ms", "latency", [5e-4]),
        ("latency=0,1,2ms", "latency", [0.0, 1e-3, 2e-3]),
    ],
)
def test_parse_sweep(spec: str, variable: str, levels: list[float]) -> None:
    var, got = parse_sweep(spec)
    assert var == variable
    assert got == pytest.approx(levels, abs=1e-15)


@pytest.mark.parametrize(
    ("spec", "words"),
    [
        ("latncy=0:2ms:9", "VAR one of latency, jitter, drop"),
        ("latency", "expected VAR=LEVELS"),
        ("latency=0:2ms", "START:STOP:N"),
        ("latency=0:2ms:0", "N must be >= 1"),
        ("latency=0:2hz:3", "unit 'hz'"),
        ("drop=0:2ms:3", "takes none or %"),
        ("drop=0:150%:3", "not a probability"),
        ("latency=-1ms:1ms:3", "not a delay"),
        ("latency=a:b:3", "not a number"),
    ],
)
def test_parse_sweep_errors_are_one_line(spec: str, words: str) -> None:
    with pytest.raises(ValueError) as err:
        parse_sweep(spec)
    assert words in str(err.value) and "\n" not in str(err.value)


def test_point_faults() -> None:
    base = {"bench": "b", "base_effects": None, "schemes": ("ct",), "distribution": "uniform",
            "out_dir": "x", "identify": False, "duration_s": None, "seed": 5}  # fmt: skip
    assert point_faults(PointSpec("latency", 0.0, **base)) is None
    assert point_faults(PointSpec("latency", 1e-3, **base)) == {
        "seed": 5,
        "robot": {"latency_s": 1e-3},
    }
    assert point_faults(PointSpec("jitter", 2e-4, **base))["robot"] == {
        "jitter": {"distribution": "uniform", "scale_s": 2e-4}
    }
    assert point_faults(PointSpec("drop", 0.1, **base))["robot"] == {"drop_probability": 0.1}


def _square(x: int) -> int:
    return x * x


def test_executors_map_in_order() -> None:
    assert list(SerialExecutor().map(_square, [3, 1, 2])) == [9, 1, 4]
    pool = LocalProcessExecutor(2)
    assert list(pool.map(_square, range(5))) == [0, 1, 4, 9, 16]
    assert pool.describe() == {"kind": "process", "workers": 2}
    assert make_executor("process").describe()["workers"] >= 1
    with pytest.raises(ValueError, match="unknown executor"):
        make_executor("ray")


def test_summarize_means_and_spread_over_seeds() -> None:
    def point(level: float, seed: int, e: float, baseline: bool = False) -> dict:
        run = {"status": "complete", "reason": None, "max_position_error_rad": [e, 2 * e],
               "rms_position_error_rad": [e, e], "max_velocity_error_rad_s": [e, e],
               "rms_velocity_error_rad_s": [e, e]}  # fmt: skip
        return {"level": level, "seed": seed, "baseline": baseline, "control": {"ct": run},
                "identify": {"filtered_dynamic": {"max_abs_relative_error": e,
                                                  "relative_error": [e] * 9}}}  # fmt: skip

    results = [point(0.0, 0, 1.0, baseline=True), point(1e-3, 0, 2.0), point(1e-3, 1, 4.0)]
    s = summarize("jitter", [0.0, 1e-3], results)
    m = s["control"]["ct"]["max_position_error_rad"]
    assert m[0]["mean"] == [1.0, 2.0] and m[0]["n"] == 1
    assert m[1]["mean"] == [3.0, 6.0] and m[1]["std"] == [1.0, 2.0] and m[1]["min"] == [2.0, 4.0]
    assert s["identify"]["filtered_dynamic"]["max_abs_relative_error"][1]["mean"] == 3.0
    d = s["degradation"]["ct"]
    assert d["ratio_to_baseline"][1] == [3.0, 3.0]
    assert d["first_level_above"]["+100%"] == [1e-3, 1e-3]


def test_two_level_sweep_end_to_end(tmp_path: Path) -> None:
    """latency 0 and 2 ms, one seed, serial: control and identification in lockstep, sweep.json
    and both plots written; the 0-level point is the zero-fault baseline."""
    out = tmp_path / "sweep"
    args = args_for(["--sweep", "latency=0:2ms:2", "--bench", "virtual-inprocess", "--out",
                     str(out), "--executor", "serial", "--study-duration", "1.0"])  # fmt: skip
    doc = sweep(args, progress=False)
    assert doc["status"] == "complete", doc["failures"]
    saved = json.loads((out / "sweep.json").read_text())
    assert saved["levels"] == [0.0, 0.002] and saved["seeds"] == [0] and saved["deterministic"]
    assert saved["points_run"] == 2  # the baseline and the 2 ms point
    assert {Path(p).name for p in saved["plots"]} == {"sweep-tracking.png", "sweep-parameters.png"}
    assert all(Path(p).stat().st_size > 10_000 for p in saved["plots"])
    ct = saved["control"]["ct"]["max_position_error_rad"]
    base = saved["control"]["ct"]["max_position_error_rad_baseline"]
    assert ct[0]["mean"] == base and all(math.isfinite(x) for x in base)
    assert ct[1]["mean"] != base  # the latency changed the tracking
    fd = saved["identify"]["filtered_dynamic"]["max_abs_relative_error"]
    assert fd[1]["mean"] > fd[0]["mean"]  # and it biased the identification
    effects = (out / "points" / "latency-01-seed0" / "effects.toml").read_text()
    assert "latency_s = 0.002" in effects
