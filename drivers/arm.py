"""The Drive/Arm API the loops see: the same for every transport and for real drives.

An :class:`Arm` is a link to N drives. The loop runner uses only this interface, so it does not
know whether it runs over slcan, SocketCAN, socketcand, an in-process bus or a serial line:

    with make_arm(bench) as arm:          # open: connect, configure (e.g. PDOs by SDO)
        arm.enable()                      # CiA 402: shutdown, switch on, enable operation
        s = arm.start()                   # first feedback q(t_0), nothing commanded yet
        for k in range(n):
            tau = controller(s)
            s = arm.cycle(tau)            # command held over one period, feedback at its end
    # on exit, exception or Ctrl-C: zero torque, drives disabled, link closed

Units are SI here (rad, Nm); counts and per-mille stay inside the drivers.
"""

from __future__ import annotations

import abc
import contextlib
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, NoReturn, NotRequired, TypedDict

from drivers.process import note_drives_opened
from profiles.bench import DEFAULT_FEEDBACK_BUDGET_S  # realtime: later feedback = link dead

DEFAULT_SPIN_S = 0.0002  # realtime wait without a scheduler: spin the last 0.2 ms
LIVENESS_POLL_S = 0.005  # a late wait checks every 5 ms whether the link or peer died
MAX_ERRORS_KEPT = 100  # LinkStats.errors: a link that fails every frame must not grow it forever


class LinkError(RuntimeError):
    """The link to the drives failed (timeout, dead transport, protocol error)."""


class SafetyStop(RuntimeError):  # noqa: N818 (it is a stop, not a bug)
    """The host's own limits tripped: the arm was stopped (zero torque, drives disabled)."""


@dataclass(frozen=True)
class Fault:
    joint: int  # 0-based
    error_code: int  # CiA 402 / EMCY code (serial drives mapped onto the same codes)
    text: str = ""


@dataclass(frozen=True)
class Sample:
    """Feedback of one period.

    ``q_rad``: encoder readings; ``status``: CiA 402 statuswords (serial drives report the
    equivalent bits); ``tau_Nm``: the torque commanded for the period that ended, as quantized
    by the driver (what the drive applies, unless it faulted); ``t``: time of the sample on the
    link's clock (k·h in lockstep); ``sent_at``/``received_at``/``deadline``: host monotonic
    times in seconds since the link opened (realtime diagnostics; equal to ``t`` in lockstep).
    """

    t: float
    q_rad: tuple[float, ...]
    status: tuple[int, ...]
    tau_Nm: tuple[float, ...] = ()
    sent_at: float = math.nan
    received_at: float = math.nan
    deadline: float = math.nan


@dataclass(frozen=True)
class SafetyLimits:
    """Host-side limits (a real bench enforces these even if the drive does not)."""

    torque_Nm: tuple[float, ...]
    velocity_rad_s: tuple[float, ...] = ()
    position_rad: tuple[tuple[float, float], ...] = ()

    def clamp_torque(self, tau: Sequence[float]) -> tuple[float, ...]:
        """Clamp each command to ±limit; a non-finite command is a SafetyStop, never a clamp."""
        out = []
        for j, (t, lim) in enumerate(zip(tau, self.torque_Nm, strict=True)):
            value = float(t)
            if not math.isfinite(value):
                raise SafetyStop(f"joint {j + 1} torque command is {value}: refusing to send it")
            out.append(max(-lim, min(lim, value)))
        return tuple(out)

    def check(self, q: Sequence[float], dq: Sequence[float] | None) -> str | None:
        """The first limit violated, as one line, or None."""
        for j, (lo, hi) in enumerate(self.position_rad):
            if not lo <= q[j] <= hi:
                return f"joint {j + 1} position {q[j]:.4f} rad outside [{lo}, {hi}]"
        if dq is not None:
            for j, lim in enumerate(self.velocity_rad_s):
                if abs(dq[j]) > lim:
                    return f"joint {j + 1} velocity {dq[j]:.3f} rad/s beyond {lim}"
        return None


