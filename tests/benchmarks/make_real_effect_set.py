"""Write a set of effects concealed in real recordings (issue 26, "Proof"): per case the
unmodified recording, the same recording with exactly one known effect written into it, and
``truth.json`` saying which (effect, joint, size).

    .venv/bin/python tests/benchmarks/make_real_effect_set.py --out DIR [--seed 0]
        [--robot dfki-a0,dfki-c0,panda,kuka-lwr4,dfki-pendulum] [--only K]

Sources (``SOURCES``; the real data of ../shared/realdata, tests/realdata.py):
  * ``dfki-a0``, ``dfki-c0``: the DFKI double pendulum's system-identification recordings of
    designs A.0 and C.0 (BSD-3), read and written in their own layout (``--format dfki``); the
    torque modified is the one the format judges by default (``tau_con``, the command); the
    other torque columns are kept as they are.
  * ``panda``: the Panda recording of Gaz et al. (2019) (GPL-3), written as this project's
    ``t,q1..q7,tau1..tau7`` CSV (the joint-torque sensors' torque).
  * ``kuka-lwr4``: the two runs of FloBaRoID's KUKA LWR4+ (``kuka-lwr4-flobaroid``, LGPL-3;
    ~25 s at 200 Hz), each written as the standard CSV (tests/realdata.py ``kuka_columns``: the
    joint-torque sensors' torque); the payload on the profile's a priori URDF.
  * ``dfki-pendulum``: the five controllers' recordings of the DFKI simple pendulum (BSD-3),
    written in their own layout (time, position, velocity, torque) and read with ``--columns
    t=time,q1=position,tau1=torque``; the payload on the profile's URDF (one joint: a mass seen
    through its inertia about the axis and its first moment).
The files made from Panda or KUKA data must stay out of the repository: write them to a
temporary or runs directory only (``--out`` under the repository is refused for them).

How each effect is written (the plant's conventions of virtual_robot/effects.py: the recorded
torque is the command that, through the changed torque path or on the changed arm, makes the
recorded motion). Torques at row i are evaluated at the state of the row the reader aligns them
with (row i + the source's loop delay); the state is the smoothed motion of
:func:`hil.identify.urdf.smoothed_positions` at :func:`hil.identify.urdf.smoothing_cutoff_hz`,
except a payload's (:func:`payload_motion`): smoothed only above :data:`PAYLOAD_CUTOFF` of the
sampling rate (50 Hz at DFKI's 500 Hz). A point mass's torque is mostly inertial on a fast arm
(84 % of joint 1's on DFKI C.0 trajectory 00), and the identification's cutoff (12.8 Hz there)
takes out acceleration the recorded motion has and a real payload's torque would carry:
written at 12.8 Hz, the C.0 payloads of the sets were read 45–60 % light beside a drag and a
rotor inertia (or a joint-2 gain); at 50 Hz, 14 % light to 2 % heavy, alone. A quarter of the
rate let the encoder's noise through (the 99.9th percentile of |q̈| five times the median).

Effect: what is written (truth magnitude; size drawn, and why):
  * torque_gain: τ_j / g, g = 1 + ε (relative ε; ±5–20 %: magnet temperature gives ~5 %, a
    wrong current or gear scale more);
  * torque_offset: τ_j − c (offset_Nm c; ±3–10 % of the joint's RMS torque);
  * transport_delay: τ[i] ← τ[i + k], the last k rows dropped (delay_s, rows; 2–8 ms, a few
    bus periods, at least one row);
  * coulomb_asymmetry: τ_j + a sgn(q̇_j) in one direction only (the change of each level;
    a 3–10 % of the RMS torque; sgn 0 under DEAD_BAND_RAD_S);
  * angle_offset: q_j + δ (offset_rad δ; ±0.02–0.06 rad, 1.1–3.4°, an encoder re-zeroed);
  * cogging: τ_j − A sin(N q_j + φ) (amplitude_Nm, periods_per_rev, phase_rad; A 3–8 % of the
    RMS torque);
  * velocity_squared_drag: τ_j + c q̇_j |q̇_j| (coefficient_Nms2; the drag's RMS 5–15 % of the
    RMS torque), outside the diagnosis's vocabulary;
  * payload: τ + RNEA of a point mass at (q, q̇, q̈), on a recording whose every joint is
    actuated (mass_kg, com_m in the last joint's frame;
    20–60 % of the last body's mass, at 0.8–1.2 times its centre of mass).

Cogging's N is an integer with at least two periods over the swept range (the diagnosis's own
rule, hil.diagnose.candidates.cogging_periods) and a spatial frequency at the joint's RMS speed
under half the smoothing cutoff: higher N would be low-passed away before any model sees it.
Sizes are relative to the joint's RMS torque so the same rule fits a 0.5 Nm pendulum and a
87 Nm arm: an effect smaller than ~3 % is under the recordings' own model error (the owners'
model leaves 10–20 % NRMSE on these files), one above ~20 % would be found by anything.
Nulls: ``same`` (the recording rewritten unmodified) and, where the arm has more recordings,
``other`` (another recording of the same arm and day as the reference: nothing changed on the
arm, but the excitation and the noise did).

Prints one JSON summary on stdout. Everything follows from ``--seed``.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # tests/, for realdata

from realdata import realdata

from drivers.recording import Recording
from hil.identify.urdf import smoothed_positions, smoothing_cutoff_hz
from profiles.recording_format import load_format
from profiles.robot import load_any_robot

REPO = Path(__file__).resolve().parents[2]
DFKI = "dfki-double-pendulum"
# the owners' URDFs of each design (their model 2.1 / 3.1: the rigid bodies of models 2.0 / 3.0)
DFKI_URDF = {
    "dfki-a0": "design_A.0__model_2.1__pendubot.urdf",
    "dfki-c0": "design_C.0__model_3.1__acrobot.urdf",
}
DFKI_GLOB = {
    "dfki-a0": "design_A.0__2022081[25]__sys_id__*.csv",
    "dfki-c0": "design_C.0__20220914__sys_id__*.csv",
}
EFFECTS = (
    "torque_gain",
    "torque_offset",
    "transport_delay",
    "coulomb_asymmetry",
    "angle_offset",
    "cogging",
    "velocity_squared_drag",
    "payload",
)
# what each arm's part of the default set holds (the "x of 10" and "5 of 5"); a 7-joint
# arm with two runs also gets the other run as a null
SEVEN_JOINT = ("torque_gain", "angle_offset", "payload", "transport_delay")
PLAN = {
    "dfki-a0": (*EFFECTS, "null:same", "null:other"),
    "dfki-c0": (*EFFECTS, "null:same", "null:other"),
    "panda": (*SEVEN_JOINT, "null:same"),
    "kuka-lwr4": (*SEVEN_JOINT, "coulomb_asymmetry", "null:same", "null:other"),
    "dfki-pendulum": (*EFFECTS, "null:same", "null:other"),
}
DEAD_BAND_RAD_S = 0.01  # sgn(q̇) = 0 below this smoothed speed (a Coulomb law's sticking band)


@dataclass
class Source:
    """One real recording in its own layout: the file's columns, which are time, positions and
    the judged torque, the rows' loop delay, and the arm's URDF for the payload."""

    name: str
    robot: str
    path: Path
    licence: str
    header: list[str]
    data: np.ndarray  # (rows, columns) as in the file
    time: str
    positions: tuple[str, ...]
    torques: tuple[str, ...]
    loop_delay: int
    urdf_xml: str
    gravity_m_s2: float
    fmt: str | None  # --format to read the written files with
    columns: str | None = None  # else --columns to read them with

    def col(self, name: str) -> np.ndarray:
        return self.data[:, self.header.index(name)]

    @property
    def t(self) -> np.ndarray:
        return self.col(self.time)

    @property
    def q(self) -> np.ndarray:
        return np.column_stack([self.col(c) for c in self.positions])

    @property
    def tau(self) -> np.ndarray:
        return np.column_stack([self.col(c) for c in self.torques])

    @property
    def n_joints(self) -> int:
        return len(self.positions)

    def with_columns(self, values: dict[str, np.ndarray], rows: slice = slice(None)) -> Source:
        data = self.data[rows].copy()
        for name, v in values.items():
            data[:, self.header.index(name)] = v
        return replace(self, data=data)

    def write(self, path: Path) -> None:
        # 17 significant digits: every float64 of the file comes back exactly
        np.savetxt(path, self.data, delimiter=",", header=",".join(self.header), comments="",
                   fmt="%.17g")  # fmt: skip

    def diagnose_args(self) -> list[str]:
        """The `hil diagnose` / `hil identify` options that read the written files."""
        read = ["--format", self.fmt] if self.fmt else []
        return (
            read + (["--columns", self.columns] if self.columns else []) + ["--robot", self.robot]
        )


def _dfki_urdf_xml(robot: str) -> str:
    """The owners' URDF with the ``world`` link their ``base_weld`` joint names (missing from the
    file, which urdfdom refuses); "" when ../shared/realdata is absent (no payload then)."""
    path = realdata(DFKI) / "params" / DFKI_URDF[robot]
    if not path.is_file():
        return ""
    text = path.read_text(encoding="utf-8")
    return re.sub(r"(<robot[^>]*>)", r'\1\n  <link name="world" />', text, count=1)


def dfki_source(path: Path, robot: str) -> Source:
    """One DFKI recording in its own layout (the dfki format's layout that fits its header)."""
    header = path.read_text(encoding="utf-8").split("\n", 1)[0].strip().split(",")
    layout = load_format("dfki").layout_for(header)
    if layout is None:
        raise ValueError(f"{path}: no layout of the dfki format fits its header")
    torque = layout.torques[layout.default_torque]
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return Source(path.stem, robot, path, "BSD-3-Clause", header, data, layout.time,
                  layout.positions, torque.columns, torque.loop_delay, _dfki_urdf_xml(robot),
                  load_any_robot(robot).gravity_m_s2, "dfki")  # fmt: skip


def dfki_sources(robot: str) -> list[Source]:
    """The system-identification recordings of a DFKI design."""
    records = realdata(DFKI) / "records"
    return [dfki_source(p, robot) for p in sorted(records.glob(DFKI_GLOB[robot]))]


def panda_sources() -> list[Source]:
    """The Panda recording of Gaz et al. (2019), as this project's t,q1..q7,tau1..tau7."""
    from drivers.one_per_line import read_one_per_line_log

    folder = realdata("panda-gaz2019") / "rbt_log"
    rec = read_one_per_line_log(folder)
    n = rec.n_joints
    header = ["t", *(f"q{j + 1}" for j in range(n)), *(f"tau{j + 1}" for j in range(n))]
    data = np.column_stack([rec.t, rec.q, rec.tau])
    profile = load_any_robot("panda")
    xml = Path(profile.urdf).read_text(encoding="utf-8")
    return [Source("panda-gaz2019", "panda", folder, "GPL-3.0", header, data, "t",
                   tuple(header[1:n + 1]), tuple(header[n + 1:]), 0, xml,
                   profile.gravity_m_s2, None)]  # fmt: skip


def kuka_sources() -> list[Source]:
    """The two runs of the KUKA LWR4+ (FloBaRoID), as this project's t,q1..q7,tau1..tau7."""
    from realdata import KUKA, kuka_columns

    runs = sorted(int(p.stem.rsplit("_", 1)[1]) for p in realdata(KUKA).glob("measurements_*.npz"))
    profile = load_any_robot("kuka-lwr4")
    xml = Path(profile.urdf).read_text(encoding="utf-8")
    sources = []
    for run in runs:
        header, data = kuka_columns(run)
        n = (len(header) - 1) // 2
        sources.append(Source(f"kuka-measurements_{run}", "kuka-lwr4",
                              realdata(KUKA) / f"measurements_{run}.npz", "LGPL-3.0", header,
                              data, "t", tuple(header[1:n + 1]), tuple(header[n + 1:]), 0, xml,
                              profile.gravity_m_s2, None))  # fmt: skip
    return sources


PENDULUM = "dfki-simple-pendulum"
PENDULUM_COLUMNS = "t=time,q1=position,tau1=torque"  # docs/real-data.md, "DFKI simple pendulum"


def pendulum_source(path: Path) -> Source:
    """One recording of the DFKI simple pendulum (BSD-3) in its own layout (time, position,
    velocity, torque), read with ``--columns``; the payload on the profile's URDF."""
    profile = load_any_robot("dfki-pendulum")
    xml = Path(profile.urdf).read_text(encoding="utf-8")
    header = path.read_text(encoding="utf-8").split("\n", 1)[0].strip().split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return Source(path.stem, "dfki-pendulum", path, "BSD-3-Clause", header, data, "time",
                  ("position",), ("torque",), 0, xml, profile.gravity_m_s2, None,
                  PENDULUM_COLUMNS)  # fmt: skip


def pendulum_sources() -> list[Source]:
    """The five controllers' recordings of the DFKI simple pendulum."""
    return [pendulum_source(p) for p in sorted((realdata(PENDULUM) / "records").glob("*.csv"))]


# robot -> its recordings
SOURCES: dict[str, Callable[[], list[Source]]] = {
    "dfki-a0": lambda: dfki_sources("dfki-a0"),
    "dfki-c0": lambda: dfki_sources("dfki-c0"),
    "panda": panda_sources,
    "kuka-lwr4": kuka_sources,
    "dfki-pendulum": pendulum_sources,
}
# the recordings whose licence keeps them (and every file made from them) out of the tree
OUTSIDE_TREE = ("panda", "kuka-lwr4")


# --- the motion and the effects --------------------------------------------------------------


@dataclass(frozen=True)
class Motion:
    """Smoothed q, q̇, q̈ at the rows each torque row is aligned with (row i + loop delay)."""

    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    cutoff_hz: float


# a payload's motion is smoothed only above this fraction of the sampling rate (module doc)
PAYLOAD_CUTOFF = 0.1


def motion_at_torque_rows(src: Source, cutoff_hz: float | None = None) -> Motion:
    """The smoothed motion at the rows the torques act on; ``cutoff_hz``: the smoothing's
    cutoff, else :func:`hil.identify.urdf.smoothing_cutoff_hz`."""
    t = src.t
    rec = Recording.from_arrays(t, src.q, src.tau)
    cutoff = smoothing_cutoff_hz(rec) if cutoff_hz is None else cutoff_hz
    spline = smoothed_positions(rec, cutoff)
    at = t[np.clip(np.arange(len(t)) + src.loop_delay, 0, len(t) - 1)]
    return Motion(spline(at), spline(at, 1), spline(at, 2), cutoff)


def payload_motion(src: Source) -> Motion:
    """The motion a payload's torque is computed at: smoothed only above
    :data:`PAYLOAD_CUTOFF` of the sampling rate (module doc)."""
    rate = 1.0 / float(np.median(np.diff(src.t)))
    return motion_at_torque_rows(src, PAYLOAD_CUTOFF * rate)


def _sign(v: np.ndarray) -> np.ndarray:
    return np.where(np.abs(v) < DEAD_BAND_RAD_S, 0.0, np.sign(v))


def _signed(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.choice([-1.0, 1.0]) * rng.uniform(lo, hi))


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def pinocchio_model(src: Source) -> Any:
    import pinocchio as pin

    if not src.urdf_xml:
        raise ValueError(f"{src.name}: no URDF of {src.robot} found (../shared/realdata)")
    model = pin.buildModelFromXML(src.urdf_xml)
    model.gravity.linear = np.array([0.0, 0.0, -src.gravity_m_s2])
    return model


def payload_torque(src: Source, motion: Motion, mass_kg: float, com_m: np.ndarray) -> np.ndarray:
    """Torque of a point mass at ``com_m`` (the last joint's frame) at the motion, by Pinocchio's
    RNEA: RNEA(arm + mass) − RNEA(arm), which is RNEA of the mass alone (RNEA is linear in the
    bodies' inertias)."""
    import pinocchio as pin

    arm = pinocchio_model(src)
    loaded = pin.Model(arm)
    last = loaded.njoints - 1
    loaded.inertias[last] = loaded.inertias[last] + pin.Inertia(
        float(mass_kg), np.asarray(com_m, float), np.zeros((3, 3))
    )
    da, dl = arm.createData(), loaded.createData()
    out = np.empty_like(motion.q)
    for i, (q, v, a) in enumerate(zip(motion.q, motion.dq, motion.ddq, strict=True)):
        out[i] = pin.rnea(loaded, dl, q, v, a) - pin.rnea(arm, da, q, v, a)
    return out


def make_effect(
    src: Source, effect: str, joint: int, rng: np.random.Generator
) -> tuple[Source, dict[str, Any]]:
    """``src`` with ``effect`` written into joint ``joint`` (0-based; payload: the arm), and
    the truth: {effect, joint (1-based; None for the arm), magnitude, size}."""
    motion = motion_at_torque_rows(src)
    tau = src.tau
    name_tau, name_q = src.torques[joint], src.positions[joint]
    level = _rms(tau[:, joint])
    dq = motion.dq[:, joint]
    if effect == "torque_gain":
        eps = _signed(rng, 0.05, 0.20)
        new, mag = {name_tau: tau[:, joint] / (1.0 + eps)}, {"relative": eps}
        size = eps
    elif effect == "torque_offset":
        c = _signed(rng, 0.03, 0.10) * level
        new, mag, size = {name_tau: tau[:, joint] - c}, {"offset_Nm": c}, c
    elif effect == "transport_delay":
        dt = np.diff(src.t)
        k = max(1, math.floor(rng.uniform(0.002, 0.008) / float(np.median(dt))))
        n = len(src.t) - k
        delay = float(np.mean(src.t[k:] - src.t[:-k]))
        shifted = src.with_columns({c: src.col(c)[k:] for c in src.torques}, slice(0, n))
        truth = {"effect": effect, "joint": None, "size": delay,
                 "magnitude": {"delay_s": delay, "rows": k}}  # fmt: skip
        return shifted, truth
    elif effect == "coulomb_asymmetry":
        a = float(rng.uniform(0.03, 0.10)) * level
        direction = float(rng.choice([-1.0, 1.0]))
        s = _sign(dq)
        new = {name_tau: tau[:, joint] + a * s * (s == direction)}
        mag = {
            "positive_Nm": a if direction > 0 else 0.0,
            "negative_Nm": a if direction < 0 else 0.0,
        }
        size = mag["negative_Nm"] - mag["positive_Nm"]
    elif effect == "angle_offset":
        d = _signed(rng, 0.02, 0.06)
        new, mag, size = {name_q: src.col(name_q) + d}, {"offset_rad": d}, d
    elif effect == "cogging":
        q = motion.q[:, joint]
        lowest = max(3, math.ceil(4 * math.pi / max(float(np.ptp(q)), 1e-9)))
        highest = max(lowest, math.floor(math.pi * motion.cutoff_hz / max(_rms(dq), 1e-9)))
        periods = int(rng.integers(lowest, highest + 1))
        amp = float(rng.uniform(0.03, 0.08)) * level
        phase = float(rng.uniform(0.0, 2 * math.pi))
        new = {name_tau: tau[:, joint] - amp * np.sin(periods * q + phase)}
        mag = {"amplitude_Nm": amp, "periods_per_rev": float(periods), "phase_rad": phase}
        size = amp
    elif effect == "velocity_squared_drag":
        drag = dq * np.abs(dq)
        c = float(rng.uniform(0.05, 0.15)) * level / max(_rms(drag), 1e-12)
        new, mag, size = {name_tau: tau[:, joint] + c * drag}, {"coefficient_Nms2": c}, c
    elif effect == "payload":
        import pinocchio as pin

        arm = pinocchio_model(src)
        body = arm.inertias[arm.njoints - 1]
        mass = float(rng.uniform(0.2, 0.6)) * float(body.mass)
        com = np.asarray(body.lever, float) * float(rng.uniform(0.8, 1.2))
        extra = payload_torque(src, payload_motion(src), mass, com)
        new = {c: tau[:, j] + extra[:, j] for j, c in enumerate(src.torques)}
        truth = {"effect": effect, "joint": None, "size": mass,
                 "magnitude": {"mass_kg": mass, "com_m": [float(x) for x in com],
                               "joint_frame": str(arm.names[arm.njoints - 1])}}  # fmt: skip
        del pin
        return src.with_columns(new), truth
    else:
        raise ValueError(f"unknown effect {effect!r} (one of {', '.join(EFFECTS)})")
    truth = {"effect": effect, "joint": joint + 1, "size": size, "magnitude": mag}
    return src.with_columns(new), truth


# --- the set -----------------------------------------------------------------------------------


def _inside_repo(path: Path) -> bool:
    try:
        path.resolve().relative_to(REPO)
    except ValueError:
        return False
    return True


IN_JOINT_TORQUE = ("torque_gain", "torque_offset", "coulomb_asymmetry", "cogging",
                   "velocity_squared_drag")  # fmt: skip  # written into τ_j alone


def _actuated_joints(src: Source) -> list[int]:
    """The joints (0-based) whose torque column is not 0 throughout (a passive joint's is)."""
    return [j for j in range(src.n_joints) if np.any(src.tau[:, j] != 0.0)]


def _angle_joints(src: Source) -> list[int]:
    """The joints (0-based) on whose angle the arm's torques can depend. Rotation about a
    vertical first axis (the Panda's and the KUKA's joint 1) changes neither M(q), the Coriolis
    terms nor gravity, whatever the bodies' inertias: an encoder offset there changes no
    recorded torque against any model, and no method could see it. Tested by Pinocchio's RNEA
    of the URDF's joints with generic bodies, at a few recorded positions, every velocity and
    acceleration 1; without a URDF, every joint."""
    if not src.urdf_xml:
        return list(range(src.n_joints))
    import pinocchio as pin

    model = pin.Model(pinocchio_model(src))
    generic = np.random.default_rng(0)  # structure, not the URDF's values: a symmetric last
    for i in range(1, model.njoints):  # link hides its angle in the URDF, not in a fitted θ
        mass, com = 1.0 + generic.uniform(), generic.uniform(-0.1, 0.1, 3)
        model.inertias[i] = pin.Inertia(mass, com, np.diag(generic.uniform(0.01, 0.02, 3)))
    data = model.createData()
    ones = np.ones(src.n_joints)
    rows = src.q[np.linspace(0, len(src.q) - 1, 8).astype(int)]
    moved = []
    for j in range(src.n_joints):
        step = np.eye(src.n_joints)[j] * 0.05
        change = max(
            np.max(
                np.abs(
                    pin.rnea(model, data, q + step, ones, ones)
                    - pin.rnea(model, data, q, ones, ones)
                )
            )
            for q in rows
        )
        if change > 1e-9:
            moved.append(j)
    return moved


def _drawn_joint(src: Source, effect: str, rng: np.random.Generator) -> int:
    """The joint an effect is written into (0-based): for an effect written into τ_j alone,
    one whose torque column is not 0 throughout. A passive joint (DFKI C.0's pendubot and
    acrobot recordings log τ_con ≡ 0 on one joint) has no torque to scale, offset or add a
    term proportional to its RMS to: the file would come out unchanged and its truth
    unobservable. An encoder offset: a joint on whose angle the torques depend
    (:func:`_angle_joints`). One draw either way, so the other cases of a seed stay as they
    were."""
    joint = int(rng.integers(src.n_joints))
    if effect == "angle_offset":
        seen = _angle_joints(src)
    elif effect in IN_JOINT_TORQUE:
        seen = _actuated_joints(src)
    else:
        return joint
    return joint if joint in seen or not seen else seen[joint % len(seen)]


def _payload_source(sources: list[Source], effect: str, k: int) -> int:
    """The source a case is written into: for a payload, one whose every joint is actuated.
    A point mass on a passive joint's link (DFKI C.0 trajectory 06 logs τ_con ≡ 0 on joint 2)
    changes that joint's motion, not its torque: its RNEA torque written there would be a
    torque no actuator gave. The next such source after the drawn one, with no other draw, so
    the other cases of a seed stay as they were."""

    def actuated(src: Source) -> bool:
        return len(_actuated_joints(src)) == src.n_joints

    if effect != "payload" or actuated(sources[k]):
        return k
    full = [i for i in range(len(sources)) if actuated(sources[(k + i) % len(sources)])]
    return (k + full[0]) % len(sources) if full else k


def plan_cases(robots: list[str], rng: np.random.Generator) -> list[dict[str, Any]]:
    """The cases to write: robot, source index, effect and joint of each."""
    cases = []
    for robot in robots:
        sources = SOURCES[robot]()
        if not sources:
            raise SystemExit(f"make_real_effect_set: no recordings of {robot} found")
        for effect in PLAN[robot]:
            k = _payload_source(sources, effect, int(rng.integers(len(sources))))
            other = None
            if effect == "null:other":
                if len(sources) < 2:
                    continue
                other = int(rng.choice([i for i in range(len(sources)) if i != k]))
            joint = _drawn_joint(sources[k], effect, rng)
            cases.append({"robot": robot, "sources": sources, "source": k, "other": other,
                          "effect": effect, "joint": joint})  # fmt: skip
    return cases


def write_set(out: Path, robots: list[str], seed: int, only: int | None = None) -> dict[str, Any]:
    """Write the set to ``out`` (replaced if it holds an earlier set's truth.json) and return
    its truth document."""
    if any(r not in SOURCES for r in robots):
        raise SystemExit(f"make_real_effect_set: robots are {', '.join(SOURCES)}")
    if any(r in OUTSIDE_TREE for r in robots) and _inside_repo(out):
        raise SystemExit(
            f"make_real_effect_set: {out} is inside the repository; the Panda (GPL-3) and KUKA "
            "(LGPL-3) data must not enter it: write to a temporary or runs directory"
        )
    if out.exists():
        if (out / "truth.json").is_file():
            shutil.rmtree(out)
        elif any(out.iterdir()):
            raise SystemExit(f"make_real_effect_set: {out} is not empty and holds no truth.json")
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    cases = plan_cases(robots, rng)[:only]
    entries = []
    for n, case in enumerate(cases):
        src: Source = case["sources"][case["source"]]
        name = f"case-{n + 1:02d}"
        folder = out / name
        folder.mkdir()
        if case["effect"].startswith("null:"):
            reference = src if case["other"] is None else case["sources"][case["other"]]
            modified, truth = src, []
        else:
            reference = src
            modified, one = make_effect(src, case["effect"], case["joint"], rng)
            truth = [one]
        reference.write(folder / "reference.csv")
        modified.write(folder / "recording.csv")
        entries.append({
            "case": name, "robot": case["robot"], "effect": case["effect"],
            "null": not truth, "truth": truth,
            "recording": src.name, "reference": reference.name, "licence": src.licence,
            "diagnose_args": modified.diagnose_args(),
        })  # fmt: skip
        print(f"make_real_effect_set: {name} {case['robot']} {src.name} {case['effect']}"
              f"{'' if not truth else f' {truth[0]}'}", file=sys.stderr)  # fmt: skip
    doc = {"generated_by": "tests/benchmarks/make_real_effect_set.py", "seed": seed,
           "robots": robots, "cases": entries}  # fmt: skip
    (out / "truth.json").write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    return doc


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="directory of the set (outside the repo "
                        "for Panda/KUKA data)")  # fmt: skip
    parser.add_argument("--seed", type=int, default=0, help="seed of the set's random draws")
    parser.add_argument("--robot", default="dfki-a0,dfki-c0,panda",  # kuka-lwr4 by name
                        help=f"comma-separated, of {', '.join(SOURCES)}")  # fmt: skip
    parser.add_argument("--only", type=int, default=None, help="write the first K cases")
    args = parser.parse_args(argv)
    robots = [r.strip() for r in args.robot.split(",") if r.strip()]
    doc = write_set(Path(args.out), robots, args.seed, args.only)
    print(json.dumps({"out_dir": args.out, "cases": len(doc["cases"]),
                      "null": sum(c["null"] for c in doc["cases"])}))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
