"""`hil replay RUN_DIR`: re-run a recorded realtime run in lockstep with its timing trace imposed
(hil/timing/replay.py; docs/jitter.md, "Studies")."""

from __future__ import annotations

import argparse

from hil.cli_options import (
    add_bench_option,
    add_out_options,
    add_report_options,
    prepare_out_dir,
    print_document,
    say,
)
from hil.timing.replay import COMPUTE_S, format_replay, replay_run


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", help="a realtime run directory (hil run / hil control)")
    add_bench_option(p, default=None, help="virtual bench to replay on (default: the recorded one)")
    add_out_options(p, "output directory (default: a new runs/replay/<date>T<time>)")
    p.add_argument(
        "--trace-source",
        choices=("auto", "robot", "host"),
        default="auto",
        help="robot: the virtual robot's event log (exact); host: the host's stamps in "
        "signals.csv; auto: robot if the run has one",
    )
    p.add_argument(
        "--compute",
        type=float,
        default=None,
        help="host stamps only: seconds from a cycle's feedback to its command taking effect "
        "(default, measured here: "
        + ", ".join(f"{k} {v * 1e3:g} ms" for k, v in COMPUTE_S.items())
        + ")",
    )
    add_report_options(p, plot="skip replay.png")


def main(args: argparse.Namespace) -> int:
    if args.compute is not None and not args.compute >= 0:
        raise ValueError(f"--compute must be >= 0 s, got {args.compute}")
    out = prepare_out_dir(args.out, args.overwrite, (args.run_dir,), default="replay")
    say("replay", f"{args.run_dir} in lockstep with its timing -> {out}")
    doc = replay_run(
        args.run_dir,
        out,
        bench=args.bench,
        source=args.trace_source,
        compute_s=args.compute,
        plot=not args.no_plot,
    )
    print_document(args, doc, lambda: format_replay(doc))
    return 0
