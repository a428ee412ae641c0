"""Experiment profile: open-loop excitation torques (Reyes & Kelly eqs. (31)-(32) and the like)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from profiles.loader import Fields, load_toml


@dataclass(frozen=True)
class Sine:
    amplitude_Nm: float
    omega_rad_s: float
    phase_rad: float


@dataclass(frozen=True)
class JointExcitation:
    """τ(t) = offset_Nm + step_Nm (1 − e^{−step_rate t}) + Σ_k A_k sin(ω_k t + φ_k)
    (eqs. (31)-(32); the constant ``offset_Nm``, default 0, carries the mean of a designed
    periodic torque, hil/excitation.py)."""

    step_Nm: float
    step_rate_per_s: float
    sines: tuple[Sine, ...]
    offset_Nm: float = 0.0

    def torque(self, t: float | np.ndarray) -> float | np.ndarray:
        t_arr = np.asarray(t, dtype=float)
        tau = self.offset_Nm + self.step_Nm * (1.0 - np.exp(-self.step_rate_per_s * t_arr))
        for s in self.sines:
            tau = tau + s.amplitude_Nm * np.sin(s.omega_rad_s * t_arr + s.phase_rad)
        return float(tau) if np.ndim(t) == 0 else tau

    def peak_Nm(self) -> float:
        """Upper bound on |τ(t)| (offset, step and all amplitudes)."""
        return (
            abs(self.offset_Nm) + abs(self.step_Nm) + sum(abs(s.amplitude_Nm) for s in self.sines)
        )


@dataclass(frozen=True)
class ExperimentProfile:
    name: str
    source: str
    kind: str
    period_s: float
    duration_s: float
    initial_q_rad: tuple[float, float]
    joints: tuple[JointExcitation, JointExcitation]

    def torque(self, t: float) -> tuple[float, float]:
        """Commanded torques [Nm] at time t."""
        return (self.joints[0].torque(t), self.joints[1].torque(t))

    def torque_table(self, t: np.ndarray) -> np.ndarray:
        """Commanded torques at every time in ``t``, shape (len(t), 2)."""
        return np.column_stack([self.joints[0].torque(t), self.joints[1].torque(t)])


KINDS = ("open_loop_torque",)


def load_experiment(name_or_path: str | Path) -> ExperimentProfile:
    data, source = load_toml("experiments", name_or_path)
    f = Fields(data, source)
    if data.get("kind") == "tracking":  # closed loop: profiles/tracking.py, `hil control`
        raise f.error("kind", "a tracking experiment is closed loop: run it with `hil control`")
    f.only({"name", "description", "kind", "period_s", "duration_s", "initial_q_rad", "joints"})
    kind = f.string("kind")
    if kind not in KINDS:
        raise f.error(
            "kind", f"unknown experiment kind {kind!r}; expected one of {', '.join(KINDS)}"
        )
    joint_tables = f.tables("joints")
    if len(joint_tables) != 2:
        raise f.error("joints", f"must have 2 entries (one per joint), got {len(joint_tables)}")
    joints = []
    for jt in joint_tables:
        jt.only({"step_Nm", "step_rate_per_s", "offset_Nm", "sines"})
        sines = []
        for st in jt.tables("sines") if jt.has("sines") else []:
            st.only({"amplitude_Nm", "omega_rad_s", "phase_rad"})
            sines.append(
                Sine(
                    st.number("amplitude_Nm"),
                    st.number("omega_rad_s", lo=0.0),
                    st.number("phase_rad", 0.0),
                )
            )
        joints.append(
            JointExcitation(
                jt.number("step_Nm", 0.0),
                jt.number("step_rate_per_s", 1.0, lo=0.0),
                tuple(sines),
                offset_Nm=jt.number("offset_Nm", 0.0),
            )
        )
    initial = f.numbers("initial_q_rad", 2, [0.0, 0.0], lo=-2 * math.pi, hi=2 * math.pi)
    return ExperimentProfile(
        name=f.string("name"),
        source=source,
        kind=kind,
        period_s=f.number("period_s", positive=True, hi=1.0),
        duration_s=f.number("duration_s", positive=True),
        initial_q_rad=initial,  # type: ignore[arg-type]
        joints=(joints[0], joints[1]),
    )
