"""The plant's one stick–slip step, for any arm: the 2-DOF closed form of Reyes & Kelly (1997)
(:class:`virtual_robot.plant.Plant`) and the n-joint arm of a URDF through Pinocchio
(:class:`virtual_robot.urdf_plant.UrdfPlant`) are its two backends (:class:`StickSlipArm`).

Friction per joint i is Karnopp's stick–slip (Karnopp (1985)):
  * sliding, f_i = b_i q̇_i + F_i(dir) dir, the direction frozen over a step, so each RK4 step
    integrates a smooth ODE in one *stick mode* (which joints stick, which way the others slide);
  * stuck, q̈_i = 0 and f_i is the constraint torque that holds it; it breaks away in the
    direction of that torque when it leaves its static band [−F_s⁻, F_s⁺]
    (:func:`release_stuck_joints`, :func:`breakaway_joint`), checked at step boundaries.
:func:`step` advances dt: the breakaway test, one RK4 step of the backend's mode (its
:meth:`~StickSlipArm.flow`); where a sliding joint's velocity changes sign inside it, the step
is cut where q̇_i = 0 (:func:`locate_stick`: Brent's method, :func:`brent_zero`, on the RK4
flow map, to ~1e-12 of the step), the joint is clamped to rest (the kinetic energy removed
booked as dissipated) and sticks, and the rest of the step is integrated in the new mode.
:func:`advance_delayed` cuts the steps where a delayed command arrives (the transport-delay
effect, timing faults).

What a backend gives (:class:`StickSlipArm`) is its dynamics in a stick mode: the RK4 flow of
the current mode (its M(q), bias and friction: the 2-DOF closed form unrolled into scalar code,
Pinocchio's ABA of the arm or of the arm with its stuck joints locked, or the compiled kernel
of :mod:`virtual_robot.compiled_step`), the holding torques of its stuck joints, and its
bookkeeping (state, energy, torque path). Each backend keeps its own fast paths for the steps
without events (the 2-DOF plant's sliding loop, the n-joint plant's compiled periods); they
stop before a step with an event and leave it to :func:`step`.

Imports: the standard library only (Brent's method is scipy's brentq ported, so that the 2-DOF
plant, which needs nothing of scipy, does not load it: its import costs a served robot's start
and, lazily, its first stick event).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, MutableSequence, Sequence
from typing import Any, Protocol

# The stick search's tolerance on the crossing time, relative to the step (xtol = this · dt).
ZERO_VELOCITY = 1e-12
# Stick events at most per integration step; more is chattering, and the step is closed.
MAX_EVENTS_PER_STEP = 8
# What is left of a step after a stick event is not integrated when shorter than this (s).
MIN_STEP_S = 1e-15
# Iterations of Brent's method at most (scipy's brentq's default maxiter)
BRENT_ITERATIONS = 100

# What a backend's flow map returns at s (its state after s, with its energy terms); opaque here.
End = Any


class StickSlipArm(Protocol):
    """What :func:`step` needs of an arm: the dynamics of its current stick mode and its
    bookkeeping. ``stuck`` and ``slip_dir`` per joint are the stick mode (a sliding joint's
    friction direction, ±1); ``band_positive``/``band_negative``: the static bands
    [−F_s⁻, F_s⁺] of Karnopp's test."""

    n_joints: int
    t: float
    steps: int
    stick_events: int
    stuck: MutableSequence[bool]
    slip_dir: MutableSequence[float]

    @property
    def band_positive(self) -> Sequence[float]: ...

    @property
    def band_negative(self) -> Sequence[float]: ...

    def any_stuck(self) -> bool:
        """Whether some joint sticks (the breakaway test has work to do)."""
        ...

    def hold_torque(self, dt: float) -> None:
        """The shaft torque held over the next dt (an amplifier lag: its mean over dt)."""
        ...

    def flow(self, s: float) -> End:
        """The RK4 flow map of the current stick mode from the current state over s, under the
        torque held over s: q̈ = M⁻¹(τ − C q̇ − g − f), the sliding joints' friction
        directions frozen, the stuck joints' q̈_i = 0."""
        ...

    def start(self) -> End:
        """The flow map at s = 0: the current state, nothing booked."""
        ...

    def velocity(self, end: End, joint: int) -> float:
        """``joint``'s velocity in ``end``."""
        ...

    def crossed(self, end: End) -> Sequence[int]:
        """The sliding joints with a static band whose velocity changed sign by ``end``."""
        ...

    def locate(self, dt: float, crossed: Sequence[int], end: End) -> tuple[float, int, End]:
        """:func:`locate_stick` of this arm (a backend may run the same search compiled)."""
        ...

    def commit(self, end: End, s: float) -> None:
        """Take the state ``end`` the flow reached at s, with its energy terms and the torque
        path's state after s (unchanged for s = 0: a joint that sticks at once)."""
        ...

    def holding_torques(self) -> Sequence[float]:
        """The friction each stuck joint needs to stay at rest now (q̈_S = 0, from the
        constrained dynamics), zero for the sliding joints."""
        ...

    def energy_J(self) -> float:
        """Kinetic plus potential energy now."""
        ...

    def rest(self, joint: int) -> None:
        """Set ``joint``'s velocity to exactly zero (it sticks)."""
        ...

    def dissipate(self, energy_J: float) -> None:
        """Book ``energy_J`` as dissipated (the kinetic energy a clamp to rest removed)."""
        ...

    def mode_changed(self) -> None:
        """After ``stuck`` or ``slip_dir`` changed: the new stick mode's constants."""
        ...


