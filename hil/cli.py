"""`hil` command line, the host application.

`hil run` records an experiment over a bench; `hil demo` runs the main job end to end on the
embedded default (the virtual robot, no hardware, no root). The host never imports the plant's
physics (docs/design.md: the plant is the world, the host only knows its model): the virtual robot
runs as its own process behind a real transport.

The other subcommands live with their capability (``COMMANDS``); the plumbing every command
shares (common options, ``--json``, ``--out``, progress and error lines, exit status) is
:mod:`hil.cli_options` (docs/cli.md).

Errors are one line, ``hil <command>: error: ...``. Exit status (docs/faults.md, "Exit status"):

=====  =========================================================================================
0      done
1      the run or check failed (an incomplete recording, a failed comparison, an internal error)
2      usage: bad arguments, or a profile, parameter file or recording that cannot be used; an
       --out another live run holds; a closed standard output (the result would be lost)
3      link failure: the robot could not be reached or started (lost mid-run: 1, see meta.json)
128+N  stopped by signal N, the same for every command (``hil`` and ``virtual-robot``): 130
       Ctrl-C (SIGINT), 143 SIGTERM, 129 SIGHUP; drives driven were commanded to zero torque
       and disabled (drivers.process)
141    stdout's reader left (``| head``): quietly, as SIGPIPE ends a Unix tool
=====  =========================================================================================
"""

from __future__ import annotations

import sys

if __name__ == "__main__":
    # `python -m hil.cli`: the exit signals before this module's imports below (a SIGTERM during
    # them ends with the one line), then this module imported again, as hil.cli, and run
    import importlib

    from drivers.process import run_command_line

    sys.exit(run_command_line("hil", lambda: importlib.import_module("hil.cli").main))

import argparse
import importlib
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from pathlib import Path

from drivers.logsetup import add_verbosity_options, configure, verbosity
from drivers.process import limit_blas_threads
from hil import __version__
from hil.cli_options import (
    EXIT_USAGE,
    RunInterrupted,
    add_bench_option,
    add_drive_options,
    add_out_options,
    add_report_options,
    drive_kwargs,
    prepare_out_dir,
    print_document,
    require_complete,
    run_command,
    run_exit,
    say,
    simulate_offline,
)

# Subcommands that live in their own modules: name -> (module, help). Each module provides
# ``add_arguments(parser)`` and ``main(args) -> int`` (exit status).
COMMANDS: dict[str, tuple[str, str]] = {
    "identify": ("hil.identify.cli", "identify θ1..θ9 (Reyes & Kelly 1997), print Table II"),
    "control": ("hil.control.cli", "track a trajectory with PD, CT, FED or RFED; --compare"),
    "excite": (
        "hil.identify.excite_cli",
        "design an optimal Fourier excitation, write its profile",
    ),
    "diagnose": ("hil.diagnose.cli", "find the physics the model leaves out (mismatch diagnosis)"),
    "jitter": (
        "hil.timing.jitter_cli",
        "measure realtime loop timing: jitter, latency, misses, bus load",
    ),
    "replay": (
        "hil.timing.replay_cli",
        "re-run a realtime run in lockstep with its timing trace imposed",
    ),
}


JSON_SUMMARY = "print one JSON summary on stdout"


@dataclass(frozen=True)
class DemoLengths:
    """How long each of the demo's recordings runs [s]: the Reyes & Kelly fit run and its
    held-out multisine, each Khosla & Kanade tracking run, the diagnosis run."""

    excitation_s: float
    tracking_s: float
    diagnosis_s: float


# the profiles' own lengths (reyes-kelly, validation-multisine, khosla-kanade-tracking, diagnosis)
DEMO_FULL = DemoLengths(excitation_s=10.0, tracking_s=6.0, diagnosis_s=20.0)
# `hil demo --quick`: the same steps and outputs on shorter runs. 4 s of excitation still fits
# θ1..θ3 within 2 %; 3 s of tracking is the first move out and back to 0 (with its holds); 14 s of
# diagnosis keeps the fast part and joint 1's first slow move with the holds around it, where
# the direction-dependent Coulomb friction shows.
DEMO_QUICK = DemoLengths(excitation_s=4.0, tracking_s=3.0, diagnosis_s=14.0)


