"""Output directories and exits (issues 30 and 31), each reproduced: an output directory
belongs to one run at a time, a start that fails leaves nothing behind, runs without --out
never collide, every command ends on a signal with the same exit status and clean-up, and a
result is never lost without a word.

Realtime runs here use a 2 s feedback budget (a loaded machine must not end them early); every
wait polls for the state it needs, with generous timeouts.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cli_run import ROOT, finish_all, wait_rows

from drivers import process
from drivers.outdir import OutDirBusyError, release_out_dirs, take_out_dir
from drivers.process import run_status
from hil.cli_options import run_command
from profiles import resolve

ENTRY = [sys.executable, "-m", "hil.entry"]
ROBOT = [sys.executable, "-m", "virtual_robot.cli"]


def _patient(tmp_path: Path, base: str) -> str:
    """``base`` with a 2 s feedback budget (tests of signals and locks, not of the link)."""
    text = resolve("benches", base).read_text()
    assert "feedback_budget_s = 0.25" in text
    path = tmp_path / f"{base}-patient.toml"
    path.write_text(text.replace("feedback_budget_s = 0.25", "feedback_budget_s = 2.0", 1))
    return str(path)


def _start(argv: list[str], cwd: Path = ROOT) -> subprocess.Popen:
    return subprocess.Popen(
        argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=cwd
    )


def _run(argv: list[str], cwd: Path = ROOT, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        argv, capture_output=True, text=True, cwd=cwd, timeout=timeout, check=False
    )


def _meta(out: Path) -> dict:
    return json.loads((out / "meta.json").read_text())


def _own_lines(err: str, prog: str = "hil") -> list[str]:
    """The lines the command said of its own (not progress percentages)."""
    return [ln for ln in err.splitlines() if ln.startswith(prog) and "%" not in ln]


def _poll(predicate, proc: subprocess.Popen, timeout: float = 60.0, what: str = "") -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        if proc.poll() is not None:
            _, err = proc.communicate()
            raise AssertionError(f"ended early ({proc.returncode}) waiting for {what}: {err}")
        time.sleep(0.02)
    raise AssertionError(f"timed out waiting for {what}")


def _handlers_installed(pid: int) -> bool:
    """Process ``pid`` catches SIGHUP (its exit signals are installed)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    caught = next(ln for ln in status.splitlines() if ln.startswith("SigCgt:")).split()[1]
    return bool(int(caught, 16) & (1 << (signal.SIGHUP - 1)))


def _stop(proc: subprocess.Popen, sig: int = signal.SIGINT, timeout: float = 60) -> str:
    try:
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=timeout)
    finally:
        proc.kill()
    return err


# ---- one run at a time -----------------------------------------------------------------------
def test_overwrite_cannot_take_a_live_runs_directory(tmp_path: Path) -> None:
    """Issue 31: a realtime run to D, and while it runs a second `hil run --out D --overwrite`:
    the second is refused in one line naming the first's pid (exit 2); the first's files stay."""
    out = tmp_path / "D"
    bench = _patient(tmp_path, "virtual-slcan")
    first = _start([*ENTRY, "run", "--bench", bench, "--mode", "realtime", "--duration", "60",
                    "--out", str(out), "--overwrite", "--no-plot"])  # fmt: skip
    try:
        wait_rows(out, 100, first, timeout=120)
        second = _run([*ENTRY, "run", "--bench", "virtual-serial", "--duration", "2",
                       "--out", str(out), "--overwrite", "--no-plot"])  # fmt: skip
        assert second.returncode == 2, second.stderr
        lines = _own_lines(second.stderr)
        assert len(lines) == 1, second.stderr
        assert f"in use by another run (pid {first.pid})" in lines[0], lines[0]
        assert "recorded" not in second.stdout
        assert first.poll() is None  # the first run goes on
    finally:
        err = _stop(first)
    assert first.returncode == 130, err
    meta = _meta(out)
    assert meta["status"] == "interrupted" and meta["bench"] != "virtual-serial"
    assert (out / "bus.log").is_file() and not (out / "serial.log").exists()
    rows = (out / "signals.csv").read_text().count("\n") - 1
    assert rows == meta["rows"] >= 100


