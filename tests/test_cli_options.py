"""The plumbing every `hil` command shares (hil/cli_options.py): one wording per shared option,
one error line, one exit status per kind of failure, --json as one document; and the one
set-up of `hil control` (hil/control/tracking.py: prepare)."""

from __future__ import annotations

import argparse
import json

import can
import numpy as np
import pytest

from drivers.arm import LinkError
from drivers.recording import RecordingError
from hil import cli_options as opts
from hil.bench.jobs import ExecutorUnavailableError
from hil.bench.launch import LaunchError
from hil.bench.run import UsageError
from hil.cli import COMMANDS, _parser
from hil.control.tracking import PROFILE_LABEL, compare_schemes, prepare, run_control
from hil.model.params import ParamsError
from profiles import ProfileError

DRIVE = ("--mode", "--effects", "--seed", "--confirm-real")  # commands that drive a bench


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = _parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def test_every_command_is_wired_and_a_shared_option_says_one_thing() -> None:
    subs = _subparsers()
    assert set(COMMANDS) | {"run", "demo"} == set(subs)
    driving = [n for n, p in subs.items() if "--confirm-real" in p._option_string_actions]
    assert sorted(driving) == ["control", "identify", "jitter", "run"]
    assert "--mode" not in subs["jitter"]._option_string_actions  # realtime by nature
    helps: dict[str, set[str | None]] = {}
    for name, p in subs.items():
        for flag, action in p._option_string_actions.items():
            if flag in ("--json", "--overwrite") or (flag in DRIVE and name in driving):
                helps.setdefault(flag, set()).add(action.help)
    assert set(helps) == {*DRIVE, "--json", "--overwrite"}
    assert {flag: len(texts) for flag, texts in helps.items() if len(texts) > 1} == {
        "--json": 2  # a command's "summary" or "document"
    }


def test_a_command_imports_only_its_own_module() -> None:
    """`hil run` (and `hil --version`) start without importing the other commands' modules;
    `hil -v identify` gets identify's arguments, and only its module (with scipy.signal:
    imported before any run starts, never inside a running loop, where its ~1 s of import
    starved the drives' watchdog)."""
    import subprocess
    import sys

    script = """
import sys
from hil.cli import COMMANDS, _parse
args = _parse(sys.argv[1:])
print(args.command, sorted(m for m, _ in COMMANDS.values() if m in sys.modules),
      "scipy.signal" in sys.modules)
"""

    def loaded(*argv: str) -> str:
        proc = subprocess.run([sys.executable, "-c", script, *argv], capture_output=True,
                              text=True, timeout=120, check=False)  # fmt: skip
        assert proc.returncode == 0, proc.stderr
        return proc.stdout.strip()

    assert loaded("run", "--out", "x", "--no-plot") == "run [] False"
    assert loaded("-v", "identify", "--from", "x", "--no-plot") == (
        "identify ['hil.identify.cli'] True"
    )


def test_drive_kwargs_are_what_run_experiment_takes() -> None:
    args = _parser().parse_args(
        ["run", "--out", "x", "--mode", "lockstep", "--effects", "payload", "--seed", "3",
         "--confirm-real", "--no-plot"]
    )  # fmt: skip
    assert opts.drive_kwargs(args) == {
        "mode": "lockstep",
        "effects": "payload",
        "seed": 3,
        "confirm_real": True,
        "plot": False,
    }
    jitter = _parser().parse_args(["jitter"])
    assert opts.drive_kwargs(jitter) == {
        "effects": None,
        "seed": None,
        "confirm_real": False,
        "plot": True,
    }