def _parser(with_arguments: Collection[str] = COMMANDS) -> argparse.ArgumentParser:
    """The command line; the arguments of the ``COMMANDS`` in ``with_arguments`` (their modules
    imported), the others listed by name and help only: a command's start does not pay for the
    imports of the other commands (scipy.signal alone is about 1 s of CPU)."""
    p = argparse.ArgumentParser(prog="hil", description="Hardware-in-the-loop bench host.")
    p.add_argument("--version", action="version", version=f"hil {__version__}")
    add_verbosity_options(p)
    # the same options after the subcommand (`hil run -v`); SUPPRESS keeps the top-level value
    common = argparse.ArgumentParser(add_help=False)
    add_verbosity_options(common, subcommand=True)
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    r = sub.add_parser("run", help="record one experiment over a bench", parents=[common])
    add_bench_option(r)
    r.add_argument(
        "--attach",
        metavar="CHANNEL",
        default=None,
        help="use the virtual robot already serving on CHANNEL (what `virtual-robot serve` "
        "announced: a pty, or HOST:PORT for socketcand) instead of starting one",
    )
    r.add_argument(
        "--robot",
        default=None,
        help="robot profile or file in place of the bench's, e.g. cicese3 (its drives on the "
        "bus; host limits from its [limits] unless it is the bench's own robot; docs/urdf.md)",
    )
    r.add_argument(
        "--clear-faults",
        action="store_true",
        help="clear a fault the drives hold (from an earlier run, e.g. a second SYNC producer) "
        "before enabling them; each cleared fault is logged",
    )
    r.add_argument("--experiment", default="reyes-kelly", help="experiment profile or file")
    r.add_argument("--duration", type=float, default=None, help="seconds (default: experiment's)")
    add_out_options(r, "run directory to write (default: a new runs/run/<date>T<time>)")
    r.add_argument(
        "--mcap",
        action="store_true",
        help="also write run.mcap beside signals.csv (ROS 2 sensor_msgs/JointState as JSON; "
        "Foxglove opens it; hil identify --from OUT/run.mcap reads it)",
    )
    add_drive_options(r)
    add_report_options(r, plot="skip positions.png", json_help=JSON_SUMMARY)
    d = sub.add_parser(
        "demo", help="the main job end to end on the default virtual robot", parents=[common]
    )
    add_out_options(d, "directory for the demo's runs (default: a new runs/demo/<date>T<time>)")
    d.add_argument(
        "--quick",
        action="store_true",
        help=f"the same steps and outputs on shorter runs: {DEMO_QUICK.excitation_s:g} s of "
        f"excitation (not {DEMO_FULL.excitation_s:g}), {DEMO_QUICK.tracking_s:g} s of tracking "
        f"(not {DEMO_FULL.tracking_s:g}), {DEMO_QUICK.diagnosis_s:g} s of diagnosis excitation "
        f"(not {DEMO_FULL.diagnosis_s:g})",
    )
    add_report_options(d, plot="skip every step's PNG plots", json_help=JSON_SUMMARY)
    for name, (module, help_text) in COMMANDS.items():
        parser = sub.add_parser(name, help=help_text, parents=[common])
        if name in with_arguments:
            importlib.import_module(module).add_arguments(parser)
    return p


def _command_of(argv: Sequence[str]) -> str | None:
    """The subcommand ``argv`` names: its first word that is not an option (the top-level
    options take no value); None when that is no command of ours."""
    first = next((a for a in argv if not a.startswith("-")), None)
    return first if first in (*COMMANDS, "run", "demo") else None


