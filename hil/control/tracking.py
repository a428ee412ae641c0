"""`hil control`: run a tracking controller (PD, CT, FED, RFED) over a bench, and compare them.

One run: the bench is set up as for `hil run` (:func:`hil.bench.run.record_over_bench`: virtual
robot,
arm, recording), and each period the loop calls a command that estimates the velocity from the
encoder readings (backward difference), evaluates the reference (hil/control/trajectory.py) at t =
k·h
and the controller (hil/control/controllers.py), and returns the torque clipped at the drive limits.

A run directory holds the standard ``signals.csv`` / ``meta.json`` / traffic log, plus
``control.csv`` (row k: the reference, the velocity estimate, the control law's torque before
clipping, the clip flags and the torque split), ``control.json`` (the tracking errors and clip
counts) and the plots. :func:`compare_schemes` runs every scheme with every parameter set and
returns the Table 2 document that `hil control --compare --json` prints.

Tracking errors (Khosla & Kanade 1987, Section 4.1, "dynamic tracking accuracy"): position error
e_k = q_d(t_k) − q_k on the encoder readings; velocity error q̇_d(t_k) − q̇_k with q̇_k the central
difference (q_{k+1} − q_{k−1}) / 2h of the recording (centred on t_k, unlike the backward
difference the controller uses in real time). Maximum and RMS over the run, per joint. t_k is
k·h in lockstep; in realtime, the time the sample was actually taken (:func:`sample_times`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np

from drivers.arm import Sample
from drivers.recording import read_signals, write_json_atomic
from hil.bench.run import UsageError, bench_meta, check_bench, record_over_bench
from hil.control.controllers import (
    SCHEMES,
    BackwardDifference,
    Controller,
    DynamicsModel,
    Gains,
    Reference,
    make_controller,
)
from hil.control.signals import central_velocity, sample_times
from hil.control.trajectory import PointToPoint, khosla_kanade_moves
from hil.model.closed_form import ArmModel
from hil.model.params import (
    ParamsError,
    ParamSet,
    check_inertia,
    load_base_params,
    load_params,
    robot_params,
)
from profiles.bench import BenchProfile
from profiles.experiment import check_duration
from profiles.robot import describes_urdf_only
from profiles.tracking import TrackingProfile, load_tracking

DEFAULT_EXPERIMENT = "khosla-kanade-tracking"
CONTROL_CSV = "control.csv"
CONTROL_JSON = "control.json"
PROFILE_LABEL = "profile"

if TYPE_CHECKING:
    from typing_extensions import Unpack  # typing.Unpack for **kwargs from Python 3.12


# ---- parameter sets ---------------------------------------------------------------------------
@dataclass(frozen=True)
class LabelledParams:
    """θ̃ for the controllers' model and the name it has in tables and directories."""

    label: str
    params: ParamSet

    def describe(self) -> dict[str, Any]:
        return {
            "label": self.label,
            "source": self.params.source,
            "scheme": self.params.scheme,
            "theta": [float(x) for x in self.params.theta],
        }


def parse_params_spec(spec: str, urdf_model: DynamicsModel | None = None) -> LabelledParams:
    """``[LABEL=]FILE[#SCHEME]`` -> θ̃ of FILE (its selected scheme, or SCHEME), named LABEL.

    Without a label: the file's stem, or ``DIR/params`` for a ``params.json`` (``DIR/identify``
    for an ``identify.json``, as written by `hil identify`), with ``#SCHEME`` appended when one
    is picked. With ``urdf_model`` (a URDF arm's), FILE holds its base parameters
    (:func:`hil.model.params.load_base_params`) and has no schemes.
    """
    label, sep, rest = spec.partition("=")
    if not sep:
        label, rest = "", spec
    path_text, _, scheme = rest.partition("#")
    if not path_text:
        raise UsageError(f"--params {spec!r}: no file (expected [LABEL=]FILE[#SCHEME])")
    if urdf_model is None:
        params = load_params(path_text, scheme or None)
    elif scheme:
        raise UsageError(f"--params {spec!r}: a URDF arm's parameter file has no schemes")
    else:
        params = load_base_params(path_text, urdf_model)
    if not label:
        path = Path(path_text)
        label = (
            f"{path.parent.name or '.'}/{path.stem}"
            if path.stem in ("params", "identify")
            else path.stem
        )
        if scheme:
            label += f"#{scheme}"
    return LabelledParams(label, params)


