"""One served robot, several hosts (issue 31 item 2): a second host is refused before it sends
anything, a stray SYNC does not lock the bus, a faulted robot says why and is cleared by
``hil run --clear-faults`` or by SIGUSR1 to ``virtual-robot serve``, and the socketcand hub
drops clients that never finish the handshake. Each wait polls for what it needs (no fixed
sleeps that a loaded machine could outrun)."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import can
import pytest
from cli_run import ROOT, start_hil, wait_rows
from hosts import open_together

from drivers.links import open_arm
from profiles.bench import load_bench
from virtual_robot.socketcand_hub import SocketcandHub

SYNC = can.Message(arbitration_id=0x080, data=b"", is_extended_id=False)


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[subprocess.Popen, int, Path]]:
    """``virtual-robot serve --bench virtual-socketcand``: (process, port, its stderr file)."""
    log = tmp_path / "serve.err"
    with log.open("w") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "virtual_robot.cli", "serve", "--bench", "virtual-socketcand"],
            stdout=subprocess.PIPE,
            stderr=err,
            text=True,
            cwd=ROOT,
        )
    try:
        port = json.loads(proc.stdout.readline())["port"]
        yield proc, port, log
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()


def _attach(out: Path, port: int, *args: str, duration: str = "1") -> list[str]:
    return ["run", "--out", str(out), "--no-plot", "--bench", "virtual-socketcand",
            "--attach", f"127.0.0.1:{port}", "--duration", duration, *args]  # fmt: skip


def _hil(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    proc = start_hil(*args)
    try:
        out, err = proc.communicate(timeout=timeout)
    finally:
        proc.kill()
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def _wait_for(path: Path, text: str, timeout: float = 30.0, times: int = 1) -> str:
    """Wait until ``text`` stands ``times`` times in the file ``path``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        got = path.read_text()
        if got.count(text) >= times:
            return got
        time.sleep(0.05)
    raise AssertionError(f"{text!r} not in {path.name} after {timeout} s: {path.read_text()}")


def _fault_by_two_producers(port: int, log: Path) -> None:
    """Two raw clients each send a SYNC, the second within the first's lease: the robot faults
    (0x8100) as it must when two producers share a bus; both then leave."""
    faults = log.read_text().count("drives faulted (0x8100)")
    buses = [
        can.Bus(interface="socketcand", host="127.0.0.1", port=port, channel="can0")
        for _ in range(2)
    ]
    try:
        for bus in buses:
            bus.send(SYNC)
        _wait_for(log, "drives faulted (0x8100)", times=faults + 1)
    finally:
        for bus in buses:
            bus.shutdown()


def test_a_second_host_is_refused_and_the_first_run_goes_on(
    tmp_path: Path, served: tuple[subprocess.Popen, int, Path]
) -> None:
    _, port, log = served
    first = start_hil(*_attach(tmp_path / "a", port, duration="600"))
    try:
        wait_rows(tmp_path / "a", 200, first)
        second = _hil(*_attach(tmp_path / "b", port))
        assert second.returncode == 3, second.stderr
        assert "another host is on the bus" in second.stderr
        assert second.stderr.count("\n") == 1, second.stderr  # one line
        rows = (tmp_path / "a" / "signals.csv").read_text().count("\n")
        wait_rows(tmp_path / "a", rows + 400, first)  # the first run was not disturbed
        first.send_signal(signal.SIGINT)
        first.communicate(timeout=60)
    finally:
        first.kill()
    meta = json.loads((tmp_path / "a" / "meta.json").read_text())
    assert meta["status"] == "interrupted", meta
    assert "faulted" not in log.read_text()


