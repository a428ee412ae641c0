"""The physical gate of the mismatch diagnosis: is a fit a physical arm?

A fit of the nominal model plus term columns is physical when M(q) is positive definite for
every q and friction and rotor inertia are not negative beyond their blocked jackknife
standard errors (:func:`physical_theta`, :func:`unphysical`), and no torque gain removes most
of the torque. :func:`final_fit` fits the nominal model with the accepted terms on all rows,
:func:`physical_gate` drops accepted terms until that fit is physical,
:func:`rigid_body_deviation` measures a fit's rigid-body parameters against a reference.
:func:`bounded_fit` is least squares with those signs bounded, :func:`held_at_zero` the nominal
fit with the coefficients it puts on their bound held there (a recording that cannot tell a
viscous friction from zero gives it a negative least-squares value).

Imports: :mod:`hil.diagnose.candidates`, :mod:`hil.diagnose.problem`,
:mod:`hil.diagnose.stats`, :mod:`hil.model`; never the selection or the stages after it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hil.diagnose.candidates import Accepted, Candidate, term_width
from hil.diagnose.problem import Problem, design_cv, fit_theta, robust_scale
from hil.diagnose.stats import CrossValidation, block_stats, cross_validate
from hil.model.closed_form import ArmModel
from hil.model.estimators import blocked_bootstrap, bounded_quadratic_fit
from hil.model.protocol import ArmDynamics

# A torque gain error below this (the shaft gets less than half the command) is not a gain
# error but a model that has stopped describing the arm.
MIN_GAIN = -0.5


# A friction coefficient is called negative only when it is below zero by more than this many
# of its own (blocked jackknife) standard errors: a viscous term the recording cannot determine
# scatters around zero, and -0.002 ± 0.004 Nm s is not a verdict on the arm.
SE_TOLERANCE = 2.0


def jackknife_se(fold_beta: np.ndarray) -> np.ndarray:
    """Standard error of each coefficient from the leave-one-block-out fits."""
    n = fold_beta.shape[0]
    return np.sqrt((n - 1) / n * np.sum((fold_beta - fold_beta.mean(0)) ** 2, axis=0))


def physical_theta(
    theta: np.ndarray, se: np.ndarray | None = None, model: ArmDynamics | None = None
) -> tuple[np.ndarray, list[str]]:
    """θ of ``model`` (default the 9-parameter one; its first parameters of ``theta``) with
    coefficients that must be ≥ 0 (friction, a rotor inertia) but are negative within
    SE_TOLERANCE of their standard errors ``se`` set to zero, and what is still not physical
    about it (``model.physical_consistency``: M(q) positive definite for every q, friction and
    rotor inertia ≥ 0)."""
    model = ArmModel(()) if model is None else model
    th = np.array(theta[: model.n_params], float)
    if se is not None:
        cols = [i for i in model.nonnegative_columns if i < len(se)]
        bound = -SE_TOLERANCE * np.asarray(se, float)[cols]
        fr = th[cols]
        fr[(fr < 0) & (fr >= bound)] = 0.0
        th[cols] = fr
    return th, list(model.physical_consistency(th)["violations"])


def bounded_fit(
    prob: Problem, model: ArmDynamics, extra: np.ndarray | None, target: np.ndarray, draws: int
) -> tuple[np.ndarray, np.ndarray]:
    """[θ, β] of Ψ θ + ``extra`` β ≈ ``target`` (scaled rows), θ's physical signs bounded, and
    its blocked-bootstrap draws (draws, p)."""
    # Ψ scaled a block at a time, not joined with ``extra`` into one copy (a 60 s Panda
    # recording's scaled Ψ is 0.2 GB)
    stats = block_stats(
        prob.design_groups([] if extra is None else [extra]), target, prob.w, prob.blocks
    )
    H_b, g_b = stats.G.sum(axis=1), stats.r.sum(axis=1)  # (B, p, p), (B, p)
    lower = np.full(H_b.shape[-1], -np.inf)
    lower[list(model.nonnegative_columns)] = 0.0
    theta, _method = bounded_quadratic_fit(H_b.sum(axis=0), g_b.sum(axis=0), lower)
    if not draws:
        return theta, theta[None, :]
    return theta, blocked_bootstrap(H_b, g_b, draws=draws)


@dataclass(frozen=True)
class HeldAtZero:
    """The nominal fit with the coefficients bounded least squares puts on their bound held
    there (:func:`held_at_zero`): its problem (those columns of Ψ zero), θ, θ's jackknife SE,
    and the coefficients held with their least-squares values."""

    prob: Problem
    theta: np.ndarray
    se: np.ndarray
    held: dict[int, float]


def nominal_fit_se(prob: Problem) -> np.ndarray:
    """The jackknife SE of the nominal fit's θ (leave one block out)."""
    stats = block_stats(prob.design_groups([]), prob.y, prob.w, prob.blocks)
    return jackknife_se(cross_validate(stats).fold_beta)


