"""Golden check of the virtual robot's plants (issue 29, item 5): the recordings of
``virtual-robot simulate`` and of ``hil run`` over the in-process bench, for the 2-DOF
closed-form arms (cicese, dfki-a0 with its MIT-mode drives) and the n-joint URDF arms (cicese3,
ur5e; the compiled and the Python step), with and without the effects that act on the stick-slip
plant (Stribeck, cogging, amplifier lag and transport delay, gain/offset/encoder errors, payload,
per-joint Coulomb levels).

  python tests/golden_plant.py --write DIR      # run every case, write DIR/<case>/...
  python tests/golden_plant.py --compare DIR    # run again into a temporary directory and
                                                # compare each signals.csv with cmp (byte for byte)
                                                # and meta.json's plant counters

Run ``--write`` on the tree before a change to the plant and ``--compare`` after it: 0
differences is the proof that the change left every recording as it was (``--only TEXT``: the
cases whose name contains it). The fast test (tests/test_stick_slip.py) runs a few of these
cases in-process against their sha256 digests, committed there.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent

# (name, command, arguments, extra environment); a case that fails is recorded as failing
# (its first error line), so a change that makes it pass or fail differently shows too.
Case = tuple[str, str, tuple[str, ...], dict[str, str]]

_TWO_DOF_EFFECTS = (
    "none",
    "stribeck",
    "cogging",
    "amplifier-lag",
    "miscalibrated",
    "payload",
    "symmetric-coulomb",
)
_URDF_EFFECTS = ("none", "stribeck", "cogging", "amplifier-lag", "miscalibrated")
# The shipped effects profiles give two joints; their n-joint versions (written under the
# output directory, the same text on every run).
_N_JOINT_EFFECTS = {
    "stribeck": "[stribeck]\nbreakaway_ratio = {r}\nvelocity_rad_s = {v}\nexponent = 2.0\n",
    "cogging": "[cogging]\nperiods_per_rev = {p}\namplitude_Nm = {a}\nphase_rad = {ph}\n",
    "amplifier-lag": "[amplifier_lag]\ntime_constant_s = {tc}\n[transport_delay]\n"
    "delay_s = 0.0005\n",
    "miscalibrated": "[torque_gain_error]\nrelative = {g}\n[torque_offset]\noffset_Nm = {o}\n"
    "[encoder_offset]\noffset_rad = {e}\n",
    # a slower lag on symmetric Coulomb friction (tests/test_openloop.py's actuator_lag case):
    # joints that break away on the lag's mean torque and stick again at once
    "lag-symmetric": "[coulomb]\npositive_Nm = {c}\nnegative_Nm = {c}\n[amplifier_lag]\n"
    "time_constant_s = {tl}\n",
}
_PYTHON = {"DDBENCH_PLANT_KERNEL": "python"}


def cases() -> list[Case]:
    """Every golden case."""
    out: list[Case] = []
    for effects in _TWO_DOF_EFFECTS:
        out.append(
            (f"sim-cicese-{effects}", "virtual-robot simulate",
             ("--robot", "cicese", "--effects", effects), {})
        )  # fmt: skip
        out.append(
            (f"run-cicese-{effects}", "hil run",
             ("--bench", "virtual-inprocess", "--effects", effects, "--duration", "4"), {})
        )  # fmt: skip
    out.append(
        ("sim-cicese-lag-symmetric", "virtual-robot simulate",
         ("--robot", "cicese", "--effects", "@lag-symmetric:2"), {})
    )  # fmt: skip
    out.append(
        ("run-cicese-lag-symmetric", "hil run",
         ("--bench", "virtual-inprocess", "--effects", "@lag-symmetric:2", "--duration", "4"), {})
    )  # fmt: skip
    for effects in ("none", "stribeck", "amplifier-lag"):
        out.append(
            (f"sim-dfki-a0-{effects}", "virtual-robot simulate",
             ("--robot", "dfki-a0", "--effects", effects, "--duration", "4"), {})
        )  # fmt: skip
    cicese3 = ("--robot", "cicese3", "--experiment", "cicese3-excitation")
    for effects in (*_URDF_EFFECTS, "joint3-asymmetry", "joint3-gain", "lag-symmetric"):
        fx = f"@{effects}:3" if effects in _N_JOINT_EFFECTS else effects
        for kernel, env in (("compiled", {}), ("python", _PYTHON)):
            duration = "3" if kernel == "compiled" else "1.5"
            out.append(
                (f"sim-cicese3-{effects}-{kernel}", "virtual-robot simulate",
                 (*cicese3, "--effects", fx, "--duration", duration), env)
            )  # fmt: skip
    for effects in ("none", "stribeck", "amplifier-lag"):
        fx = f"@{effects}:3" if effects in _N_JOINT_EFFECTS else effects
        out.append(
            (f"run-cicese3-{effects}", "hil run",
             ("--bench", "virtual-inprocess", *cicese3, "--effects", fx, "--duration", "2"), {})
        )  # fmt: skip
    for kernel, env in (("compiled", {}), ("python", _PYTHON)):
        out.append(
            (f"sim-ur5e-stribeck-{kernel}", "virtual-robot simulate",
             ("--robot", "ur5e", "--experiment", "ur5e-excitation", "--effects", "@stribeck:6",
              "--duration", "1.5"), env)
        )  # fmt: skip
    return out


def n_joint_effects(name: str, n: int, directory: Path) -> Path:
    """The effects profile ``name`` for ``n`` joints, written to ``directory``."""
    text = _N_JOINT_EFFECTS[name].format(
        r=[1.35, 1.25, 1.3, 1.2, 1.3, 1.25][:n],
        v=[0.08, 0.1, 0.09, 0.08, 0.1, 0.12][:n],
        p=[120, 96, 80, 120, 96, 80][:n],
        a=[1.5, 0.12, 0.05, 0.8, 0.1, 0.03][:n],
        ph=[0.0, 0.5, 1.0, 0.0, 0.5, 1.0][:n],
        tc=[0.002, 0.0015, 0.001, 0.002, 0.0015, 0.001][:n],
        g=[0.04, -0.03, 0.02, 0.04, -0.03, 0.02][:n],
        o=[0.6, 0.05, 0.02, 0.3, 0.05, 0.02][:n],
        e=[0.003, -0.002, 0.001, 0.003, -0.002, 0.001][:n],
        c=[7.6095, 1.734, 0.4, 1.0, 0.5, 0.2][:n],
        tl=[0.003, 0.002, 0.002, 0.003, 0.002, 0.002][:n],
    )
    path = directory / f"{name}-{n}.toml"
    path.write_text(f'name = "{name}-{n}"\n' + text)
    return path


def resolve(args: tuple[str, ...], directory: Path) -> tuple[str, ...]:
    """The arguments with each ``@name:n`` (an n-joint effects profile) written to
    ``directory`` and replaced by its path."""
    out = []
    for a in args:
        if a.startswith("@"):
            name, n = a[1:].split(":")
            a = str(n_joint_effects(name, int(n), directory))
        out.append(a)
    return tuple(out)


def run_case(case: Case, out: Path) -> dict[str, object]:
    """Run one case into ``out``; its signals.csv digest and meta.json's plant counters."""
    _, command, args, env = case
    tool, *sub = command.split()
    out.mkdir(parents=True, exist_ok=True)
    args = resolve(args, out.parent)
    argv = [str(BIN / tool), *sub, *args, "--out", str(out), "--overwrite", "--no-plot"]
    proc = subprocess.run(
        argv, capture_output=True, text=True, env=os.environ | env, cwd=ROOT, check=False
    )
    result: dict[str, object] = {"argv": [command, *case[2]], "env": env}
    if proc.returncode != 0:
        lines = [x for x in proc.stderr.splitlines() if x.strip()]
        error = lines[-1] if lines else f"exit {proc.returncode}"
        result["error"] = error.replace(str(out.parent), "DIR").replace(str(ROOT), "ROOT")
        return result
    signals = out / "signals.csv"
    result["sha256"] = hashlib.sha256(signals.read_bytes()).hexdigest()
    meta = json.loads((out / "meta.json").read_text())
    result["counters"] = {k: meta.get(k) for k in ("plant_steps", "stick_events", "faults")}
    return result