def test_two_runs_started_together_do_not_share_a_directory(tmp_path: Path) -> None:
    """Issue 31: two `hil run --out D` started at the same instant: one records, the other is
    refused (exit 2) and D holds the one run, whole."""
    out = tmp_path / "D"
    argv = [*ENTRY, "run", "--bench", "virtual-inprocess", "--duration", "20", "--out",
            str(out), "--no-plot"]  # fmt: skip
    procs = [_start(argv), _start(argv)]
    results = [(*r, p.pid) for r, p in zip(finish_all(procs, timeout=300), procs, strict=True)]
    codes = sorted(r[0] for r in results)
    assert codes == [0, 2], results
    (_, winner_out, _, winner), (_, _, loser_err, _) = sorted(results, key=lambda r: r[0])
    lines = _own_lines(loser_err)
    assert len(lines) == 1, loser_err
    assert f"in use by another run (pid {winner})" in lines[0] or "not empty" in lines[0]
    meta = _meta(out)
    assert meta["status"] == "complete" and meta["process"]["pid"] == winner
    assert (out / "signals.csv").read_text().count("\n") - 1 == meta["rows"] == 8000
    assert str(out / "signals.csv") in winner_out


def test_lock_is_the_kernels_so_a_killed_owner_frees_it(tmp_path: Path) -> None:
    """The lock dies with its owner, SIGKILL included; while it lives nobody else takes the
    directory, even through --overwrite; a directory this process holds is taken again as is."""
    out = tmp_path / "D"
    code = (
        "import sys, time\n"
        "from drivers.outdir import take_out_dir\n"
        f"take_out_dir({str(out)!r}, False)\n"
        "print('taken', flush=True)\n"
        "time.sleep(600)\n"
    )
    owner = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, cwd=ROOT
    )
    try:
        assert owner.stdout.readline().strip() == "taken"
        with pytest.raises(OutDirBusyError, match=f"in use by another run \\(pid {owner.pid}\\)"):
            take_out_dir(out, True)
    finally:
        owner.kill()
        owner.wait(30)
    assert take_out_dir(out, False) == out  # the owner was killed: free
    assert take_out_dir(out, False) == out  # held by this process already
    (out / "meta.json").write_text("{}")
    release_out_dirs(130)  # interrupted after the recording began: kept
    assert (out / "meta.json").is_file()


def test_a_refused_start_leaves_nothing_behind(tmp_path: Path) -> None:
    """Issue 31: a start refused for a bad profile (an unknown --effects name) writes nothing
    into --out, so the corrected rerun is not refused as "not empty"."""
    out = tmp_path / "D"
    bad = _run([*ENTRY, "run", "--bench", "virtual-slcan", "--effects", "nosuch",
                "--duration", "0.5", "--out", str(out), "--no-plot"])  # fmt: skip
    assert bad.returncode in (2, 3), bad.stderr
    assert "nosuch" in bad.stderr
    assert not out.exists(), list(out.iterdir())
    good = _run([*ENTRY, "run", "--bench", "virtual-slcan", "--duration", "0.5",
                 "--out", str(out), "--no-plot"])  # fmt: skip
    assert good.returncode == 0, good.stderr
    assert _meta(out)["status"] == "complete"


def test_sigterm_before_the_recording_begins_leaves_a_rerunnable_directory(
    tmp_path: Path,
) -> None:
    """Issue 31: SIGTERM while `hil run` is still starting its robot (its log exists, no
    meta.json yet): exit 143, one line, and the rerun to the same --out is not refused."""
    out = tmp_path / "D"
    argv = [*ENTRY, "run", "--bench", "virtual-slcan", "--out", str(out), "--no-plot"]
    proc = _start([*argv, "--duration", "60"])
    try:
        _poll(lambda: (out / "virtual-robot.log").exists(), proc, what="the robot's launch")
        err = _stop(proc, signal.SIGTERM)
    finally:
        proc.kill()
    assert proc.returncode == 143, err
    assert "Traceback" not in err and len(_own_lines(err)) == 1, err
    began = (out / "meta.json").exists()  # the signal came after the recording began: kept
    if not began:  # stopped before its first row: nothing kept
        assert not out.exists() or not any(out.iterdir()), list(out.iterdir())
    again = _run([*argv, "--duration", "0.5", *(["--overwrite"] if began else [])])
    assert again.returncode == 0, again.stderr


