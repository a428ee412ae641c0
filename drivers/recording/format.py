"""The recording format (docs/design.md): a run directory with signals.csv, meta.json, plots.

Row k of signals.csv: t = k·h; q = encoder reading sampled at t; tau = torque commanded at t and
held over [t, t + h) (zero-order hold), after quantization. Base columns t,q1,q2,tau1,tau2 in
s, rad, Nm (an n-joint arm: t,q1..qn,tau1..taun, :func:`base_columns`); more columns may
follow. Here: the file names, the base columns, the reader's error type and the strict JSON
(no NaN, no infinity) every document of a run is written in.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

BASE_COLUMNS = ("t", "q1", "q2", "tau1", "tau2")


def base_columns(n_joints: int = 2) -> tuple[str, ...]:
    """``t, q1..qn, tau1..taun``: the base columns of an n-joint recording (2: BASE_COLUMNS)."""
    if n_joints < 1:
        raise ValueError(f"a recording has at least one joint, got {n_joints}")
    joints = range(1, n_joints + 1)
    return ("t", *(f"q{j}" for j in joints), *(f"tau{j}" for j in joints))


SIGNALS = "signals.csv"
META = "meta.json"


class RecordingError(ValueError):
    """A recording that cannot be read; the message is one line naming the file."""


def write_json_atomic(path: Path, document: dict[str, Any]) -> None:
    """Write JSON so that a reader never sees half a file (write, then rename); strict JSON
    (:func:`dumps_strict`: no NaN or Infinity)."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(dumps_strict(document, indent=2) + "\n")
    os.replace(tmp, path)


def dumps_strict(document: Any, **kwargs: Any) -> str:
    """``document`` as strict JSON (RFC 8259 has no NaN or Infinity, and strict parsers refuse
    Python's): every non-finite number becomes null, with a ``<key>_null_reason`` beside it
    (:func:`strict_json`); numpy scalars and arrays as numbers and lists, paths as strings.
    ``allow_nan=False`` is the guard: a non-finite number that gets past the sanitiser fails
    here, loudly, instead of writing invalid JSON."""
    return json.dumps(strict_json(document), allow_nan=False, default=_json_default, **kwargs)


def strict_json(value: Any) -> Any:
    """A copy of ``value`` (dicts, lists, tuples, numpy arrays and scalars, floats) in which
    every NaN or ±Infinity is None. In a dict, a key whose value was (or held) a non-finite
    number gets ``<key>_null_reason`` beside it saying which (``"NaN"``, or ``"NaN at index
    3, Infinity at index 5"`` for a list), so a null is never silent."""
    cleaned, _ = _strict(value)
    return cleaned


def _strict(value: Any) -> tuple[Any, str | None]:
    """(value with non-finite numbers as None, what was replaced or None)."""
    if isinstance(value, bool) or value is None or isinstance(value, int | str):
        return value, None
    if isinstance(value, np.ndarray):
        value = value.tolist()
    elif isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float):
        if math.isfinite(value):
            return value, None
        return None, "NaN" if math.isnan(value) else ("Infinity" if value > 0 else "-Infinity")
    if isinstance(value, Mapping):
        out: dict[Any, Any] = {}
        reasons: dict[str, str] = {}
        for key, item in value.items():
            out[key], why = _strict(item)
            if why is not None:
                reasons[f"{key}_null_reason"] = why
        for key, why in reasons.items():
            out.setdefault(key, f"not a finite number: {why}")
        return out, None  # its own keys say what they hold
    if isinstance(value, list | tuple):
        items, whys = [], []
        for i, item in enumerate(value):
            cleaned, why = _strict(item)
            items.append(cleaned)
            if why is not None and len(whys) < 3:
                whys.append(f"{why} at index {i}" if " at index " not in why else f"[{i}]: {why}")
        return items, (", ".join(whys) if whys else None)
    return value, None


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serializable: {type(value).__name__}")
