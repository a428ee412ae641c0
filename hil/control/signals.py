"""Signals of a tracking run derived from its recording: when each sample was taken, and the
velocity from positions. The run's metrics (:mod:`hil.control.tracking`) and its plots
(:mod:`hil.control.plots`) both use them, so they live below both.
"""

from __future__ import annotations

import numpy as np

from drivers.recording import Recording


def sample_times(rec: Recording) -> np.ndarray:
    """When each row's q was sampled: t = k·h in lockstep; in realtime k·h plus how late that
    period's SYNC/request went out (``sync_sent_s − deadline_s``), so that a late sample is
    compared with the reference at the time it was taken, not counted as a tracking error."""
    t = rec.t
    if "sync_sent_s" not in rec.columns or "deadline_s" not in rec.columns:
        return t
    late = rec.columns["sync_sent_s"] - rec.columns["deadline_s"]
    return t + np.nan_to_num(late, nan=0.0)


def central_velocity(t: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(q_{k+1} − q_{k−1}) / (t_{k+1} − t_{k−1}) (second order, also for uneven t) inside,
    one-sided at the two ends; shape of q."""
    return np.gradient(q, t, axis=0) if len(q) > 1 else np.zeros_like(q)