def urdf_model_of(robot: str) -> DynamicsModel | None:
    """The controllers' model of ``robot`` when its profile describes the arm by a URDF only: a
    :class:`hil.model.urdf.UrdfArmModel` (base parameters, Pinocchio). None for the 2-DOF
    CICESE-type arm, which keeps its closed form (the fast path, :meth:`ControlSetup.model_for`)."""
    if not describes_urdf_only(robot):
        return None
    from hil.model.urdf import UrdfArmModel

    return UrdfArmModel.from_profile(robot)


def profile_params(robot: str, urdf_model: DynamicsModel | None = None) -> ParamSet:
    """θ̃ of the robot profile: θ1..θ9 (and its terms') of the closed form, or, with the URDF
    arm's model, its base parameters from the URDF and the profile's friction."""
    if urdf_model is None:
        return robot_params(robot)
    from profiles.robot import load_urdf_robot

    theta = urdf_model.base_theta()  # type: ignore[attr-defined]
    return ParamSet(theta, source=load_urdf_robot(robot).source, scheme="profile")


def parameter_sets(
    specs: Sequence[str | LabelledParams | ParamSet],
    *,
    include_profile: bool,
    robot: str,
    model: DynamicsModel | None = None,
) -> list[LabelledParams]:
    """The profile's θ (if asked) followed by each spec, with unique labels. ``model``: the URDF
    arm's model when ``robot`` is one (default: built here, :func:`urdf_model_of`)."""
    urdf_model = model if model is not None else urdf_model_of(robot)
    out: list[LabelledParams] = []
    if include_profile:
        out.append(LabelledParams(PROFILE_LABEL, profile_params(robot, urdf_model)))
    for spec in specs:
        if isinstance(spec, LabelledParams):
            item = spec
        elif isinstance(spec, ParamSet):
            item = LabelledParams(Path(spec.source).stem or "params", spec)
        else:
            item = parse_params_spec(spec, urdf_model)
        _check_physical(item, urdf_model)
        label, n = item.label, 2
        while any(p.label == label for p in out):
            label, n = f"{item.label}-{n}", n + 1
        out.append(LabelledParams(label, item.params))
    if not out:
        raise UsageError("no parameter set to run with")
    return out


def _check_physical(item: LabelledParams, urdf_model: DynamicsModel | None = None) -> None:
    """Refuse θ̃ whose inertia matrix M(q) is not positive definite for every q
    (:func:`hil.model.params.check_inertia`): the CT, FED and RFED laws would command nonsense,
    and PD's parameters are the same file's. A URDF arm's base parameters: M(q) ≻ 0 at sampled
    configurations (``UrdfArmModel.physical_consistency``)."""
    try:
        check_inertia(item.params, urdf_model)
    except ParamsError as exc:
        raise UsageError(f"--params {item.label}: {exc}") from None