@dataclass
class LinkStats:
    """Counters a link keeps for meta.json."""

    cycles: int = 0
    frames_sent: int = 0
    frames_received: int = 0
    timeouts: int = 0
    # realtime timing events: feedback that came later than one period after its SYNC/request
    # but within the feedback budget (the run goes on), and the longest wait seen
    late_feedback: int = 0
    max_feedback_wait_s: float = 0.0
    errors: list[str] = field(default_factory=list)

    def note_error(self, text: str) -> None:
        """Keep ``text`` in :attr:`errors`, up to MAX_ERRORS_KEPT of them."""
        errors = self.errors
        if len(errors) < MAX_ERRORS_KEPT:
            errors.append(text)
        elif len(errors) == MAX_ERRORS_KEPT:
            errors.append("(further errors not kept)")

    def waited(self, wait_s: float, period_s: float) -> None:
        """Count one feedback wait (realtime): late if longer than one period."""
        if wait_s > period_s:
            self.late_feedback += 1
        if wait_s > self.max_feedback_wait_s:
            self.max_feedback_wait_s = wait_s


class LinkSettings(TypedDict):
    """The keyword settings every Arm's constructor takes (``**link: Unpack[LinkSettings]``)
    and :meth:`Arm._init_link` checks: one list of them, not one per protocol."""

    period_s: float
    mode: str  # "lockstep" | "realtime"
    timeout_s: float
    limits: SafetyLimits
    feedback_budget_s: NotRequired[float | None]  # realtime: later feedback = link dead
    feedback_timeout_periods: NotRequired[int | None]  # the older name, in periods


