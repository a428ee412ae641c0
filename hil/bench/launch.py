"""Start the virtual robot of a virtual bench, and stop it afterwards.

A bench with ``virtual = true`` runs ``virtual-robot serve`` as a subprocess and reads the
channel it announces (one JSON line on its stdout). The ``virtual`` transport (python-can's
in-process bus) cannot cross a process boundary, so that one bench starts the very same server
entry point in a thread instead: the only place the host loads ``virtual_robot``, and only its
``serve`` function, never the physics directly. A bench with ``attach = true`` starts nothing: the
robot already serves on the bench's channel (``virtual-robot serve``, ``hil run --attach``), and
it keeps running after the host is done.
"""

from __future__ import annotations

import json
import os
import queue
import select
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from importlib import import_module
from pathlib import Path
from typing import Any

from drivers.process import cpu_ticks
from profiles.bench import BenchProfile

# A robot that dies is noticed at once (poll). One that is alive but does not announce is given
# READY_TIMEOUT_S, and as long again each time it has used CPU meanwhile (it is still starting:
# its imports take seconds, and many times that in a software-emulated guest on a loaded
# machine, where no wall-clock bound holds), up to READY_MAX_S in all: one that neither
# announces nor works for READY_TIMEOUT_S has hung.
READY_TIMEOUT_S = 60.0
READY_MAX_S = 600.0


class LaunchError(RuntimeError):
    """The virtual robot did not start (its last stderr line is in the message)."""


