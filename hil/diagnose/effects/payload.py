"""A payload: a point mass m at c (in the last body's frame) that the nominal model lacks.

For an arm described by a URDF the nominal rows are Ψ_b θ_b with θ_b = E θ_std (the base
parameters, :class:`hil.model.urdf.UrdfArmModel`), so the rows of the last body's ten standard
parameters (Pinocchio's order m, m c, I at the frame origin) are Ψ_b E_last. A point mass adds
m (1, c, |c|² 1 − c cᵀ) to them; with h = m c that is linear in (m, h) once the inertia's c is
held at ĉ: m I = (ĉ·h) 1 − ½ (h ĉᵀ + ĉ hᵀ) (exact at ĉ = c), so the fit is repeated with
ĉ = h / m. The 2-DOF closed-form θ has no body parameters to place it in: not tested there.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hil.diagnose.effects.base import Context, Effect, SimInput, r4, register

# Pinocchio's dynamic parameters: m, mx, my, mz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz
_INERTIA = ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2))


def _inertia_vector(matrix: np.ndarray) -> np.ndarray:
    return np.array([matrix[a, b] for a, b in _INERTIA])


def point_mass_standard(m: float, c: np.ndarray) -> np.ndarray:
    """The ten standard parameters of a point mass m at c."""
    c = np.asarray(c, float)
    inertia = m * (float(c @ c) * np.eye(3) - np.outer(c, c))
    return np.concatenate([[m], m * c, _inertia_vector(inertia)])


def _last_body(ctx: Context) -> np.ndarray:
    """E's columns of the last body's standard parameters (p_base, 10)."""
    n = ctx.n_joints
    return ctx.model.base.expand[:, 10 * (n - 1) : 10 * n]


class Payload(Effect):
    name = "payload"
    width = 4
    nonlinear = True
    partners = ("torque_gain", "encoder_offset")
    separate = (
        "a motion with the last joints still and the first ones moving slowly, then the same "
        "with the payload off (a mass shows in gravity at every pose, a gain in every torque)"
    )
    floor = 0.01  # kg

    def applies(self, ctx: Context) -> bool:
        return not ctx.closed_form

    def variants(self, ctx: Context) -> list[int | None]:
        return [None]

    def start(self, ctx: Context, joint: int | None) -> Any:
        return np.zeros(3)

    def columns(self, ctx: Context, joint: int | None, at: Any) -> np.ndarray:
        Y = ctx.Psi_raw @ _last_body(ctx)  # (K, n, 10): rows of the last body's parameters
        c = np.asarray(at, float)
        cols = [Y[:, :, 0]]
        for k in range(3):
            e = np.zeros(3)
            e[k] = 1.0
            inertia = c[k] * np.eye(3) - 0.5 * (np.outer(e, c) + np.outer(c, e))
            cols.append(Y[:, :, 1 + k] + Y[:, :, 4:] @ _inertia_vector(inertia))
        return np.stack(cols, axis=-1)

    def update(self, ctx, joint, beta, at):
        m = float(beta[0])
        return np.asarray(beta[1:4], float) / m if abs(m) > 1e-9 else np.zeros(3)

    def estimate(self, ctx, joint, beta, se, at):
        m, s = float(beta[0]), float(se[0])
        c = np.asarray(beta[1:4], float) / m if abs(m) > 1e-9 else np.zeros(3)
        c_se = np.asarray(se[1:4], float) / max(abs(m), 1e-9)
        return (
            {
                "mass_kg": r4(m),
                "mass_se_kg": r4(s),
                "centre_m": [r4(x) for x in c],
                "centre_se_m": [r4(x) for x in c_se],
                "body": f"the last body (joint {ctx.n_joints}'s frame)",
            },
            m,
            s,
        )

    def words(self, e: dict[str, Any]) -> str:
        c = ", ".join(f"{x:+.3g}" for x in e["centre_m"])
        return (
            f"a payload of {e['mass_kg']:.3g} ± {e['mass_se_kg']:.2g} kg at ({c}) m on {e['body']}"
        )

    def simulation(self, ctx: Context, joint: int | None, e: dict[str, Any]) -> SimInput:
        std = point_mass_standard(e["mass_kg"], np.array(e["centre_m"]))
        return SimInput(dtheta=_last_body(ctx) @ std)


register(Payload())