# ---- runs without --out --------------------------------------------------------------------
@pytest.mark.slow  # every command with a default output twice, each its own process: ~20 s
def test_every_command_twice_with_defaults_keeps_both_runs(tmp_path: Path) -> None:
    """Issue 30: each command run twice without --out writes a new directory each time (both
    kept, no error) and runs/latest points to the newest; --out stays exact. `hil demo` takes
    the same default (prepare_out_dir(default="demo")) and is left out for its length;
    `virtual-robot serve` writes no run directory."""
    sim = _run([*ROBOT, "simulate", "--duration", "1.5", "--no-plot", "--out", "base"],
               cwd=tmp_path)  # fmt: skip
    assert sim.returncode == 0, sim.stderr
    rt = _run([*ENTRY, "run", "--bench", _patient(tmp_path, "virtual-inprocess"), "--mode",
               "realtime", "--duration", "1", "--no-plot", "--out", "rt"],
              cwd=tmp_path)  # fmt: skip
    assert rt.returncode == 0, rt.stderr
    inprocess = ["--bench", "virtual-inprocess"]
    # runs/ group -> command line
    commands = {
        "simulate": [*ROBOT, "simulate", "--duration", "0.5", "--no-plot", "--json"],
        "run": [*ENTRY, "run", *inprocess, "--duration", "0.3", "--no-plot", "--json"],
        "identify": [*ENTRY, "identify", "--from", "base", "--no-plot", "--json"],
        "diagnose": [*ENTRY, "diagnose", "base", "--no-plots", "--json"],
        "control-pd": [*ENTRY, "control", "--scheme", "pd", *inprocess, "--duration", "0.3",
                       "--no-plot", "--json"],
        "control-compare": [*ENTRY, "control", "--compare", *inprocess,
                            "--schemes", "pd,ct", "--duration", "0.3", "--no-plot", "--json"],
        "excite": [*ENTRY, "excite", "--starts", "1", "--time-budget", "1", "--no-simulate",
                   "--no-plot", "--json"],
        "replay": [*ENTRY, "replay", "rt", "--no-plot", "--json"],
        "jitter-virtual-inprocess": [*ENTRY, "jitter", *inprocess, "--duration", "0.3",
                                     "--json"],
    }  # fmt: skip
    for name, argv in commands.items():
        for _ in range(2):
            proc = _run(argv, cwd=tmp_path)
            assert proc.returncode == 0, (name, proc.stderr)
            json.loads(proc.stdout)  # one document
        if name == "diagnose":  # writes files only where --out says
            continue
        runs = sorted(p for p in (tmp_path / "runs" / name).iterdir() if p.name != "latest")
        assert len(runs) == 2, (name, runs)
        assert all(any(r.iterdir()) for r in runs), (name, runs)
        latest = tmp_path / "runs" / name / "latest"
        assert latest.resolve() == runs[-1].resolve(), name
        assert (tmp_path / "runs" / "latest").resolve() == runs[-1].resolve(), name
    assert sorted(p.name for p in tmp_path.iterdir() if p.suffix != ".toml") == [
        "base",
        "rt",
        "runs",
    ]


# ---- signals and exits ---------------------------------------------------------------------
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_identify_over_a_bench_exits_as_the_signal_says(tmp_path: Path, sig: int) -> None:
    """Issue 31: `hil identify` over a bench exited 1 on SIGTERM/SIGINT; now 128 + N, one
    line, the fit run kept and marked interrupted."""
    out = tmp_path / "id"
    bench = _patient(tmp_path, "virtual-slcan")
    proc = _start([*ENTRY, "identify", "--bench", bench, "--mode", "realtime", "--duration",
                   "60", "--out", str(out), "--no-plot"])  # fmt: skip
    try:
        wait_rows(out / "fit", 100, proc, timeout=120)
        err = _stop(proc, sig)
    finally:
        proc.kill()
    assert proc.returncode == 128 + sig, err
    assert "Traceback" not in err and len(_own_lines(err)) <= 3, err  # start, running, stop
    assert "drives at zero torque and disabled" in _own_lines(err)[-1], err
    assert _meta(out / "fit")["status"] == "interrupted"


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_simulate_ends_on_a_signal_with_its_line_and_meta(tmp_path: Path, sig: int) -> None:
    """Issue 31: `virtual-robot simulate` on SIGTERM/SIGHUP died with no line and meta.json
    `running`; every exit signal now ends it like Ctrl-C: 128 + N, one line, `interrupted`."""
    out = tmp_path / "sim"
    proc = _start([*ROBOT, "simulate", "--duration", "3000", "--no-plot", "--out", str(out)])
    try:
        _poll(
            lambda: (
                (out / "signals.csv").is_file() and (out / "signals.csv").stat().st_size > 10_000
            ),
            proc,
            timeout=120,
            what="rows",
        )
        err = _stop(proc, sig)
    finally:
        proc.kill()
    assert proc.returncode == 128 + sig, err
    name = signal.Signals(sig).name
    lines = [ln for ln in err.splitlines() if "simulated" not in ln]
    want = "stopped by " + name if sig != signal.SIGINT else "interrupted by the user"
    assert len(lines) == 1 and want in lines[0], err
    meta = _meta(out)
    assert meta["status"] == "interrupted" and run_status(meta) == "interrupted"
    assert meta["reason"] == (f"stopped by {name}" if sig != signal.SIGINT else want + " (Ctrl-C)")