# ---- the per-period command -------------------------------------------------------------------
class ControlLog:
    """``control.csv``, written row by row (flushed every ``flush_every`` rows, and on close)."""

    def __init__(
        self, path: Path, part_names: Sequence[str], flush_every: int = 50, n_joints: int = 2
    ) -> None:
        self.part_names = tuple(part_names)
        joints = range(1, n_joints + 1)
        self.columns = (
            "t",
            *(f"{name}{j}" for name in ("qd", "dqd", "ddqd") for j in joints),
            *(f"dq{j}_est" for j in joints),
            *(f"{name}{j}" for name in ("tau_law", "clipped") for j in joints),
            *(f"{name}{j}" for name in self.part_names for j in joints),
        )
        self.flush_every = max(1, flush_every)
        self.rows = 0
        self._file = open(path, "w")  # noqa: SIM115 (closed in close())
        self._file.write(",".join(self.columns) + "\n")
        self._file.flush()

    def write(self, values: Sequence[float]) -> None:
        self._file.write(",".join(repr(float(v)) for v in values) + "\n")
        self.rows += 1
        if self.rows % self.flush_every == 0:
            self._file.flush()

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()

    def __enter__(self) -> ControlLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class TrackingCommand:
    """``command(k, sample)`` for the loop runner: velocity estimate, reference, control law."""

    def __init__(
        self,
        controller: Controller,
        trajectory: PointToPoint,
        period_s: float,
        n_periods: int,
        log: ControlLog | None = None,
    ) -> None:
        self.controller = controller
        self.period_s = period_s
        # the reference at t_k = k·h for every period, computed once (a pure function of t)
        self.reference = trajectory.at(np.arange(n_periods) * period_s)
        self.n_joints = n = controller.model.n_joints
        self.velocity = BackwardDifference(period_s, n)
        self.log = log
        self.clipped_cycles = [0] * n
        self.peak_tau_law = [0.0] * n

    def __call__(self, k: int, sample: Sample) -> tuple[float, ...]:
        t = k * self.period_s
        q = np.asarray(sample.q_rad, dtype=float)
        dq = self.velocity(q)
        qd, dqd, ddqd = (r[k] for r in self.reference)
        cmd = self.controller(t, q, dq, Reference(qd, dqd, ddqd))
        for j in range(self.n_joints):
            if cmd.clipped[j]:
                self.clipped_cycles[j] += 1
            self.peak_tau_law[j] = max(self.peak_tau_law[j], abs(float(cmd.tau_law[j])))
        if self.log is not None:
            row = [t, *qd, *dqd, *ddqd, *dq, *cmd.tau_law, *cmd.clipped]
            for name in self.log.part_names:
                row.extend(cmd.parts[name])
            self.log.write(row)
        return tuple([float(x) for x in cmd.tau])


# ---- metrics ----------------------------------------------------------------------------------
def tracking_errors(
    t: np.ndarray, q: np.ndarray, trajectory: PointToPoint
) -> dict[str, list[float]]:
    """Max and RMS position and velocity tracking errors per joint (Khosla & Kanade Table 2);
    ``t`` are the sample times (:func:`sample_times`)."""
    qd, dqd, _ = trajectory.at(t)
    e = qd - q
    ev = dqd - central_velocity(t, q)
    return {
        "max_position_error_rad": np.max(np.abs(e), axis=0).tolist(),
        "rms_position_error_rad": np.sqrt(np.mean(e**2, axis=0)).tolist(),
        "max_velocity_error_rad_s": np.max(np.abs(ev), axis=0).tolist(),
        "rms_velocity_error_rad_s": np.sqrt(np.mean(ev**2, axis=0)).tolist(),
    }


def reference_torque_margin(
    theta: np.ndarray,
    trajectory: PointToPoint,
    limits: Sequence[float],
    h: float,
    model: DynamicsModel | None = None,
) -> dict[str, list[float]]:
    """Peak |τ_d| of the inverse dynamics along the reference (θ̃ of ``model``, default the 2-DOF
    closed form; friction included) and the fraction of each drive limit left: what the
    trajectory costs before any feedback."""
    model = ArmModel() if model is None else model
    t = np.arange(0.0, trajectory.duration_s + h / 2, h)
    qd, dqd, ddqd = trajectory.at(t)
    peak = np.max(np.abs(model.torque(theta, qd, dqd, ddqd)), axis=0)
    lim = np.asarray(limits, dtype=float)
    return {
        "peak_reference_torque_Nm": peak.tolist(),
        "torque_limit_Nm": lim.tolist(),
        "margin_fraction": (1.0 - peak / lim).tolist(),
    }


