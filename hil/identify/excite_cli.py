"""`hil excite`: design an optimal periodic excitation and write it as an open-loop profile.

Optimizes a finite Fourier series trajectory (hil/identify/excitation.py) for the condition number
or
D-optimality of the regressor, within the bench's position, velocity and torque limits; turns
its nominal inverse-dynamics torque into an ``open_loop_torque`` experiment profile (a constant
plus harmonics); then checks, in the world (``virtual-robot simulate`` as a subprocess, default
effects), that the realized open-loop motion stays in range and still excites well, next to the
same criteria for the paper's excitation, eqs. (31)-(32), realized the same way.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from drivers.options import float_list
from drivers.recording import Recording, read_signals
from hil.cli_options import (
    add_bench_option,
    add_report_options,
    error,
    prepare_out_dir,
    print_document,
    say,
    simulate_offline,
)
from hil.identify.excitation import (
    CRITERIA,
    DesignResult,
    ExcitationLimits,
    criteria,
    derivatives_from_positions,
    design_bias,
    design_excitation,
    fit_torque_series,
    nominal_torque,
    profile_toml,
    torque_fit_error,
    trajectory_header,
)
from hil.model.params import robot_params

PAPER_EXPERIMENT = "reyes-kelly"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--criterion", choices=CRITERIA, default="dopt", help="default dopt")
    p.add_argument("--harmonics", type=int, default=5, help="L, trajectory harmonics (default 5)")
    p.add_argument(
        "--fundamental-hz", type=float, default=0.5, help="ω_f/2π in Hz (default 0.5: 2 s period)"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the random starts (default 0)")
    p.add_argument("--starts", type=int, default=4, help="random starts (default 4)")
    p.add_argument(
        "--time-budget", type=float, default=60.0, help="no new start after this many s (60)"
    )
    p.add_argument(
        "--torque-margin", type=float, default=0.8, help="fraction of the drives' torque (0.8)"
    )
    p.add_argument(
        "--velocity-margin", type=float, default=0.8, help="fraction of the velocity limit (0.8)"
    )
    p.add_argument(
        "--position-limit",
        default="1.2,2.0",
        help="|q1|,|q2| bounds in rad (default 1.2,2.0: link 1 stays below the horizontal, "
        "where open-loop drift stays small; see docs/excitation.md)",
    )
    p.add_argument(
        "--max-bias",
        type=float,
        default=0.02,
        help="bound on the relative θ bias the robot profile's direction-dependent Coulomb "
        "friction causes in least squares, per regression form (default 0.02 = 2 %%; 0 "
        "ignores it)",
    )
    add_bench_option(p, help="bench whose limits apply")
    p.add_argument(
        "--params",
        default=None,
        help="parameter file (hil identify) for the nominal model (default: the robot profile)",
    )
    p.add_argument(
        "--torque-harmonics",
        type=int,
        default=200,
        help="harmonics of ω_f in the profile's torque series (default 200)",
    )
    p.add_argument("--duration", type=float, default=10.0, help="profile duration in s (10)")
    p.add_argument(
        "--out",
        default=None,
        help="profile to write (default: excitation.toml in a new runs/excite/<date>T<time>)",
    )
    p.add_argument("--name", default=None, help="profile name (default: the file's stem)")
    p.add_argument("--plot", default=None, help="plot to write (default: --out with .png)")
    p.add_argument(
        "--no-simulate",
        action="store_true",
        help="skip the world check (virtual-robot simulate of the design and of eqs. 31-32)",
    )
    add_report_options(p, plot="skip the plot", json_help="print one JSON summary on stdout")


def _position_limit(text: str) -> tuple[float, float]:
    q1, q2 = float_list(
        text, "--position-limit", 2, "positive numbers Q1,Q2 in rad", lambda q: q > 0
    )
    return q1, q2


def _check_args(args: argparse.Namespace) -> None:
    if args.harmonics < 2:
        raise ValueError(f"--harmonics must be >= 2 (to start at rest), got {args.harmonics}")
    if args.harmonics > 20:
        raise ValueError(f"--harmonics must be <= 20, got {args.harmonics}")
    if not (math.isfinite(args.fundamental_hz) and 0.01 <= args.fundamental_hz <= 5.0):
        raise ValueError(f"--fundamental-hz must be in [0.01, 5], got {args.fundamental_hz}")
    if args.starts < 1:
        raise ValueError(f"--starts must be >= 1, got {args.starts}")
    if not args.time_budget > 0:
        raise ValueError(f"--time-budget must be > 0 s, got {args.time_budget}")
    for name in ("torque_margin", "velocity_margin"):
        value = getattr(args, name)
        if not (math.isfinite(value) and 0.0 < value <= 1.0):
            raise ValueError(f"--{name.replace('_', '-')} must be in (0, 1], got {value}")
    if not (math.isfinite(args.max_bias) and 0.0 <= args.max_bias < 1.0):
        raise ValueError(f"--max-bias must be in [0, 1), got {args.max_bias}")
    if args.torque_harmonics < 1:
        raise ValueError(f"--torque-harmonics must be >= 1, got {args.torque_harmonics}")
    if not (math.isfinite(args.duration) and args.duration > 0):
        raise ValueError(f"--duration must be > 0 s, got {args.duration}")
    if args.out is not None and Path(args.out).suffix != ".toml":
        raise ValueError(f"--out must name a .toml file, got {args.out!r}")
    if args.plot is not None and Path(args.plot).suffix != ".png":
        raise ValueError(f"--plot must name a .png file, got {args.plot!r}")


def _simulate(robot: str, profile: str, duration_s: float, out_dir: Path) -> Recording:
    """The world's open-loop response (``virtual-robot simulate`` as its own process)."""
    simulate_offline(robot, profile, duration_s, out_dir, plot=False)
    return read_signals(out_dir)