class StartWait:
    """How long to wait for a started process (READY_TIMEOUT_S and READY_MAX_S): ``more()`` is
    true until it has neither announced nor used CPU for READY_TIMEOUT_S, or READY_MAX_S have
    passed. Without /proc (not Linux) its CPU time is unknown: READY_TIMEOUT_S in all."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.started = time.monotonic()
        self.deadline = self.started + READY_TIMEOUT_S
        self.cpu = cpu_ticks(pid)

    def more(self) -> bool:
        now = time.monotonic()
        if now < self.deadline:
            return True
        cpu = cpu_ticks(self.pid)
        if cpu is None or self.cpu is None or cpu == self.cpu:
            return False  # no work since the last deadline: hung (or unknown)
        self.cpu = cpu
        self.deadline = min(now + READY_TIMEOUT_S, self.started + READY_MAX_S)
        return now < self.deadline

    def why(self) -> str:
        waited = time.monotonic() - self.started
        if waited >= READY_MAX_S:
            return f"still starting after {waited:.0f} s"
        return f"no CPU used for {READY_TIMEOUT_S:.0f} s, {waited:.0f} s after its start"


class VirtualRobotProcess:
    """Context manager: a running virtual robot for ``bench``; ``channel`` is what it announced."""

    def __init__(
        self,
        bench: BenchProfile,
        *,
        mode: str | None = None,
        effects: str | None = None,
        seed: int | None = None,
        log_path: str | Path | None = None,
        event_log: str | Path | None = None,
        initial_q: Sequence[float] | None = None,
    ) -> None:
        self.bench, self.mode, self.effects, self.seed = bench, mode, effects, seed
        # the arm's position at rest when the robot starts (an experiment's initial_q_rad)
        self.initial_q = None if initial_q is None else tuple(float(x) for x in initial_q)
        self.log_path = Path(log_path) if log_path else None
        # realtime: the robot writes its own sample and command times here (`hil replay`)
        self.event_log = Path(event_log) if event_log else None
        self.channel: dict[str, Any] = {}
        self.proc: subprocess.Popen[str] | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._log = None

    # ---- lifecycle ------------------------------------------------------------------------
    def __enter__(self) -> VirtualRobotProcess:
        if self.bench.attach:  # somebody else's robot: use its channel, start and stop nothing
            self.channel = {"channel": self.bench.channel, "attached": True}
            return self
        try:
            if self.bench.in_process:
                self._start_thread()
            else:
                self._start_process()
        except BaseException:  # Ctrl-C or SIGTERM during the launch: no robot left behind
            self.stop()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def alive(self) -> bool:
        if self.bench.attach:
            return True  # not ours to watch: a dead robot shows as a link failure
        if self.proc is not None:
            return self.proc.poll() is None
        return self._thread is not None and self._thread.is_alive()

    @property
    def pid(self) -> int | None:
        return self.proc.pid if self.proc is not None else None

    def stop(self) -> None:
        """SIGTERM, then SIGKILL after 3 s (subprocess); set the stop event (thread)."""
        self._stop.set()
        if self.proc is not None:
            if self.proc.poll() is None:
                self.proc.send_signal(signal.SIGTERM)
                try:
                    self.proc.wait(timeout=3.0)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
            self.proc.wait()  # reaped on every path: no zombie robot
            if self.proc.stdout is not None:
                self.proc.stdout.close()
        if self._thread is not None:
            self._thread.join(timeout=3.0)
        if self._log is not None:
            self._log.close()
            self._log = None

    # ---- helpers ------------------------------------------------------------------------------
    def _args(self) -> list[str]:
        # the bench's robot, which `hil run --robot` may have replaced (bench_for_robot)
        args = ["--bench", self.bench.source, "--robot", self.bench.robot, "--exit-with-parent"]
        if self.mode:
            args += ["--mode", self.mode]
        if self.effects:
            args += ["--effects", self.effects]
        if self.seed is not None:
            args += ["--seed", str(self.seed)]
        if self.event_log is not None:
            args += ["--event-log", str(self.event_log)]
        if self.initial_q is not None:  # repr: the exact float, read back by float()
            args += ["--initial-q", ",".join(repr(x) for x in self.initial_q)]
        return args

    def _start_process(self) -> None:
        if self.log_path is not None:
            self.log_path.parent.mkdir(parents=True, exist_ok=True)
            self._log = open(self.log_path, "w")  # noqa: SIM115 (closed in stop())
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "virtual_robot.cli", "serve", *self._args()],
            stdout=subprocess.PIPE,
            stderr=self._log or subprocess.DEVNULL,
            text=True,
            start_new_session=True,  # a Ctrl-C at the terminal goes to the host, which stops us
        )
        assert self.proc.stdout is not None
        waited = StartWait(self.proc.pid)
        fd = self.proc.stdout.fileno()
        while waited.more():
            ready, _, _ = select.select([fd], [], [], 0.1)
            if ready:
                line = self.proc.stdout.readline()
                if line:
                    self.channel = json.loads(line)
                    return
            if self.proc.poll() is not None:
                break
        reason = self._last_log_line() or f"no announcement ({waited.why()})"
        self.stop()
        raise LaunchError(f"virtual robot for bench {self.bench.name} did not start: {reason}")

    def _last_log_line(self) -> str:
        if self.log_path is None or not self.log_path.is_file():
            return ""
        lines = [ln for ln in self.log_path.read_text().splitlines() if ln.strip()]
        return lines[-1] if lines else ""

    def _start_thread(self) -> None:
        serve = import_module("virtual_robot.serve").serve
        announced: queue.Queue[dict[str, Any]] = queue.Queue()
        channel = f"ddbench-{os.getpid()}-{id(self)}"
        bench = self.bench
        if not bench.channel:
            from dataclasses import replace

            bench = replace(bench, channel=channel)

        ready = threading.Event()

        def announce(info: dict[str, Any]) -> None:
            ready.set()
            announced.put(info)

        def run() -> None:
            try:
                serve(
                    bench,
                    effects=self.effects,
                    mode=self.mode,
                    seed=self.seed,
                    announce=announce,
                    stop=self._stop,
                    event_log=self.event_log,
                    initial_q=self.initial_q,
                )
            except Exception as exc:  # refused before serving (e.g. effects the robot lacks)
                if ready.is_set():
                    raise
                announced.put({"event": "failed", "reason": str(exc)})

        self._thread = threading.Thread(target=run, name="virtual-robot", daemon=True)
        self._thread.start()
        try:
            info = announced.get(timeout=READY_TIMEOUT_S)
        except queue.Empty:
            info = {"event": "failed", "reason": "no announcement"}
        if info.get("event") == "failed":
            self.stop()
            raise LaunchError(
                f"in-process virtual robot for {bench.name} did not start: {info['reason']}"
            )
        self.channel = info


__all__ = [
    "LaunchError",
    "VirtualRobotProcess",
]