# ---- one run ----------------------------------------------------------------------------------
class ControlSettings(TypedDict, total=False):
    """The settings every run of one :func:`run_control` or :func:`compare_schemes` shares
    (:func:`prepare`'s keywords; `hil control`'s options)."""

    experiment: str
    duration_s: float | None
    mode: str | None
    effects: str | None
    seed: int | None
    kp: Sequence[float] | None
    kv: Sequence[float] | None
    confirm_real: bool
    robot: str | None


@dataclass
class ControlSetup:
    """What every run of a comparison shares: bench, experiment, gains, duration, and the
    schemes and parameter sets to run."""

    bench: BenchProfile
    experiment: TrackingProfile
    trajectory: PointToPoint
    gains: Gains
    mode: str
    n_periods: int
    robot: str = "cicese"
    urdf_model: DynamicsModel | None = None  # a URDF arm's model (one for every parameter set)
    effects: str | None = None
    seed: int | None = None
    notes: list[str] = field(default_factory=list)
    schemes: tuple[str, ...] = SCHEMES
    parameter_sets: list[LabelledParams] = field(default_factory=list)

    @property
    def period_s(self) -> float:
        return self.bench.period_s

    @property
    def torque_limit_Nm(self) -> tuple[float, ...]:
        return tuple(self.bench.torque_limit_Nm)

    def model_for(self, params: LabelledParams) -> DynamicsModel:
        """The model θ̃ of ``params`` is written for: the URDF arm's, or the closed form with
        the parameter set's terms."""
        if self.urdf_model is not None:
            return self.urdf_model
        return ArmModel(params.params.terms)

    def describe(self) -> dict[str, Any]:
        e = self.experiment
        return {
            "bench": self.bench.name,
            "mode": self.mode,
            "period_s": self.period_s,
            "duration_s": self.n_periods * self.period_s,
            "experiment": e.name,
            "experiment_profile": e.source,
            "trajectory": {
                "amplitude_rad": list(e.amplitude_rad),
                "pattern": list(e.pattern),
                "move_s": e.move_s,
                "hold_s": e.hold_s,
                "start_hold_s": e.start_hold_s,
                "full_duration_s": self.trajectory.duration_s,
                **self.trajectory.peaks(),
            },
            "gains": {
                "kp": list(self.gains.kp),
                "kv": list(self.gains.kv),
                "damping_ratio": self.gains.damping_ratio(),
            },
            "typical_q_rad": list(e.typical_q_rad),
            "velocity_estimate": e.velocity,
            "ct_friction_velocity": e.ct_friction_velocity,
            "effects": self.effects,
            "seed": self.seed,
            "notes": list(self.notes),
        }


