"""Two hosts on a bus without a hub (issue 31 item 2, a real CAN bus): the host that claims the
bus first keeps it and the other refuses in one line, whether they attach together or one after
the other, while the first is idle or cycling. On python-can's in-process virtual bus (every
frame to every other participant, none back to its sender: a CAN bus) with two CanArm hosts,
and across processes: two `hil run --attach` on a socketcand hub that forwards every frame as
copper does (no host role granted)."""

from __future__ import annotations

import threading
import uuid
from collections.abc import Iterator
from pathlib import Path

import can
import pytest
from cli_run import finish_all, start_hil
from hosts import open_together

from drivers.arm import LinkError, SafetyLimits
from drivers.can_arm import CanArm
from profiles.drive import load_drive
from profiles.robot import load_robot
from virtual_robot.can_server import CanDriveServer
from virtual_robot.robot import LOCKSTEP, VirtualRobot
from virtual_robot.socketcand_hub import SocketcandHub

H = 0.0025
LIMITS = SafetyLimits((200.0, 15.0), (12.0, 25.0), ((-3.2, 3.2), (-3.2, 3.2)))
REFUSAL = "another host is on the bus"


class Bus:
    """A virtual CAN bus with the cicese drives served on it, and hosts to attach."""

    def __init__(self) -> None:
        self.channel = f"test-host-claim-{uuid.uuid4().hex}"
        self.server_bus = can.Bus(interface="virtual", channel=self.channel)
        self.server = CanDriveServer(
            VirtualRobot(load_robot("cicese"), period_s=H), self.server_bus
        )
        self.server.start()
        self.arms: list[CanArm] = []

    def host(self) -> CanArm:
        drives = [load_drive(n) for n in load_robot("cicese").drives]
        arm = CanArm(
            lambda: can.Bus(interface="virtual", channel=self.channel),
            drives,
            period_s=H,
            mode=LOCKSTEP,
            timeout_s=0.5,
            limits=LIMITS,
        )
        self.arms.append(arm)
        return arm

    def close(self) -> None:
        for arm in self.arms:
            arm.close()
        self.server.stop()
        self.server_bus.shutdown()


@pytest.fixture
def bus() -> Iterator[Bus]:
    b = Bus()
    try:
        yield b
    finally:
        b.close()


def _runs(arm: CanArm, periods: int = 200) -> None:
    arm.enable()
    arm.start()
    for _ in range(periods):
        arm.cycle((0.0, 0.0))
    assert arm.faults() == []


@pytest.mark.parametrize("attempt", range(3))
def test_two_hosts_attaching_together_one_refuses_the_other_runs(bus, attempt):
    arms = [bus.host(), bus.host()]
    outcomes = open_together(arms)
    assert sorted(outcomes)[1] == "open", outcomes  # exactly one attached
    refusal = sorted(outcomes)[0]
    assert refusal.startswith(REFUSAL) and "\n" not in refusal, outcomes
    _runs(arms[outcomes.index("open")])


def test_a_rival_claim_heard_after_the_silent_listen_refuses_before_ours_is_sent(bus, monkeypatch):
    """A rival's claiming heartbeat that arrives after our silent listen but before our claim
    is set wins the bus, and we send no heartbeat of ours: had we sent it, the rival could
    lose to it by (node-ID, nonce) and both hosts would refuse (seen in CI)."""
    from drivers.can_arm import setup
    from drivers.protocol import cia402 as co

    arm = bus.host()
    listen = setup.NodeSetup._listen
    calls = []

    def listen_then_hear_a_rival(self, seconds):
        listen(self, seconds)
        if not calls:  # the first (silent) listen: the rival's claim comes in just after it
            self._host_heartbeat(co.HEARTBEAT_BASE + 1, co.host_heartbeat(False, bytes(4)))
        calls.append(seconds)

    monkeypatch.setattr(setup.NodeSetup, "_listen", listen_then_hear_a_rival)
    sent: list[int] = []
    send = arm._send
    monkeypatch.setattr(arm, "_send", lambda msg, *a, **k: (sent.append(msg.arbitration_id),
                                                               send(msg, *a, **k))[1])  # fmt: skip
    with pytest.raises(LinkError, match=REFUSAL) as refused:
        arm.open()
    assert "claiming it" in str(refused.value)
    assert calls == [setup.HOST_LISTEN_S]  # refused before the claim's listen
    assert not any(co.HEARTBEAT_BASE < cob < co.HEARTBEAT_BASE + 128 for cob in sent), sent


def test_a_late_host_is_refused_by_an_idle_first_host(bus):
    """The first host is open but sends nothing (no SYNC, no SDO): the second hears a silent
    bus, claims it, and the first's answer (its heartbeat: holding the bus) refuses it."""
    first = bus.host()
    first.open()
    with pytest.raises(LinkError, match=REFUSAL) as refused:
        bus.host().open()
    assert "holding" in str(refused.value) and "\n" not in str(refused.value)
    _runs(first)


def test_a_late_host_is_refused_by_a_cycling_first_host(bus):
    first = bus.host()
    first.open()
    first.enable()
    first.start()
    stop = threading.Event()

    def cycle() -> None:
        while not stop.is_set():
            first.cycle((0.0, 0.0))

    thread = threading.Thread(target=cycle)
    thread.start()
    try:
        with pytest.raises(LinkError, match=REFUSAL):
            bus.host().open()
    finally:
        stop.set()
        thread.join(10)
    assert first.faults() == []
    _runs(first, 50)


class CopperHub(SocketcandHub):
    """A socketcand hub that forwards every frame to every other participant and grants no
    host role: what two hosts meet on a real CAN bus (SocketcandHub grants the role to the
    first host frame, atomically: a bus has no such referee)."""

    @staticmethod
    def _host_frame(msg: can.Message) -> str | None:
        return None


def _attach(out: Path, port: int) -> list[str]:
    return ["run", "--out", str(out), "--no-plot", "--bench", "virtual-socketcand",
            "--attach", f"127.0.0.1:{port}", "--duration", "1"]  # fmt: skip


@pytest.mark.parametrize("attempt", range(2))
def test_two_host_processes_on_a_bus_without_a_hub(tmp_path, attempt):
    """Two `hil run --attach` processes started together on a bus that forwards everything:
    one runs its second to the end, the other refuses in one line (exit 3)."""
    robot = VirtualRobot(load_robot("cicese"), period_s=H)
    with CopperHub(channel="can0") as hub:
        bus = hub.robot_bus()
        server = CanDriveServer(robot, bus)
        server.start()
        try:
            procs = [start_hil(*_attach(tmp_path / name, hub.port)) for name in "ab"]
            results = [(code, err) for code, _, err in finish_all(procs, timeout=120)]
        finally:
            server.stop()
            bus.shutdown()
    codes = sorted(code for code, _ in results)
    assert codes == [0, 3], results
    refusal = next(err for code, err in results if code == 3)
    print(refusal)
    assert REFUSAL in refusal and refusal.count("\n") == 1, refusal
    winner = "ab"[[code for code, _ in results].index(0)]
    rows = (tmp_path / winner / "signals.csv").read_text().count("\n") - 1
    assert rows == 400, rows  # 1 s at 2.5 ms
