"""The effect interface and its registry (:mod:`hil.diagnose.effects`).

An effect is a physical way a recording departs from its nominal model θ₀ (the profile's, a
``--params`` file's, or one identified from reference recordings). Against θ₀ the recording's
rows (:mod:`hil.diagnose.columns`: y ≈ Ψ θ, y the filtered torque side) leave the residual
r = y − Ψ θ₀; an effect on joint j (or on the arm) explains part of it as X β with X its
columns (built over the same intervals and through the same filter as Ψ) and β its
coefficients. A nonlinear effect (an encoder offset, a point mass's centre) is linearised at a
point ``at`` and moved there by Gauss–Newton steps (:meth:`Effect.update`), its model change at
``at`` (:meth:`Effect.shift`) taken off r first.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hil.diagnose.columns import RecordingRows, moving_average
from hil.model.protocol import ArmDynamics

REFINE_STEPS = 4  # Gauss–Newton steps of the nonlinear patterns (encoder angle, payload centre)


@dataclass
class Context:
    """What an effect builds its columns from: the rows of the recording(s) judged, the nominal
    model object and its θ₀ (in the model's parameters)."""

    rows: list[RecordingRows]
    model: ArmDynamics
    theta0: np.ndarray
    Psi_raw: np.ndarray  # (K, n, p), the stacked nominal design
    # the nominal model's torque rows (K, n): Ψ θ₀ with the nominal model's own departures
    # (:attr:`hil.diagnose.drift.Nominal.terms`); None: Ψ θ₀
    prediction: np.ndarray | None = None
    # the 2-DOF arm's geometry from its profile (link1_m: l1, gravity_m_s2: g; link 2's mass,
    # first moments and inertia about joint 2: hil.diagnose.cli.arm_geometry), when known
    geometry: dict[str, float] | None = None
    memo: dict = field(default_factory=dict)  # rows an effect rebuilt, kept for its next call

    def predicted(self) -> np.ndarray:
        return self.Psi_raw @ self.theta0 if self.prediction is None else self.prediction

    def rms_torque(self, joint: int) -> float:
        """The RMS of the nominal model's torque on ``joint``'s rows: the scale a size in Nm is
        read against (one floor for a 0.5 Nm pendulum and an 87 Nm arm)."""
        tau = self.predicted()[:, joint]
        return max(float(np.sqrt(np.mean(tau[np.isfinite(tau)] ** 2))), 1e-12)

    @property
    def n_joints(self) -> int:
        return self.Psi_raw.shape[1]

    def driven(self) -> list[int]:
        """Joints whose recorded torque is not zero on every row: an unactuated joint (DFKI
        design C.0's second joint records τ = 0) has no torque a gain could scale."""
        return [j for j in range(self.n_joints) if any(np.any(r.tau[:, j] != 0) for r in self.rows)]

    @property
    def closed_form(self) -> bool:
        """The 2-DOF closed-form model (no Pinocchio body parameters)."""
        return not hasattr(self.model, "n_body_params")

    def stack(self, build) -> np.ndarray:
        """``build(rows)`` of every recording, stacked as the design is."""
        return np.concatenate([build(r) for r in self.rows])

    def filtered(self, build) -> np.ndarray:
        """F of per-interval values ``build(rows)`` (K, n, ...), as Ψ and y are filtered."""
        return self.stack(lambda r: moving_average(build(r), r.window))


@dataclass
class SimInput:
    """What an effect changes in the open-loop simulation of the nominal model: θ (``dtheta``
    added), the torque reaching the shaft (``gain``: τ_shaft = g τ on a joint; ``offset``:
    + c Nm), the encoder (``angle``: reading = true angle + δ)."""

    dtheta: np.ndarray | None = None
    gain: dict[int, float] = field(default_factory=dict)
    offset: dict[int, float] = field(default_factory=dict)
    angle: dict[int, float] = field(default_factory=dict)


class Effect:
    """One drift pattern. Subclasses set the class attributes and the methods they need."""

    name: str = ""
    width: int = 1
    partners: tuple[str, ...] = ()  # effects it may be confounded with
    separate: str = ""  # the experiment that tells it from those partners
    nonlinear: bool = False
    # tested as a finding of its own (False: only as the partner a finding is confounded with)
    primary: bool = True
    # kept in a nominal model identified from reference recordings when they show it: only a
    # departure θ cannot take up (a gain, a friction level, a mass are θ's own business there)
    in_reference: bool = False
    # the smallest size worth naming, in the unit of :meth:`estimate`'s size (:meth:`smallest`)
    floor: float = 0.0
    # the size is in Nm and :attr:`floor` a fraction of the joint's RMS torque: an absolute Nm
    # floor names a 2 % offset on an 87 Nm joint and refuses a 10 % one on a 0.2 Nm joint
    floor_of_torque: bool = False
    # a Gauss–Newton step of the linearisation point smaller than this is converged (its unit)
    step_tolerance: float = 0.0
    # its size is an amplitude of several coefficients (no sign): a change since the reference
    # is the size of the coefficients' difference, not the difference of two sizes
    sized_by_amplitude: bool = False
    # its coefficients are tested for a change together (Hotelling's T² of their change): its
    # size is one coefficient beside the Gauss–Newton step's, whose trade-off inflates the size's
    # own SE (a C.0 payload's change: 3.8 SE in its mass, 13.6 jointly)
    tested_jointly: bool = False
    # on a recording that reruns the reference's motion, its model change on the recording's
    # side alone is that of the paired difference r_rec − r_ref (:meth:`hil.diagnose.drift.fit.
    # Fit.judged_rows`): a change between the two recorded torques themselves (a delay: the
    # recording's torque is the reference's shifted, and the same shift on both sides keeps it
    # between them), so its point is stepped on the paired difference; False: a change of the
    # model's input (an encoder angle), taken off both sides alike at the same point
    shifts_recorded_torque: bool = False
    # what would show it where no torque of the recordings changes with it (its columns are
    # round-off: :func:`hil.diagnose.drift.select.unseen`), said in the report
    when_unseen: str = ""

    def applies(self, ctx: Context) -> bool:
        return True

    def variants(self, ctx: Context) -> list[int | None]:
        """Joints (0-based) the effect is tested on; None: one variant for the arm."""
        return list(range(ctx.n_joints))

    def acts_on(self, ctx: Context, joint: int | None) -> list[int]:
        """The joints whose rows its columns reach (its held-out error is judged there)."""
        return list(range(ctx.n_joints)) if joint is None else [joint]

    def start(self, ctx: Context, joint: int | None) -> Any:
        """The linearisation point before any fit (nonlinear effects)."""
        return None

    def starts(self, ctx: Context, joint: int | None) -> list[Any]:
        """Linearisation points the Gauss–Newton steps start from (nonlinear effects whose fit
        has more than one stationary point); the one that fits best is kept."""
        return [self.start(ctx, joint)]

    def point_columns(self, ctx: Context, cols: np.ndarray) -> np.ndarray:
        """Of its columns at a linearisation point, those of the pattern at that very point:
        without the columns of the Gauss–Newton step, which can fit what no point of the
        pattern fits. Starting points (:meth:`starts`) are compared by these. All of them
        when the columns are exact at every point (a cogging's periods, an asymmetry's
        direction)."""
        return cols

    def change_point(self, ctx: Context, joint: int | None, at: Any) -> Any:
        """Where a change since the reference, the difference of the coefficients fitted on
        both sides at ``at``, is read: the starting point where β is an increment of the
        point (an encoder angle), ``at`` where β holds the size itself."""
        return self.start(ctx, joint)

    def paired_columns(
        self, ctx: Context, joint: int | None, at: Any, recorded: np.ndarray
    ) -> np.ndarray | None:
        """X (K, n, width) of the paired difference r_rec − r_ref when the recording reruns the
        reference's motion (``recorded``: the reference's recorded torque (K, n) on the same
        rows), where a pattern that scales the recorded torque is exact in it; None: its
        :meth:`columns`, the same on both sides for a pattern of the motion alone."""
        return None

    def unresolvable(self, ctx: Context, joint: int | None, at: Any) -> str | None:
        """Why the rows cannot resolve the pattern at the point ``at`` at all (what their own
        filter leaves of it is too little to size it by), None when they can: its size would
        be read from a remnant scaled up, so it is no finding whatever its SE."""
        return None

    def smallest(self, ctx: Context, joint: int | None) -> float:
        """The smallest size worth naming, in the size's units: :attr:`floor`, or that fraction
        of the joint's RMS torque where :attr:`floor_of_torque` (a size in Nm)."""
        if self.floor_of_torque and joint is not None:
            return self.floor * ctx.rms_torque(joint)
        return self.floor

    def settled(self, at: Any, new: Any) -> bool:
        """Whether a Gauss–Newton step from ``at`` to ``new`` is below :attr:`step_tolerance`
        (0: only no step at all, a cogging's periods, an asymmetry's direction)."""
        step = np.abs(np.asarray(new, dtype=float) - np.asarray(at, dtype=float))
        return bool(np.all(step <= self.step_tolerance))

    def change(
        self, beta: np.ndarray, beta_back: np.ndarray, se: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The coefficients of the change since the reference from ``beta`` (the recording's)
        and ``beta_back`` (the same term's on the reference rows), and the change's standard
        error from ``se``, that of ``beta − beta_back``. By default the difference: an additive
        pattern's shared misfit adds the same to both sides."""
        return beta - beta_back, se

    def opposed(
        self, forward: dict[str, Any], back: dict[str, Any], size: float, size_back: float
    ) -> bool:
        """Whether the reverse comparison (the reference judged against the recording's θ,
        :func:`hil.diagnose.drift.judge.reverse_check`) shows the change with the opposite sign, as
        a real change does: ``forward`` / ``back`` the two :meth:`estimate` dicts, ``size`` /
        ``size_back`` their sizes. By default the signs of the sizes."""
        return size * size_back < 0

    def columns(self, ctx: Context, joint: int | None, at: Any) -> np.ndarray:
        """X (K, n, width) in Nm per unit coefficient."""
        raise NotImplementedError

    def shift(self, ctx: Context, joint: int | None, at: Any) -> np.ndarray | None:
        """The model's change (K, n) Nm at the linearisation point ``at`` (nonlinear effects)."""
        return None

    def update(self, ctx: Context, joint: int | None, beta: np.ndarray, at: Any) -> Any:
        """The next linearisation point after a fit gave ``beta`` at ``at``."""
        return at

    def estimate(
        self, ctx: Context, joint: int | None, beta: np.ndarray, se: np.ndarray, at: Any
    ) -> tuple[dict[str, Any], float, float]:
        """The finding's numbers, and its size with the standard error of that size."""
        raise NotImplementedError

    def words(self, estimate: dict[str, Any]) -> str:
        raise NotImplementedError

    def simulation(self, ctx: Context, joint: int | None, estimate: dict[str, Any]) -> SimInput:
        """How the simulation takes it; an effect that does not override this is not
        simulated (:meth:`simulated`)."""
        return SimInput()

    def simulated(self) -> bool:
        """Whether the open-loop simulation takes it (it overrides :meth:`simulation`)."""
        return type(self).simulation is not Effect.simulation

    def unphysical(
        self, ctx: Context, joint: int | None, estimate: dict[str, Any], source: str
    ) -> str | None:
        """Why the nominal model (from ``source``: "profile", "params" or "reference") with
        this pattern at ``estimate`` describes no physical arm, in words; None when it may.
        For what θ alone cannot show: a Δθ (:meth:`simulation`) is checked by the model's
        ``physical_consistency`` when it is simulated."""
        return None


REGISTRY: dict[str, Effect] = {}


def register(effect: Effect) -> Effect:
    """Add ``effect`` to the registry (by its name; a name registered again replaces it)."""
    if not effect.name:
        raise ValueError("an effect needs a name")
    REGISTRY[effect.name] = effect
    return effect


def on_joint(column: np.ndarray, joint: int, n_joints: int) -> np.ndarray:
    """(K, w) columns of one joint's rows → (K, n, w), zero on the other joints."""
    out = np.zeros((column.shape[0], n_joints, column.shape[1]))
    out[:, joint, :] = column
    return out