def prepare(
    bench_name: str,
    *,
    schemes: Sequence[str] = SCHEMES,
    params: Sequence[str | LabelledParams | ParamSet] = (),
    include_profile: bool = True,
    experiment: str | None = None,
    duration_s: float | None = None,
    mode: str | None = None,
    effects: str | None = None,
    seed: int | None = None,
    kp: Sequence[float] | None = None,
    kv: Sequence[float] | None = None,
    confirm_real: bool = False,
    robot: str | None = None,
) -> ControlSetup:
    """Load and check everything the runs need, before anything starts moving: the schemes,
    bench, experiment, duration and gains, then the parameter sets (the profile's θ if
    ``include_profile``, then each of ``params``). ``robot``: a robot profile in place of the
    bench's (e.g. cicese3: its drives on the bus, its model in the controllers, its tracking
    experiment by default)."""
    unknown = [s for s in schemes if s not in SCHEMES]
    if unknown or not schemes:
        raise UsageError(f"unknown scheme(s) {unknown}; expected some of {', '.join(SCHEMES)}")
    bench = check_bench(bench_name, confirm_real=confirm_real, effects=effects, robot=robot)
    robot = bench.robot
    urdf_model = urdf_model_of(robot)
    n = 2 if urdf_model is None else urdf_model.n_joints
    exp = load_tracking(experiment or default_experiment(robot))
    if exp.n_joints != n:
        raise UsageError(
            f"experiment {exp.name} moves {exp.n_joints} joints, robot {robot} has {n}"
        )
    if len(bench.torque_limit_Nm) != n:
        raise UsageError(
            f"bench {bench.name}: {len(bench.torque_limit_Nm)} torque limits, robot {robot} has "
            f"{n} joints"
        )
    trajectory = khosla_kanade_moves(
        exp.amplitude_rad,
        exp.pattern,
        move_s=exp.move_s,
        hold_s=exp.hold_s,
        start_hold_s=exp.start_hold_s,
    )
    duration = trajectory.duration_s if duration_s is None else duration_s
    try:
        check_duration(duration, bench.period_s)  # finite, > 0, ≤ 24 h, rows bounded
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    for name, values in (("--kp", kp), ("--kv", kv)):
        if values is not None and (
            len(values) != n or not all(math.isfinite(v) and v >= 0 for v in values)
        ):
            raise UsageError(f"{name} takes {n} finite gains >= 0 (one per joint)")
    gains = Gains(tuple(kp or exp.kp), tuple(kv or exp.kv))
    notes = []
    if abs(exp.period_s - bench.period_s) > 1e-12:
        notes.append(f"experiment period {exp.period_s} s; the bench's {bench.period_s} s is used")
    return ControlSetup(
        bench=bench,
        experiment=exp,
        trajectory=trajectory,
        gains=gains,
        mode=mode or bench.mode,
        n_periods=max(2, round(duration / bench.period_s)),
        robot=robot,
        urdf_model=urdf_model,
        effects=effects,
        seed=seed,
        notes=notes,
        schemes=tuple(schemes),
        parameter_sets=parameter_sets(
            params, include_profile=include_profile, robot=robot, model=urdf_model
        ),
    )


def default_experiment(robot: str) -> str:
    """The tracking experiment of ``robot``: ``khosla-kanade-tracking-<robot>`` where one is
    shipped, else the 2-DOF arm's :data:`DEFAULT_EXPERIMENT`."""
    from profiles.loader import ProfileError, load_toml

    name = f"{DEFAULT_EXPERIMENT}-{Path(robot).stem}"
    try:
        load_toml("experiments", name)
    except ProfileError:
        return DEFAULT_EXPERIMENT
    return name


def _controller(setup: ControlSetup, scheme: str, params: LabelledParams) -> Controller:
    return make_controller(
        scheme,
        params.params.theta,
        setup.gains,
        setup.torque_limit_Nm,
        model=setup.model_for(params),
        q_typical=setup.experiment.typical_q_rad,
        friction_velocity=setup.experiment.ct_friction_velocity,
    )


def run_scheme(
    setup: ControlSetup,
    scheme: str,
    params: LabelledParams,
    out_dir: str | Path,
    *,
    plot: bool = True,
    progress: bool = True,
) -> dict[str, Any]:
    """Run one scheme over the bench and record it; returns the run's summary (control.json)."""
    controller = _controller(setup, scheme, params)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    h = setup.period_s
    realtime = setup.mode == "realtime"

    def meta(channel: dict[str, Any]) -> dict[str, Any]:
        return {
            **bench_meta("hil control", setup.bench, channel, setup.mode),
            "duration_s": setup.n_periods * h,
            "scheme": scheme,
            "params": params.describe(),
            "typical_inertia_J": controller.J.tolist(),
            **{k: v for k, v in setup.describe().items() if k not in ("bench", "mode")},
            "robot": setup.bench.robot,
        }

    n = controller.model.n_joints
    with ControlLog(out / CONTROL_CSV, controller.part_names, 1 if realtime else 50, n) as log:
        command = TrackingCommand(controller, setup.trajectory, h, setup.n_periods, log)
        run = record_over_bench(
            setup.bench,
            out,
            command,
            setup.n_periods,
            meta,
            mode=setup.mode,
            effects=setup.effects,
            seed=setup.seed,
            progress=progress,
        )
    result = run.result
    summary: dict[str, Any] = {
        "scheme": scheme,
        "params": params.label,
        "out_dir": str(out),
        "signals": str(out / "signals.csv"),
        "status": result.status,
        "reason": run.reason,
        "rows": result.rows,
        "realtime_factor": round(run.realtime_factor, 2) if run.realtime_factor else None,
        "clipped_cycles": list(command.clipped_cycles),
        "peak_torque_law_Nm": list(command.peak_tau_law),
        "torque_limit_Nm": list(setup.bench.torque_limit_Nm),
        "typical_inertia_J": controller.J.tolist(),
        "plots": [],
    }
    if result.rows >= 2:
        rec = read_signals(out)
        summary.update(tracking_errors(sample_times(rec), rec.q, setup.trajectory))
        if plot:
            from hil.control.plots import plot_run

            summary["plots"] = [
                str(p) for p in plot_run(out, setup.trajectory, scheme, params.label)
            ]
    write_json_atomic(out / CONTROL_JSON, summary)
    return summary