def test_two_hosts_attaching_together_one_refuses_the_other_runs(
    served: tuple[subprocess.Popen, int, Path],
) -> None:
    """Both start their listen together, hear a silent bus and send their set-up at once: the
    hub grants the host role to one, the other hears its set-up and refuses in one line; the
    drives never see the second host (no fault) and the first runs."""
    _, port, log = served
    bench = load_bench("virtual-socketcand")
    for _ in range(3):
        arms = [open_arm(bench, {"channel": f"127.0.0.1:{port}"}) for _ in range(2)]
        try:
            outcomes = open_together(arms)
            assert sorted(outcomes)[1] == "open", outcomes  # exactly one attached
            refusal = sorted(outcomes)[0]
            assert refusal.startswith("another host is on the bus"), outcomes
            assert "\n" not in refusal
            arm = arms[outcomes.index("open")]
            arm.enable()
            arm.start()
            for _ in range(200):
                arm.cycle((0.0, 0.0))
            assert arm.faults() == []
        finally:
            for arm in arms:
                arm.close()
    assert "faulted" not in log.read_text()


def test_a_faulted_robot_says_why_and_is_cleared(
    tmp_path: Path, served: tuple[subprocess.Popen, int, Path]
) -> None:
    proc, port, log = served
    _fault_by_two_producers(port, log)
    refused = _hil(*_attach(tmp_path / "c", port))
    assert refused.returncode == 3, refused.stderr
    assert "0x8100" in refused.stderr and "--clear-faults" in refused.stderr
    proc.send_signal(signal.SIGUSR1)  # serve resets its drives
    _wait_for(log, "drive faults reset (0x8100, 0x8100)")
    assert _hil(*_attach(tmp_path / "d", port)).returncode == 0

    _fault_by_two_producers(port, log)
    cleared = _hil(*_attach(tmp_path / "e", port, "--clear-faults"))
    assert cleared.returncode == 0, cleared.stderr
    assert "clearing joint 1's fault 0x8100" in cleared.stderr
    assert "clearing joint 2's fault 0x8100" in cleared.stderr


def test_a_stray_sync_gives_up_the_producer_role_once_silent() -> None:
    """The first SYNC makes its sender the producer; a SYNC from another participant within
    HOST_LEASE_S is a conflict, after it (the first fell silent) a hand-over."""
    conflicts: list[str] = []
    with SocketcandHub(on_sync_conflict=conflicts.append) as hub:
        hub.HOST_LEASE_S = 2.0  # long: a loaded machine may hold a frame a while in transit
        robot = hub.robot_bus()
        stray, host = (
            can.Bus(interface="socketcand", host="127.0.0.1", port=hub.port, channel="can0")
            for _ in range(2)
        )
        try:
            stray.send(SYNC)
            assert robot.recv(5.0) is not None
            time.sleep(2.5)  # the stray producer is silent past the lease
            for _ in range(3):
                host.send(SYNC)
                assert robot.recv(5.0) is not None  # forwarded: the host is the producer now
            stray.send(SYNC)  # within the host's lease: refused, reported once
            host.send(SYNC)
            assert robot.recv(5.0) is not None
            # the two clients' frames travel on two connections: the stray's may reach the
            # hub after the host's, so wait for it rather than assume the order
            deadline = time.monotonic() + 10.0
            while hub.foreign_syncs == 0 and time.monotonic() < deadline:
                time.sleep(0.01)
            assert robot.recv(0.2) is None  # the stray's SYNC was not forwarded
            assert hub.foreign_syncs == 1 and len(conflicts) == 1, conflicts
        finally:
            stray.shutdown()
            host.shutdown()


def test_a_client_that_never_enters_raw_mode_is_dropped() -> None:
    with SocketcandHub() as hub:
        hub.HANDSHAKE_TIMEOUT_S = 0.3
        sock = socket.create_connection(("127.0.0.1", hub.port), timeout=5.0)
        try:
            assert sock.recv(64) == b"< hi >"
            assert sock.recv(64) == b""  # closed by the hub, not by us
        finally:
            sock.close()
        deadline = time.monotonic() + 5.0
        while hub.clients and time.monotonic() < deadline:
            time.sleep(0.02)
        assert hub.clients == 0
