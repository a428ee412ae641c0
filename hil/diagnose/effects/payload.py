"""A payload: a point mass m at c (in the last body's frame) that the nominal model lacks.

For an arm described by a URDF the nominal rows are Ψ_b θ_b with θ_b = E θ_std (the base
parameters, :class:`hil.model.urdf.UrdfArmModel`), so the rows of the last body's ten standard
parameters (Pinocchio's order m, m c, I at the frame origin) are Ψ_b E_last. A point mass adds
m (1, c, |c|² 1 − c cᵀ) to them; with h = m c that is linear in (m, h) once the inertia's c is
held at ĉ: m I = (ĉ·h) 1 − ½ (h ĉᵀ + ĉ hᵀ) (exact at ĉ = c), so the fit is repeated with
ĉ = h / m.

Where the last body's frame origin lies on every joint axis (a one-joint pendulum: a mass at
the origin makes no torque), m has no column of its own in that form and is seen only through
the mass's inertia about the axes. There the point mass is fitted as the 2-DOF one below, by
Gauss–Newton in its centre: X = [Y φ(1, ĉ), Y ∂φ/∂c_k (ĉ)] with φ(m, c) the ten parameters above,
β = (m, m δc), the next ĉ = ĉ + δc, from a centre on either side of each axis
(:data:`DEGENERATE_STARTS` times the body's own centre-of-mass distance); a centre along an
axis that no torque sees (the pendulum's own axis) stays where it started.

On the 2-DOF closed form (Reyes & Kelly (1997), Section 5) a point mass m on link 2 at l_p from
joint 2 adds Δθ1 = m (l1² + l_p²), Δθ2 = l1 m l_p, Δθ3 = m l_p², Δθ4 = g m l1, Δθ5 = g m l_p
(:func:`virtual_robot.effects.payload_theta` without its own inertia): the torque
m x(l_p), x(l) = a + l b + l² c with a = l1² Ψ₁ + g l1 Ψ₄, b = l1 Ψ₂ + g Ψ₅, c = Ψ₁ + Ψ₃. It is
linearised in l_p at l̂ (Gauss–Newton): X = [x(l̂), x'(l̂) = b + 2 l̂ c], β = (m, m δl), the next
l̂ = l̂ + δl, from several starting centres (:meth:`Payload.starts`), the best fit kept. The
least squares has two stationary branches: holding l_p² at l̂ with (m, m l_p) free (three
free numbers for two) converged on DFKI A.0 to −0.107 kg for a 0.154 kg payload. It needs l1
and g from the robot profile.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hil.diagnose.effects.base import Context, Effect, SimInput, register
from hil.diagnose.finding import rounded

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


def _body_rows(ctx: Context) -> np.ndarray:
    """Y (K, n, 10): the rows of the last body's standard parameters."""
    return ctx.Psi_raw @ _last_body(ctx)


# the mass column of a mass at the last frame's origin is round-off against its first moments'
# (module doc): below this fraction of their norm the point mass is fitted in its centre
DEGENERATE_MASS = 1e-9
# the degenerate form's starting centres: on either side of each axis of the last frame, at
# these multiples of the last body's centre-of-mass distance (0.1 m where it has none)
DEGENERATE_STARTS = (1.0,)


def _degenerate(ctx: Context) -> bool:
    """Whether a mass at the last frame's origin makes no torque (module doc)."""
    if ("payload", "degenerate") not in ctx.memo:
        Y = _body_rows(ctx)
        moments = float(np.linalg.norm(Y[:, :, 1:4]))
        ctx.memo[("payload", "degenerate")] = bool(
            moments > 0 and np.linalg.norm(Y[:, :, 0]) <= DEGENERATE_MASS * moments
        )
    return ctx.memo[("payload", "degenerate")]