def breakaway_joint(
    held: Sequence[float],
    stuck: Sequence[bool],
    band_positive: Sequence[float],
    band_negative: Sequence[float],
) -> int:
    """The stuck joint that breaks away now, or −1: Karnopp's test on each stuck joint i, whose
    holding torque ``held[i]`` (the friction that keeps q̈_i = 0) must stay inside its static band
    [−band_negative[i], band_positive[i]]; of those outside, the one furthest outside relative to
    its band goes first (the others are checked again once it slides). Any number of joints."""
    worst, worst_ratio = -1, 1.0
    for i, f in enumerate(held):
        if not stuck[i]:
            continue
        band = band_positive[i] if f > 0 else band_negative[i]
        ratio = abs(f) / band if band > 0 else (math.inf if f != 0 else 0.0)
        if ratio > worst_ratio:
            worst, worst_ratio = i, ratio
    return worst


def brent_zero(
    f: Callable[[float], float],
    a: float,
    b: float,
    xtol: float,
    rtol: float = 4 * sys.float_info.epsilon,
    maxiter: int = BRENT_ITERATIONS,
) -> float:
    """The zero of f in [a, b] (f(a) f(b) ≤ 0) to xtol + rtol |x|, by Brent's method (Brent
    (1973) ch. 4) as scipy.optimize.brentq runs it (scipy/optimize/Zeros/brentq.c, C. Harris,
    BSD-3-Clause): the same operations in the same order, so the same iterates and root
    (tests/test_stick_slip.py compares them; rk4_aba.cpp's ``brentq`` is the same port for the
    compiled step). ValueError where brentq raises it (same signs at the ends, a NaN),
    RuntimeError after ``maxiter`` iterations without convergence."""

    def value(x: float) -> float:
        fx = f(x)
        if math.isnan(fx):
            raise ValueError(f"the function value at x={x} is NaN: Brent's method cannot continue")
        return fx

    xpre, xcur = a, b
    xblk = fblk = spre = scur = 0.0
    fpre = value(xpre)
    fcur = value(xcur)
    if fpre * fcur > 0:
        raise ValueError("f(a) and f(b) must have different signs")
    if fpre == 0:
        return xpre
    if fcur == 0:
        return xcur
    fabs = abs
    for _ in range(maxiter):
        if fpre * fcur < 0:
            xblk, fblk = xpre, fpre
            spre = scur = xcur - xpre
        if fabs(fblk) < fabs(fcur):
            xpre, xcur, xblk = xcur, xblk, xcur
            fpre, fcur, fblk = fcur, fblk, fcur
        delta = (xtol + rtol * fabs(xcur)) / 2
        sbis = (xblk - xcur) / 2
        if fcur == 0 or fabs(sbis) < delta:
            return xcur
        if fabs(spre) > delta and fabs(fcur) < fabs(fpre):
            if xpre == xblk:
                stry = -fcur * (xcur - xpre) / (fcur - fpre)  # interpolate
            else:  # extrapolate
                dpre = (fpre - fcur) / (xpre - xcur)
                dblk = (fblk - fcur) / (xblk - xcur)
                stry = -fcur * (fblk * dblk - fpre * dpre) / (dblk * dpre * (fblk - fpre))
            bound = fabs(spre) if fabs(spre) < 3 * fabs(sbis) - delta else 3 * fabs(sbis) - delta
            if 2 * fabs(stry) < bound:
                spre, scur = scur, stry  # good short step
            else:
                spre = scur = sbis  # bisect
        else:
            spre = scur = sbis  # bisect
        xpre, fpre = xcur, fcur
        if fabs(scur) > delta:
            xcur += scur
        else:
            xcur += delta if sbis > 0 else -delta
        fcur = value(xcur)
    raise RuntimeError(f"Brent's method did not converge in {maxiter} iterations")


def release_stuck_joints(arm: StickSlipArm) -> None:
    """Let the stuck joints whose holding torque leaves the static band break away, one at a
    time (:func:`breakaway_joint`), in the direction of that torque; the others are tested
    again in the new mode."""
    for _ in range(arm.n_joints):
        if not arm.any_stuck():
            return
        held = arm.holding_torques()
        worst = breakaway_joint(held, arm.stuck, arm.band_positive, arm.band_negative)
        if worst < 0:
            return
        arm.stuck[worst] = False
        arm.slip_dir[worst] = 1.0 if held[worst] > 0 else -1.0
        arm.mode_changed()