def cmd_demo(args: argparse.Namespace) -> int:
    """The main job on the default virtual bench: record the Reyes & Kelly excitation over the
    HIL link (virtual-slcan, lockstep), check it against the offline simulation, identify
    θ1..θ9 from it (Table II, validated on a held-out run), compare the four controllers
    of Khosla & Kanade (1987) with the profile's and the identified parameters, and diagnose
    what the 9-parameter model leaves out (joint 1's direction-dependent Coulomb friction)."""
    import numpy as np

    from drivers.recording import read_signals
    from hil.bench.run import run_experiment

    lengths = DEMO_QUICK if args.quick else DEMO_FULL
    plot = not args.no_plot
    out = prepare_out_dir(args.out, args.overwrite, default="demo", command="demo")
    run_dir, sim_dir = out / "hil-run-virtual-slcan", out / "simulate-reyes-kelly"
    say(
        "demo",
        f"{lengths.excitation_s:g} s of the Reyes & Kelly (1997) excitation, eqs. (31)-(32), "
        f"over the virtual-slcan bench (CiA 402 over slcan on a pty) -> {run_dir}",
    )
    run = run_experiment(
        "virtual-slcan",
        "reyes-kelly",
        run_dir,
        duration_s=lengths.excitation_s,
        progress=False,
        plot=plot,
    )
    require_complete("demo run", run)
    say("demo", f"the same experiment offline (virtual-robot simulate) -> {sim_dir}")
    sim = simulate_offline(  # else exit 1
        "cicese", "reyes-kelly", lengths.excitation_s, sim_dir, plot=plot
    )
    a, b = read_signals(run_dir), read_signals(sim_dir)
    identical = bool(np.array_equal(a.q, b.q) and np.array_equal(a.tau, b.tau))
    summary = {
        "quick": bool(args.quick),
        "hil_run": run,
        "simulate": sim,
        "hil_run_equals_simulate": identical,
        "max_abs_q_difference_rad": float(np.max(np.abs(a.q - b.q))),
    }
    identification, id_text = _demo_identify(out, run_dir, lengths.excitation_s, plot)
    summary["identify"] = identification
    control, control_text = _demo_control(
        out, Path(identification["params_files"][0]), lengths.tracking_s, plot
    )
    summary["control"] = control
    diagnosis, diagnosis_text = _demo_diagnose(out, lengths.diagnosis_s, plot)
    summary["diagnose"] = diagnosis
    check = (
        "bit-identical to the offline simulation"
        if identical
        else f"NOT identical to the offline simulation "
        f"(max |dq| = {summary['max_abs_q_difference_rad']:.3g} rad)"
    )
    text = [
        f"recording: {run['signals']} ({run['rows']} rows, {run['realtime_factor']}x "
        f"real time over slcan, bus log {run['traffic_log']})",
        f"plot:      {run['plot'] or 'none (--no-plot)'}",
        f"offline:   {sim['signals']} ({sim['realtime_factor']}x real time)",
        f"check:     q and tau over the HIL link are {check}",
    ]
    print_document(
        args, summary, "\n\n".join(["\n".join(text), id_text, control_text, diagnosis_text])
    )
    return 0 if identical else 1


def _demo_diagnose(out: Path, duration_s: float, plot: bool) -> tuple[dict, str]:
    """Record the diagnosis excitation (fast multisine, then slow moves with holds) over the
    bench and diagnose it as a user runs ``hil diagnose RUN --robot cicese --out DIR``: against
    the profile's nominal model (its θ and terms), which leaves out the default robot's
    direction-dependent joint-1 Coulomb friction."""
    from hil.bench.run import run_experiment
    from hil.diagnose.cli import format_report, run_diagnose

    run_dir, diag_dir = out / "hil-run-diagnosis", out / "diagnose"
    say(
        "demo",
        f"{duration_s:g} s of the diagnosis excitation over virtual-slcan -> {run_dir}; "
        f"hil diagnose {run_dir} --robot cicese (the profile's nominal model) -> {diag_dir}",
    )
    run = run_experiment(
        "virtual-slcan", "diagnosis", run_dir, duration_s=duration_s, progress=False, plot=plot
    )
    require_complete("diagnosis run", run)
    args = _parser(("diagnose",)).parse_args(
        ["diagnose", str(run_dir), "--robot", "cicese", "--out", str(diag_dir), "-q",
         *([] if plot else ["--no-plots"])]
    )  # fmt: skip
    doc, _recordings = run_diagnose(args)
    return doc, format_report(doc)


def _demo_control(out: Path, params: Path, duration_s: float, plot: bool) -> tuple[dict, str]:
    """Control step of the demo: PD, CT, FED and RFED (Khosla & Kanade 1987) tracking the
    Section 4.2 trajectory over virtual-slcan, with the profile's θ and the identified θ."""
    from hil.control.tracking import compare_schemes, format_table

    control_dir = out / "control"
    say(
        "demo",
        f"control comparison (PD, CT, FED, RFED; profile and identified θ) -> {control_dir}",
    )
    doc = compare_schemes(
        "virtual-slcan",
        control_dir,
        params=[f"identified={params}"],
        progress=False,
        duration_s=duration_s,
        plot=plot,
    )
    if doc["status"] == "interrupted":  # the comparison stops, and the demo with it
        raise RunInterrupted(f"control comparison interrupted ({control_dir} keeps its runs)")
    return doc, format_table(doc)


