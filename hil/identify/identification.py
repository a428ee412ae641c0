"""One identification API for every arm: :func:`identify` (a model, a recording, a scheme) returns
an :class:`Identification`, whose :meth:`Identification.to_json` is the one layout every
``identify.json`` holds under ``identifications`` (docs/schemas/identify.schema.json).

The estimators it calls are the engines of :mod:`hil.identify.schemes` and
:mod:`hil.identify.urdf`:

* a 2-DOF closed-form model (:class:`hil.model.closed_form.ArmModel`) with a recursive
  estimator (``estimator`` ``rls``, ``ls`` or ``wls``): the three schemes of Reyes & Kelly (1997)
  as the paper runs them, RLS from P(0) = 1000·I, on the ``exact`` or the paper's
  ``discretization`` (:func:`hil.identify.schemes.identify`: the Table II reproduction, the
  9-parameter model only);
* a 2-DOF model with ``estimator="bounded"`` (the default): feasible weighted least squares on
  the exact rows at the real time stamps, bounded to a physical θ when least squares is not, with
  blocked-bootstrap uncertainty (:func:`hil.identify.schemes.identify_model`);
* an n-joint arm described by a URDF (:class:`hil.model.urdf.UrdfArmModel`): weighted least
  squares of its base parameters on the smoothed torque rows (``filtered_dynamic``) or least
  squares on the energy rows (``supplied_energy``, ``filtered_power``), friction bounded ≥ 0, the
  physically consistent fit when M(q) is still indefinite (:mod:`hil.identify.urdf`).

Whatever the engine, θ is offered as parameters only when it is an arm
(:func:`unusable_reason`); a command adds its own verdicts (held-out validation) with
:meth:`Identification.failing`. Imports :mod:`hil.identify.schemes`, :mod:`hil.identify.urdf`
(lazily: Pinocchio loads only for a URDF arm), :mod:`hil.model` and :mod:`drivers.recording`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np

from drivers.recording import Recording
from hil.identify.schemes import (
    ESTIMATORS,
    Progress,
    Uncertainty,
    identify_model,
    irregular_times,
)
from hil.identify.schemes import identify as identify_schemes
from hil.model.closed_form import ArmModel
from hil.model.regressors import DISCRETIZATIONS, SCHEMES

BOUNDED = "bounded"  # the estimator of real recordings: weighted, bounded, with uncertainty
AUTO: Literal["auto"] = "auto"  # a URDF arm's smoothing cutoff decided from the data


def _is_urdf(model: Any) -> bool:
    """A URDF arm's model (:class:`hil.model.urdf.UrdfArmModel`: base parameters of standard
    ones), told by what it has, not by its class."""
    return hasattr(model, "standard_names")


def unusable_reason(theta: np.ndarray, consistency: dict[str, Any]) -> str | None:
    """Why an identified θ may not be offered as parameters (None: it may): a non-finite
    entry, or a θ that is not physically consistent (M(q) not positive definite for every q, a
    negative friction coefficient: the model's ``physical_consistency``). Such a θ is a failed
    fit (pure noise, swapped torque columns, too little excitation), not an arm: every
    model-based law and simulation given it commands or integrates nonsense."""
    if not np.all(np.isfinite(theta)):
        return "θ holds a non-finite number"
    if not consistency["consistent"]:
        return "not physically consistent: " + "; ".join(consistency["violations"])
    return None


@dataclass(frozen=True)
class Identification:
    """θ of ``model`` by one scheme from one recording, whatever the arm.

    ``theta``: the estimate offered (bounded or physically consistent when least squares is not
    physical; ``theta_least_squares`` then holds least squares', else None); ``method`` says
    which; ``uncertainty`` per parameter (None for the paper's recursive estimators, which give
    none); ``consistency``: the model's physical-consistency check of ``theta``;
    ``failed_reason``: why θ is not offered as parameters (None: it is), set from
    :func:`unusable_reason` and by :meth:`failing`; ``result``: the engine's own result
    (:class:`~hil.identify.schemes.SchemeResult`, :class:`~hil.identify.schemes.
    ModelIdentification`, :class:`~hil.identify.urdf.TorqueIdentification` or
    :class:`~hil.identify.urdf.EnergyIdentification`) for what only it has (RLS history,
    friction-step rows, variance inflation)."""

    model: Any
    scheme: str
    discretization: str
    estimator: str
    lam: float | None
    theta: np.ndarray
    method: str
    rows: int
    consistency: dict[str, Any]
    uncertainty: Uncertainty | None = None
    theta_least_squares: np.ndarray | None = None
    theta_standard: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)
    failed_reason: str | None = None
    result: Any = None

    @property
    def usable(self) -> bool:
        """θ may be offered as identified parameters."""
        return self.failed_reason is None

    def failing(self, reason: str | None) -> Identification:
        """This identification, FAILED for ``reason`` (a command's own verdict, e.g. held-out
        validation) unless it failed already or ``reason`` is None."""
        if reason is None or self.failed_reason is not None:
            return self
        return replace(self, failed_reason=reason)

    def to_json(self) -> dict[str, Any]:
        """The layout of every ``identify.json``'s ``identifications`` entries."""
        urdf = hasattr(self.model, "standard_names")  # a UrdfArmModel: base parameters
        return {
            "model": "urdf" if urdf else "closed_form",
            "terms": list(self.model.terms),
            "scheme": self.scheme,
            "discretization": self.discretization,
            "estimator": self.estimator,
            "lambda_rad_s": self.lam,
            "method": self.method,
            "names": list(self.model.names),
            "units": list(self.model.units),
            "theta": [float(x) for x in self.theta],
            "theta_least_squares": None
            if self.theta_least_squares is None
            else [float(x) for x in self.theta_least_squares],
            "rows": self.rows,
            "uncertainty": None if self.uncertainty is None else self.uncertainty.as_json(),
            "physical_consistency": self.consistency,
            "usable": self.usable,
            "failed_reason": self.failed_reason,
        }


def identify(
    model: Any,
    recording: Recording,
    scheme: str = "filtered_dynamic",
    *,
    discretization: str = "exact",
    estimator: str = BOUNDED,
    lam: float | None = None,
    held_out: float = 0.0,
    cutoff_hz: float | Literal["auto"] | None = AUTO,
    consistent: bool = False,
    progress: Progress | None = None,
) -> Identification:
    """Identify ``model``'s θ from ``recording`` by ``scheme`` (``filtered_dynamic``,
    ``supplied_energy`` or ``filtered_power``); the engine by model and ``estimator`` (module
    docstring).

    ``lam``: the rows' filter bandwidth, rad/s (default: 50 for the paper's estimators, else
    twice the excitation bandwidth read from the data). ``discretization``: ``exact`` or
    ``paper`` (the paper's recursive estimators only). URDF arm only: ``held_out``, the last
    fraction of the time span left out of the fit; ``cutoff_hz``, the smoothing of the
    positions (``auto``: :func:`hil.identify.urdf.smoothing_cutoff_hz` for the torque rows,
    :func:`hil.identify.urdf.energy_rows_cutoff` for the energy rows; None: the energy rows on
    the raw positions); ``consistent``, the fit
    constrained to physically consistent standard parameters. ``progress``: told the rows done
    (the paper's estimators). Raises ValueError with one line for an option the engine has not."""
    if scheme not in SCHEMES:
        raise ValueError(f"unknown scheme {scheme!r}; expected one of {', '.join(SCHEMES)}")
    if discretization not in DISCRETIZATIONS:
        raise ValueError(
            f"unknown discretization {discretization!r}; one of {', '.join(DISCRETIZATIONS)}"
        )
    if estimator not in (BOUNDED, *ESTIMATORS):
        raise ValueError(
            f"unknown estimator {estimator!r}; one of {BOUNDED}, {', '.join(ESTIMATORS)}"
        )
    if discretization != "exact" and estimator == BOUNDED:
        raise ValueError(
            "the paper's discretization is the 9-parameter reproduction's: give a recursive "
            f"estimator ({', '.join(ESTIMATORS)}) of the 2-DOF model without terms"
        )
    if not _is_urdf(model):
        if estimator == BOUNDED:
            return _bounded(model, recording, scheme, lam)
        if model.terms:
            raise ValueError(
                f"the paper's estimators fit θ1..θ9 only; a model with terms "
                f"({', '.join(model.terms)}) takes estimator {BOUNDED!r}"
            )
        return _paper(model, recording, scheme, discretization, estimator, lam, progress)
    if estimator != BOUNDED:
        raise ValueError(
            f"an arm described by a URDF is fitted by the {BOUNDED!r} estimator only "
            f"(its rows are the exact ones), not {estimator!r}"
        )
    return _urdf(model, recording, scheme, lam, held_out, cutoff_hz, consistent)


def _paper(
    model: ArmModel,
    rec: Recording,
    scheme: str,
    discretization: str,
    estimator: str,
    lam: float | None,
    progress: Progress | None,
) -> Identification:
    lam = 50.0 if lam is None else float(lam)
    res = identify_schemes(
        rec.q, rec.tau, rec.period_s, schemes=[scheme], discretization=discretization, lam=lam,
        estimator=estimator, t=irregular_times(rec), segments=rec.segments(), progress=progress,
    )[scheme]  # fmt: skip
    method = {
        "rls": "recursive least squares, eqs. (20)-(22)",
        "ls": "batch least squares",
        "wls": "feasible weighted least squares",
    }[estimator]
    return Identification(
        model, scheme, discretization, estimator, lam, res.theta, method, res.rows,
        res.consistency, failed_reason=unusable_reason(res.theta, res.consistency), result=res,
    )  # fmt: skip


def _bounded(model: ArmModel, rec: Recording, scheme: str, lam: float | None) -> Identification:
    res = identify_model(rec.t, rec.q, rec.tau, model, lam=lam, scheme=scheme)
    bounded = res.theta is not res.theta_ls
    return Identification(
        model, scheme, "exact", BOUNDED, res.lam, res.theta, res.method, res.rows,
        res.consistency, res.uncertainty, res.theta_ls if bounded else None, None,
        list(res.notes), unusable_reason(res.theta, res.consistency), res,
    )  # fmt: skip


def _urdf(
    model: Any,
    rec: Recording,
    scheme: str,
    lam: float | None,
    held_out: float,
    cutoff_hz: float | Literal["auto"] | None,
    consistent: bool,
) -> Identification:
    from hil.identify.urdf import (
        energy_rows_cutoff,
        identify_energy,
        identify_torque,
        smoothing_cutoff_hz,
    )

    if scheme == "filtered_dynamic":
        cutoff = smoothing_cutoff_hz(rec) if cutoff_hz in (AUTO, None) else float(cutoff_hz)
        res: Any = identify_torque(
            model, rec, held_out=held_out, consistent=consistent, cutoff_hz=cutoff
        )
        rows, used_lam = len(res.rows.t), None
    else:
        cutoff = (
            energy_rows_cutoff(rec, smoothing_cutoff_hz(rec)) if cutoff_hz == AUTO else cutoff_hz
        )
        res = identify_energy(
            model, rec, scheme, lam=lam, held_out=held_out, cutoff_hz=cutoff,
            consistent=consistent,
        )  # fmt: skip
        rows, used_lam = res.rows, res.lam
    consistency = model.physical_consistency(res.theta)
    return Identification(
        model, scheme, "exact", BOUNDED, used_lam, res.theta, res.method, rows, consistency,
        res.uncertainty, res.theta_least_squares, res.theta_standard, [],
        unusable_reason(res.theta, consistency), res,
    )  # fmt: skip


__all__ = ["AUTO", "BOUNDED", "Identification", "identify", "unusable_reason"]