def run_control(
    bench_name: str,
    scheme: str,
    out_dir: str | Path,
    *,
    params: str | LabelledParams | ParamSet | None = None,
    plot: bool = True,
    progress: bool = True,
    **settings: Unpack[ControlSettings],
) -> dict[str, Any]:
    """`hil control --scheme S`: one run with the profile's θ or those of ``params``."""
    if scheme not in SCHEMES:
        raise UsageError(f"unknown scheme {scheme!r}; expected one of {', '.join(SCHEMES)}")
    setup = prepare(
        bench_name,
        schemes=(scheme,),
        params=[params] if params is not None else [],
        include_profile=params is None,
        **settings,
    )
    (chosen,) = setup.parameter_sets
    summary = run_scheme(setup, scheme, chosen, out_dir, plot=plot, progress=progress)
    return {
        "kind": "hil control",
        **setup.describe(),
        "params": chosen.describe(),
        "reference_torque": reference_torque_margin(
            chosen.params.theta,
            setup.trajectory,
            setup.torque_limit_Nm,
            setup.period_s,
            setup.model_for(chosen),
        ),
        "run": summary,
    }


# ---- comparison (Table 2) ---------------------------------------------------------------------
def compare_schemes(
    bench: str,
    out_dir: str | Path,
    *,
    params: Sequence[str | LabelledParams | ParamSet] = (),
    include_profile: bool = True,
    schemes: Sequence[str] = SCHEMES,
    plot: bool = True,
    progress: bool = True,
    on_run: Callable[[dict[str, Any]], None] | None = None,
    **settings: Unpack[ControlSettings],
) -> dict[str, Any]:
    """Run every scheme with every parameter set (the profile's θ first, then each of
    ``params``: ``[LABEL=]FILE[#SCHEME]`` strings or loaded sets) and return the comparison
    document: Table 2 (max and RMS position and velocity errors per joint per scheme) per
    parameter set, clip counts, and each model-based scheme's gain over PD.

    Runs go to ``out_dir/<params label>/<scheme>/``; the document to ``out_dir/compare.json``.
    ``settings``: :class:`ControlSettings`.
    """
    setup = prepare(
        bench, schemes=schemes, params=params, include_profile=include_profile, **settings
    )
    sets = setup.parameter_sets
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    results: dict[str, dict[str, Any]] = {}
    ratios: dict[str, dict[str, list[float | None]]] = {}
    failed = []
    interrupted = False
    for ps in sets:
        if interrupted:
            break
        results[ps.label] = {}
        for scheme in setup.schemes:
            run = run_scheme(
                setup, scheme, ps, out / _safe(ps.label) / scheme, plot=plot, progress=progress
            )
            results[ps.label][scheme] = run
            if run["status"] != "complete":
                failed.append(f"{ps.label}/{scheme}: {run['status']} ({run['reason']})")
            if on_run is not None:
                on_run(run)
            if run["status"] == "interrupted":  # Ctrl-C stops the comparison, not just one run
                interrupted = True
                break
        ratios[ps.label] = improvement_over_pd(results[ps.label])
    sets = [ps for ps in sets if ps.label in results]
    doc: dict[str, Any] = {
        "kind": "hil control compare",
        **setup.describe(),
        "schemes": list(setup.schemes),
        "parameter_sets": [ps.describe() for ps in sets],
        "reference_torque": {
            ps.label: reference_torque_margin(
                ps.params.theta,
                setup.trajectory,
                setup.torque_limit_Nm,
                setup.period_s,
                setup.model_for(ps),
            )
            for ps in sets
        },
        "results": results,
        "max_position_error_reduction_vs_pd": ratios,
        "status": "interrupted" if interrupted else "failed" if failed else "complete",
        "failures": failed,
        "out_dir": str(out),
        "plots": [],
    }
    if plot:
        from hil.control.plots import plot_comparison

        doc["plots"] = [
            str(p)
            for ps in sets
            for p in plot_comparison(
                out, results[ps.label], setup.trajectory, ps.label, _safe(ps.label)
            )
        ]
    write_json_atomic(out / "compare.json", doc)
    return doc