class Arm(abc.ABC):
    """A link to the drives of one arm. Subclasses: one per protocol (CAN 402, serial). What
    their lifecycle shares is here: the settings (:meth:`_init_link`), the safe stop on every
    exit path, and in a cycle the command check, the limits and the safety stop
    (:meth:`_command`, :meth:`_check_limits`, :meth:`_safety_stop`)."""

    n_joints: int = 2
    period_s: float
    mode: str  # "lockstep" | "realtime"
    stats: LinkStats
    opened_at: float | None = None  # time.monotonic() when open() finished connecting

    def _init_link(
        self,
        drives: Sequence[Any],
        *,
        period_s: float,
        mode: str,
        timeout_s: float,
        limits: SafetyLimits,
        feedback_budget_s: float | None = None,
        feedback_timeout_periods: int | None = None,
    ) -> None:
        """The settings every link shares, checked once here (subclasses call this first)."""
        if mode not in ("lockstep", "realtime"):
            raise ValueError(f"mode must be 'lockstep' or 'realtime', got {mode!r}")
        if not drives:
            raise ValueError("at least one drive")
        if not period_s > 0 or not timeout_s > 0:
            raise ValueError("period_s and timeout_s must be > 0")
        if len(limits.torque_Nm) != len(drives):
            raise ValueError(f"{len(drives)} drives but {len(limits.torque_Nm)} torque limits")
        self.drives = tuple(drives)
        self.n_joints = len(self.drives)
        self.period_s = float(period_s)
        self.mode = mode
        self.timeout_s = float(timeout_s)
        self.limits = limits
        if feedback_timeout_periods is not None:  # the older name, in periods
            if feedback_budget_s is not None:
                raise ValueError("feedback_budget_s or feedback_timeout_periods, not both")
            if feedback_timeout_periods < 1:
                raise ValueError("feedback_timeout_periods must be >= 1")
            feedback_budget_s = feedback_timeout_periods * self.period_s
        budget = DEFAULT_FEEDBACK_BUDGET_S if feedback_budget_s is None else feedback_budget_s
        if not budget >= self.period_s or not math.isfinite(budget):
            raise ValueError(f"feedback_budget_s must be at least one period, got {budget}")
        self.feedback_budget_s = float(budget)
        self.stats = LinkStats()

    @property
    def feedback_timeout_s(self) -> float:
        """How long a cycle waits for feedback before the link is declared dead: ``timeout_s`` in
        lockstep, ``feedback_budget_s`` in realtime. A closed transport or a dead peer
        (:attr:`peer_alive`) ends the wait at once, whatever is left of it."""
        if self.mode == "lockstep":
            return self.timeout_s
        return self.feedback_budget_s

    # Set by whoever started the other end (hil.bench.run: the virtual robot process): False once it
    # is gone, so a wait for feedback stops at once instead of running out its budget.
    peer_alive: Callable[[], bool] | None = None

    def peer_gone(self) -> bool:
        """True if :attr:`peer_alive` says the other end is gone."""
        alive = self.peer_alive
        return alive is not None and not alive()

    def now(self) -> float:
        """Host monotonic time in seconds since the link opened (the clock of deadlines)."""
        return time.monotonic() - (self.opened_at if self.opened_at is not None else 0.0)

    # Set by the loop runner (hil.bench.scheduler.DeadlineScheduler.wait_until): waits until a
    # deadline on the clock of :meth:`now`. None: :meth:`wait_for_deadline`'s own sleep + spin.
    deadline_waiter: Callable[[float], object] | None = None

    def wait_for_deadline(self, deadline: float) -> None:
        """Wait until ``deadline`` (host seconds since open): the loop's scheduler if it set
        ``deadline_waiter``, else sleep and spin the last ``DEFAULT_SPIN_S``."""
        waiter = self.deadline_waiter
        if waiter is not None:
            waiter(deadline)
            return
        remaining = deadline - self.now()
        if remaining > DEFAULT_SPIN_S:
            time.sleep(remaining - DEFAULT_SPIN_S)
        while self.now() < deadline:
            pass

    @abc.abstractmethod
    def open(self) -> None:
        """Connect and configure (CAN: NMT, PDO map by SDO; serial: DMODE, ECHO0)."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the transport. Does not command anything (see :meth:`safe_stop`)."""

    @abc.abstractmethod
    def enable(self) -> None:
        """Bring every drive to OPERATION ENABLED in torque mode; LinkError if one will not."""

    @abc.abstractmethod
    def disable(self) -> None:
        """Zero torque and disable every drive."""

    @abc.abstractmethod
    def start(self) -> Sample:
        """The first feedback, q(t_0), before any torque is commanded."""

    @abc.abstractmethod
    def cycle(self, tau_Nm: Sequence[float], deadline: float | None = None) -> Sample:
        """Command ``tau_Nm`` for one period; return the feedback at the end of that period.

        ``deadline`` (realtime): host monotonic time, seconds since open, at which the period
        ends; the link waits for it before sampling. Raises LinkError if feedback does not come.
        """

    @abc.abstractmethod
    def faults(self) -> list[Fault]:
        """Active faults of every drive."""

    @abc.abstractmethod
    def clear_faults(self) -> None:
        """Fault reset on every drive in FAULT."""

    def traffic_log(self) -> str | None:
        """Path of the raw traffic log this link writes, if any."""
        return None

    def safe_stop(self) -> None:
        """Best effort zero torque and disable; never raises (used on every exit path)."""
        # a dead link must not mask the error that brought us here
        with contextlib.suppress(Exception):
            self.disable()

    # ---- what every link's cycle shares: the command check and the safety stop ---------------
    def _note_error(self, text: str) -> None:
        """Keep ``text`` in :attr:`stats` (a link with a traffic log writes it there too)."""
        self.stats.note_error(text)

    def _safety_stop(self, reason: str) -> NoReturn:
        """Stop the arm (:meth:`safe_stop`: zero torque, drives disabled), keep the reason,
        raise :class:`SafetyStop`."""
        self.safe_stop()
        self._note_error(f"safety stop: {reason}")
        raise SafetyStop(reason)

    def _command(self, tau_Nm: Sequence[float], started: bool) -> tuple[float, ...]:
        """The torque of a :meth:`cycle`, clamped to the limits. RuntimeError before
        :meth:`start` (``started`` False); a command that is not one finite value per joint is a
        safety stop."""
        if not started:
            raise RuntimeError(f"{type(self).__name__}.cycle() before start()")
        if len(tau_Nm) != self.n_joints or not all(math.isfinite(float(t)) for t in tau_Nm):
            self._safety_stop(
                f"torque command {tuple(tau_Nm)} is not {self.n_joints} finite values"
            )
        return self.limits.clamp_torque(tau_Nm)

    def _check_limits(self, q: Sequence[float], dq: Sequence[float] | None) -> None:
        """A safety stop if the feedback ``q`` (and ``dq`` where known) is outside the limits."""
        reason = self.limits.check(q, dq)
        if reason is not None:
            self._safety_stop(reason)

    def __enter__(self) -> Arm:
        note_drives_opened()  # an interruption from here on ends with the drives disabled
        self.open()
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        try:
            self.safe_stop()
        finally:
            self.close()


__all__ = [
    "Arm",
    "Fault",
    "LinkError",
    "LinkSettings",
    "LinkStats",
    "SafetyLimits",
    "SafetyStop",
    "Sample",
]
