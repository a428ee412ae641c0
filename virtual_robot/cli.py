"""`virtual-robot` command line: offline simulation (and, with the HIL link, the drive server)."""

from __future__ import annotations

import sys

if __name__ == "__main__":
    # `python -m virtual_robot.cli`: the exit signals before this module's imports below (a
    # signal during them ends with the one line, not a traceback or a silent death by SIGHUP),
    # then this module imported again, as virtual_robot.cli, and run
    import importlib

    from drivers.process import run_command_line

    sys.exit(
        run_command_line("virtual-robot", lambda: importlib.import_module("virtual_robot.cli").run)
    )

import argparse
import contextlib
import math
import os
import threading
from collections.abc import Sequence

from drivers.logsetup import add_verbosity_options, configure, verbosity
from drivers.options import float_list
from drivers.outdir import new_run_dir, release_out_dirs, take_out_dir
from drivers.process import (
    STDOUT_CLOSED,
    interrupt_exit_code,
    interrupt_reason,
    limit_blas_threads,
    reader_gone,
    run_command_line,
    stdout_closed,
)
from drivers.recording import RecordingError, dumps_strict
from profiles import ProfileError
from profiles.bench import BenchProfile, load_bench
from profiles.effects import load_effects
from profiles.experiment import check_duration, check_step, load_experiment
from profiles.robot import load_any_robot
from virtual_robot.plant import DEFAULT_STEP_S


def _parser() -> argparse.ArgumentParser:
    from importlib.metadata import PackageNotFoundError, version

    try:
        release = version("ddbench")
    except PackageNotFoundError:  # run from a source tree that is not installed
        release = "unknown"
    p = argparse.ArgumentParser(
        prog="virtual-robot", description="The emulated Reyes & Kelly direct-drive arm."
    )
    p.add_argument("--version", action="version", version=f"virtual-robot {release}")
    add_verbosity_options(p)
    common = argparse.ArgumentParser(add_help=False)
    add_verbosity_options(common, subcommand=True)
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    s = sub.add_parser(
        "simulate", help="run an experiment offline and write a recording", parents=[common]
    )
    s.add_argument(
        "--robot",
        default="cicese",
        help="robot profile name or TOML file (a URDF-only profile runs the n-joint plant)",
    )
    s.add_argument("--experiment", default="reyes-kelly", help="experiment profile name or file")
    s.add_argument(
        "--effects", default=None, help="effects profile name or file (concealed physics)"
    )
    s.add_argument(
        "--duration", type=float, default=None, help="seconds (default: the experiment's)"
    )
    s.add_argument(
        "--out",
        default=None,
        help="run directory to write (default: a new runs/simulate/<date>T<time>)",
    )
    s.add_argument(
        "--overwrite",
        action="store_true",
        help="empty a non-empty --out directory first (without it, such a --out is refused; "
        "a directory another live run holds is refused either way)",
    )
    s.add_argument(
        "--step",
        type=float,
        default=DEFAULT_STEP_S,
        help=f"integrator step in s (default {DEFAULT_STEP_S})",
    )
    s.add_argument("--no-plot", action="store_true", help="skip positions.png")
    s.add_argument("--json", action="store_true", help="print one JSON summary on stdout")

    v = sub.add_parser("serve", help="serve the drives over a bench's transport", parents=[common])
    v.add_argument("--bench", default="virtual-slcan", help="bench profile name or TOML file")
    v.add_argument(
        "--robot",
        default=None,
        help="robot profile name or TOML file (default: the bench's; a URDF-only profile "
        "serves its n drives on the n-joint plant)",
    )
    v.add_argument("--effects", default=None, help="effects profile name or file")
    v.add_argument("--seed", type=int, default=None, help="seed for any randomness (recorded)")
    v.add_argument(
        "--mode",
        choices=("lockstep", "realtime"),
        default=None,
        help="time mode (default: the bench's)",
    )
    v.add_argument(
        "--confirm-real",
        action="store_true",
        help="serve on a real (non-virtual) bench's bus or a real CAN interface: the emulated "
        "drives then answer beside real ones; the same confirmation `hil` asks for",
    )
    v.add_argument(
        "--exit-with-parent",
        action="store_true",
        help="stop when the process that started us dies (used by `hil`)",
    )
    v.add_argument(
        "--initial-q",
        default=None,
        metavar="Q1,Q2,...",
        help="the arm's position at rest when serving starts, rad, one per joint (default 0; "
        "`hil run` passes its experiment's initial_q_rad)",
    )
    v.add_argument(
        "--event-log",
        default=None,
        help="realtime: write the robot's sample and command times here (for `hil replay`)",
    )
    return p


