"""The n-joint virtual arm of a URDF robot profile: Pinocchio's rigid-body dynamics plus, per
joint, the stick–slip friction of the 2-DOF plant (:mod:`virtual_robot.plant`), and the offline
simulation that writes an n-joint recording (``virtual-robot simulate --robot cicese3``).

This module is longer than 800 lines because it is one plant: its Pinocchio dynamics, the
locked-joint models of its stuck joints, the bridge to its compiled step (which must match the
Python step bit for bit, so both sit side by side) and its offline simulation.

Integration is fixed-step RK4 (default 0.5 ms) on (q, q̇), with the supplied work ∫τᵀq̇ dt and
the friction work ∫fᵀq̇ dt kept as in the 2-DOF plant, so the energy balance
E(t) − E(0) = W_in − W_f can be checked on this plant too (τ and the Coulomb levels are constant
between bookings, so their work is τᵀΔq and levelᵀΔq exactly; the viscous part is the RK4
quadrature of bᵀq̇²).

Friction per joint i is Karnopp's stick–slip, by the one stick–slip step of the virtual robot
(:mod:`virtual_robot.stick_slip`: the breakaway test, the located stick events), of which this
plant is the Pinocchio backend (its ``StickSlipArm`` methods) and the 2-DOF plant
(:mod:`virtual_robot.plant`) the closed-form one:
  * sliding, f_i = b_i q̇_i + F_i(dir) dir, with the direction fixed over a step (each RK4 step
    integrates a smooth ODE); when q̇_i changes sign inside a step, the step is cut where q̇_i = 0
    (Brent's method on the RK4 flow map, to ~1e-12 of the step) and the joint sticks;
  * stuck, q̈_i = 0 and f_i is the constraint torque that holds it, from the constrained
    dynamics M_FF q̈_F = (τ − C q̇ − g − f)_F, f_S = (τ − C q̇ − g)_S − M_SF q̈_F (F sliding,
    S stuck joints, :meth:`UrdfPlant.holding_torques`); it breaks away when f_S leaves the
    static band (:func:`virtual_robot.stick_slip.release_stuck_joints`).
With every joint sliding (the common case) the accelerations are Pinocchio's ABA
(Featherstone (2008) ch. 7) of τ − f; with joints stuck, the ABA of the arm with those joints
locked where they stand (Pinocchio's reduced model: q̈_F = M_FF⁻¹ r_F exactly, since q_S and
q̇_S = 0 do not change while they stick), and the holding torques f_S from one RNEA.

Speed (issue 14; ``python tests/benchmarks/bench_urdf.py --only-simulate``): the steps of a
control period run in C++ when the compiled step builds (:mod:`virtual_robot.compiled_step`,
``rk4_aba.cpp``): the same RK4 (:func:`_rk4_aba`), the same locked-joint models (one per
stuck set, its placements and inertias recomputed for a new q_S by buildReducedModel's own
expressions) and breakaway test, around Pinocchio's C++ ABA and RNEA, in one call per period
and stick mode, returning at a velocity crossing or a breakaway, which the stick–slip step
handles as before (its single steps, accelerations and the located stick, by scipy's brentq
ported, also come from the kernel then); bit-identical to the Python step, which runs when the
kernel cannot be built or ``DDBENCH_PLANT_KERNEL=python``. The offline simulation's held
rows (:meth:`UrdfPlant.advance_periods`) give the kernel many control periods per call, each
with its own torque, and the kernel handles their stick events and breakaways itself, by
the stick–slip step's sequence of operations, until a joint is beyond its drive's overspeed
threshold.

Concealed effects (an effects profile, docs/effects.md) per joint, by the 2-DOF plant's equations
(:mod:`virtual_robot.effects`) and in the same places: the torque path (transport delay, amplifier
lag as its mean over each step, gain and offset errors) sets the shaft torque held over a step;
the encoder offset acts on ``measured_q``; the Coulomb override and Stribeck's breakaway set the
friction levels and static bands; cogging τ_cog(q), Stribeck F(|q̇|) and the drag c q̇² change
within a step, so with any of them the step is :func:`_rk4_effects` (the forces evaluated at
every RK4 stage), not the sliding fast path. A payload is refused (it is a body of the URDF).
Energy: the work of the cogging torques is booked exactly (they are conservative), the friction
beyond the Coulomb levels by RK4 quadrature, so E(t) − E(0) = W_in − W_f holds with effects.

The world builds its own Pinocchio model from the URDF file; it never imports the host's
(``hil``) model, and the host never reads the effects profile.
Imports profiles, drivers (recording, units), virtual_robot.plant/drive/offline/effects/
compiled_step/stick_slip.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin

from profiles.drive import load_drive
from profiles.effects import EffectsProfile
from profiles.experiment import ExperimentProfile
from profiles.robot import UrdfRobotProfile
from virtual_robot.compiled_step import (
    BREAKS,
    CROSSED,
    CompiledArm,
    KernelStatus,
    KernelUnavailableError,
    kernel_status,
)
from virtual_robot.effects import (
    TransportDelay,
    amplifier_lag_step,
    cogging_torque,
    cogging_work,
    gain_offset,
    plant_effect_params,
    stribeck_level,
    velocity_squared_drag,
)
from virtual_robot.offline import (
    SimulationResult,
    drive_meta,
    enable_drives,
    offline_rows,
    run_open_loop,
    simulation_meta,
)
from virtual_robot.plant import DEFAULT_STEP_S
from virtual_robot.stick_slip import advance_delayed, locate_stick
from virtual_robot.stick_slip import step as stick_slip_step

# Locked-joint models (UrdfPlant._locked_arm) kept for reuse.
LOCKED_ARMS_KEPT = 16


@dataclass(frozen=True)
class UrdfPlantParams:
    """What the n-joint plant integrates: the URDF's bodies; per joint, friction and armature;
    and the concealed effects, named as :class:`virtual_robot.plant.PlantParams` names them
    (``()``: none on any joint)."""

    urdf: str
    gravity_m_s2: float
    viscous_Nms: tuple[float, ...]
    coulomb_positive_Nm: tuple[float, ...]
    coulomb_negative_Nm: tuple[float, ...]
    armature_kgm2: tuple[float, ...]
    breakaway_positive_Nm: tuple[float, ...] = ()  # static band; () = the Coulomb level
    breakaway_negative_Nm: tuple[float, ...] = ()
    stribeck_velocity_rad_s: tuple[float, ...] = ()
    stribeck_exponent: float = 2.0
    cogging_periods_per_rev: tuple[float, ...] = ()
    cogging_amplitude_Nm: tuple[float, ...] = ()
    cogging_phase_rad: tuple[float, ...] = ()
    amplifier_lag_s: tuple[float, ...] = ()
    transport_delay_s: float = 0.0
    torque_gain_error: tuple[float, ...] = ()
    torque_offset_Nm: tuple[float, ...] = ()
    encoder_offset_rad: tuple[float, ...] = ()
    drag_Nms2: tuple[float, ...] = ()  # velocity-squared drag coefficient c per joint

    @classmethod
    def from_profile(
        cls, robot: UrdfRobotProfile, effects: EffectsProfile | None = None
    ) -> UrdfPlantParams:
        """The arm of ``robot`` with the concealed ``effects`` (fitted to its joints: an array
        of the wrong length is a one-line ProfileError). A payload is refused in one line: on
        an n-joint arm it is a body of the URDF, not an effect."""
        effects = (effects or EffectsProfile()).for_joints(robot.n_joints, robot.name)
        if effects.payload is not None:
            raise ValueError(
                f"effects {effects.name} (payload): the n-joint plant ({robot.name}) takes no "
                "payload effect; add the payload as a body of its URDF"
            )
        return cls(
            urdf=robot.urdf,
            gravity_m_s2=robot.gravity_m_s2,
            viscous_Nms=robot.viscous_Nms,
            armature_kgm2=robot.armature_kgm2,
            **plant_effect_params(effects, robot.coulomb_positive_Nm, robot.coulomb_negative_Nm),
        )


class UrdfPlant:
    """Fixed-step simulation of an n-joint arm under a zero-order-held torque command.

    ``command(τ)`` sets the joint torques, ``advance_to(t)`` integrates to time t; the state is
    ``q``/``dq`` (numpy arrays, n), ``measured_q`` what the encoders see (with the
    encoder-offset effect).
    """

    def __init__(
        self,
        params: UrdfPlantParams,
        q0: Sequence[float] | None = None,
        dq0: Sequence[float] | None = None,
        t0: float = 0.0,
        max_step_s: float = DEFAULT_STEP_S,
    ) -> None:
        if not max_step_s > 0:
            raise ValueError("max_step_s must be > 0")
        model = pin.buildModelFromUrdf(params.urdf)
        joints = model.joints[1:]
        # joint i + 1 moves coordinate i (the locked-joint models name joints by that index)
        if any(j.nq != 1 or j.nv != 1 for j in joints) or [j.idx_v for j in joints] != list(
            range(model.nv)
        ):
            raise ValueError(f"{params.urdf}: only 1-DOF revolute/prismatic joints are supported")
        n = model.nv
        if len(params.viscous_Nms) != n:
            raise ValueError(
                f"{params.urdf}: {n} joints, friction given for {len(params.viscous_Nms)}"
            )
        model.gravity.linear = np.array([0.0, 0.0, -params.gravity_m_s2])
        model.armature = np.asarray(params.armature_kgm2, dtype=float)  # gr² I_rotor per joint
        self.model, self.data = model, model.createData()
        self.params = params
        self.n_joints = n
        self.max_step_s = max_step_s
        self.t = t0
        self.q = np.zeros(n) if q0 is None else np.array(q0, dtype=float)
        self.dq = np.zeros(n) if dq0 is None else np.array(dq0, dtype=float)
        if self.q.shape != (n,) or self.dq.shape != (n,):
            raise ValueError(f"initial state: need {n} values per joint vector")
        self.b = np.asarray(params.viscous_Nms, dtype=float)
        self._viscous = bool(self.b.any())  # without viscous friction its terms are skipped
        self.coulomb_pos = np.asarray(params.coulomb_positive_Nm, dtype=float)
        self.coulomb_neg = np.asarray(params.coulomb_negative_Nm, dtype=float)
        # the static band: the breakaway level with Stribeck friction, else the Coulomb level
        self.band_pos = np.asarray(params.breakaway_positive_Nm or self.coulomb_pos, dtype=float)
        self.band_neg = np.asarray(params.breakaway_negative_Nm or self.coulomb_neg, dtype=float)
        self._init_effects(params)
        # A joint without Coulomb friction never sticks: its dynamics are smooth.
        self.sticky = np.maximum(self.band_pos, self.band_neg) > 0
        self.stuck = self.sticky & (self.dq == 0.0)
        self.slip_dir = np.where(self.dq >= 0, 1.0, -1.0)
        self.command_Nm = np.zeros(n)  # the shaft torque (amplifier output, powered joints)
        self._held_Nm = np.zeros(n)  # the last command delivered, before the amplifiers
        self._powered = np.ones(n, dtype=bool)
        self._all_powered = True
        self._powered_given: tuple[bool, ...] = (True,) * n  # as set_powered was last given it
        # Energy bookkeeping (work_in_J, dissipated_J): with τ held over a command and the
        # Coulomb levels fixed over a stick mode, ∫τᵀq̇ dt = τᵀΔq and ∫levelᵀq̇ dt = levelᵀΔq
        # exactly, so both are booked when τ or the mode changes, from the q of the last booking;
        # the viscous part ∫bᵀq̇² dt (RK4 quadrature) and stick clamping losses per step.
        self._level = np.zeros(n)
        self._locked_arms: dict[tuple[bytes, bytes], tuple[Any, Any]] = {}
        self._booked_q = self.q
        self._work_booked = 0.0
        self._dissipated_booked = 0.0
        self.mode_changed()
        self.steps = 0
        self.stick_events = 0
        # The sliding-path RK4 substeps in C++ when the compiled step builds (compiled_step.py)
        self._compiled: CompiledArm | None = None
        self.kernel: KernelStatus = kernel_status()
        if self.kernel.kernel == "compiled" and (self._in_derivative or self._lag is not None):
            # the kernel holds τ − f_c over a step; these effects change it within one
            self.kernel = KernelStatus(
                "python", "cogging, Stribeck, drag or an amplifier lag act within a step"
            )
        if self.kernel.kernel == "compiled":
            try:
                self._compiled = CompiledArm(params.urdf, params.gravity_m_s2, params.armature_kgm2)
            except KernelUnavailableError as exc:
                self.kernel = KernelStatus("python", str(exc))
            else:  # for the stick events of advance_periods, which the kernel handles itself
                self._compiled.set_friction(
                    self.sticky,
                    (self.coulomb_pos, self.coulomb_neg),
                    (self.band_pos, self.band_neg),
                )

    # ---- inputs and outputs -----------------------------------------------------------------
    def command(
        self,
        torque_Nm: Sequence[float],
        issued_at: float | None = None,
        powered: Sequence[bool] | None = None,
        deliver_at: float | None = None,
    ) -> None:
        """Joint torques from now on (issued at ``issued_at``, default now: with the transport
        delay effect they reach the amplifiers that much later); an unpowered joint's amplifier
        gives none, from now. ``deliver_at``: the command reaches the drives at this time, not
        at ``issued_at`` (an injected timing fault or a replayed timing trace,
        virtual_robot.timing_faults); the transport-delay effect, if any, runs from there, as in
        the 2-DOF plant's :meth:`~virtual_robot.plant.Plant.command` (the same queue). The
        signature is the 2-DOF plant's (virtual_robot.stepping.SteppedPlant)."""
        tau = np.array(torque_Nm, dtype=float)
        if tau.shape != (self.n_joints,):
            raise ValueError(f"need {self.n_joints} torques, got {tau.shape}")
        if deliver_at is not None:
            if self._delay is None:  # from now on commands go through the delivery queue
                self._delay = TransportDelay(self.params.transport_delay_s)
            self._delay.push(deliver_at, tuple(tau))
        elif self._delay is not None:
            self._delay.push(self.t if issued_at is None else issued_at, tuple(tau))
        else:
            self._held_Nm = tau  # a new array: nothing else holds it
        self.set_powered(powered if powered is not None else [True] * self.n_joints)

    def set_powered(self, powered: Sequence[bool]) -> None:
        """Switch the amplifiers: an unpowered joint gets no torque, a powered one the held."""
        given = tuple(powered)
        if given != self._powered_given:  # mostly the same as at the last command
            self._powered = np.array(given, dtype=bool)
            self._all_powered = all(given)
            self._powered_given = given
        if self._lag is None:  # with a lag, each step's torque is set where it starts
            self._apply_torque(self._held_Nm)

    def _apply_torque(self, amplifier_Nm: np.ndarray) -> None:
        """The shaft torque from the amplifiers' outputs: their gain and offset errors on the
        powered joints, nothing at all on the unpowered ones (no offset, no lag tail)."""
        tau = amplifier_Nm
        if self._gain_offset is not None:
            tau = gain_offset(tau, *self._gain_offset)
        if not self._all_powered:
            tau = np.where(self._powered, tau, 0.0)
        self._book_work()
        self.command_Nm = tau
        self._tau_minus_level = tau - self._level

    def kernel_summary(self) -> dict[str, str]:
        """Which step integrates the sliding joints, and why not the compiled one (one line)."""
        k = self.kernel
        return {"kernel": k.kernel} | ({"reason": k.reason} if k.reason else {})

    @property
    def measured_q(self) -> np.ndarray:
        """What the encoders see: q plus the encoder-offset effect, if any."""
        return self.q if self._encoder_offset is None else self.q + self._encoder_offset

    @property
    def work_in_J(self) -> float:
        """∫ τᵀ q̇ dt so far (τ the shaft torque, with cogging)."""
        moved = self.q - self._booked_q
        return self._work_booked + float(self.command_Nm @ moved) + self._cogging_work()

    @property
    def dissipated_J(self) -> float:
        """∫ fᵀ q̇ dt so far, plus the kinetic energy lost where a joint is clamped to rest."""
        return self._dissipated_booked + float(self._level @ (self.q - self._booked_q))

    def _book_work(self) -> None:
        """Book τᵀΔq and levelᵀΔq since the last booking, before τ or the levels change."""
        moved = self.q - self._booked_q
        self._work_booked += float(self.command_Nm @ moved) + self._cogging_work()
        self._dissipated_booked += float(self._level @ moved)
        self._booked_q = self.q

    def energy_J(self) -> float:
        """Kinetic plus potential energy (Pinocchio's, potential relative to the URDF's origin)."""
        m, d = self.model, self.data
        kinetic = pin.computeKineticEnergy(m, d, self.q, self.dq)
        return float(kinetic + pin.computePotentialEnergy(m, d, self.q))

    def advance_to(self, t_end: float) -> None:
        """Integrate to ``t_end`` in steps of at most ``max_step_s`` (cut where a delayed
        command arrives, with the transport delay effect); while every joint slides, the
        compiled step takes them when there is one (:meth:`_advance_compiled`)."""
        if self._delay is not None:
            advance_delayed(self, self._delay, t_end, self.max_step_s)
            return
        while self.t < t_end - 1e-12:
            if self._compiled is not None:
                self._advance_compiled(t_end)
            else:
                self.step(min(self.max_step_s, t_end - self.t))

    def _advance_compiled(self, t_end: float) -> None:
        """The steps :meth:`step` would take towards ``t_end``, by the compiled kernel
        (rk4_aba.cpp: :func:`_rk4_aba` in C++ on the same models, the arm's or the locked
        arm's, with Karnopp's test of :func:`~virtual_robot.stick_slip.release_stuck_joints`
        before each step) until t_end or the first step where a watched velocity changes sign
        or a stuck joint breaks away; that step then goes through :meth:`step` (with its RK4
        already taken, or from its start)."""
        compiled = self._compiled
        stuck = None
        if self._n_stuck:
            stuck = (self._compiled_locked(), self.command_Nm, self._band_s)
        q, v, t, dissipated, steps, outcome, crossing = compiled.advance(
            self.q,
            self.dq,
            self._tau_minus_level,
            self.b if self._viscous else None,
            self._watch,
            self.t,
            t_end,
            self.max_step_s,
            self._dissipated_booked,
            stuck,
        )
        self.q, self.dq, self.t, self._dissipated_booked = q, v, t, dissipated
        self.steps += steps
        if outcome == CROSSED:
            self.step(*crossing)
        elif outcome == BREAKS:
            self.step(min(self.max_step_s, t_end - self.t))

    def advance_periods(
        self,
        torques: np.ndarray,
        n0: int,
        period_s: float,
        bounds: tuple[np.ndarray, np.ndarray],
        q_out: np.ndarray,
        dq_out: np.ndarray,
    ) -> tuple[int, bool]:
        """Control periods one after another, by the compiled kernel: before period j the
        command ``torques[j]`` (every amplifier powered), then :meth:`advance_to` of
        (n0 + j) · period_s, its end state into q_out[j], dq_out[j]; all of them in one kernel
        call (ddb_run_periods), which handles the stick events and breakaways as
        :func:`virtual_robot.stick_slip.step` and its breakaway test do, by the same
        operations (the energy books to round-off: its sums run in joint order). Stops after the
        first period that ends with some |q̇_i| > bounds[0]_i or |q_i| > bounds[1]_i
        (or a NaN). Returns (periods integrated, whether the last ended inside the bounds);
        (0, True) at once when the kernel is not running or an effect acts on the command or
        the encoders (the caller then commands each period itself). ``torques``, q_out,
        dq_out: C-contiguous rows."""
        if (
            self._compiled is None
            or self._delay is not None
            or self._lag is not None
            or self._gain_offset is not None
            or self._encoder_offset is not None
            or not self._all_powered
            or not len(torques)
        ):
            return 0, True
        inside, stop, state, counts = self._compiled.run_periods(
            self.q, self.dq, self.b if self._viscous else None, self.stuck, self.slip_dir,
            self.command_Nm, self._booked_q, torques, n0, period_s, self.max_step_s, bounds,
            (self.t, self._dissipated_booked, self._work_booked), q_out, dq_out,
        )  # fmt: skip
        self.q, self.dq, stuck, slip_dir, self._booked_q = state
        self.t, self._dissipated_booked, self._work_booked, steps, events, modes = counts
        self.steps += steps
        self.stick_events += events
        # the command of the period it stopped in, as command() leaves it
        tau = torques[stop if stop < len(torques) else -1].copy()
        self._held_Nm = self.command_Nm = tau
        if modes:  # the kernel's stick mode, already booked there
            self.stuck, self.slip_dir = stuck != 0.0, slip_dir
            self._set_mode()
        else:
            self._tau_minus_level = tau - self._level
        return (len(torques), True) if inside else (stop + 1, False)

    # ---- dynamics -----------------------------------------------------------------------------
    def _set_mode(self) -> None:
        """The stick mode's constants (:meth:`mode_changed` after its booking): the signed
        Coulomb level per joint (direction frozen until the next change), which velocities to
        watch for a sign change, and the index sets of the constrained dynamics (sliding F,
        stuck S)."""
        self._level = self.slip_dir * np.where(
            self.slip_dir > 0, self.coulomb_pos, self.coulomb_neg
        )
        self._tau_minus_level = self.command_Nm - self._level
        self._watch = np.where(self.sticky & ~self.stuck, self.slip_dir, 0.0)
        self._n_stuck = int(self.stuck.sum())
        self._free, self._stuck_idx = np.flatnonzero(~self.stuck), np.flatnonzero(self.stuck)
        # the stuck joints' static bands [−band_neg, band_pos] (Karnopp's test)
        self._band_s = self.band_pos[self._stuck_idx], -self.band_neg[self._stuck_idx]
        self._reduced = None  # built when first needed (:meth:`_locked_arm`)
        self._locked_handle: int | None = None  # looked up when first needed (_compiled_locked)
        if self._in_derivative:
            self._mode_forces()

    def _compiled_locked(self) -> int | None:
        """The compiled kernel's arm of the current stick mode: None with every joint sliding,
        else its handle of the arm with the stuck joints locked where they stand, looked up
        once per mode (q_S does not change while the joints stick), as :meth:`_locked_arm`."""
        if not self._n_stuck:
            return None
        if self._locked_handle is None:
            self._locked_handle = self._compiled.locked(self._stuck_idx, self.q)
        return self._locked_handle

    def _locked_arm(self) -> tuple[Any, Any] | None:
        """The arm with the stuck joints locked where they stand (Pinocchio's reduced model and
        its data; None when every joint is stuck): its ABA gives the sliding joints'
        accelerations M_FF⁻¹ r_F. Kept for the last few stuck sets and positions, since one joint
        often stays stuck while another sticks and breaks away."""
        if self._reduced is None and self._free.size:
            stuck = self._stuck_idx
            key = (stuck.tobytes(), self.q[stuck].tobytes())
            self._reduced = self._locked_arms.get(key)
            if self._reduced is None:
                reduced = pin.buildReducedModel(self.model, [int(j) + 1 for j in stuck], self.q)
                reduced.armature = self.model.armature[self._free]
                if len(self._locked_arms) >= LOCKED_ARMS_KEPT:
                    self._locked_arms.pop(next(iter(self._locked_arms)))
                self._reduced = self._locked_arms[key] = reduced, reduced.createData()
        return self._reduced

    def _accelerations(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """q̈ at (q, q̇) in the current stick mode under the held command, friction levels frozen:
        the arm's ABA of τ − f with every joint sliding; with some stuck, q̈_S = 0 and q̈_F from
        M_FF q̈_F = (τ − C q̇ − g − f)_F, the ABA of the arm with those joints locked (q_S and
        q̇_S = 0 do not change while they stick); the derivative :func:`_rk4_aba` integrates
        (with cogging, Stribeck or drag, the forces of :meth:`_state_forces`)."""
        if self._compiled is not None:  # the same in C++ (rk4_aba.cpp)
            b = self.b if self._viscous else None
            return self._compiled.accelerations(
                self._compiled_locked(), q, v, self._tau_minus_level, b
            )
        c = self._tau_minus_level - self.b * v if self._viscous else self._tau_minus_level
        if self._in_derivative:
            c = np.zeros(self.n_joints)
            c[self._free] = self._state_forces(q[self._free], v[self._free])[0]
        if not self._n_stuck:
            return pin.aba(self.model, self.data, q, v, c)
        a = np.zeros(self.n_joints)
        locked = self._locked_arm()
        if locked is not None:
            free = self._free
            a[free] = pin.aba(*locked, q[free], v[free], c[free])
        return a

    def _rk4_mode(self, dt: float) -> tuple[np.ndarray, np.ndarray, float]:
        """One RK4 step of dt in the current stick mode under the held command, by
        :func:`_rk4_aba`: every joint sliding, the arm's ABA; some stuck, the ABA of the arm
        with those locked (q_S and q̇_S = 0 stay as they are); all stuck, no motion.
        Returns (q, q̇, ∫bᵀq̇² dt). tests/test_urdf_plant.py checks it against a textbook RK4
        on the constrained dynamics by CRBA and RNEA. With an amplifier lag, the torque is its
        mean over dt (:meth:`_apply_lag`); with cogging, Stribeck or drag, the forces depend on
        the state within the step (:func:`_rk4_effects`, and the third value is ∫(f − F_c)ᵀq̇
        dt: the friction work beyond the Coulomb levels booked apart)."""
        if self._lag is not None:
            self._apply_lag(dt)
        b = self.b if self._viscous else None
        if self._compiled is not None:  # the same in C++ (rk4_aba.cpp)
            return self._compiled.step(
                self._compiled_locked(), self.q, self.dq, self._tau_minus_level, b, dt
            )
        if not self._n_stuck:
            if self._in_derivative:
                return _rk4_effects(self.model, self.data, self.q, self.dq, self._state_forces, dt)
            return _rk4_aba(self.model, self.data, self.q, self.dq, self._tau_minus_level, b, dt)
        locked = self._locked_arm()
        if locked is None:
            return self.q, self.dq, 0.0
        free = self._free
        if self._in_derivative:
            q_f, v_f, viscous = _rk4_effects(
                *locked, self.q[free], self.dq[free], self._state_forces, dt
            )
        else:
            q_f, v_f, viscous = _rk4_aba(
                *locked,
                self.q[free],
                self.dq[free],
                self._tau_minus_level[free],
                None if b is None else b[free],
                dt,
            )
        q, v = self.q.copy(), self.dq.copy()
        q[free], v[free] = q_f, v_f
        return q, v, viscous

    # ---- the stick-slip step's backend (virtual_robot.stick_slip.StickSlipArm) ---------------
    def step(self, dt: float, first: tuple[np.ndarray, np.ndarray, float] | None = None) -> None:
        """Advance dt (:func:`virtual_robot.stick_slip.step`: stick events located);
        ``first``: the step's RK4 in the current mode, already taken (stuck joints already
        checked for breakaway), by the compiled kernel."""
        stick_slip_step(self, dt, first)

    @property
    def band_positive(self) -> np.ndarray:
        return self.band_pos

    @property
    def band_negative(self) -> np.ndarray:
        return self.band_neg

    def any_stuck(self) -> bool:
        return self._n_stuck > 0

    def hold_torque(self, dt: float) -> None:
        """With an amplifier lag, its mean over the step (:meth:`_apply_lag`)."""
        if self._lag is not None:
            self._apply_lag(dt)

    def flow(self, s: float) -> tuple[np.ndarray, np.ndarray, float]:
        return self._rk4_mode(s)

    def start(self) -> tuple[np.ndarray, np.ndarray, float]:
        return self.q, self.dq, 0.0

    def velocity(self, end: tuple[np.ndarray, np.ndarray, float], joint: int) -> float:
        return end[1][joint]

    def crossed(self, end: tuple[np.ndarray, np.ndarray, float]) -> Sequence[int]:
        """The sliding sticky joints whose velocity changed sign (``_watch``: their slip
        directions, zero for the others)."""
        turned = end[1] * self._watch
        return () if turned.min() >= 0.0 else np.flatnonzero(turned < 0.0).tolist()

    def locate(
        self, dt: float, crossed: Sequence[int], end: tuple[np.ndarray, np.ndarray, float]
    ) -> tuple[float, int, tuple[np.ndarray, np.ndarray, float]]:
        """:func:`virtual_robot.stick_slip.locate_stick`; with the compiled step, the same in
        the kernel (rk4_aba.cpp, ddb_locate: scipy's brentq ported operation for operation, so
        the same root to the last bit). Without an amplifier lag the flow map is a pure
        function of s (a lag's mean torque is set as a side effect: recomputed)."""
        if self._compiled is not None:
            mask = np.zeros(self.n_joints, dtype=bool)
            mask[np.asarray(crossed, dtype=int)] = True
            b = self.b if self._viscous else None
            return self._compiled.locate(
                self._compiled_locked(), self.q, self.dq, self._tau_minus_level, b,
                self.slip_dir, mask, end[1], dt,
            )  # fmt: skip
        return locate_stick(self, dt, crossed, end, memo=self._lag is None)

    def commit(self, end: tuple[np.ndarray, np.ndarray, float], s: float) -> None:
        self.q, self.dq, viscous = end
        self._dissipated_booked += viscous
        if self._lag is not None and s > 0.0:  # (a stick at s = 0: no time passed, the lag stays)
            self._advance_lag(s)

    def holding_torques(self) -> np.ndarray:
        """f_S = (τ − C q̇ − g)_S − M_SF q̈_F = (τ − RNEA(q, q̇, q̈))_S, the friction that keeps
        the stuck joints at rest (q̈_S = 0); zero on the sliding joints."""
        q, dq, tau, stuck = self.q, self.dq, self.command_Nm, self._stuck_idx
        if self._cogging is not None:
            tau = tau + cogging_torque(q, *self._cogging)
        a = self._accelerations(q, dq)
        held = np.zeros(self.n_joints)
        held[stuck] = tau[stuck] - pin.rnea(self.model, self.data, q, dq, a)[stuck]
        return held

    def rest(self, joint: int) -> None:
        self.dq = self.dq.copy()
        self.dq[joint] = 0.0

    def dissipate(self, energy_J: float) -> None:
        self._dissipated_booked += energy_J

    def mode_changed(self) -> None:
        """After a joint sticks or breaks away: the work so far booked, the new mode's
        constants (:meth:`_set_mode`)."""
        self._book_work()
        self._set_mode()

    # ---- concealed effects (virtual_robot.effects; docs/effects.md) ---------------------------
    def _init_effects(self, p: UrdfPlantParams) -> None:
        """The effects' per-joint arrays; None where an effect is off on every joint."""
        n = self.n_joints

        def per_joint(name: str, values: tuple[float, ...]) -> np.ndarray | None:
            if values and len(values) != n:
                raise ValueError(f"{p.urdf}: {n} joints, {name} given for {len(values)}")
            a = np.asarray(values, dtype=float)
            return a if a.any() else None

        self._lag = per_joint("amplifier_lag_s", p.amplifier_lag_s)
        self._lag_state = np.zeros(n)  # amplifier outputs (the lag's state)
        gain = per_joint("torque_gain_error", p.torque_gain_error)
        offset = per_joint("torque_offset_Nm", p.torque_offset_Nm)
        self._gain_offset = None
        if gain is not None or offset is not None:
            self._gain_offset = (
                np.zeros(n) if gain is None else gain,
                np.zeros(n) if offset is None else offset,
            )
        self._encoder_offset = per_joint("encoder_offset_rad", p.encoder_offset_rad)
        self._drag = per_joint("drag_Nms2", p.drag_Nms2)
        self._stribeck_v = per_joint("stribeck_velocity_rad_s", p.stribeck_velocity_rad_s)
        self._stribeck_exponent = p.stribeck_exponent
        amplitude = per_joint("cogging_amplitude_Nm", p.cogging_amplitude_Nm)
        self._cogging = None
        if amplitude is not None:
            periods = per_joint("cogging_periods_per_rev", p.cogging_periods_per_rev)
            phase = per_joint("cogging_phase_rad", p.cogging_phase_rad)
            self._cogging = (
                np.zeros(n) if periods is None else periods,
                amplitude,
                np.zeros(n) if phase is None else phase,
            )
        self._delay = TransportDelay(p.transport_delay_s) if p.transport_delay_s else None
        # forces that change within a step with q or q̇ (the 2-DOF plant's _deriv has them too)
        self._in_derivative = (
            self._cogging is not None or self._stribeck_v is not None or self._drag is not None
        )

    def deliver_due(self) -> None:
        """The newest delayed command that has arrived reaches the amplifiers."""
        assert self._delay is not None
        due = self._delay.pop_due(self.t)
        if due is not None:
            self._held_Nm = np.array(due, dtype=float)
            if self._lag is None:
                self._apply_torque(self._held_Nm)

    def _apply_lag(self, dt: float) -> None:
        """The shaft torque over the next dt: each amplifier's first-order lag toward the held
        command, its mean over dt (:func:`virtual_robot.effects.amplifier_lag_step`)."""
        assert self._lag is not None
        mean = np.array(
            [
                amplifier_lag_step(x, cmd, dt, tc)[0]
                for x, cmd, tc in zip(self._lag_state, self._held_Nm, self._lag, strict=True)
            ]
        )
        self._apply_torque(mean)

    def _advance_lag(self, dt: float) -> None:
        """The lag's state after a step of dt; an unpowered amplifier discharges to zero."""
        assert self._lag is not None
        end = [
            amplifier_lag_step(x, cmd, dt, tc)[1]
            for x, cmd, tc in zip(self._lag_state, self._held_Nm, self._lag, strict=True)
        ]
        self._lag_state = np.where(self._powered, end, 0.0)

    def _cogging_work(self) -> float:
        """Work of the cogging torques since the last booking (exact: they are conservative)."""
        if self._cogging is None:
            return 0.0
        return cogging_work(self._booked_q, self.q, *self._cogging)

    def _state_forces(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, float]:
        """Generalized forces on the sliding joints at their (q, q̇), with the effects that vary
        within a step: τ + τ_cog(q) − F(|q̇|) dir − b q̇, F the Coulomb level, or the Stribeck
        curve, plus the drag c q̇² (virtual_robot.effects; the 2-DOF plant's _deriv and
        _friction_level). Also the friction power beyond the frozen Coulomb levels,
        (f − F_c dir)ᵀ q̇ (those are booked exactly, as without effects). The per-joint
        constants of the sliding joints are :meth:`_mode_forces`'."""
        free, b, d, coulomb, breakaway, stribeck_v, drag, cogging, frozen = self._sliding_fx
        c = self.command_Nm[free] - b * v
        if cogging is not None:
            c += cogging_torque(q, *cogging)
        speed = np.abs(v)
        level = coulomb
        if stribeck_v is not None:
            level = stribeck_level(coulomb, breakaway, speed, stribeck_v, self._stribeck_exponent)
        if drag is not None:
            level = level + velocity_squared_drag(drag, speed)
        sliding = d * level
        c -= sliding
        return c, float((b * v + sliding - frozen) @ v)

    def _mode_forces(self) -> None:
        """The constants of :meth:`_state_forces` for the sliding joints of this stick mode."""
        f = self._free
        d = self.slip_dir[f]
        forward = d > 0

        def on_free(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[f]

        self._sliding_fx = (
            f,
            self.b[f],
            d,
            np.where(forward, self.coulomb_pos[f], self.coulomb_neg[f]),
            np.where(forward, self.band_pos[f], self.band_neg[f]),
            on_free(self._stribeck_v),
            on_free(self._drag),
            None if self._cogging is None else tuple(a[f] for a in self._cogging),
            self._level[f],
        )


def _rk4_aba(
    model: Any,
    data: Any,
    q: np.ndarray,
    v: np.ndarray,
    tau_minus_level: np.ndarray,
    b: np.ndarray | None,
    dt: float,
) -> tuple[np.ndarray, np.ndarray, float]:
    """One classical RK4 step of dt on (q, q̇) of ``model`` with every joint sliding: the four
    ABA calls (Featherstone (2008) ch. 7) of τ − level − b q̇ and as few array operations as
    that takes (each costs about a tenth of an ABA call); without viscous friction (``b``
    None) its terms are skipped. Also the RK4 quadrature of the viscous dissipation ∫bᵀq̇² dt.
    Returns (q, q̇, ∫bᵀq̇² dt)."""
    aba, c = pin.aba, tau_minus_level
    h2 = 0.5 * dt
    k = dt / 6.0
    if b is not None:
        a1 = aba(model, data, q, v, c - b * v)
        y = v + h2 * a1
        a2 = aba(model, data, q + h2 * v, y, c - b * y)
        z = v + h2 * a2
        a3 = aba(model, data, q + h2 * y, z, c - b * z)
        u = v + dt * a3
        a4 = aba(model, data, q + dt * z, u, c - b * u)
        viscous = k * float(b @ (v * v + 2.0 * (y * y + z * z) + u * u))
    else:
        a1 = aba(model, data, q, v, c)
        y = v + h2 * a1
        a2 = aba(model, data, q + h2 * v, y, c)
        z = v + h2 * a2
        a3 = aba(model, data, q + h2 * y, z, c)
        u = v + dt * a3
        a4 = aba(model, data, q + dt * z, u, c)
        viscous = 0.0
    return (
        q + k * (v + 2.0 * (y + z) + u),
        v + k * (a1 + 2.0 * (a2 + a3) + a4),
        viscous,
    )


def _rk4_effects(
    model: Any,
    data: Any,
    q: np.ndarray,
    v: np.ndarray,
    forces: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, float]],
    dt: float,
) -> tuple[np.ndarray, np.ndarray, float]:
    """One classical RK4 step of dt on (q, q̇) of ``model`` with every joint sliding, the
    generalized forces ``forces(q, q̇)`` (and a power) evaluated at each of the four stages:
    :func:`_rk4_aba` for forces that change within the step (cogging, Stribeck, drag).
    Returns (q, q̇, RK4 quadrature of the power over the step)."""
    aba = pin.aba
    h2 = 0.5 * dt
    k = dt / 6.0
    c, p1 = forces(q, v)
    a1 = aba(model, data, q, v, c)
    y = v + h2 * a1
    c, p2 = forces(q + h2 * v, y)
    a2 = aba(model, data, q + h2 * v, y, c)
    z = v + h2 * a2
    c, p3 = forces(q + h2 * y, z)
    a3 = aba(model, data, q + h2 * y, z, c)
    u = v + dt * a3
    c, p4 = forces(q + dt * z, u)
    a4 = aba(model, data, q + dt * z, u, c)
    return (
        q + k * (v + 2.0 * (y + z) + u),
        v + k * (a1 + 2.0 * (a2 + a3) + a4),
        k * (p1 + 2.0 * (p2 + p3) + p4),
    )


