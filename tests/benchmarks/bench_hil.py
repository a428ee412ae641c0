"""Benchmarks of the HIL link (`make bench`): lockstep speed, realtime timing, CAN bus load.

Targets (issue 3): lockstep over virtual-slcan >= 10x real time at h = 2.5 ms; realtime 400 Hz
for 60 s over virtual-slcan and virtual-serial with deadline misses <= 0.1 % and p99
command-to-feedback latency <= 1 ms; the same figures at 1 kHz, whatever they are; CAN bus load
of the 400 Hz and 1 kHz loops on a 1 Mbit/s bus.

    python tests/benchmarks/bench_hil.py [--realtime-seconds 60] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import tomllib
from pathlib import Path

import can

from hil.run import run_experiment
from profiles import resolve

BITRATE = 1_000_000


def frame_bits(dlc: int, stuffing: bool) -> int:
    """Bits on the wire of a standard (11-bit) data frame with ``dlc`` bytes, plus intermission.

    44 + 8n bits of frame (SOF, id, RTR, IDE, r0, DLC, data, CRC, delimiters, ACK, EOF) and
    3 of intermission; worst-case bit stuffing adds one bit per 4 of the 34 + 8n stuffed bits.
    """
    bits = 47 + 8 * dlc
    if stuffing:
        bits += (34 + 8 * dlc - 1) // 4
    return bits


def bus_load(log: Path, seconds: float) -> dict[str, float]:
    frames = list(can.LogReader(str(log)))
    nominal = sum(frame_bits(m.dlc, False) for m in frames)
    worst = sum(frame_bits(m.dlc, True) for m in frames)
    return {
        "frames_per_s": len(frames) / seconds,
        "load_nominal_pct": 100 * nominal / seconds / BITRATE,
        "load_worst_case_stuffing_pct": 100 * worst / seconds / BITRATE,
    }


# The shipped benches stop a realtime run after 3 periods without feedback (the issue asks the
# host to notice a dead robot that fast). This VM stalls that long about once a minute, which
# would end a 60 s timing run early; the benchmark measures the link's timing, so its copies of
# the benches wait 20 periods. A stall still counts as the deadline misses it causes.
BENCH_FEEDBACK_TIMEOUT_PERIODS = 20


def bench_file(tmp: Path, base: str, period_s: float) -> Path:
    data = tomllib.loads(resolve("benches", base).read_text())
    text = resolve("benches", base).read_text()
    path = tmp / f"{base}-{round(1 / period_s)}hz.toml"
    old = f"period_s = {data['period_s']}"
    assert old in text and "feedback_timeout_periods = 3" in text
    text = text.replace(old, f"period_s = {period_s}", 1)
    text = text.replace(
        "feedback_timeout_periods = 3",
        f"feedback_timeout_periods = {BENCH_FEEDBACK_TIMEOUT_PERIODS}",
        1,
    )
    path.write_text(text)
    return path


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--realtime-seconds", type=float, default=60.0)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    results: dict[str, dict] = {}
    ok = True
    with tempfile.TemporaryDirectory() as tmp_dir:
        tmp = Path(tmp_dir)
        s = run_experiment(
            "virtual-slcan",
            "reyes-kelly",
            tmp / "lockstep",
            duration_s=10.0,
            mode="lockstep",
            plot=False,
            progress=False,
        )
        results["lockstep virtual-slcan 400 Hz"] = {
            "status": s["status"],
            "realtime_factor": s["realtime_factor"],
            "target": ">= 10",
        }
        ok &= s["status"] == "complete" and s["realtime_factor"] >= 10
        for base in ("virtual-slcan", "virtual-serial"):
            for hz in (400, 1000):
                name = f"realtime {base} {hz} Hz"
                out = tmp / name.replace(" ", "-")
                bench = bench_file(tmp, base, 1.0 / hz)
                print(f"running {name} for {args.realtime_seconds:g} s ...", file=sys.stderr)
                s = run_experiment(
                    str(bench),
                    "reyes-kelly",
                    out,
                    duration_s=args.realtime_seconds,
                    mode="realtime",
                    plot=False,
                    progress=False,
                )
                timing = s["timing"]
                entry = {
                    "status": s["status"],
                    "reason": s["reason"],
                    "cycles": timing.get("cycles"),
                    "deadline_misses": timing.get("deadline_misses"),
                    "deadline_miss_pct": 100 * timing.get("deadline_miss_fraction", float("nan")),
                    "late_releases": timing.get("late_releases"),
                    "late_release_pct": 100 * timing.get("late_release_fraction", float("nan")),
                    "latency_p50_ms": timing.get("command_to_feedback_latency", {}).get("p50_ms"),
                    "latency_p99_ms": timing.get("command_to_feedback_latency", {}).get("p99_ms"),
                    "latency_max_ms": timing.get("command_to_feedback_latency", {}).get("max_ms"),
                    "sync_lateness_p99_ms": timing.get("sync_lateness", {}).get("p99_ms"),
                }
                if base == "virtual-slcan":
                    entry["bus"] = bus_load(out / "bus.log", s["rows"] / hz)
                if hz == 400:
                    entry["target"] = "misses <= 0.1 %, p99 latency <= 1 ms"
                    ok &= (
                        s["status"] == "complete"
                        and entry["deadline_miss_pct"] <= 0.1
                        and entry["latency_p99_ms"] <= 1.0
                    )
                results[name] = entry
    if args.json:
        print(json.dumps({"results": results, "all_targets_met": bool(ok)}))
    else:
        for name, entry in results.items():
            print(name)
            for key, value in entry.items():
                print(f"  {key:28s} {value}")
        print("all targets met" if ok else "SOME TARGETS MISSED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