def _realized(rec: Recording, theta: np.ndarray) -> dict[str, Any]:
    """Criteria and range of a recording, q̇ and q̈ by central differences of the encoder q."""
    q, dq, ddq = derivatives_from_positions(rec.q, rec.period_s)
    return {
        **criteria(q, dq, ddq, theta),
        "max_abs_q_rad": np.abs(rec.q).max(0).tolist(),
        "max_abs_dq_rad_s": np.abs(dq).max(0).tolist(),
        "max_abs_tau_Nm": np.abs(rec.tau).max(0).tolist(),
    }


def _plot(
    path: Path,
    design: DesignResult,
    theta: np.ndarray,
    series_torque: np.ndarray,
    t: np.ndarray,
    limits: ExcitationLimits,
    realized: Recording | None,
) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    q, dq, _ = design.trajectory.evaluate(t)
    tau = nominal_torque(design.trajectory, theta, t)
    fig, axes = plt.subplots(3, 2, figsize=(11, 8), sharex=True)
    rows = (
        (q, "q{} [rad]", limits.position_rad),
        (dq, "q̇{} [rad/s]", limits.velocity_rad_s),
        (tau, "τ{} [Nm]", limits.torque_Nm),
    )
    for r, (values, label, lim) in enumerate(rows):
        for j in range(2):
            ax = axes[r, j]
            ax.plot(t, values[:, j], lw=1.2, label="designed")
            if r == 0 and realized is not None:
                ax.plot(realized.t, realized.q[:, j], lw=0.9, ls="--", label="realized (world)")
            if r == 2:
                ax.plot(t, series_torque[:, j], lw=0.7, label="profile series")
            for sign in (-1, 1):
                ax.axhline(sign * lim[j], color="k", ls=":", lw=0.8)
            ax.set_ylabel(label.format(j + 1))
            ax.grid(True, alpha=0.3)
            if j == 1:
                ax.legend(loc="upper right", fontsize=7)
    for j in range(2):
        axes[2, j].set_xlabel("t [s]")
    fig.suptitle(
        f"hil excite: {design.criterion}-optimal Fourier excitation, L = "
        f"{design.trajectory.harmonics}, f = {design.trajectory.omega_f / (2 * math.pi):g} Hz "
        f"(dotted: limits with margins)"
    )
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _pair(values: tuple[float, float]) -> str:
    return f"[{values[0]:g}, {values[1]:g}]"


def _bound(max_bias: float) -> str:
    return f"bound {100 * max_bias:g} %" if max_bias > 0 else "not constrained"


def _percent(worst: dict[str, float]) -> str:
    return ", ".join(f"{form} {100 * b:.2g} %" for form, b in worst.items())


def _fmt(x: float | None) -> str:
    return "-" if x is None else f"{x:.4g}"