@pytest.mark.parametrize(
    ("exc", "status"),
    [
        (ProfileError("bench.toml", "period_s", "must be > 0"), opts.EXIT_USAGE),
        (ParamsError("p"), opts.EXIT_USAGE),
        (RecordingError("r"), opts.EXIT_USAGE),
        (UsageError("u"), opts.EXIT_USAGE),
        (FileNotFoundError("f"), opts.EXIT_USAGE),
        (PermissionError("f"), opts.EXIT_USAGE),
        (np.linalg.LinAlgError("singular"), opts.EXIT_USAGE),
        (ExecutorUnavailableError("no dask"), opts.EXIT_USAGE),
        (LinkError("l"), opts.EXIT_LINK),
        (LaunchError("l"), opts.EXIT_LINK),
        (ConnectionRefusedError("c"), opts.EXIT_LINK),
        (can.CanError("c"), opts.EXIT_LINK),
        (RuntimeError("r"), opts.EXIT_FAILED),
        (OSError("o"), opts.EXIT_FAILED),
    ],
)
def test_an_error_is_one_line_and_its_kind_is_the_exit_status(
    exc: BaseException, status: int, capsys: pytest.CaptureFixture[str]
) -> None:
    def fails(_args: object) -> int:
        raise exc

    assert opts.run_command("diagnose", fails, None) == status
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == f"hil diagnose: error: {exc}\n"


def test_an_unexpected_error_is_not_swallowed() -> None:
    def bug(_args: object) -> int:
        raise KeyError("a bug shows its traceback")

    with pytest.raises(KeyError):
        opts.run_command("run", bug, None)


def test_run_exit(capsys: pytest.CaptureFixture[str]) -> None:
    assert opts.run_exit("run", "complete", "not said") == opts.EXIT_OK
    assert capsys.readouterr().err == ""
    assert opts.run_exit("run", "failed", "failed: why") == opts.EXIT_FAILED
    assert opts.run_exit("jitter", "interrupted", "run interrupted") == opts.EXIT_INTERRUPTED
    assert capsys.readouterr().err == "hil run: failed: why\nhil jitter: run interrupted\n"


def test_print_document_is_one_json_line_or_the_text(capsys: pytest.CaptureFixture[str]) -> None:
    doc = {"theta": np.float64(0.5), "rows": np.int64(3)}
    opts.print_document(argparse.Namespace(json=True), doc, lambda: pytest.fail("no text"))
    out = capsys.readouterr().out
    assert out.count("\n") == 1 and json.loads(out) == {"theta": 0.5, "rows": 3.0}
    opts.print_document(argparse.Namespace(json=False), doc, "the table")
    assert capsys.readouterr().out == "the table\n"


def test_stage_progress_is_throttled_on_stderr(capsys: pytest.CaptureFixture[str]) -> None:
    """At most one line per interval, the first only after one interval (a short run prints
    none), on stderr; disabled (-q) prints nothing; a negative interval is refused."""
    now = [0.0]
    progress = opts.StageProgress("identify", every_s=5.0, clock=lambda: now[0])
    for t, done in ((1.0, 10), (4.9, 20), (5.0, 30), (6.0, 40), (10.5, 50)):
        now[0] = t
        progress("filtered_dynamic: least squares", done, 200)
    out, err = capsys.readouterr()
    assert out == ""
    assert err.splitlines() == [
        "hil identify: filtered_dynamic: least squares: 30 of 200 rows (15 %)",
        "hil identify: filtered_dynamic: least squares: 50 of 200 rows (25 %)",
    ]
    silent = opts.StageProgress("identify", every_s=0.0, enabled=False)
    silent("x", 1, 2)
    assert capsys.readouterr() == ("", "")
    with pytest.raises(ValueError, match=">= 0 s"):
        opts.StageProgress("identify", every_s=-1.0)


def test_split_list() -> None:
    assert opts.split_list(" ct, pd,,rfed ") == ["ct", "pd", "rfed"]
    assert opts.split_list("") == []


def test_simulate_offline_failure_is_one_line(tmp_path) -> None:
    with pytest.raises(RuntimeError, match=r"^virtual-robot simulate failed: .*no-such"):
        opts.simulate_offline("cicese", "no-such", 1.0, tmp_path / "sim", plot=False)
    assert not (tmp_path / "sim" / "signals.csv").exists()


