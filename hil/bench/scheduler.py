"""The realtime loop's scheduler: absolute deadlines, sleep (then spin), and the OS's help.

Deadlines are absolute, t_k = t_0 + k·h, computed from k (never by adding h to the previous
deadline), so rounding and late wake-ups do not accumulate: the loop does not drift.

Waiting for a deadline (:meth:`DeadlineScheduler.wait_until`): ``time.sleep`` until
``spin_margin`` before it, then read the clock in a loop until it has passed. A sleep wakes
5–60 µs late on this VM (p99; rare wake-ups 150 µs late and more under load) and a spinning
loop is released within a clock read (< 1 µs) of the deadline, at the price of a core for the
margin. The margin adapts: every ``ADAPT_EVERY`` waits it becomes the p99 of the recent sleep
overshoots plus ``MARGIN_HEADROOM_S``, within [``MIN_SPIN_S``, min(``MAX_SPIN_S``, h/4)].

``spin=False`` only sleeps, to the deadline itself: the variant measured for issue 13, where a
FIFO thread that spins holds its CPU against every normal task, the kernel worker that carries
a pty's data among them (docs/jitter.md, "Beside CPU-bound jobs"). Measured beside two CPU
hogs it did not change how many 60 s runs over the ptys completed, and it releases later (a
SCHED_FIFO sleep has no timer slack but still woke ~35 µs late, median, under load;
``tests/benchmarks/bench_deadline_wait.py``), so the spin stays the default. ``sched_yield``
while spinning would not help that worker either: a FIFO thread yields only to realtime
threads of its own priority. The split (time slept, time spun, how late sleeps woke) is kept
for the report.

What the OS gives (:func:`acquire_realtime`, before the link opens, so that the threads it
starts inherit it): ``SCHED_FIFO`` at priority ``RT_PRIORITY`` (below the kernel's threaded
interrupt handlers at 50) for the threads of the host process and of the virtual robot's
process (it stands in for the drives, which a loaded host does not slow down; without it a busy
machine starves the robot and its multi-ms replies show up as the loop's jitter), and
``mlockall(MCL_CURRENT | MCL_FUTURE)`` for the host (no page faults on pages already mapped,
none paged out). Both need privileges (root,
CAP_SYS_NICE / CAP_IPC_LOCK, or RLIMIT_RTPRIO / RLIMIT_MEMLOCK); what was refused, and why, is
in the report, and the first refusal in a process is said once on stderr. The Linux kernel's RT
throttling (95 % of each second by default) still bounds a runaway FIFO thread.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import errno
import os
import resource
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

POLICIES = ("auto", "off")  # auto: try SCHED_FIFO and mlockall, fall back; off: do not try
RT_PRIORITY = 10
MCL_CURRENT, MCL_FUTURE = 1, 2
DEFAULT_SPIN_S = 200e-6  # margin before the first adaptation (the drivers' old fixed value)
MIN_SPIN_S = 50e-6
MAX_SPIN_S = 1e-3
MARGIN_HEADROOM_S = 30e-6
ADAPT_EVERY = 200  # waits between margin updates (and the window they look at)

_warned = False


def _warn_once(message: str, stream: Any = None) -> bool:
    """Print ``message`` on stderr the first time in this process; True if printed."""
    global _warned
    if _warned:
        return False
    _warned = True
    print(message, file=stream or sys.stderr, flush=True)
    return True


class DeadlineScheduler:
    """Absolute deadlines t_0 + k·h and a wait that sleeps, then spins (``spin=False``: only
    sleeps, to the deadline).

    ``clock`` and ``sleep`` are injectable (a test runs it on a simulated clock); ``clock`` is
    the clock of the deadlines (e.g. :meth:`drivers.arm.Arm.now`).
    """

    def __init__(
        self,
        period_s: float,
        *,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        spin_s: float = DEFAULT_SPIN_S,
        adaptive: bool = True,
        spin: bool = True,
    ) -> None:
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        self.period_s = float(period_s)
        self.clock = clock
        self.sleep = sleep
        self.spin = spin
        self.max_spin_s = min(MAX_SPIN_S, self.period_s / 4) if spin else 0.0
        self.spin_margin_s = min(spin_s, self.max_spin_s)
        self.adaptive = adaptive and spin
        self.t0 = 0.0
        self.waits = 0
        self.already_late = 0  # called at or after the deadline: nothing to wait for
        self.late_wakeups = 0  # the sleep itself returned after the deadline
        self.slept_s = 0.0
        self.spun_s = 0.0
        self.spin_reads = 0
        self._oversleep: list[float] = []  # how late each sleep woke, against its request
        self._window: list[float] = []
        self._adapt_due = False

    def start(self, t0: float | None = None) -> float:
        """Set t_0 (now, if not given); returns it."""
        self.t0 = self.clock() if t0 is None else float(t0)
        return self.t0

    def deadline(self, k: int) -> float:
        """t_0 + k·h, from k: no accumulated rounding, no drift."""
        return self.t0 + k * self.period_s

    def wait_for(self, k: int) -> float:
        """Wait for deadline k; returns the release time (the clock when the wait ended)."""
        return self.wait_until(self.deadline(k))

    def wait_until(self, target: float) -> float:
        """Sleep until ``spin_margin_s`` before ``target``, then spin until it has passed
        (without spin: sleep until ``target``; a sleep never returns early).

        Returns the release time. If ``target`` has already passed, returns at once."""
        self.waits += 1
        if self._adapt_due:
            # The margin update (a percentile: ~0.3 ms) runs here, before the sleep, where the
            # period has slack; run between the wake-up and the release it delayed that release.
            self._adapt()
        now = self.clock()
        if now >= target:
            self.already_late += 1
            return now
        wake = target - self.spin_margin_s
        oversleep = None
        if wake > now:
            self.sleep(wake - now)
            woke = self.clock()
            self.slept_s += woke - now
            oversleep = woke - wake
            now = woke
            if now >= target:
                if self.spin_margin_s > 0:  # woke past the deadline despite the margin
                    self.late_wakeups += 1
                self._record_oversleep(oversleep)
                return now
        spun_from = now
        clock = self.clock
        reads = 0
        while now < target:
            now = clock()
            reads += 1
        self.spin_reads += reads
        self.spun_s += now - spun_from
        if oversleep is not None:
            self._record_oversleep(oversleep)
        return now

    def _record_oversleep(self, late: float) -> None:
        self._oversleep.append(late)
        if not self.adaptive:
            return
        window = self._window
        window.append(late)
        if len(window) >= ADAPT_EVERY:
            self._adapt_due = True

    def _adapt(self) -> None:
        """New spin margin: the p99 of the recent oversleeps plus headroom, within bounds."""
        window = self._window
        p99 = float(np.percentile(window, 99))
        self.spin_margin_s = min(self.max_spin_s, max(MIN_SPIN_S, p99 + MARGIN_HEADROOM_S))
        window.clear()
        self._adapt_due = False

    def report(self) -> dict[str, Any]:
        """The sleep/spin split and the sleeps' overshoot, for meta.json."""
        over = np.asarray(self._oversleep) * 1e6
        n = max(1, self.waits)
        method = "sleep, then spin" + (" (adaptive margin)" if self.adaptive else "")
        out: dict[str, Any] = {
            "method": method if self.spin else "sleep to the deadline (no spin)",
            "waits": self.waits,
            "spin_margin_us": self.spin_margin_s * 1e6,
            "mean_sleep_us": self.slept_s / n * 1e6,
            "mean_spin_us": self.spun_s / n * 1e6,
            "spin_fraction_of_period": self.spun_s / n / self.period_s,
            "already_late": self.already_late,
            "late_wakeups": self.late_wakeups,
        }
        if over.size:
            out["sleep_overshoot_us"] = {
                "median": float(np.median(over)),
                "p99": float(np.percentile(over, 99)),
                "max": float(over.max()),
            }
        return out


