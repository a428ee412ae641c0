"""Fit metrics shared by every report (identification validation, diagnosis)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike


def nrmse(reference: ArrayLike, estimate: ArrayLike) -> np.ndarray:
    """Normalized RMS error per column, as a fraction (0 = perfect; 1 = no better than the mean).

    NRMSE = ‖y − ŷ‖₂ / ‖y − mean(y)‖₂ over the samples (first axis) of each column, where y is
    ``reference`` (e.g. the recorded q) and ŷ is ``estimate`` (e.g. the simulated q). Multiply by
    100 for a percentage. Inputs of shape (N,) give a 0-d array, (N, k) give shape (k,). A column
    whose reference is constant (no spread beyond rounding) has no scale: its NRMSE is nan.
    Non-finite samples propagate as nan.
    """
    y = np.asarray(reference, dtype=float)
    y_hat = np.asarray(estimate, dtype=float)
    if y.shape != y_hat.shape:
        raise ValueError(f"nrmse: reference shape {y.shape} != estimate shape {y_hat.shape}")
    if y.ndim not in (1, 2):
        raise ValueError(f"nrmse: expected shape (N,) or (N, k), got {y.shape}")
    if y.shape[0] == 0:
        raise ValueError("nrmse: no samples")
    error = np.linalg.norm(y - y_hat, axis=0)
    spread = np.linalg.norm(y - y.mean(axis=0), axis=0)
    # constant: no spread beyond the rounding of the mean (a passive joint's torque of 1e-17 Nm
    # scatter gave NRMSEs of 1e17 %)
    constant = (np.ptp(y, axis=0) == 0) | (
        spread <= 1e-9 * np.linalg.norm(y, axis=0) + np.finfo(float).tiny
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(constant, np.nan, error / np.where(constant, 1.0, spread))
    return np.asarray(ratio)


__all__ = [
    "nrmse",
]