# ---- hil control's one set-up -----------------------------------------------------------------
def test_prepare_checks_schemes_first_then_loads_the_parameter_sets(tmp_path) -> None:
    with pytest.raises(UsageError, match=r"unknown scheme\(s\) \['lqr'\]"):
        prepare("no-such-bench", schemes=("ct", "lqr"))  # before the bench is looked up
    with pytest.raises(UsageError, match="unknown scheme"):
        prepare("virtual-inprocess", schemes=())
    setup = prepare("virtual-inprocess", schemes=("pd", "ct"), duration_s=0.5, seed=4)
    assert setup.schemes == ("pd", "ct")
    assert [p.label for p in setup.parameter_sets] == [PROFILE_LABEL]
    assert setup.describe()["seed"] == 4 and setup.n_periods == round(0.5 / setup.period_s)
    with pytest.raises(UsageError, match="no parameter set"):
        prepare("virtual-inprocess", include_profile=False)


def test_run_control_and_compare_schemes_refuse_before_running(tmp_path) -> None:
    with pytest.raises(UsageError, match="unknown scheme 'lqr'; expected one of"):
        run_control("virtual-inprocess", "lqr", tmp_path / "one")
    with pytest.raises(UsageError, match=r"unknown scheme\(s\) \['lqr'\]"):
        compare_schemes("virtual-inprocess", tmp_path / "cmp", schemes=["ct", "lqr"])
    with pytest.raises(UsageError, match=r"--kp takes 2 finite gains >= 0 \(one per joint\)"):
        compare_schemes("virtual-inprocess", tmp_path / "cmp", kp=[1.0])
    assert not (tmp_path / "one").exists() and not (tmp_path / "cmp").exists()


# ---- comma-separated numbers: one parser for both command lines (drivers/options.py) -------
@pytest.mark.parametrize("text", ["1,x", "1", "1,2,3", "1,", "1,nan", "1,inf", "1,-2", "1,0", ""])
def test_float_list_refuses_in_one_line(text: str) -> None:
    from drivers.options import float_list

    with pytest.raises(ValueError) as exc:
        float_list(text, "--opt", 2, "positive numbers", lambda v: v > 0)
    assert str(exc.value) == f"--opt takes 2 positive numbers, comma-separated, got {text!r}"


def test_float_list_reads_the_numbers() -> None:
    from drivers.options import float_list

    assert float_list(" 0.5, -1e-3 ,2", "--q", 3, "angles", lambda v: True) == (0.5, -1e-3, 2.0)


def test_initial_q_and_position_limit_are_read_by_the_one_parser(capsys) -> None:
    """`virtual-robot serve --initial-q` and `hil excite --position-limit` refuse bad lists in
    the one parser's words (drivers.options.float_list; the virtual robot may not import hil)."""
    from hil import cli
    from virtual_robot.cli import main as vr_main

    assert vr_main(["serve", "--bench", "virtual-slcan", "--initial-q", "0,x"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith(
        "--initial-q takes 2 angles in [-2 pi, 2 pi] rad (one per joint), comma-separated, "
        "got '0,x'"
    ), err
    assert cli.main(["excite", "--position-limit", "1,x"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        "hil excite: error: --position-limit takes 2 positive numbers Q1,Q2 in rad, "
        "comma-separated, got '1,x'"
    ), err


def test_the_exit_status_table_of_docs_faults_md_is_the_codes():
    """docs/faults.md's "Exit status" table lists exactly the statuses the commands return
    (hil.cli_options.EXIT_*, 128 + N for a signal, 128 + SIGPIPE for a reader gone), with the
    numbers of the three exit signals (drivers.process.EXIT_SIGNALS)."""
    import re
    import signal
    from pathlib import Path

    from drivers.process import EXIT_SIGNALS

    text = (Path(__file__).resolve().parent.parent / "docs" / "faults.md").read_text()
    section = text.split("## Exit status", 1)[1].split("\n## ", 1)[0]
    rows = dict(re.findall(r"^\| (\d+|128 \+ N) \| (.+) \|$", section, re.M))
    codes = {opts.EXIT_OK, opts.EXIT_FAILED, opts.EXIT_USAGE, opts.EXIT_LINK}
    assert set(rows) == {str(c) for c in codes} | {"128 + N", str(128 + signal.SIGPIPE)}
    for name in EXIT_SIGNALS:
        assert (
            f"{128 + signal.Signals[name]} {'Ctrl-C (SIGINT)' if name == 'SIGINT' else name}"
            in (rows["128 + N"])
        ), name
    assert opts.EXIT_INTERRUPTED == 128 + signal.SIGINT