# ---- what the OS allows ---------------------------------------------------------------------
@dataclass
class Scheduling:
    """What :func:`acquire_realtime` got: policy, priority, memory lock, and why not."""

    requested: str  # auto | off
    policy: str = "SCHED_OTHER"
    priority: int = 0
    realtime_refused: str | None = None
    memory_locked: bool = False
    memory_lock_refused: str | None = None
    host_threads: int = 0  # threads of this process put under SCHED_FIFO (later ones inherit)
    peer: dict[str, Any] | None = None  # the virtual robot process: pid, policy, threads, refused
    warned: bool = False
    _restore: list[tuple[int, int, int]] = field(default_factory=list, repr=False)

    @property
    def fell_back(self) -> bool:
        return self.requested != "off" and (
            self.realtime_refused is not None or self.memory_lock_refused is not None
        )

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("_restore")
        return d


def _libc() -> ctypes.CDLL:
    return ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)


def _mlockall() -> None:
    """mlockall(MCL_CURRENT | MCL_FUTURE); OSError with errno if refused."""
    if _libc().mlockall(MCL_CURRENT | MCL_FUTURE) != 0:
        code = ctypes.get_errno()
        raise OSError(code, os.strerror(code))


def _munlockall() -> None:
    _libc().munlockall()


def _set_fifo(tid: int, priority: int) -> None:
    """SCHED_FIFO for one thread (Linux: a thread id; 0 = the calling thread)."""
    os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))


def _threads(pid: int) -> list[int]:
    """Thread ids of a process (Linux /proc); [] where that is not readable."""
    try:
        return sorted(int(t) for t in os.listdir(f"/proc/{pid}/task"))
    except (OSError, ValueError):
        return []


def _current_policy(tid: int) -> tuple[int, int] | None:
    try:
        return os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority
    except OSError:
        return None


def _refusal(exc: OSError, what: str) -> str:
    name = errno.errorcode.get(exc.errno or 0, "error")
    return f"{what}: {name} ({exc.strerror or exc})"


