"""Identification of θ1..θ9 from recordings: the three schemes of Reyes & Kelly (1997), their
Table II, and validation on the fitting recording and on a held-out one.

Pure computation over arrays and :class:`~drivers.recording.Recording` objects; running the
experiments over a bench and writing files is :mod:`hil.identify_cli`'s job.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers.recording import Recording
from hil.estimators import least_squares, recursive_least_squares, weighted_least_squares
from hil.metrics import nrmse
from hil.model import THETA_NAMES, physical_consistency
from hil.openloop import simulate_open_loop
from hil.regressors import SCHEMES, build_regression

ESTIMATORS = ("rls", "ls", "wls")
SCHEME_TITLES = {
    "supplied_energy": "Supplied Energy",
    "filtered_power": "Filtered Power",
    "filtered_dynamic": "Filtered Dynamic",
}
# Reyes & Kelly (1997) Table II, the real arm: "measured" column and the three schemes'
# estimates at t = 10 s (None where the paper gives none: its supplied-energy run diverged).
PAPER_TABLE_II: dict[str, list[float | None]] = {
    "measured": [2.351, 0.084, 0.102, 38.465, 1.825, 2.288, 0.175, 7.60, 1.734],
    "supplied_energy": [2.14, 0.088, 0.087, 39.04, None, None, None, None, None],
    "filtered_power": [1.99, 0.084, 0.084, 36.20, 2.01, 2.35, 0.192, 4.95, 1.01],
    "filtered_dynamic": [1.98, 0.087, 0.084, 38.48, 1.99, 2.11, 0.120, 6.20, 1.18],
}
HISTORY_POINTS = 500  # θ̂(k) samples kept for plots and JSON


@dataclass
class SchemeResult:
    """One scheme's estimates: ``theta`` is the one reported (per ``estimator``)."""

    scheme: str
    discretization: str
    lam: float
    estimator: str
    theta: np.ndarray
    theta_rls: np.ndarray
    theta_ls: np.ndarray
    theta_wls: np.ndarray
    history_t: np.ndarray
    history: np.ndarray  # θ̂(k) of RLS at history_t, (len(history_t), 9)
    rows: int
    rows_excluded: int
    consistency: dict[str, Any]
    timing_s: dict[str, float] = field(default_factory=dict)

    def relative_error(self, reference: np.ndarray) -> np.ndarray:
        return (self.theta - reference) / reference


