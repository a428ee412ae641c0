"""What closed loop does to each diagnosis estimate, measured (docs/diagnosis.md, "Closed loop").

    python tests/benchmarks/closed_loop_bias.py [--out DIR]

For each concealed effect below, a PD tracking run of the default robot (`hil control --scheme
pd`, the shipped tracking experiment, 6 s at 400 Hz, lockstep, in-process bench) and
`hil diagnose` of it: the truth next to what was found (or why it was not). Then the torque-gain
regression on its own, y ≈ Ψθ + r·(−F[τ_j]), over the whole run: with θ free (what the
selection fits) and with θ1..θ5 held at the reference (the robot profile's Table I; friction
and r free). For the gain cases also the diagnosis with its simulation gate switched off, to show
the selection's own estimate (`relative`) next to `relative_at_reference_theta`, and the held-out
simulated position of the gain read with θ free and with θ1..θ5 at the reference (the two
readings the gate judges, in that order), the gate at each reading alone, and for joint 1's
gain the diagnosis against a reference whose θ1, θ4 are 3 % high (not identifiable, said why).
A few minutes on a loaded machine; ``--only gain_j1,gain_j2`` runs some of the cases.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/, for diagnose_cases

from diagnose_cases import diagnose_capturing_gate

from drivers.recording import read_signals
from hil.diagnose import gates, heldout
from hil.diagnose.columns import gain_column, recording_rows
from hil.diagnose.findings import AT_REFERENCE
from hil.diagnose.pipeline import diagnose
from hil.model.params import robot_params

CASES = {
    "null": ("", "nothing beyond joint 1's asymmetry"),
    "gain_j1": ("[torque_gain_error]\nrelative = [0.05, 0.0]\n", "torque_gain j1 +5 %"),
    "gain_j2": ("[torque_gain_error]\nrelative = [0.0, 0.05]\n", "torque_gain j2 +5 %"),
    "offset_j2": ("[torque_offset]\noffset_Nm = [0.0, 0.3]\n", "torque_offset j2 0.3 Nm"),
    "cogging": (
        "[cogging]\nperiods_per_rev = [120, 96]\namplitude_Nm = [1.5, 0.12]\n"
        "phase_rad = [0.0, 0.5]\n",
        "cogging 1.5 Nm x 120 / 0.12 Nm x 96",
    ),
    "lag_j1": ("[amplifier_lag]\ntime_constant_s = [0.002, 0.0]\n", "actuator_lag j1 2 ms"),
    "angle_j1": ("[encoder_offset]\noffset_rad = [0.01, 0.0]\n", "angle_offset j1 0.01 rad"),
}


def gain_fits(run: Path, reference: np.ndarray) -> list[tuple[float, float]]:
    """Per joint: r with θ free, and r with θ1..θ5 at ``reference``."""
    rec = read_signals(run)
    rows = recording_rows(rec.q, rec.tau, rec.period_s)
    sw = np.sqrt(rows.weights)
    out = []
    for j in (0, 1):
        Z = np.concatenate([rows.Psi, gain_column(rows, j)], axis=2)
        free = np.linalg.lstsq(
            (Z * sw[:, :, None]).reshape(-1, 10), (rows.y * sw).reshape(-1), rcond=None
        )[0]
        target = rows.y - rows.Psi[:, :, :5] @ reference[:5]
        fixed = np.linalg.lstsq(
            (Z[:, :, 5:] * sw[:, :, None]).reshape(-1, 5), (target * sw).reshape(-1), rcond=None
        )[0]
        out.append((float(free[-1]), float(fixed[-1])))
    return out


def _keep_all(prob, accepted, findings, nominal, say, se=None, shaft=None, **_kw):
    return accepted, findings, {}, shaft


def ungated_findings(run: Path, reference: np.ndarray) -> list[str]:
    """The findings with the simulation gate switched off (every accepted term kept, the gain
    read with θ free): what the selection estimated before the gate judged it."""
    doc, _ = diagnose_capturing_gate(read_signals(run), reference, _keep_all)
    return [
        f"{f['effect']} j{f['joint']} {f['estimate']}"
        for f in doc["findings"]
        if f["effect"] != "torque_offset"
    ]


def with_reference_off(run: Path, reference: np.ndarray, joint: int) -> dict[str, str]:
    """The diagnosis against a reference whose θ1 and θ4 (in joint 1's torque only) are 3 %
    high: the torque_gain finding, or why the gain on ``joint`` is not one."""
    off = np.array(reference, float)
    off[[0, 3]] *= 1.03
    doc = diagnose([read_signals(run)], off).document
    found = [f["estimate"] for f in doc["findings"] if f["effect"] == "torque_gain"]
    return (
        {"found": str(found)}
        if found
        else {"not a finding": doc["not_findings"].get(f"gain:{joint}", "-")}
    )


def reference_reading(run: Path, reference: np.ndarray) -> dict[str, list]:
    """Held-out simulated position NRMSE per joint of the accepted model (the gate switched
    off) read three ways: θ free with the gain (the gate's first reading), θ free without the
    gain, and the gain's reference reading (θ1..θ5 held at ``reference``, r =
    `relative_at_reference_theta`: the gate's second reading, gates.pinned_rigid_body)."""
    _, args = diagnose_capturing_gate(read_signals(run), reference, _keep_all)
    prob, accepted, findings, nominal, se, shaft = args
    no_gain = [a for a in accepted if a.cand.kind != "gain"]
    rest = [f for f in findings if f.effect != "torque_gain"]
    at_ref = [
        replace(f, estimate={**f.estimate, "reading": AT_REFERENCE})
        if f.effect == "torque_gain"
        else f
        for f in findings
    ]
    out = {}
    for name, terms, finds in (
        ("free", accepted, findings),
        ("no gain", no_gain, rest),
        ("reference", accepted, at_ref),
    ):
        pinned = gates.pinned_rigid_body(prob, finds, reference)
        fit = heldout.before_after(
            prob, terms, finds, nominal, False, se, shaft, rigid_reference=pinned
        )[0]
        out[name] = fit.after.position_nrmse
    return out


def gate_at_each_reading(run: Path, reference: np.ndarray) -> dict[str, str]:
    """The simulation gate run on the accepted terms with the gain read only with θ free (its
    second reading switched off: no reference) and only at the reference: kept, or why not."""
    _, args = diagnose_capturing_gate(read_signals(run), reference, _keep_all)
    prob, accepted, findings, nominal, se, shaft = args
    out = {}
    for name, ref, reading in (
        ("θ free", None, "relative"),
        ("reference", reference, AT_REFERENCE),
    ):
        finds = [
            replace(f, estimate={**f.estimate, "reading": reading})
            if f.effect == "torque_gain"
            else f
            for f in findings
        ]
        say = lambda _m: None  # noqa: E731
        _, _, dropped, _ = gates.simulation_gate(
            prob, list(accepted), finds, nominal, say, se, shaft, reference=ref
        )
        gain = [k for k in dropped if k.startswith("gain")]
        out[name] = f"dropped: {dropped[gain[0]]}" if gain else "kept"
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None, help="keep the runs here (default: a temporary dir)")
    ap.add_argument("--only", default=None, help="comma-separated case names")
    args = ap.parse_args()
    names = args.only.split(",") if args.only else list(CASES)
    base = Path(args.out or tempfile.mkdtemp(prefix="closed-loop-bias-"))
    base.mkdir(parents=True, exist_ok=True)
    reference = robot_params("cicese").theta
    for name in names:
        body, truth = CASES[name]
        cmd = [sys.executable, "-m", "hil.cli", "control", "--scheme", "pd", "--bench",
               "virtual-inprocess", "--out", str(base / name), "--overwrite", "--no-plot",
               "-q"]  # fmt: skip
        if body:
            (base / f"{name}.toml").write_text(f'name = "{name}"\n{body}')
            cmd += ["--effects", str(base / f"{name}.toml")]
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        doc = diagnose([read_signals(base / name)], reference).document
        found = "; ".join(
            f"{f['effect']} j{f['joint']} "
            + ", ".join(f"{k} {v}" for k, v in f["estimate"].items() if k != "symmetric_model_Nm")
            for f in doc["findings"]
            if f["effect"] not in ("torque_offset",) or f["joint"] != 1
        )
        print(f"{name:10s} truth: {truth}")
        print(f"{'':10s} found: {found or 'nothing'}")
        for key, why in doc["not_findings"].items():
            print(f"{'':10s} not a finding: {key}: {why}")
        if name.startswith("gain"):
            print(
                f"{'':10s} without the simulation gate: "
                + "; ".join(ungated_findings(base / name, reference))
            )
            pos = reference_reading(base / name, reference)
            print(
                f"{'':10s} held-out simulated position (θ free with the gain / without it / "
                "θ1..θ5 at the reference with r at the reference): "
                + " / ".join(
                    ", ".join(f"{100 * x:.3f} %" for x in pos[k])
                    for k in ("free", "no gain", "reference")
                )
            )
            for reading, verdict in gate_at_each_reading(base / name, reference).items():
                print(f"{'':10s} simulation gate, gain read {reading} alone: {verdict}")
            if name == "gain_j1":
                for key, what in with_reference_off(base / name, reference, 1).items():
                    print(f"{'':10s} with θ1, θ4 of the reference 3 % high: {key}: {what}")
        fits = gain_fits(base / name, reference)
        print(
            f"{'':10s} gain regression r (θ free / θ1..θ5 at the reference): "
            + "; ".join(f"j{j + 1} {a:+.4f} / {b:+.4f}" for j, (a, b) in enumerate(fits))
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