PARENT_POLL_S = 0.05  # how soon a dead host is noticed (serve() then disables the drives)


def _watch_parent(stop: threading.Event) -> None:
    """Stop serving once our parent is gone; serving ends with the drives disabled (serve.py)."""
    parent = os.getppid()

    def run() -> None:
        while not stop.wait(PARENT_POLL_S):
            if os.getppid() != parent:
                print(
                    "virtual-robot: host process gone; drives disabled, stopping", file=sys.stderr
                )
                stop.set()

    threading.Thread(target=run, name="parent-watch", daemon=True).start()


def real_channel(bench: BenchProfile) -> str | None:
    """What real bus serving ``bench`` would join, or None if it stays virtual: a bench with
    ``virtual = false``, or SocketCAN on an interface that is not a vcan/vxcan."""
    if not bench.virtual:
        return f"the real bench's channel {bench.channel!r}"
    if bench.transport == "socketcan":
        channel = bench.channel or "vcan0"
        if not channel.startswith(("vcan", "vxcan")):
            return f"SocketCAN interface {channel!r} (not a vcan)"
    return None


def _progress(t: float, total: float) -> None:
    print(f"virtual-robot: simulated {t:.1f} / {total:.1f} s", file=sys.stderr)


def cmd_simulate(args: argparse.Namespace) -> int:
    from virtual_robot.simulate import simulate

    robot = load_any_robot(args.robot)  # 2-DOF closed form, or n joints from a URDF
    experiment = load_experiment(args.experiment)
    experiment.check_joints(robot.n_joints, robot.name)
    h = experiment.period_s
    duration = experiment.duration_s if args.duration is None else args.duration
    check_duration(duration, h)  # one-line errors before anything is allocated
    check_step(args.step, h, duration)
    effects = load_effects(args.effects)
    # this run's alone until it ends (drivers/outdir.py); without --out, a new one for it
    args.out = str(
        new_run_dir("simulate") if args.out is None else take_out_dir(args.out, args.overwrite)
    )
    result = simulate(
        robot,
        experiment,
        args.out,
        effects=effects,
        duration_s=args.duration,
        step_s=args.step,
        plot=not args.no_plot,
        progress=_progress,
    )
    summary = result.summary()
    if args.json:
        print(dumps_strict(summary))
    else:
        print(
            f"wrote {summary['rows']} rows ({summary['simulated_s']:.3f} s at "
            f"{experiment.period_s * 1e3:g} ms) to {summary['signals']}"
        )
        if result.plot:
            print(f"plot: {result.plot}")
        print(f"{summary['realtime_factor']}x real time, {summary['plant_steps']} plant steps")
        if result.plant_kernel:  # the n-joint plant: which RK4 step ran (compiled_step.py)
            why = result.plant_kernel.get("reason")
            print(f"plant step: {result.plant_kernel['kernel']}" + (f" ({why})" if why else ""))
    return 0


def _initial_q(text: str | None, n_joints: int) -> tuple[float, ...] | None:
    """``--initial-q``: ``n_joints`` finite angles in [−2π, 2π] (an experiment's range), comma
    separated."""
    if text is None:
        return None
    return float_list(
        text,
        "--initial-q",
        n_joints,
        "angles in [-2 pi, 2 pi] rad (one per joint)",
        lambda q: abs(q) <= 2 * math.pi,
    )