def run_all(dest: Path, only: str = "") -> dict[str, dict[str, object]]:
    """Every case (whose name contains ``only``) into dest/<case>; the manifest, also written
    to dest/golden.json."""
    manifest = {}
    for case in (c for c in cases() if only in c[0]):
        manifest[case[0]] = run_case(case, dest / case[0])
        print(case[0], manifest[case[0]].get("sha256", manifest[case[0]].get("error")))
    (dest / "golden.json").write_text(json.dumps(manifest, indent=1, sort_keys=True) + "\n")
    return manifest


def compare(golden: Path, only: str = "") -> int:
    """Run every case again and compare with ``golden`` (cmp on each signals.csv); the count
    of differences."""
    want = json.loads((golden / "golden.json").read_text())
    differences = 0
    with tempfile.TemporaryDirectory() as tmp:
        got = run_all(Path(tmp), only)
        for name, result in got.items():
            if name not in want:
                print(f"{name}: not in {golden}")
                differences += 1
                continue
            if "sha256" in result and (golden / name / "signals.csv").exists():
                before, after = golden / name / "signals.csv", Path(tmp) / name / "signals.csv"
                cmp = subprocess.run(["cmp", str(before), str(after)], check=False)
                if cmp.returncode != 0:
                    differences += 1
                    continue
            for key in ("sha256", "counters", "error"):
                if result.get(key) != want[name].get(key):
                    print(f"{name}: {key} {want[name].get(key)} -> {result.get(key)}")
                    differences += 1
    print(f"{differences} differences over {len(got)} cases")
    return differences


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--write", type=Path, metavar="DIR")
    group.add_argument("--compare", type=Path, metavar="DIR")
    parser.add_argument("--only", default="", help="the cases whose name contains this")
    args = parser.parse_args()
    if args.write:
        args.write.mkdir(parents=True, exist_ok=True)
        run_all(args.write, args.only)
        return 0
    return 1 if compare(args.compare, args.only) else 0


if __name__ == "__main__":
    sys.exit(main())