@pytest.mark.parametrize("sig", [signal.SIGHUP, signal.SIGTERM])
def test_serve_cleans_up_on_every_exit_signal(tmp_path: Path, sig: int) -> None:
    """Issue 31: `virtual-robot serve` died on SIGHUP without its clean-up; every exit signal
    now stops it the same way: the drives disabled, its `stopped` line, 128 + N."""
    proc = _start([*ROBOT, "serve", "--bench", "virtual-socketcand"])
    try:
        info = json.loads(proc.stdout.readline())
        assert info["event"] == "ready"
        _poll(lambda: _handlers_installed(proc.pid), proc, what="serve's handlers")
        err = _stop(proc, sig)
    finally:
        proc.kill()
    assert proc.returncode == 128 + sig, err
    name = signal.Signals(sig).name
    assert f"virtual-robot: stopped by {name}; drives disabled" in err.splitlines(), err
    assert "Traceback" not in err, err


def test_a_closed_stdout_is_an_error_not_a_lost_result(tmp_path: Path) -> None:
    """Issue 31: `hil diagnose base >&-` exited 0 with the result lost; now one line on stderr
    and exit 2, before anything runs. The same for virtual-robot."""
    sim = _run([*ROBOT, "simulate", "--duration", "1.5", "--no-plot", "--out", "base"],
               cwd=tmp_path)  # fmt: skip
    assert sim.returncode == 0, sim.stderr
    for argv, prog in (
        ([*ENTRY, "diagnose", "base"], "hil diagnose"),
        ([*ROBOT, "simulate", "--duration", "0.2", "--out", "again"], "virtual-robot simulate"),
    ):
        proc = subprocess.run(
            ["bash", "-c", 'exec "$@" >&-', "bash", *argv],
            capture_output=False,
            stderr=subprocess.PIPE,
            text=True,
            cwd=tmp_path,
            timeout=300,
            check=False,
        )
        assert proc.returncode == 2, proc.stderr
        assert proc.stderr.strip().splitlines() == [f"{prog}: error: {process.STDOUT_CLOSED}"], (
            proc.stderr
        )
    assert not (tmp_path / "again").exists()


def test_an_offline_command_claims_no_drives_when_interrupted(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Issue 31: offline identify/diagnose said "drives at zero torque and disabled" where no
    drives exist; only a command that opened a link to drives says so."""

    def interrupted(_args: object) -> int:
        raise KeyboardInterrupt

    monkeypatch.setattr(process, "_drives", [])
    assert run_command("diagnose", interrupted, None) == 130
    assert capsys.readouterr().err == "hil diagnose: interrupted by the user (Ctrl-C)\n"
    process.note_drives_opened()
    assert run_command("run", interrupted, None) == 130
    err = capsys.readouterr().err
    assert err == "hil run: interrupted by the user (Ctrl-C); drives at zero torque and disabled\n"


def test_a_reader_that_leaves_early_ends_quietly(tmp_path: Path) -> None:
    """Issue 30: `hil ... --json | head -c 100` (a document longer than a pipe holds): no
    "Broken pipe" line, no traceback; the writer ends as SIGPIPE ends a Unix tool (141)."""
    sim = _run([*ROBOT, "simulate", "--duration", "1.5", "--no-plot", "--out", "base"],
               cwd=tmp_path)  # fmt: skip
    assert sim.returncode == 0, sim.stderr
    script = 'python -m hil.entry identify --from base --no-plot --json | head -c 100; ' \
             'echo "${PIPESTATUS[0]}" >&2'  # fmt: skip
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}"}
    env["PYTHONPATH"] = str(ROOT)
    proc = subprocess.run(["bash", "-c", script], capture_output=True, text=True,
                          cwd=tmp_path, timeout=300, env=env, check=False)  # fmt: skip
    assert len(proc.stdout) == 100
    status = proc.stderr.strip().splitlines()[-1]
    assert status in ("0", "141"), proc.stderr  # 0: the document fit in the pipe's buffer
    assert "Broken pipe" not in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
