"""`hil` command line, the host application.

Only `hil demo` exists so far: it runs the main job end to end on the embedded default (the
virtual robot, no hardware, no root). Until the HIL link lands, the main job is the offline
simulation of the Reyes & Kelly excitation, run in the virtual robot's own process: the host never
imports the plant's physics (DESIGN.md: the plant is the world, the host only knows its model).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="hil", description="Hardware-in-the-loop bench host.")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="record one experiment over a bench")
    r.add_argument("--bench", default="virtual-slcan", help="bench profile name or TOML file")
    r.add_argument("--experiment", default="reyes-kelly", help="experiment profile or file")
    r.add_argument("--duration", type=float, default=None, help="seconds (default: experiment's)")
    r.add_argument("--out", required=True, help="run directory to write")
    r.add_argument(
        "--mode",
        choices=("lockstep", "realtime"),
        default=None,
        help="time mode (default: the bench's)",
    )
    r.add_argument("--effects", default=None, help="virtual bench: concealed effects profile")
    r.add_argument("--seed", type=int, default=None, help="virtual bench: seed (recorded)")
    r.add_argument(
        "--confirm-real",
        action="store_true",
        help="required to drive a real arm (a bench with virtual = false)",
    )
    r.add_argument("--no-plot", action="store_true", help="skip positions.png")
    r.add_argument("--json", action="store_true", help="print one JSON summary on stdout")
    d = sub.add_parser("demo", help="the main job end to end on the default virtual robot")
    d.add_argument("--out", default="runs/demo", help="directory for the demo's runs")
    d.add_argument("--json", action="store_true", help="print one JSON summary on stdout")
    return p


def cmd_demo(args: argparse.Namespace) -> int:
    out = Path(args.out)
    sim_dir = out / "simulate-reyes-kelly"
    print(
        f"hil demo: simulating the Reyes & Kelly (1997) excitation, eqs. (31)-(32), 10 s, on the "
        f"virtual CICESE arm -> {sim_dir}",
        file=sys.stderr,
    )
    cmd = [
        sys.executable,
        "-m",
        "virtual_robot.cli",
        "simulate",
        "--robot",
        "cicese",
        "--experiment",
        "reyes-kelly",
        "--duration",
        "10",
        "--out",
        str(sim_dir),
        "--json",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        reason = proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else "no message"
        print(f"hil: error: virtual robot simulation failed: {reason}", file=sys.stderr)
        return 1
    summary = {"simulate": json.loads(proc.stdout)}
    if args.json:
        print(json.dumps(summary))
    else:
        s = summary["simulate"]
        print(f"recording: {s['signals']} ({s['rows']} rows, {s['realtime_factor']}x real time)")
        print(f"plot:      {s['plot']}")
        print(f"meta:      {Path(s['out_dir']) / 'meta.json'}")
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    from hil.run import run_experiment

    summary = run_experiment(
        args.bench,
        args.experiment,
        args.out,
        duration_s=args.duration,
        mode=args.mode,
        effects=args.effects,
        seed=args.seed,
        confirm_real=args.confirm_real,
        plot=not args.no_plot,
    )
    if args.json:
        print(json.dumps(summary))
    if summary["status"] == "complete":
        if not args.json:
            print(
                f"recorded {summary['rows']} rows to {summary['signals']} "
                f"({summary['realtime_factor']}x real time, {summary['mode']})"
            )
        return 0
    print(
        f"hil: {summary['status']}: {summary['reason']} "
        f"({summary['rows']} rows kept in {summary['signals']})",
        file=sys.stderr,
    )
    return 130 if summary["status"] == "interrupted" else 1


def main(argv: Sequence[str] | None = None) -> int:
    from drivers.arm import LinkError
    from drivers.recording import RecordingError
    from hil.launch import LaunchError
    from profiles import ProfileError

    args = _parser().parse_args(argv)
    try:
        if args.command == "run":
            return cmd_run(args)
        if args.command == "demo":
            return cmd_demo(args)
    except KeyboardInterrupt:
        print("hil: interrupted; drives commanded to zero torque and disabled", file=sys.stderr)
        return 130
    except (ProfileError, RecordingError, LaunchError, LinkError, OSError, ValueError) as exc:
        print(f"hil: error: {exc}", file=sys.stderr)
        return 2
    return 2


if __name__ == "__main__":
    sys.exit(main())