def simulate_urdf(
    robot: UrdfRobotProfile,
    experiment: ExperimentProfile,
    out_dir: str | Path,
    *,
    effects: EffectsProfile | None = None,
    duration_s: float | None = None,
    step_s: float = DEFAULT_STEP_S,
    plot: bool = True,
    progress: Callable[[float, float], None] | None = None,
) -> SimulationResult:
    """Run ``experiment`` open loop on the n-joint arm, with the concealed ``effects``, through
    its n drive models (quantized, clamped, held over each period as in
    :func:`virtual_robot.simulate.simulate`) and write the recording
    ``t, q1..qn, tau1..taun, status1..statusn`` to ``out_dir``."""
    n = robot.n_joints
    experiment.check_joints(n, robot.name)
    if robot.drives is None:
        raise ValueError(f"{robot.source}: [joints] drives: the simulation needs one per joint")
    drives_p = [load_drive(name) for name in robot.drives]
    h, n_rows = offline_rows(experiment, duration_s)
    effects = effects or EffectsProfile()
    plant = UrdfPlant(
        UrdfPlantParams.from_profile(robot, effects),
        q0=experiment.initial_q_rad,
        max_step_s=min(step_s, h),
    )
    drives = enable_drives(drives_p, h, plant.measured_q, plant.dq)
    meta = simulation_meta(
        robot,
        experiment,
        effects,
        period_s=h,
        n_rows=n_rows,
        drives=drive_meta(drives_p),
        about_robot={"urdf": robot.urdf, "n_joints": n},
    )
    meta["integrator"] = {
        "method": "RK4, fixed step, stick-slip events located; Pinocchio ABA/CRBA/RNEA",
        "step_s": plant.max_step_s,
        "kernel": plant.kernel_summary(),
    }
    commanded_Nm = experiment.torque_rows(h, n_rows)
    result = run_open_loop(
        out_dir, meta, plant, drives, drives_p, commanded_Nm, n_rows, plot=plot, progress=progress
    )
    result.plant_kernel = plant.kernel_summary()
    return result


__all__ = ["UrdfPlant", "UrdfPlantParams", "simulate_urdf"]