def cmd_serve(args: argparse.Namespace) -> int:
    """Serve until SIGTERM/SIGINT (SIGUSR1: reset the drives' faults); the first stdout line is
    the JSON announcement."""
    import signal

    from virtual_robot.serve import serve

    bench = load_bench(args.bench)
    if args.robot is not None:
        from dataclasses import replace

        load_any_robot(args.robot)  # fail fast, with the one-line error, before announcing
        bench = replace(bench, robot=args.robot)
    real = real_channel(bench)
    if real is not None and not args.confirm_real:
        raise ValueError(
            f"bench {bench.name} would put emulated drives on {real}: pass --confirm-real if "
            "that is what you want (nodes of a real arm there would clash with them)"
        )
    if args.effects is not None:
        load_effects(args.effects)  # fail fast, with the one-line error, before announcing
    initial_q = _initial_q(args.initial_q, load_any_robot(bench.robot).n_joints)
    stop = threading.Event()
    stopped_by: list[int] = []
    reset = threading.Event()  # SIGUSR1: reset the drives' faults (docs/faults.md)
    # A handler runs in the main thread between two bytecodes, possibly while that thread holds
    # an Event's internal lock (inside stop.wait): an Event.set() there would deadlock. The
    # handlers only write a byte to a pipe; a thread sets the events.
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_w, False)

    def relay() -> None:
        while True:
            byte = os.read(wake_r, 1)
            if byte == b"r":
                reset.set()
            else:
                stop.set()
                return

    threading.Thread(target=relay, name="signal-relay", daemon=True).start()

    def on_signal(signum: int, _frame: object) -> None:
        stopped_by.append(signum)
        with contextlib.suppress(OSError):  # the pipe full: a stop is on its way already
            os.write(wake_w, b"s")

    def on_reset(_signum: int, _frame: object) -> None:
        with contextlib.suppress(OSError):
            os.write(wake_w, b"r")

    for name in ("SIGTERM", "SIGINT", "SIGHUP"):  # the exit signals (drivers.process)
        signal.signal(getattr(signal, name), on_signal)
    signal.signal(signal.SIGUSR1, on_reset)
    if args.exit_with_parent:
        _watch_parent(stop)

    def announce(info: dict) -> None:
        print(dumps_strict({**info, "bench": bench.name, "pid": os.getpid()}), flush=True)

    code = serve(
        bench,
        effects=args.effects,
        mode=args.mode,
        seed=args.seed,
        announce=announce,
        stop=stop,
        event_log=args.event_log,
        initial_q=initial_q,
        reset=reset,
    )
    if stopped_by:  # the drives were disabled on the way out (serve.py)
        name = signal.Signals(stopped_by[0]).name
        print(f"virtual-robot: stopped by {name}; drives disabled", file=sys.stderr)
        return 128 + stopped_by[0]
    print("virtual-robot: stopped", file=sys.stderr)
    return code


def main(argv: Sequence[str] | None = None) -> int:
    """The ``virtual-robot`` command line: the exit signals first (SIGTERM and SIGHUP as
    Ctrl-C, :func:`drivers.process.run_command_line`), then :func:`run`; exit status 128 + the
    signal's number when one stopped it."""
    return run_command_line("virtual-robot", lambda: run, argv)


def run(argv: Sequence[str] | None = None) -> int:
    """Parse and run one subcommand; the output directories it took released as it ends
    (drivers.outdir: a start that failed before recording leaves nothing behind)."""
    status = 1
    try:
        status = _run(argv)
        return status
    finally:
        release_out_dirs(status)


def _run(argv: Sequence[str] | None) -> int:
    parser = _parser()
    args, extras = parser.parse_known_args(argv)
    if extras:  # reported by the subcommand's parser: its usage, its name
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        sub.choices[args.command].error(f"unrecognized arguments: {' '.join(extras)}")
    configure("virtual-robot", verbosity(args))
    limit_blas_threads()
    if stdout_closed():
        print(
            f"virtual-robot {args.command}: error: {STDOUT_CLOSED}",
            file=sys.stderr,
        )
        return 2
    try:
        if args.command == "simulate":
            return cmd_simulate(args)
        if args.command == "serve":
            return cmd_serve(args)
    except BrokenPipeError:  # stdout's reader left (`| head`): nothing is lost, nothing to say
        return reader_gone()
    except (ProfileError, RecordingError, ValueError, OSError) as exc:
        print(f"virtual-robot {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C, SIGTERM or SIGHUP: meta.json says "interrupted"
        # serve records nothing: a signal before its own handler is in place (its launch)
        kept = "; the recording so far is kept" if args.command == "simulate" else ""
        print(f"virtual-robot {args.command}: {interrupt_reason()}{kept}", file=sys.stderr)
        return interrupt_exit_code()
    return 2