def main(args: argparse.Namespace) -> int:
    from profiles.bench import load_bench
    from profiles.robot import load_robot

    _check_args(args)
    q_limit = _position_limit(args.position_limit)
    bench = load_bench(args.bench)
    from hil.model.params import load_params

    theta = (load_params(args.params) if args.params else robot_params(bench.robot)).theta
    limits = ExcitationLimits.from_bench(
        bench.position_limit_rad,
        bench.velocity_limit_rad_s,
        bench.torque_limit_Nm,
        max_position_rad=q_limit,
        velocity_margin=args.velocity_margin,
        torque_margin=args.torque_margin,
    )
    robot = load_robot(bench.robot)
    # (F⁺ − F⁻)/2 per joint: the Coulomb asymmetry the 9-parameter model cannot express
    asymmetry = (
        (np.array(robot.coulomb_positive_Nm) - np.array(robot.coulomb_negative_Nm)) / 2
    ).tolist()
    h = bench.period_s
    if args.out is None:  # each run its own directory: a rerun keeps the one before
        args.out = str(
            prepare_out_dir(None, False, default="excite", command="excite") / "excitation.toml"
        )
    out = Path(args.out)
    name = args.name or out.stem
    say(
        "excite",
        f"{args.criterion}-optimal design, L = {args.harmonics}, "
        f"f = {args.fundamental_hz:g} Hz, {args.starts} starts, seed {args.seed} ...",
    )
    design = design_excitation(
        theta,
        limits,
        criterion=args.criterion,
        harmonics=args.harmonics,
        fundamental_hz=args.fundamental_hz,
        seed=args.seed,
        starts=args.starts,
        time_budget_s=args.time_budget,
        asymmetry_Nm=asymmetry if args.max_bias > 0 else (0.0, 0.0),  # 0: not constrained
        max_bias=args.max_bias or 1.0,
        duration_s=args.duration,
    )
    bias = design_bias(design.trajectory, theta, asymmetry, args.duration)  # reported anyway
    worst_bias = {form: float(np.abs(b).max()) for form, b in bias.items()}
    say("excite", f"designed in {design.elapsed_s:.1f} s")
    advance = h / 2  # zero-order hold: τ(t_k) acts over [t_k, t_k + h), centred on t_k + h/2
    series = fit_torque_series(
        design.trajectory, theta, args.torque_harmonics, time_advance_s=advance
    )
    t_bench = np.arange(round(args.duration / h)) * h
    fit = torque_fit_error(series, design.trajectory, theta, t_bench, time_advance_s=advance)
    series_torque = series.evaluate(t_bench)
    tau_rms = np.sqrt(np.mean(nominal_torque(design.trajectory, theta, t_bench) ** 2, axis=0))
    fit["relative_rms"] = (np.asarray(fit["rms_Nm"]) / tau_rms).tolist()
    fit["harmonics"] = args.torque_harmonics
    fit["max_abs_series_Nm"] = np.abs(series_torque).max(0).tolist()
    command = " ".join(
        [
            "hil excite",
            f"--criterion {args.criterion}",
            f"--harmonics {args.harmonics}",
            f"--fundamental-hz {args.fundamental_hz:g}",
            f"--seed {args.seed}",
            f"--starts {args.starts}",
            f"--torque-margin {args.torque_margin:g}",
            f"--velocity-margin {args.velocity_margin:g}",
            f"--position-limit {args.position_limit}",
            f"--max-bias {args.max_bias:g}",
            f"--torque-harmonics {args.torque_harmonics}",
            f"--bench {args.bench}",
            *([f"--params {args.params}"] if args.params else []),
            f"--out {args.out}",
        ]
    )
    header = [
        f"Generated by: {command}",
        f"Optimal periodic excitation (hil/identify/excitation.py): criterion {args.criterion}, "
        f"seed {args.seed}, {design.starts} of {args.starts} starts, designed in "
        f"{design.elapsed_s:.1f} s.",
        f"Trajectory: Fourier series, L = {args.harmonics} harmonics of "
        f"{args.fundamental_hz:g} Hz (period {design.trajectory.period_s:g} s) from rest at q = 0;",
        f"limits |q| <= {_pair(limits.position_rad)} rad, |q̇| <= "
        f"{_pair(limits.velocity_rad_s)} rad/s, |τ| <= {_pair(limits.torque_Nm)} Nm (nominal).",
        f"Designed (nominal model, columns scaled by |θ|): cond = {design.designed['cond']:.4g}, "
        f"-log det = {design.designed['dopt']:.4g}.",
        f"Torque: nominal inverse dynamics, h/2 ahead (zero-order hold), as a constant plus "
        f"{args.torque_harmonics} harmonics of the fundamental;",
        f"fit error at t = k h: rms {_fmt(fit['rms_Nm'][0])}, {_fmt(fit['rms_Nm'][1])} Nm, "
        f"max {_fmt(fit['max_Nm'][0])}, {_fmt(fit['max_Nm'][1])} Nm (at Coulomb sign switches).",
        f"Predicted least-squares bias from the Coulomb asymmetry {_pair(asymmetry)} Nm: "
        "max |bias| " + _percent(worst_bias) + f" ({_bound(args.max_bias)}).",
        "Each joint: τ(t) = offset_Nm + Σ amplitude_Nm sin(omega_rad_s t + phase_rad).",
        "",
        *trajectory_header(design.trajectory),
    ]
    text = profile_toml(
        series,
        name=name,
        period_s=h,
        duration_s=args.duration,
        header=header,
        description=f"{args.criterion}-optimal Fourier excitation (hil excite)",
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".toml.tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(out)

    paper: dict[str, Any] | None = None
    realized: dict[str, Any] | None = None
    rec: Recording | None = None
    if not args.no_simulate:
        say("excite", "world check (virtual-robot simulate) ...")
        started = time.perf_counter()
        try:
            with tempfile.TemporaryDirectory(prefix="hil-excite-") as tmpdir:
                tmp_dir = Path(tmpdir)
                rec_paper = _simulate(bench.robot, PAPER_EXPERIMENT, 10.0, tmp_dir / "paper")
                rec = _simulate(bench.robot, str(out.resolve()), args.duration, tmp_dir / "design")
        except RuntimeError as exc:
            error("excite", f"{exc} (the profile {out} is written)")
            return 1
        paper = _realized(rec_paper, theta)
        realized = _realized(rec, theta)
        q_design, _, _ = design.trajectory.evaluate(rec.t)
        realized["max_abs_deviation_rad"] = np.abs(rec.q - q_design).max(0).tolist()
        realized["in_bench_range"] = bool(
            np.all(rec.q >= np.array(bench.position_limit_rad)[:, 0])
            and np.all(rec.q <= np.array(bench.position_limit_rad)[:, 1])
        )
        realized["simulate_s"] = round(time.perf_counter() - started, 2)

    plot_path = None
    if not args.no_plot:
        plot_path = _plot(
            Path(args.plot) if args.plot else out.with_suffix(".png"),
            design,
            theta,
            series_torque,
            t_bench,
            limits,
            rec,
        )

    summary = {
        "profile": str(out),
        "plot": str(plot_path) if plot_path else None,
        "criterion": args.criterion,
        "seed": args.seed,
        "harmonics": args.harmonics,
        "fundamental_hz": args.fundamental_hz,
        "starts_run": design.starts,
        "design_time_s": round(design.elapsed_s, 2),
        "limits": {
            "position_rad": list(limits.position_rad),
            "velocity_rad_s": list(limits.velocity_rad_s),
            "torque_Nm": list(limits.torque_Nm),
        },
        "coulomb_asymmetry_Nm": asymmetry,
        "predicted_bias": {form: b.tolist() for form, b in bias.items()},
        "predicted_max_abs_bias": worst_bias,
        "initial_guess": design.initial,
        "designed": {
            **design.designed,
            "max_abs_q_rad": design.extremes[0].tolist(),
            "max_abs_dq_rad_s": design.extremes[1].tolist(),
            "max_abs_tau_Nm": design.extremes[2].tolist(),
        },
        "realized": realized,
        "paper_realized": paper,
        "torque_fit": fit,
        "per_start": design.per_start,
    }

    def text() -> str:
        lines: list[str] = []
        rows = [("paper eqs. (31)-(32), realized", paper), ("initial guess", design.initial)]
        rows += [("designed (nominal)", design.designed), ("designed, realized (world)", realized)]
        lines.append(f"{'excitation':34s} {'cond':>10s} {'-log det':>10s}")
        for label, c in rows:
            if c is not None:
                lines.append(f"{label:34s} {c['cond']:10.4g} {c['dopt']:10.4g}")
        if realized is not None:
            lines.append(
                f"realized range |q| = {_fmt(realized['max_abs_q_rad'][0])}, "
                f"{_fmt(realized['max_abs_q_rad'][1])} rad; |q̇| = "
                f"{_fmt(realized['max_abs_dq_rad_s'][0])}, "
                f"{_fmt(realized['max_abs_dq_rad_s'][1])} rad/s; max deviation from the "
                f"design {_fmt(realized['max_abs_deviation_rad'][0])}, "
                f"{_fmt(realized['max_abs_deviation_rad'][1])} rad"
            )
        lines.append(
            f"torque series: {args.torque_harmonics} harmonics, fit error rms "
            f"{_fmt(fit['rms_Nm'][0])}, {_fmt(fit['rms_Nm'][1])} Nm "
            f"({100 * fit['relative_rms'][0]:.2g} %, {100 * fit['relative_rms'][1]:.2g} % of rms "
            f"torque), max {_fmt(fit['max_Nm'][0])}, {_fmt(fit['max_Nm'][1])} Nm"
        )
        lines.append(
            f"predicted θ bias from the Coulomb asymmetry {_pair(asymmetry)} Nm: max |bias| "
            + _percent(worst_bias)
            + f" ({_bound(args.max_bias)})"
        )
        lines.append(f"design time {design.elapsed_s:.1f} s ({design.starts} starts)")
        lines.append(f"profile: {out}" + (f"\nplot:    {plot_path}" if plot_path else ""))
        return "\n".join(lines)

    print_document(args, summary, text)
    if realized is not None and not realized["in_bench_range"]:
        say("excite", "warning: the realized motion leaves the bench's range")
        return 1
    return 0
