"""The plumbing every `hil` command shares: its common options, output, errors and exit status.

Each subcommand module (``hil.identify.cli``, ``hil.control.cli``, ...) builds its parser and
reports through these, so an option means and says the same everywhere:

* :func:`add_drive_options` / :func:`drive_kwargs`: ``--mode``, ``--effects``, ``--seed``,
  ``--confirm-real`` for every command that drives a bench, and the keyword arguments they (and
  ``--no-plot``) become for :func:`hil.bench.run.run_experiment` and its kin.
* :func:`add_report_options` / :func:`print_document`: ``--no-plot`` and ``--json``; one JSON
  document on stdout, or the text.
* :func:`add_out_options` / :func:`prepare_out_dir`: ``--out`` and ``--overwrite``; a command
  refuses to write into a non-empty output directory without it, so two runs never mix their
  files.
* :func:`add_html_report_option` / :func:`write_html_report`: ``--report FILE``, one
  self-contained HTML page of the command's document (:mod:`hil.report`, loaded only then).
* :func:`add_recording_options` / :func:`read_recording`: ``--format``, ``--columns``,
  ``--torque``, ``--loop-delay`` for every command that reads a recording (identify --from and
  --validate, diagnose, replay), turned into :func:`drivers.recording.read_signals` arguments
  (docs/recordings.md).
* :func:`say` / :func:`error`: progress and error lines on stderr, ``hil <command>: ...``.
* :func:`run_command`, :func:`exit_status`, :func:`run_exit` and the ``EXIT_*`` codes: an error
  that ends a command is one line, ``hil <command>: error: ...``, and its exit status says
  what kind of failure it was (:mod:`hil.cli`'s docstring has the table).
* :func:`simulate_offline`: ``virtual-robot simulate`` as its own process (the host never
  imports the plant).

Bad values raise ``ValueError`` / :class:`~drivers.recording.RecordingError` with a one-line
message; :func:`run_command` turns them into ``hil <command>: error: ...`` and exit status 2.
Imports drivers and profiles; :mod:`hil.bench` and :mod:`hil.model` only inside
:func:`exit_status` (their error classes), :mod:`hil.report` only inside
:func:`write_html_report`, so any command module may import this one.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from drivers.outdir import new_run_dir, release_out_dirs, take_out_dir
from drivers.realtime_times import ROBOT_EVENTS, on_real_times, run_trace
from drivers.recording import (
    SIGNALS,
    Recording,
    RecordingError,
    dumps_strict,
    parse_column_map,
    read_signals,
)
from profiles.recording_format import LOOP_DELAY_MAX

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_LINK, EXIT_INTERRUPTED = 0, 1, 2, 3, 130

TORQUE_SOURCES_HELP = "commanded (default), measured, or another source the --format offers"


# ---- progress, errors, exit status ------------------------------------------------------------
def say(command: str, message: str) -> None:
    """One progress or status line on stderr: ``hil <command>: <message>``."""
    print(f"hil {command}: {message}", file=sys.stderr, flush=True)


# Seconds between two progress lines of a long stage (a short run prints none).
PROGRESS_EVERY_S = 5.0


class StageProgress:
    """Progress of a long command's stages on stderr, throttled: ``hil <command>: <stage>:
    <done> of <total> rows (<pct> %)`` at most once every ``every_s`` seconds (the first after
    ``every_s``: a command that is done sooner prints none), never on stdout (``--json`` stays
    one document). Call it with (stage, done, total) as often as convenient (every chunk);
    ``enabled`` false (``--quiet``) silences it."""

    def __init__(
        self,
        command: str,
        *,
        every_s: float = PROGRESS_EVERY_S,
        enabled: bool = True,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not every_s >= 0:
            raise ValueError(f"progress interval must be >= 0 s, got {every_s}")
        self.command, self.every_s, self.enabled, self.clock = command, every_s, enabled, clock
        self.last = clock()

    def __call__(self, stage: str, done: int, total: int, unit: str = "rows") -> None:
        if not self.enabled:
            return
        now = self.clock()
        if now - self.last < self.every_s:
            return
        self.last = now
        pct = 100.0 * done / total if total > 0 else 100.0
        say(self.command, f"{stage}: {done:,} of {total:,} {unit} ({pct:.0f} %)")


def error(command: str, message: str) -> None:
    """The one-line error of a command: ``hil <command>: error: <message>``."""
    say(command, f"error: {message}")


def exit_status(exc: BaseException) -> int:
    """The exit status of an error that ended a command (the table in :mod:`hil.cli`)."""
    import can

    from drivers.arm import LinkError
    from hil.bench.jobs import ExecutorUnavailableError
    from hil.bench.launch import LaunchError
    from hil.model.params import ParamsError
    from profiles import ProfileError

    if isinstance(exc, LinkError | LaunchError | ConnectionError | TimeoutError | can.CanError):
        return EXIT_LINK
    if isinstance(
        exc,
        ProfileError | ParamsError | RecordingError | ValueError | FileNotFoundError,
    ):
        return EXIT_USAGE
    if isinstance(exc, IsADirectoryError | NotADirectoryError | PermissionError):
        return EXIT_USAGE
    if isinstance(exc, ExecutorUnavailableError):  # the extra is missing, no scheduler answered
        return EXIT_USAGE
    return EXIT_FAILED


def run_command(command: str, main: Callable[[argparse.Namespace], int], args: Any) -> int:
    """``main(args)``, its errors as one line and an exit status: a bad input, a link or an
    interruption never ends in a traceback. The output directories the command took are
    released as it ends (:func:`drivers.outdir.release_out_dirs`: a start that failed before
    any recording leaves nothing behind)."""
    status = EXIT_FAILED
    try:
        status = _run_main(command, main, args)
        return status
    finally:
        release_out_dirs(status)


def _run_main(command: str, main: Callable[[argparse.Namespace], int], args: Any) -> int:
    import can

    from drivers.arm import LinkError
    from drivers.process import STDOUT_CLOSED, stdout_closed
    from hil.bench.launch import LaunchError
    from hil.model.params import ParamsError
    from profiles import ProfileError

    if stdout_closed():
        error(command, STDOUT_CLOSED)
        return EXIT_USAGE
    try:
        return int(main(args))
    except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM or SIGHUP (drivers.process)
        from drivers.process import interrupt_exit_code, stopped_line

        line = stopped_line()
        say(
            command,
            f"{exc}; {line.split('; ', 1)[-1]}" if isinstance(exc, RunInterrupted) else line,
        )
        return interrupt_exit_code()
    except BrokenPipeError:  # stdout's reader left (`| head`): nothing is lost, nothing to say
        from drivers.process import reader_gone

        return reader_gone()
    except (
        ProfileError,
        ParamsError,
        RecordingError,
        LaunchError,
        LinkError,
        can.CanError,
        OSError,
        ValueError,
        RuntimeError,
    ) as exc:
        error(command, str(exc))
        return exit_status(exc)


class RunInterrupted(KeyboardInterrupt):
    """A run a command made ended interrupted (its loop caught the signal and kept the rows):
    the command ends as the signal ends any command (:func:`run_command`), its line this
    message."""


def require_complete(what: str, run: dict[str, Any]) -> None:
    """Go on only after a complete run (a :func:`hil.bench.run.run_experiment` summary): an
    interrupted one ends the command as its signal would (:class:`RunInterrupted`, exit
    128 + N), a failed one with RuntimeError (exit 1); both say where its rows are kept."""
    status = run["status"]
    if status == "complete":
        return
    message = f"{what} {status}: {run['reason']} ({run['rows']} rows kept in {run['signals']})"
    if status == "interrupted":
        raise RunInterrupted(message)
    raise RuntimeError(message)


def run_exit(command: str, status: str, problem: str) -> int:
    """The exit status of a command whose run ended with ``status`` (a recording's, a
    comparison's): 0 when complete; otherwise ``problem`` as ``hil <command>: <problem>`` and 130
    when interrupted, 1 when it failed."""
    if status == "complete":
        return EXIT_OK
    say(command, problem)
    return EXIT_INTERRUPTED if status == "interrupted" else EXIT_FAILED


# ---- options of the commands that drive a bench, and their output -----------------------------
def add_bench_option(
    p: argparse.ArgumentParser | argparse._MutuallyExclusiveGroup,
    *,
    default: str | None = "virtual-slcan",
    help: str = "bench profile name or TOML file",
) -> None:
    """``--bench`` (profiles/benches, or a TOML file)."""
    p.add_argument("--bench", default=default, help=help)


def add_drive_options(p: argparse.ArgumentParser, *, mode: bool = True) -> None:
    """``--mode`` (unless ``mode`` is false: a command that is realtime by nature),
    ``--effects``, ``--seed``, ``--confirm-real``."""
    if mode:
        p.add_argument(
            "--mode",
            choices=("lockstep", "realtime"),
            default=None,
            help="time mode (default: the bench's)",
        )
    p.add_argument("--effects", default=None, help="virtual bench: concealed effects profile")
    p.add_argument("--seed", type=int, default=None, help="virtual bench: seed (recorded)")
    p.add_argument(
        "--confirm-real",
        action="store_true",
        help="required to drive a real arm (a bench with virtual = false)",
    )


def drive_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """The keyword arguments :func:`add_drive_options` and ``--no-plot`` ask for, as
    :func:`hil.bench.run.run_experiment`, :func:`hil.control.tracking.run_control` and
    :func:`hil.timing.jitter_cli.measure` take them (``mode`` only where the parser has it)."""
    kwargs: dict[str, Any] = {"mode": args.mode} if hasattr(args, "mode") else {}
    return {
        **kwargs,
        "effects": args.effects,
        "seed": args.seed,
        "confirm_real": args.confirm_real,
        "plot": not args.no_plot,
    }


def add_report_options(
    p: argparse.ArgumentParser,
    *,
    plot: str | None = "skip the plots",
    plot_flag: str = "--no-plot",
    json_help: str = "print one JSON document on stdout",
) -> None:
    """``--no-plot`` (help ``plot``; none if None) and ``--json``."""
    if plot is not None:
        p.add_argument(plot_flag, dest="no_plot", action="store_true", help=plot)
    p.add_argument("--json", action="store_true", help=json_help)


def print_document(
    args: argparse.Namespace, doc: dict[str, Any], text: str | Callable[[], str]
) -> None:
    """With ``--json`` ``doc`` as one line of strict JSON on stdout (numpy scalars as numbers,
    NaN and Infinity as null with a reason: :func:`drivers.recording.dumps_strict`), else
    ``text`` (or what it returns)."""
    if getattr(args, "json", False):
        print(dumps_strict(doc))
    else:
        print(text() if callable(text) else text)


def _report_file(text: str) -> str:
    """``--report``'s value: a file to (over)write, refused at once if it is a directory."""
    if Path(text).is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a directory; give the HTML file's name")
    return text


def add_html_report_option(p: argparse.ArgumentParser) -> None:
    """``--report FILE``: one self-contained HTML report of the command's document."""
    p.add_argument(
        "--report",
        metavar="FILE",
        type=_report_file,
        help="also write one self-contained HTML report (tables, results in words, interactive "
        "plots; opens offline in any browser; docs/reports.md)",
    )


def write_html_report(
    args: argparse.Namespace,
    command: str,
    doc: dict[str, Any],
    text: str | Callable[[], str],
    *,
    recordings: Sequence[Recording] | None = None,
    paths: Sequence[str | Path | None] = (),
    name: str | None = None,
) -> None:
    """With ``--report FILE``, write :func:`hil.report.write_report` of ``doc`` (``text``: what
    the command prints) to FILE and say so; the recordings plotted are ``recordings``, or else
    ``paths`` read again with the command's recording options. :mod:`hil.report` is loaded only
    here, so a command without ``--report`` never imports it."""
    if not getattr(args, "report", None):
        return
    from hil.report.documents import write_report

    if recordings is None:
        recordings = [read_signals(p, **recording_kwargs(args)) for p in paths if p is not None]
    path = write_report(
        args.report,
        name or command,
        doc,
        text=text() if callable(text) else text,
        recordings=recordings,
    )
    say(command, f"report: {path}")


def add_schemes_option(p: argparse.ArgumentParser, schemes: Sequence[str], help: str) -> None:
    """``--schemes``, a comma list (default: all of ``schemes``); :func:`split_list` reads it."""
    p.add_argument("--schemes", default=",".join(schemes), help=help)


def split_list(text: str) -> list[str]:
    """A comma-separated option's items, stripped, empty ones left out."""
    return [item.strip() for item in text.split(",") if item.strip()]


def simulate_offline(
    robot: str, experiment: str, duration_s: float, out_dir: Path, *, plot: bool = True
) -> dict[str, Any]:
    """``virtual-robot simulate`` as its own process (docs/design.md: the host never imports the
    plant): the experiment's open-loop response in lockstep, recorded in ``out_dir``; its JSON
    summary. A failed simulation raises RuntimeError with the simulator's last line."""
    cmd = [sys.executable, "-m", "virtual_robot.cli", "simulate", "--robot", robot,
           "--experiment", experiment, "--duration", repr(float(duration_s)),
           "--out", str(out_dir), *([] if plot else ["--no-plot"]), "--json"]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        lines = proc.stderr.strip().splitlines()
        raise RuntimeError(f"virtual-robot simulate failed: {lines[-1] if lines else 'no message'}")
    return json.loads(proc.stdout)


# ---- reading recordings -----------------------------------------------------------------------


def add_recording_options(p: argparse.ArgumentParser) -> None:
    """``--format``, ``--columns``, ``--torque``, ``--loop-delay`` (docs/recordings.md)."""
    g = p.add_argument_group("reading recordings (docs/recordings.md)")
    g.add_argument(
        "--format",
        dest="recording_format",
        default=None,
        metavar="NAME|FILE",
        help="recording-format profile of foreign files (profiles/formats: dfki, kuka-lwr4, "
        "ros2-joint-state, or a TOML file); default: this bench's t,q1,q2,tau1,tau2 (an .mcap: "
        "ros2-joint-state)",
    )
    g.add_argument(
        "--columns",
        default=None,
        metavar="MAP",
        help="column map over the format's, e.g. t=time,q1=pos_meas1,q2=pos_meas2,"
        "tau1=tau_con1,tau2=tau_con2",
    )
    g.add_argument("--torque", default=None, metavar="SOURCE", help=TORQUE_SOURCES_HELP)
    g.add_argument(
        "--loop-delay",
        type=int,
        default=None,
        metavar="ROWS",
        help="the file's tau of row i acts between the q of rows i+d and i+d+1 (default: the "
        "format's; 0 for this bench's recordings)",
    )
    g.add_argument(
        "--effort-scale",
        default=None,
        metavar="F[,F...]",
        help="N·m per unit of the file's torque (gear ratio × motor torque constant), one "
        "factor or one per joint of the file; over the format's conversion",
    )
    g.add_argument(
        "--leave-out-joints",
        default=None,
        metavar="J[,J...]",
        help="the file's joints (1, 2, ...) not to read, e.g. one whose effort is mostly zero",
    )
    g.add_argument(
        "--ignore-columns",
        default=None,
        metavar="C[,C...]",
        help="columns (or an array's name for all of its columns) not to read, e.g. text",
    )


def recording_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """The :func:`read_signals` keyword arguments the options ask for, checked."""
    columns = getattr(args, "columns", None)
    if columns is not None:
        try:
            parse_column_map(columns)
        except ValueError as exc:
            raise ValueError(f"--columns: {exc}") from None
    delay = getattr(args, "loop_delay", None)
    if delay is not None and abs(delay) > LOOP_DELAY_MAX:
        raise ValueError(
            f"--loop-delay must be in [-{LOOP_DELAY_MAX}, {LOOP_DELAY_MAX}] rows, got {delay}"
        )
    torque = getattr(args, "torque", None)
    if torque is not None and not torque.strip():
        raise ValueError("--torque names no torque source")
    return {
        "fmt": getattr(args, "recording_format", None),
        "columns": columns,
        "torque": torque,
        "loop_delay": delay,
        "effort_scale": _number_list(args, "effort_scale", float),
        "leave_out": _number_list(args, "leave_out_joints", int),
        "ignore": split_list(getattr(args, "ignore_columns", None) or "") or None,
    }


def _number_list(args: argparse.Namespace, key: str, kind: type) -> list[Any] | None:
    """``--effort-scale 1.5,2`` / ``--leave-out-joints 7``: the numbers, or a one-line error."""
    text = getattr(args, key, None)
    if text is None:
        return None
    option = "--" + key.replace("_", "-")
    items = split_list(text)
    try:
        values = [kind(item) for item in items]
    except ValueError:
        raise ValueError(f"{option}: {text!r} is not a list of {kind.__name__}s") from None
    if not values:
        raise ValueError(f"{option}: names nothing")
    if kind is float and not all(math.isfinite(v) and v != 0 for v in values):
        raise ValueError(f"{option}: factors must be finite and nonzero, got {text!r}")
    if kind is int and any(v < 1 for v in values):
        raise ValueError(f"{option}: joints are numbered from 1, got {text!r}")
    return values


LARGE_RECORDING_BYTES = 50_000_000  # from here on, reading says what it does (~10 s per 100 MB)


def read_recording(
    args: argparse.Namespace,
    path: str | Path,
    *,
    command: str,
    min_rows: int = 2,
    extra_columns: bool = False,
    allow_gaps: bool = False,
    need_motion: bool = True,
    joints: int | None = None,
) -> Recording:
    """Read ``path`` with the recording options of ``args``; print what the reader noticed
    (gaps, irregular sampling, dropped duplicates, the loop delay) on stderr. Refuse a
    recording with gaps unless ``allow_gaps`` (the command analyses ``rec.segments()``
    separately), one where the arm never moves if ``need_motion``, and one with another number
    of joints than ``joints`` (when given)."""
    csv_path = Path(path) / SIGNALS if Path(path).is_dir() else Path(path)
    size = csv_path.stat().st_size if csv_path.is_file() else 0
    large = size >= LARGE_RECORDING_BYTES  # say what takes the time (seconds per 100 MB)
    if large:
        say(command, f"reading {csv_path} ({size / 1e6:.0f} MB) ...")
        started = time.perf_counter()
    progress = StageProgress(
        command,
        every_s=getattr(args, "progress_every", PROGRESS_EVERY_S),
        enabled=not getattr(args, "quiet", False),
    )
    rec = read_signals(
        path,
        **recording_kwargs(args),
        extra_columns=extra_columns,
        min_rows=min_rows,
        progress=progress,
    )
    if large:
        say(
            command,
            f"read {len(rec)} rows of {csv_path.name} in {time.perf_counter() - started:.0f} s",
        )
    rec = _on_real_times(args, path, rec, min_rows)
    for note in rec.findings_on_read:
        say(command, f"note: {rec.path}: {note}")
    if joints is not None and rec.n_joints != joints:
        raise RecordingError(
            f"{rec.path}: {rec.joints_text}; hil {command} takes "
            f"{joints} here (an n-joint arm described by a URDF: docs/urdf.md)"
        )
    if not allow_gaps and len(rec.segments()) > 1:
        gap = next((f for f in rec.findings_on_read if "gap(s) in t" in f), "gaps in t")
        raise RecordingError(
            f"{rec.path}: {gap.split(';')[0]}; hil {command} does not splice segments: give "
            "it each segment as a recording of its own"
        )
    if need_motion and len(rec) and np.all(np.ptp(rec.q, axis=0) == 0):
        raise RecordingError(
            f"{rec.path}: the arm does not move (every q is constant): nothing to {command}"
        )
    return rec


def _on_real_times(
    args: argparse.Namespace, path: str | Path, rec: Recording, min_rows: int
) -> Recording:
    """A realtime run of this bench on its real sample and command times
    (drivers/realtime_times.py): its ``t`` is only the deadline grid. Not when the reader was
    told where t or tau come from (``--format``, ``--columns``, ``--loop-delay``): ``--columns
    t=t`` reads the grid as it is."""
    told = any(recording_kwargs(args)[k] is not None for k in ("fmt", "columns", "loop_delay"))
    if told or rec.meta.get("mode") != "realtime":
        return rec
    full = rec
    if not (Path(path) / ROBOT_EVENTS).is_file():  # the host's stamps: read them too
        full = read_signals(path, **recording_kwargs(args), min_rows=min_rows)
    found = run_trace(full)
    if found is None:
        return rec
    moved = on_real_times(full, *found)
    keep = {"t", *(f"{p}{j + 1}" for p in ("q", "tau") for j in range(rec.n_joints))}
    moved.columns = {k: v for k, v in moved.columns.items() if k in keep or k in rec.columns}
    return moved


# ---- output directory -------------------------------------------------------------------------
def add_progress_option(p: argparse.ArgumentParser) -> None:
    """``--progress-every SECONDS``: the throttle of :class:`StageProgress` on a long
    analysis (reading, rows, fits, candidates), on stderr only."""
    p.add_argument(
        "--progress-every",
        type=float,
        default=PROGRESS_EVERY_S,
        metavar="SECONDS",
        help="seconds between the progress lines of a long recording's stages on stderr "
        f"(default {PROGRESS_EVERY_S:g}; -q: none)",
    )


def add_out_options(
    p: argparse.ArgumentParser, help: str, *, default: str | None = None, required: bool = False
) -> None:
    """``--out`` (a directory) and ``--overwrite``."""
    p.add_argument("--out", default=default, required=required, help=help)
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="empty a non-empty --out directory first (without it, such a --out is refused; "
        "a directory another live run holds is refused either way)",
    )