def locate_stick(
    arm: StickSlipArm, dt: float, crossed: Sequence[int], end: End, memo: bool = True
) -> tuple[float, int, End]:
    """The first of the ``crossed`` joints whose velocity reaches zero within [0, dt], the time
    s it does and the flow map there: Brent's method (:func:`brent_zero`) on that joint's
    velocity along the RK4 flow map of the current mode (:meth:`StickSlipArm.flow` over s), to
    ZERO_VELOCITY · dt in s; ``end``: the map at s = dt, already taken. ``memo``: the map is a
    pure function of s (without an amplifier lag, whose mean torque the flow sets as a side
    effect), so each point is evaluated once (brentq evaluates its bracket's ends again, and
    returns its root last)."""
    flows: dict[float, End] = {}
    if memo:
        flows[dt] = end

    def state(s: float) -> End:
        at = flows.get(s)
        if at is None:
            at = arm.flow(s)
            if memo:
                flows[s] = at
        return at

    best_s, best_joint = dt, -1
    for j in crossed:
        d = arm.slip_dir[j]

        def velocity(s: float, j: int = j, d: float = d) -> float:
            return arm.velocity(state(s), j) * d

        lo, v0 = 0.0, arm.velocity(arm.start(), j) * d
        if v0 < 0.0:
            # It already moves against its slip direction (it broke away on a lagged torque's
            # mean over the step, and the torque of the step's first instants pushes it back):
            # no zero to bracket, it sticks at once.
            lo = -1.0
        elif v0 == 0.0:
            # It broke away at the step start: it first moves in its breakaway direction, then
            # reverses inside the step. The zero at s = 0 is not the crossing (taking it would
            # stop the clock with the arm frozen); bracket the later zero.
            lo = dt
            for _ in range(60):
                lo *= 0.5
                if velocity(lo) > 0:
                    break
            else:
                lo = -1.0
        if lo < 0:
            s = 0.0  # no motion at all: it sticks at once
        elif velocity(dt) >= 0:
            s = dt  # |q̇_j| at the step's end is at round-off: the crossing is the end
        else:
            s = brent_zero(velocity, lo, dt, ZERO_VELOCITY * dt)
        if s < best_s or best_joint < 0:
            best_s, best_joint = s, int(j)
    return best_s, best_joint, state(best_s) if best_s > 0 else arm.start()


def step(arm: StickSlipArm, dt: float, first: End | None = None) -> None:
    """Advance ``arm`` by dt (module docstring): the breakaway test, an RK4 step in the stick
    mode, cut where a sliding joint's velocity reaches zero; that joint sticks and the rest of
    the step is integrated in the new mode. ``first``: the flow map at dt, already taken (the
    breakaway test already made), by a backend's fast path that stopped at this step."""
    remaining = dt
    for event in range(MAX_EVENTS_PER_STEP):
        if event and remaining <= MIN_STEP_S:  # the rest after a stick event: nothing left
            return
        if first is None:
            arm.hold_torque(remaining)
            if arm.any_stuck():
                release_stuck_joints(arm)
            end = arm.flow(remaining)
        else:
            end, first = first, None
        crossed = arm.crossed(end)
        used, joint = remaining, -1
        if crossed:
            used, joint, end = arm.locate(remaining, crossed, end)
        arm.commit(end, used)
        arm.t += used
        arm.steps += 1
        remaining -= used
        if joint < 0:
            return
        before = arm.energy_J()
        arm.rest(joint)
        arm.dissipate(before - arm.energy_J())
        arm.stuck[joint] = True
        arm.mode_changed()
        arm.stick_events += 1
    # Degenerate chattering (a joint that breaks away and reverses at once, eight times in one
    # step): the joints stay stuck for the rest of the step; keep the clock honest.
    arm.t += remaining


class DelayedCommands(Protocol):
    """A plant's queue of commands on their way to the drives (virtual_robot.effects)."""

    def next_delivery(self) -> float | None: ...


def advance_delayed(arm: Any, delay: DelayedCommands, t_end: float, max_step_s: float) -> None:
    """Integrate ``arm`` to ``t_end`` by :func:`step` in steps of at most ``max_step_s``, cut
    where a delayed command of ``delay`` arrives (``arm.deliver_due()`` hands the arrived one
    to the amplifiers)."""
    while arm.t < t_end - 1e-12:
        arm.deliver_due()
        stop = min(t_end, arm.t + max_step_s)
        arrives = delay.next_delivery()
        if arrives is not None and arm.t < arrives < stop:
            stop = arrives
        arm.step(stop - arm.t)
    arm.deliver_due()