def identify(
    q: np.ndarray,
    tau: np.ndarray,
    period_s: float,
    *,
    schemes: Sequence[str] = SCHEMES,
    discretization: str = "exact",
    lam: float = 50.0,
    estimator: str = "rls",
) -> dict[str, SchemeResult]:
    """Identify θ with each scheme: regression (eqs. (24), (28), (30)), then recursive least
    squares (eqs. (20)-(22), P(0) = 1000·I, θ̂(0) = 0), batch and weighted least squares."""
    if estimator not in ESTIMATORS:
        raise ValueError(
            f"unknown estimator {estimator!r}; expected one of {', '.join(ESTIMATORS)}"
        )
    out = {}
    for scheme in schemes:
        t0 = time.perf_counter()
        reg = build_regression(scheme, q, tau, period_s, lam, discretization)
        t1 = time.perf_counter()
        theta_ls = least_squares(reg.Psi, reg.y, reg.weights)
        t2 = time.perf_counter()
        hist = recursive_least_squares(reg.Psi, reg.y, reg.weights)
        t3 = time.perf_counter()
        theta_wls = weighted_least_squares(reg.Psi, reg.y, reg.weights)
        t4 = time.perf_counter()
        step = max(1, len(hist) // HISTORY_POINTS)
        pick = np.unique(np.r_[np.arange(0, len(hist), step), len(hist) - 1])
        chosen = {"rls": hist[-1], "ls": theta_ls, "wls": theta_wls}[estimator]
        out[scheme] = SchemeResult(
            scheme=scheme,
            discretization=discretization,
            lam=lam,
            estimator=estimator,
            theta=chosen,
            theta_rls=hist[-1],
            theta_ls=theta_ls,
            theta_wls=theta_wls,
            history_t=reg.t[pick],
            history=hist[pick],
            rows=int(reg.weights.shape[0]),
            rows_excluded=int(np.sum(reg.weights == 0)),
            consistency=physical_consistency(chosen),
            timing_s={
                "regression": t1 - t0,
                "least_squares": t2 - t1,
                "recursive_least_squares": t3 - t2,
                "weighted_least_squares": t4 - t3,
            },
        )
    return out


def initial_velocity(rec: Recording) -> tuple[float, float]:
    """q̇(0) from the first two samples (zero for a recording that starts at rest)."""
    if len(rec) < 2:
        return (0.0, 0.0)
    dq = (rec.q[1] - rec.q[0]) / rec.period_s
    return (float(dq[0]), float(dq[1]))


def validate(theta: np.ndarray, rec: Recording, *, lam: float = 50.0) -> dict[str, Any]:
    """How well θ explains a recording, both ways (per joint, NRMSE as a fraction):

    * ``position_nrmse``: the model simulated open loop from the recording's first sample,
      driven by its recorded torques (:func:`hil.openloop.simulate_open_loop`), against the
      recorded positions — the paper's Figs. 2, 4, 7;
    * ``torque_nrmse``: torque prediction, the filtered torque F[τ] against Ψθ of the
      ``exact`` filtered dynamic regression (rows with a stuck joint left out), i.e. the torque
      the model says was needed for the recorded motion, filtered at λ to keep differentiation
      noise out.
    """
    sim = simulate_open_loop(theta, rec.tau, rec.period_s, q0=rec.q[0], dq0=initial_velocity(rec))
    reg = build_regression("filtered_dynamic", rec.q, rec.tau, rec.period_s, lam, "exact")
    predicted = np.einsum("kmp,p->km", reg.Psi, theta)
    torque = [
        float(nrmse(reg.y[reg.weights[:, j] > 0, j], predicted[reg.weights[:, j] > 0, j]))
        for j in range(2)
    ]
    return {
        "recording": str(rec.path),
        "position_nrmse": [float(x) for x in nrmse(rec.q, sim.q)],
        "position_max_error_rad": [float(x) for x in np.max(np.abs(rec.q - sim.q), axis=0)],
        "torque_nrmse": torque,
        "simulated_q": sim.q,  # for plots; dropped from JSON
    }


def table_ii_rows(reference: np.ndarray, results: dict[str, SchemeResult]) -> list[dict[str, Any]]:
    """Table II layout: per parameter, the reference ("measured") value and each scheme's
    estimate with its relative error."""
    rows = []
    for i, name in enumerate(THETA_NAMES):
        row: dict[str, Any] = {"parameter": name, "measured": float(reference[i])}
        for scheme, res in results.items():
            row[scheme] = float(res.theta[i])
            row[f"{scheme}_error"] = float((res.theta[i] - reference[i]) / reference[i])
        rows.append(row)
    return rows


def format_table_ii(reference: np.ndarray, results: dict[str, SchemeResult], *, title: str) -> str:
    """The Table II layout as text: measured column, then estimate (relative error %)."""
    schemes = [s for s in ("supplied_energy", "filtered_power", "filtered_dynamic") if s in results]
    head = f"{'':8s}{'Measured':>10s}" + "".join(f"{SCHEME_TITLES[s]:>24s}" for s in schemes)
    lines = [title, head]
    for i in range(len(THETA_NAMES)):
        cells = f"θ{i + 1:<7d}{reference[i]:>10.4g}"
        for s in schemes:
            value = results[s].theta[i]
            err = 100 * (value - reference[i]) / reference[i]
            cells += f"{value:>14.4g} ({err:+6.1f}%)"
        lines.append(cells)
    consistent = "".join(
        f"{'':>13s}{'consistent' if results[s].consistency['consistent'] else 'NOT PHYSICAL':>11s}"
        for s in schemes
    )
    lines.append(f"{'physical':18s}{consistent}")
    return "\n".join(lines)