def held_at_zero(prob: Problem, theta_ls: np.ndarray, model: ArmDynamics) -> HeldAtZero | None:
    """The nominal fit of ``prob`` with the coefficients that must be ≥ 0 (friction, a rotor
    inertia) and that bounded least squares puts at 0 held there: the bounded fit's active set,
    the other coefficients refitted by least squares (on the free ones the bounded fit's optimum
    is that least squares, KKT). Their columns of Ψ are zero in the returned problem, so every
    later fit (candidates, gates, held-out) keeps them at 0 (the ridge solve gives a zero column
    a zero coefficient). None when no coefficient is on its bound."""
    bounded, _ = bounded_fit(prob, model, None, prob.y, 0)
    held = [i for i in model.nonnegative_columns if bounded[i] <= 0.0]
    if not held:
        return None
    Psi = prob.Psi_raw.copy()
    Psi[:, :, held] = 0.0
    theta = fit_theta(Psi, prob.y_raw, prob.w)
    scale = robust_scale(prob.y_raw - Psi @ theta, prob.w)
    pinned = Problem(prob.rows, prob.y_raw, Psi, prob.w, scale, prob.blocks)
    return HeldAtZero(pinned, theta, nominal_fit_se(pinned), {i: float(theta_ls[i]) for i in held})


def model_columns(model: ArmDynamics, cands: Sequence[Candidate]) -> tuple[ArmDynamics, np.ndarray]:
    """The model a fit of the nominal ``model`` with the terms ``cands`` (in design order,
    after Ψ) describes: ``model`` with the model terms among ``cands`` appended, and which
    coefficients of the fit's β are its θ."""
    p = model.n_params
    index, terms, at = list(range(p)), [], p
    for c in cands:
        width = term_width(c)
        if c.spec.model_term:
            terms.append(c.kind)
            index += range(at, at + width)
        at += width
    return (model.with_terms(tuple(terms)) if terms else model), np.array(index)


def unphysical(
    cand: Candidate | None,
    cv: CrossValidation,
    model: ArmDynamics | None = None,
    terms: Sequence[Candidate] = (),
) -> list[str]:
    """Why a fit of the nominal ``model`` (default the 9-parameter one) + the columns of
    ``terms`` (+ ``cand``) is not physical (empty when it is): M(q) not positive definite or
    negative friction in θ beyond its uncertainty (:func:`physical_theta`, with the model terms
    among ``terms`` and ``cand`` in θ), or a gain that removes most of the torque."""
    cands = [*terms, cand] if cand is not None else list(terms)
    full, index = model_columns(ArmModel(()) if model is None else model, cands)
    se = jackknife_se(cv.fold_beta)
    reasons = physical_theta(cv.beta[index], se[index], full)[1]
    if cand is not None and cand.spec.is_gain:
        r = float(cv.beta[-1])
        if r <= MIN_GAIN:
            reasons.append(f"a torque gain of {100 * r:+.0f} % removes most of the torque")
    return reasons


def rigid_body_deviation(theta: np.ndarray, reference: np.ndarray, n_rigid: int = 5) -> float:
    """‖(θ_rigid − reference)/reference‖: how far a fit's rigid-body parameters (θ1..θ5 of
    the 2-DOF model, the first ``n_rigid``) are from the reference's (robot profile or
    --params)."""
    ref = np.asarray(reference, float)[:n_rigid]
    # a URDF arm's base parameters can be zero (the offset moment of a symmetric link): those
    # are measured against the parameters' RMS instead
    scale = np.where(np.abs(ref) > 0, np.abs(ref), np.sqrt(np.mean(ref**2)))
    return float(np.linalg.norm((np.asarray(theta, float)[:n_rigid] - ref) / scale))


# --- the final model ---------------------------------------------------------------------------


@dataclass
class FinalFit:
    """Nominal + accepted terms fitted on all rows: θ, each term's coefficients, their spread
    over the leave-one-block-out fits (a jackknife standard error)."""

    theta: np.ndarray
    coefficients: list[np.ndarray]
    standard_errors: list[np.ndarray]
    cv: CrossValidation


def final_fit(prob: Problem, accepted: Sequence[Accepted]) -> FinalFit:
    cols = [prob.chosen(a) for a in accepted]
    cv = design_cv(prob, cols)
    jack = jackknife_se(cv.fold_beta)
    coefs, ses, at = [], [], prob.n_params
    for c in cols:
        p = c.shape[-1]
        coefs.append(cv.beta[at : at + p])
        ses.append(jack[at : at + p])
        at += p
    return FinalFit(cv.beta[: prob.n_params], coefs, ses, cv)


def physical_gate(
    prob: Problem, accepted: list[Accepted], rejected: dict[str, str]
) -> list[Accepted]:
    """The final model must be physical too: a term accepted early can drift once others join
    (a gain error that ends up removing most of the torque). While the refit with every
    accepted term is not physical, the last accepted term goes (the others stood without it),
    with the reason in ``rejected``."""
    accepted = list(accepted)
    while accepted:
        fit = final_fit(prob, accepted)
        reasons = unphysical(None, fit.cv, prob.model, [a.cand for a in accepted])
        for a, coef in zip(accepted, fit.coefficients, strict=True):
            if a.cand.spec.is_gain and float(coef[0]) <= MIN_GAIN:
                reasons.append(
                    f"a torque gain of {100 * float(coef[0]):+.0f} % removes most of the torque"
                )
        if not reasons:
            break
        last = accepted.pop()
        rejected[last.cand.key] = "its refit is not physical: " + "; ".join(reasons)
    return accepted
