"""The command lines' shared behaviour: --version, python -m hil, -v/-q and the log rate limit,
one error format, exit codes, and `hil run --attach` to a running `virtual-robot serve`."""

from __future__ import annotations

import json
import logging
import os
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from drivers.logsetup import BURST, WINDOW_S, RateLimit, configure
from hil import __version__

ROOT = Path(__file__).resolve().parents[1]


def _run(*argv: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, *argv], cwd=ROOT, capture_output=True, text=True, timeout=timeout
    )


def test_version_on_both_command_lines() -> None:
    hil = _run("-m", "hil", "--version")
    assert hil.returncode == 0 and hil.stdout.strip() == f"hil {__version__}"
    robot = _run("-m", "virtual_robot.cli", "--version")
    assert robot.returncode == 0 and robot.stdout.strip().startswith("virtual-robot ")


@pytest.mark.parametrize(
    ("argv", "prog"),
    [
        (("-m", "hil", "run", "--out", "x", "--bogus"), "hil run"),
        (("-m", "virtual_robot.cli", "serve", "--bogus"), "virtual-robot serve"),
    ],
)
def test_a_misspelled_option_is_reported_by_its_subcommand(argv, prog) -> None:
    proc = _run(*argv)
    assert proc.returncode == 2
    assert proc.stderr.startswith(f"usage: {prog} ")
    assert proc.stderr.splitlines()[-1] == f"{prog}: error: unrecognized arguments: --bogus"


def test_bad_input_is_one_line_exit_2() -> None:
    proc = _run("-m", "hil", "run", "--bench", "no-such", "--out", "x")
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.splitlines() == [
        line for line in proc.stderr.splitlines() if line.startswith("hil run: error: ")
    ]
    assert "no bench profile of that name" in proc.stderr


def _dead_port() -> int:
    with socket.socket() as s:  # bound, never listening: connections are refused
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_dead_socketcand_port_gives_a_handful_of_lines_and_exit_3(tmp_path: Path) -> None:
    """A refused port is reported after drivers.links.SOCKETCAND_CONNECT_S, in one line, with
    the link failure's exit status; python-can's own connect loop (10 s without pause, about
    700,000 logged refusals, one core busy) never runs: even with -v none of its lines."""
    port = _dead_port()
    argv = ["-m", "hil", "-v", "run", "--bench", "virtual-socketcand", "--out", str(tmp_path)]
    argv += ["--overwrite"]  # the second run writes to the same directory
    proc = _run(*argv, "--attach", f"127.0.0.1:{port}", "--duration", "0.1")
    lines = proc.stderr.splitlines()
    assert proc.returncode == 3, proc.stderr
    assert 1 <= len(lines) <= 8, proc.stderr[:2000]
    assert lines[-1].startswith("hil run: error: cannot open the CAN bus: socketcand at ")
    assert f"127.0.0.1:{port} refused the connection" in lines[-1]
    assert "Failed to connect to server" not in proc.stderr
    quiet = _run(*argv[:2], *argv[3:], "--attach", f"127.0.0.1:{port}", "--duration", "0.1")
    assert quiet.returncode == 3 and len(quiet.stderr.splitlines()) == 1, quiet.stderr


def test_a_flood_from_a_library_is_a_handful_of_lines_at_v(capsys) -> None:
    """The command lines' handler (configure) at -v: 10,000 identical python-can warnings (as
    its socketcand connect loop logged them) pass BURST times, the last saying so."""
    configure("hil", 1)
    try:
        log = logging.getLogger("can.interfaces.socketcand")
        for _ in range(10_000):
            log.warning("Failed to connect to server: <class 'ConnectionRefusedError'>")
        lines = capsys.readouterr().err.splitlines()
    finally:
        configure("hil", 0)  # the default levels back, then no handler, as the other tests
        for h in list(logging.getLogger().handlers):
            if getattr(h, "ddbench", False):
                logging.getLogger().removeHandler(h)
        logging.getLogger().setLevel(logging.WARNING)
    assert len(lines) == BURST, lines
    assert lines[0].startswith("hil: can.interfaces.socketcand: warning: Failed to connect")
    assert lines[-1].endswith(f"(repeats shown once per {WINDOW_S:g} s from here)")


def test_rate_limit_passes_a_burst_then_one_per_window() -> None:
    limit = RateLimit(burst=3, window_s=3600)
    record = logging.LogRecord("can", logging.WARNING, __file__, 1, "Failed", None, None)
    records = [logging.makeLogRecord(record.__dict__) for _ in range(10_000)]
    passed = [limit.filter(r) for r in records]
    assert sum(passed) == 3 and passed[:3] == [True] * 3
    assert records[2].getMessage() == "Failed (repeats shown once per 3600 s from here)"
    other = logging.LogRecord("can", logging.WARNING, __file__, 1, "other", None, None)
    assert limit.filter(other)
    limit.window_s = 0.0  # the window has passed: the next one goes out with the count
    late = logging.makeLogRecord(record.__dict__)
    assert limit.filter(late) and "9997 similar messages suppressed" in late.getMessage()