def prepare_out_dir(
    out: str | Path | None,
    overwrite: bool,
    inputs: Sequence[str | Path | None] = (),
    *,
    default: str | None = None,
    command: str | None = None,
) -> Path:
    """The command's output directory, locked for this run until the command ends
    (:func:`drivers.outdir.take_out_dir`): ``out`` exactly (refused while another live run
    holds it, ``--overwrite`` or not; a non-empty one refused unless ``overwrite``, which empties
    it first; never one that holds one of ``inputs``), or, when ``out`` is None, a new
    directory for this run, ``runs/<default>/<stamp>`` (:func:`drivers.outdir.new_run_dir`;
    ``runs/latest`` points to it once the command ends; ``command``: say where on stderr then). A
    start that fails before any recording began leaves nothing in it
    (:func:`drivers.outdir.release_out_dirs`, called by :func:`run_command`)."""
    if out is None:
        if default is None:
            raise ValueError("--out is required")
        label = command
        return new_run_dir(
            default,
            kept=None if label is None else lambda d: say(label, f"results in {d} (runs/latest)"),
        )
    return take_out_dir(out, overwrite, inputs)


def recorded_urdf_robot(recording: str | Path) -> str | None:
    """The robot a run directory of this bench was recorded with when a URDF describes it (its
    meta.json: `virtual-robot simulate` writes the profile's path, `hil run` the robot's name or
    --robot's file), so that `hil identify --from` and `hil diagnose` take an n-joint run without
    --robot; None for a 2-DOF run, a CSV, or a profile not found here (made elsewhere)."""
    from profiles import ProfileError
    from profiles.robot import describes_urdf_only

    meta = Path(recording) / "meta.json"
    try:
        recorded = json.loads(meta.read_text()) if meta.is_file() else {}
    except (OSError, ValueError):
        return None
    if not isinstance(recorded, dict):
        return None
    for profile in (recorded.get("robot_profile"), recorded.get("robot")):
        if not isinstance(profile, str):
            continue
        try:
            if describes_urdf_only(profile):
                return profile
        except (ProfileError, OSError):
            continue
    return None