def _demo_identify(out: Path, fit_dir: Path, duration_s: float, plot: bool) -> tuple[dict, str]:
    """Identification step of the demo: the recording above is the fit; a held-out multisine
    runs over the same bench; exact and paper discretizations side by side."""
    from hil.bench.run import run_experiment
    from hil.identify.cli import parse_args, run_identify

    held_dir = out / "hil-run-validation-multisine"
    say("demo", f"held-out excitation (validation-multisine) over virtual-slcan -> {held_dir}")
    held = run_experiment(
        "virtual-slcan",
        "validation-multisine",
        held_dir,
        duration_s=duration_s,
        progress=False,
        plot=plot,
    )
    require_complete("demo validation run", held)
    id_dir = out / "identify"
    say("demo", f"identification (Reyes & Kelly 1997 Table II) -> {id_dir}")
    args = parse_args(
        ["--from", str(fit_dir), "--validate", str(held_dir), "--out", str(id_dir),
         "--discretization", "both", "--json", *([] if plot else ["--no-plot"])]
    )  # fmt: skip
    return run_identify(args)


def _check_attach_channel(transport: str, channel: str) -> None:
    """``--attach CHANNEL`` checked for the bench's transport before anything is written: a
    socketcand HOST:PORT (:func:`drivers.options.host_port`), a pty or serial device that
    exists for slcan and serial; one-line ValueError saying what is expected."""
    from drivers.options import host_port

    if transport == "socketcand":
        host_port(channel, "--attach")
    elif transport in ("slcan", "serial", "fdcanusb") and not Path(channel).exists():
        raise ValueError(
            f"--attach takes the pty that `virtual-robot serve` announced for a {transport} "
            f"bench (e.g. /dev/pts/7); {channel!r} does not exist"
        )


def _attached_bench(args: argparse.Namespace) -> str:
    """``--attach``: the bench attached to the running robot, written into the run directory
    (so the run records what it used); its path."""
    from hil.bench.run import UsageError
    from profiles.bench import attached_bench_text, load_bench

    if args.effects is not None or args.seed is not None:
        raise UsageError("--effects and --seed belong to the robot; give them to its serve")
    bench = load_bench(args.bench)
    _check_attach_channel(bench.transport, args.attach)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "bench-attached.toml"
    path.write_text(attached_bench_text(bench, args.attach), encoding="utf-8")
    return str(path)


def cmd_run(args: argparse.Namespace) -> int:
    from hil.bench.run import run_experiment

    taken = prepare_out_dir(args.out, args.overwrite, default="run", command="run")
    args.out = args.out or str(taken)  # --out exactly as given, else this run's new directory
    summary = run_experiment(
        _attached_bench(args) if args.attach else args.bench,
        args.experiment,
        args.out,
        duration_s=args.duration,
        robot=args.robot,
        clear_faults=args.clear_faults,
        mcap=args.mcap,
        **drive_kwargs(args),
    )
    if args.json or summary["status"] == "complete":
        print_document(
            args,
            summary,
            f"recorded {summary['rows']} rows to {summary['signals']} "
            f"({summary['realtime_factor']}x real time, {summary['mode']})"
            + (f" and {summary['mcap']}" if summary.get("mcap") else ""),
        )
    return run_exit(
        "run",
        summary["status"],
        f"{summary['status']}: {summary['reason']} "
        f"({summary['rows']} rows kept in {summary['signals']})",
    )


def _parse(argv: Sequence[str] | None) -> argparse.Namespace:
    """Parse; an unknown option is reported by its subcommand's parser (its usage, its name)."""
    command = _command_of(sys.argv[1:] if argv is None else argv)
    parser = _parser(() if command is None else (command,))
    args, extras = parser.parse_known_args(argv)
    if extras:
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        sub.choices[args.command].error(f"unrecognized arguments: {' '.join(extras)}")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = _parse(argv)
    configure("hil", verbosity(args))
    limit_blas_threads()  # every way in (hil, python -m hil, python -m hil.cli) passes here
    if args.command == "run":
        return run_command("run", cmd_run, args)
    if args.command == "demo":
        return run_command("demo", cmd_demo, args)
    if args.command in COMMANDS:
        module = COMMANDS[args.command][0]
        return run_command(args.command, lambda a: importlib.import_module(module).main(a), args)
    return EXIT_USAGE