def improvement_over_pd(runs: dict[str, dict[str, Any]]) -> dict[str, list[float | None]]:
    """max |e| of PD / max |e| of each scheme, per joint (None where a number is missing)."""
    pd = runs.get("pd", {}).get("max_position_error_rad")
    out: dict[str, list[float | None]] = {}
    if pd is None:
        return out
    for scheme, run in runs.items():
        err = run.get("max_position_error_rad")
        if scheme == "pd" or err is None:
            continue
        out[scheme] = [p / e if e > 0 else None for p, e in zip(pd, err, strict=True)]
    return out


def _safe(label: str) -> str:
    """A parameter-set label as one directory name."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in label) or "params"


# ---- text output ------------------------------------------------------------------------------
def format_table(doc: dict[str, Any]) -> str:
    """Table 2 of Khosla & Kanade (1987) per parameter set: joints as rows, schemes as column
    pairs (position, velocity error); once for the maximum and once for the RMS errors."""
    lines: list[str] = []
    schemes = doc["schemes"]
    width = 21
    for ps in doc["parameter_sets"]:
        runs = doc["results"][ps["label"]]
        lines.append(f"parameters: {ps['label']} ({ps['source']})")
        for stat, title in (("max", "maximum"), ("rms", "RMS")):
            lines.append(f"  {title} tracking errors, position [rad] / velocity [rad/s]")
            lines.append("  joint " + "".join(f"{s.upper():>{width}}" for s in schemes))
            for j in range(len(doc["gains"]["kp"])):
                cells = []
                for s in schemes:
                    run = runs.get(s, {})  # absent if the comparison was interrupted
                    pos = run.get(f"{stat}_position_error_rad")
                    vel = run.get(f"{stat}_velocity_error_rad_s")
                    cell = "-" if pos is None else f"{pos[j]:.4f} / {vel[j]:.3f}"
                    cells.append(f"{cell:>{width}}")
                lines.append(f"  {j + 1:>5} " + "".join(cells))
        joints = "/".join(str(j + 1) for j in range(len(doc["gains"]["kp"])))
        clips = ", ".join(
            f"{s.upper()} {'/'.join(str(c) for c in runs[s]['clipped_cycles'])}"
            for s in schemes
            if s in runs
        )
        lines.append(f"  clipped cycles (joint {joints}): {clips}")
        ratio = doc["max_position_error_reduction_vs_pd"].get(ps["label"], {})
        if ratio:
            parts = [
                f"{s.upper()} " + "/".join("-" if r is None else f"{r:.1f}x" for r in v)
                for s, v in ratio.items()
            ]
            lines.append(
                f"  max position error of PD / scheme (joint {joints}): " + ", ".join(parts)
            )
        lines.append("")
    if doc.get("failures"):
        lines.append("failed runs: " + "; ".join(doc["failures"]))
    return "\n".join(lines).rstrip()


__all__ = [
    "DEFAULT_EXPERIMENT",
    "LabelledParams",
    "compare_schemes",
    "format_table",
    "improvement_over_pd",
    "parse_params_spec",
    "run_control",
]