def _unit_mass_rows(Y: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Y φ(1, c) (K, n) and its derivatives in c (K, n, 3): a unit point mass at c."""
    value = Y @ point_mass_standard(1.0, c)
    slopes = []
    for k in range(3):
        e = np.zeros(3)
        e[k] = 1.0
        d_inertia = 2 * c[k] * np.eye(3) - (np.outer(e, c) + np.outer(c, e))
        slopes.append(Y[:, :, 1 + k] + Y[:, :, 4:] @ _inertia_vector(d_inertia))
    return value, np.stack(slopes, axis=-1)


def _body_lever(ctx: Context) -> float:
    """The last body's centre-of-mass distance from its frame in the profile's URDF (m); 0.1
    where it has none (no mass, or its centre at the frame's origin)."""
    std = np.asarray(ctx.model.standard_theta, float)[10 * (ctx.n_joints - 1) :][:4]
    lever = float(np.linalg.norm(std[1:4]) / std[0]) if std[0] > 0 else 0.0
    return lever or 0.1


# starting centres of the 2-DOF point mass, in link-1 lengths from joint 2 (module doc), a
# quarter length apart: where the mass's inertial and gravity torques nearly cancel (a swing)
# its fit is sharp in the centre, and a 0.35 kg mass at 0.185 m on A.0 (l1 = 0.3 m) fitted
# worse at 0.3 m than at 0 (whence the steps went to a negative mass)
PLANAR_STARTS = tuple(np.arange(-2.0, 2.01, 0.25))


def _planar_columns(ctx: Context, lp: float) -> np.ndarray:
    """(x(l̂), x'(l̂)) of the 2-DOF arm's point mass on link 2 at l̂ = ``lp`` (module doc),
    (K, 2, 2)."""
    assert ctx.geometry is not None
    P, l1, g = ctx.Psi_raw, ctx.geometry["link1_m"], ctx.geometry["gravity_m_s2"]
    a = l1**2 * P[:, :, 0] + g * l1 * P[:, :, 3]
    b = l1 * P[:, :, 1] + g * P[:, :, 4]
    c = P[:, :, 0] + P[:, :, 2]
    return np.stack([a + lp * b + lp**2 * c, b + 2 * lp * c], axis=-1)


def _planar_rest(ctx: Context, m: float, lp: float) -> str | None:
    """Why link 2 of the 2-DOF profile, less a point mass m < 0 at l_p on its axis, is no rigid
    body: its mass gone, or its inertia about its own centre of mass below zero (too little
    mass left to carry its first moment); None when it may be one. Link 2's mass, first moments
    and inertia about joint 2 are the profile's (``ctx.geometry``); None without them."""
    geo = ctx.geometry or {}
    if "link2_kg" not in geo:
        return None
    m2 = geo["link2_kg"]
    rest = m2 + m
    if rest <= 0:
        return f"{-m:.3g} kg taken off link 2 is more than its {m2:.3g} kg"
    along = geo["link2_moment_kgm"] + m * lp
    across = geo["link2_moment_across_kgm"]
    about_joint = geo["link2_inertia_kgm2"] + m * lp**2
    about_centre = about_joint - (along**2 + across**2) / rest  # parallel-axis theorem
    if about_centre < 0:
        return (
            f"without {-m:.3g} kg at {lp:.3g} m link 2 keeps {rest:.3g} kg, too little to carry "
            f"its first moment {along:.3g} kg m (its inertia about its centre of mass would be "
            f"{about_centre:.3g} kg m²)"
        )
    return None


class Payload(Effect):
    name = "payload"
    width = 4  # (m, m c) of a URDF arm's last body; 2 on the 2-DOF arm (m, m l_p)
    nonlinear = True
    partners = ("torque_gain", "encoder_offset")
    separate = (
        "a motion with the last joints still and the first ones moving slowly, then the same "
        "with the payload off (a mass shows in gravity at every pose, a gain in every torque)"
    )
    floor = 0.01  # kg

    def applies(self, ctx: Context) -> bool:
        return not ctx.closed_form or bool(ctx.geometry)

    def variants(self, ctx: Context) -> list[int | None]:
        return [None]

    step_tolerance = 1e-7  # m of the centre
    tested_jointly = True  # the mass beside the centre's step (Effect.tested_jointly)

    def _in_centre(self, ctx: Context) -> bool:
        """Fitted by Gauss–Newton in its centre, β = (m, m δc): the 2-DOF closed form, and a
        URDF arm whose mass column is degenerate (module doc)."""
        return ctx.closed_form or _degenerate(ctx)

    def start(self, ctx: Context, joint: int | None) -> Any:
        if not ctx.closed_form and _degenerate(ctx):
            return self.starts(ctx, joint)[0]
        return np.zeros(1 if ctx.closed_form else 3)

    def starts(self, ctx: Context, joint: int | None) -> list[Any]:
        if ctx.closed_form:
            assert ctx.geometry is not None
            return [np.array([k * ctx.geometry["link1_m"]]) for k in PLANAR_STARTS]
        if not _degenerate(ctx):
            return [self.start(ctx, joint)]
        lever = _body_lever(ctx)
        return [
            sign * k * lever * np.eye(3)[axis]
            for k in DEGENERATE_STARTS
            for axis in range(3)
            for sign in (1.0, -1.0)
        ]

    def point_columns(self, ctx: Context, cols: np.ndarray) -> np.ndarray:
        # the 2-DOF mass at l̂ is x(l̂) alone: with x'(l̂) free as well, a start at 0.2 m fitted
        # a DFKI C.0 payload (0.20 kg at 0.37 m) better than one at 0.4 m, and its steps went to
        # −0.62 kg at 0.04 m (the same for a centre fitted in three directions)
        return cols[..., :1] if self._in_centre(ctx) else cols

    def change_point(self, ctx: Context, joint: int | None, at: Any) -> Any:
        # β = (m, m δc) holds the mass itself; a URDF arm's (m, m c) at ĉ as well, its centre
        # read from the start as before
        return at if self._in_centre(ctx) else self.start(ctx, joint)

    def columns(self, ctx: Context, joint: int | None, at: Any) -> np.ndarray:
        if ctx.closed_form:
            return _planar_columns(ctx, float(np.asarray(at).ravel()[0]))
        Y = _body_rows(ctx)  # (K, n, 10): rows of the last body's parameters
        c = np.asarray(at, float)
        if _degenerate(ctx):
            value, slopes = _unit_mass_rows(Y, c)
            return np.concatenate([value[..., None], slopes], axis=-1)
        cols = [Y[:, :, 0]]
        for k in range(3):
            e = np.zeros(3)
            e[k] = 1.0
            inertia = c[k] * np.eye(3) - 0.5 * (np.outer(e, c) + np.outer(c, e))
            cols.append(Y[:, :, 1 + k] + Y[:, :, 4:] @ _inertia_vector(inertia))
        return np.stack(cols, axis=-1)

    def update(self, ctx, joint, beta, at):
        m = float(beta[0])
        if ctx.closed_form:
            # Gauss–Newton step of l_p, at most one link-1 length at a time
            assert ctx.geometry is not None
            l1 = ctx.geometry["link1_m"]
            step = float(np.clip(beta[1] / m, -l1, l1)) if abs(m) > 1e-9 else 0.0
            return np.asarray(at, float) + step
        if _degenerate(ctx):  # a Gauss–Newton step of the centre, at most its scale at a time
            lever = _body_lever(ctx)
            step = np.asarray(beta[1:], float) / m if abs(m) > 1e-9 else np.zeros(3)
            return np.asarray(at, float) + np.clip(step, -lever, lever)
        k = len(beta) - 1
        return np.asarray(beta[1:], float) / m if abs(m) > 1e-9 else np.zeros(k)

    def estimate(self, ctx, joint, beta, se, at):
        m, s = float(beta[0]), float(se[0])
        if ctx.closed_form:
            lp = float(np.asarray(at).ravel()[0]) + (float(beta[1]) / m if abs(m) > 1e-9 else 0.0)
            return (
                {
                    "mass_kg": rounded(m),
                    "mass_se_kg": rounded(s),
                    "centre_m": [rounded(lp)],
                    "centre_se_m": [rounded(float(se[1]) / max(abs(m), 1e-9))],
                    "body": "link 2 (distance from joint 2 along the link)",
                },
                m,
                s,
            )
        c = np.asarray(beta[1:4], float) / m if abs(m) > 1e-9 else np.zeros(3)
        c_se = np.asarray(se[1:4], float) / max(abs(m), 1e-9)
        unseen: list[str] = []
        if _degenerate(ctx):  # β = (m, m δc) at ĉ; a direction no torque sees stays at ĉ
            c = np.asarray(at, float) + c
            value, slopes = _unit_mass_rows(_body_rows(ctx), np.asarray(at, float))
            floor = DEGENERATE_MASS * float(np.linalg.norm(value))
            unseen = ["xyz"[k] for k in range(3) if np.linalg.norm(slopes[..., k]) <= floor]
        out = {
            "mass_kg": rounded(m),
            "mass_se_kg": rounded(s),
            "centre_m": [rounded(x) for x in c],
            "centre_se_m": [rounded(x) for x in c_se],
            "body": f"the last body (joint {ctx.n_joints}'s frame)",
        }
        if unseen:  # its centre along the joint axis: no torque depends on it
            out["centre_not_determined"] = unseen
        return out, m, s

    def words(self, e: dict[str, Any]) -> str:
        c = ", ".join(f"{x:+.3g}" for x in e["centre_m"])
        m = e["mass_kg"]
        if m < 0:  # the model carries a mass the arm does not (a load taken off, a heavy model)
            return (
                f"a point mass of {-m:.3g} ± {e['mass_se_kg']:.2g} kg at ({c}) m on {e['body']} "
                "that the model has and the arm lacks (a load taken off)"
            )
        unseen = e.get("centre_not_determined")
        along = (
            f" (its {', '.join(unseen)} not determined: no torque depends on it)" if unseen else ""
        )
        return f"a payload of {m:.3g} ± {e['mass_se_kg']:.2g} kg at ({c}) m on {e['body']}{along}"

    def unphysical(self, ctx, joint, e, source):
        # a mass added leaves every body physical; one taken off must leave a body behind. The
        # bodies' masses are known only in the profile's own model (a fitted θ₀ lumps them, and
        # may hold a load its recordings carried)
        m = e["mass_kg"]
        if m >= 0 or source != "profile":
            return None
        if ctx.closed_form:
            return _planar_rest(ctx, m, e["centre_m"][0])
        model = ctx.model
        n = ctx.n_joints
        std = np.array(model.standard_theta, float)
        std[10 * (n - 1) : 10 * n] += point_mass_standard(m, np.array(e["centre_m"]))
        body = f"body of {model.joint_names[-1]}"
        bad = [v for v in model.physical_consistency(std)["violations"] if v.startswith(body)]
        return f"without {-m:.3g} kg the {'; '.join(bad)}" if bad else None

    def simulation(self, ctx: Context, joint: int | None, e: dict[str, Any]) -> SimInput:
        if ctx.closed_form:
            assert ctx.geometry is not None
            m, lp = e["mass_kg"], e["centre_m"][0]
            l1, g = ctx.geometry["link1_m"], ctx.geometry["gravity_m_s2"]
            d = np.zeros(len(ctx.theta0))
            d[:5] = [m * (l1**2 + lp**2), l1 * m * lp, m * lp**2, g * m * l1, g * m * lp]
            return SimInput(dtheta=d)
        std = point_mass_standard(e["mass_kg"], np.array(e["centre_m"]))
        return SimInput(dtheta=_last_body(ctx) @ std)


register(Payload())