def test_a_log_message_is_one_line_unless_debugging() -> None:
    """python-can's socketcand formats the traceback into its "Failed to receive" error: the
    line keeps the error and drops the traceback (all of it at -vv)."""
    handler = configure("hil", 0)
    try:
        text = "Failed to receive: [Errno 104] Connection reset by peer  Traceback (most recent "
        text += 'call last):\n  File "socketcand.py", line 1, in _recv_internal\nOSError: reset'
        record = logging.LogRecord(
            "can.interfaces.socketcand", logging.ERROR, "", 1, text, (), None
        )
        assert handler.format(record) == (
            "hil: can.interfaces.socketcand: error: Failed to receive: [Errno 104] Connection "
            "reset by peer"
        )
        logging.getLogger().setLevel(logging.DEBUG)  # debugging: the whole message
        assert "OSError: reset" in handler.format(record) and "Traceback" in handler.format(record)
    finally:
        for h in list(logging.getLogger().handlers):
            if getattr(h, "ddbench", False):
                logging.getLogger().removeHandler(h)
        logging.getLogger().setLevel(logging.WARNING)


def test_third_party_loggers_are_quiet_by_default() -> None:
    handler = configure("test", 0)
    try:
        assert not logging.getLogger("can.interfaces.socketcand").isEnabledFor(logging.WARNING)
        assert logging.getLogger("hil.bench.run").isEnabledFor(logging.WARNING)
        # an SDO abort is raised to the command, which says it in its own line: the client's
        # log of it only from -v on
        assert not logging.getLogger("canopen.sdo.client").isEnabledFor(logging.ERROR)
        assert logging.getLogger("canopen.nmt").isEnabledFor(logging.ERROR)
        configure("test", 1)
        assert logging.getLogger("canopen").isEnabledFor(logging.WARNING)
        assert logging.getLogger("canopen.sdo.client").isEnabledFor(logging.ERROR)
        configure("test", -1)
        assert not logging.getLogger("hil").isEnabledFor(logging.WARNING)
    finally:
        for h in list(logging.getLogger().handlers):
            if getattr(h, "ddbench", False):
                logging.getLogger().removeHandler(h)
        del handler


def test_hil_run_attaches_to_a_running_robot(tmp_path: Path) -> None:
    """`virtual-robot serve` started by hand; `hil run --attach` records over it without
    --confirm-real, and the robot serves on afterwards (a second run attaches again)."""
    robot = subprocess.Popen(
        [sys.executable, "-m", "virtual_robot.cli", "serve", "--bench", "virtual-socketcand"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        info = json.loads(robot.stdout.readline())
        for n in (1, 2):
            out = tmp_path / f"run{n}"
            proc = _run(
                "-m",
                "hil",
                "run",
                "--bench",
                "virtual-socketcand",
                "--attach",
                info["channel"],
                "--duration",
                "0.5",
                "--no-plot",
                "--json",
                "--out",
                str(out),
            )
            assert proc.returncode == 0, proc.stderr
            summary = json.loads(proc.stdout)
            assert summary["status"] == "complete" and summary["rows"] == 200
            meta = json.loads((out / "meta.json").read_text())
            assert meta["channel"]["attached"] is True
            assert "attach = true" in (out / "bench-attached.toml").read_text()
        assert robot.poll() is None  # still serving
    finally:
        robot.terminate()
        robot.wait(10)


def test_one_blas_thread_where_a_command_starts_not_on_import() -> None:
    """`import hil` changes no environment; a command (any way in: here `hil.cli.main`, which
    `python -m hil.cli` runs) limits the loaded BLAS to one thread and sets the variable its
    child processes inherit."""
    code = textwrap.dedent(
        """
        import json, os
        import numpy
        import hil, hil.bench, hil.identify
        before = os.environ.get("OPENBLAS_NUM_THREADS")
        from hil.cli import main
        main(["diagnose", "/nonexistent/recording.csv"])
        from threadpoolctl import threadpool_info
        blas = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
        print(json.dumps([before, os.environ.get("OPENBLAS_NUM_THREADS"), blas]))
        """
    )
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120
    )
    before, after, blas = json.loads(proc.stdout.strip().splitlines()[-1])
    assert before is None and after == "1"
    assert blas and all(n == 1 for n in blas)


DFKI_FILE = (
    Path(__file__).parent / "data" / "dfki" / "design_A.0__20220815__sys_id__trajectory_00.csv"
)


@pytest.mark.parametrize(
    "argv",
    [
        ["hil.cli", "identify", "--from", str(DFKI_FILE), "--format", "dfki", "--robot", "dfki-a0"],
        ["virtual_robot.cli", "simulate", "--duration", "0.2"],
    ],
    ids=["hil", "virtual-robot"],
)
def test_a_reader_that_leaves_the_pipe_ends_the_command_quietly(argv, tmp_path: Path) -> None:
    """`hil ... --json | head -c 100`: the reader closes the pipe before the document is written;
    no "error: [Errno 32] Broken pipe", no traceback, the shell's status for SIGPIPE (141)."""
    argv = [*argv, "--out", str(tmp_path / "run")]  # never the default runs/ of the tree
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone before the child writes anything
    try:
        proc = subprocess.run(
            [sys.executable, "-m", *argv, "--json"],
            stdout=write_end,
            stderr=subprocess.PIPE,
            text=True,
            timeout=300,
            check=False,
        )
    finally:
        os.close(write_end)
    assert proc.returncode == 141, proc.stderr
    assert "Broken pipe" not in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