def _limits_hint() -> str:
    try:
        rtprio = resource.getrlimit(resource.RLIMIT_RTPRIO)[0]
        memlock = resource.getrlimit(resource.RLIMIT_MEMLOCK)[0]
    except (AttributeError, OSError, ValueError):
        return ""

    def text(v: int) -> str:
        return "unlimited" if v == resource.RLIM_INFINITY else str(v)

    return f"euid {os.geteuid()}, RLIMIT_RTPRIO {text(rtprio)}, RLIMIT_MEMLOCK {text(memlock)} B"


def _fifo_for(
    got: Scheduling, tids: list[int], priority: int, set_fifo: Callable[[int, int], None]
) -> tuple[int, str | None]:
    """SCHED_FIFO for each thread; (threads set, first refusal). Remembers how to undo it."""
    done, refused = 0, None
    for tid in tids:
        before = _current_policy(tid)
        try:
            set_fifo(tid, priority)
        except OSError as exc:
            if exc.errno == errno.ESRCH:  # the thread ended meanwhile
                continue
            refused = refused or _refusal(exc, "sched_setscheduler(SCHED_FIFO)")
            continue
        done += 1
        if before is not None:
            got._restore.append((tid, *before))
    return done, refused


def acquire_realtime(
    requested: str = "auto",
    *,
    priority: int = RT_PRIORITY,
    peer_pid: int | None = None,
    set_fifo: Callable[[int, int], None] = _set_fifo,
    mlockall: Callable[[], None] = _mlockall,
    warn: Callable[[str], bool] = _warn_once,
) -> Scheduling:
    """Try SCHED_FIFO for this process's threads (and ``peer_pid``'s: the virtual robot, which
    stands in for the drives) and mlockall; say what was refused (once per process)."""
    if requested not in POLICIES:
        raise ValueError(f"realtime policy must be one of {', '.join(POLICIES)}, got {requested!r}")
    got = Scheduling(requested)
    if requested == "off":
        got.realtime_refused = got.memory_lock_refused = "not requested (--realtime-policy off)"
        return got
    # The memory lock first, at normal priority: mlockall faults in every mapped page (≈ 200 MB
    # here, tens to hundreds of ms, partly from disk), which at SCHED_FIFO would hold a CPU
    # against every normal task that long.
    try:
        mlockall()
    except (OSError, AttributeError) as exc:
        reason = _refusal(exc, "mlockall") if isinstance(exc, OSError) else f"mlockall: {exc}"
        got.memory_lock_refused = reason
    else:
        got.memory_locked = True
    if not hasattr(os, "sched_setscheduler"):
        got.realtime_refused = "os.sched_setscheduler is not available on this OS"
    else:
        me = threading.get_native_id()
        others = [t for t in _threads(os.getpid()) if t != me]
        done, refused = _fifo_for(got, [0], priority, set_fifo)
        if done:
            got.policy, got.priority = "SCHED_FIFO", priority
            got.host_threads = 1 + _fifo_for(got, others, priority, set_fifo)[0]
        else:
            got.realtime_refused = refused
        if peer_pid is not None:
            tids = _threads(peer_pid) or [peer_pid]
            n, peer_refused = (
                (0, got.realtime_refused) if not done else _fifo_for(got, tids, priority, set_fifo)
            )
            got.peer = {
                "pid": peer_pid,
                "policy": "SCHED_FIFO" if n else "SCHED_OTHER",
                "threads": n,
                "refused": peer_refused if not n else None,
            }
    if got.fell_back:
        missing = [
            what
            for what, refused in (
                ("SCHED_FIFO", got.realtime_refused),
                ("memory lock", got.memory_lock_refused),
            )
            if refused
        ]
        reasons = [r for r in (got.realtime_refused, got.memory_lock_refused) if r]
        hint = _limits_hint()
        got.warned = warn(
            f"hil: warning: realtime loop without {' and '.join(missing)} "
            f"({'; '.join(reasons + ([hint] if hint else []))}): "
            "best effort timing (sleep, then spin)"
        )
    return got


def release_realtime(
    got: Scheduling,
    *,
    munlockall: Callable[[], None] = _munlockall,
) -> None:
    """Undo :func:`acquire_realtime`: previous policies back, memory unlocked. Never raises."""
    for tid, policy, priority in reversed(got._restore):
        with contextlib.suppress(OSError):
            os.sched_setscheduler(tid, policy, os.sched_param(priority))
    got._restore.clear()
    if got.memory_locked:
        with contextlib.suppress(OSError):
            munlockall()


@contextlib.contextmanager
def realtime_scheduling(
    requested: str = "auto", *, peer_pid: int | None = None
) -> Iterator[Scheduling]:
    """:func:`acquire_realtime` for the duration of a ``with`` block."""
    got = acquire_realtime(requested, peer_pid=peer_pid)
    try:
        yield got
    finally:
        release_realtime(got)


__all__ = [
    "POLICIES",
    "DeadlineScheduler",
    "Scheduling",
    "realtime_scheduling",
]
