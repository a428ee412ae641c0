"""The torque path from the commanded to the measured torque, where a recording holds both
(issue 26, item 3; e.g. the DFKI files' ``tau_con`` and ``tau_meas``, profiles/formats/dfki.toml).

Both torques are read onto this project's rows (row k's torque acts over [t_k, t_{k+1}), each
source with its own loop delay, drivers.recording), so a perfect path is τ_meas[k] = τ_cmd[k].
Per joint the path is fitted as

    τ_meas[k] = g · x[k − d] + b + e[k],   x = the command through a first-order lag T
    (x[k] = x[k−1] + (1 − e^{−Δt_k/T}) (τ_cmd[k] − x[k−1]), exact for a held command),

by least squares for g and b on a grid of delays d (whole rows within ±MAX_DELAY_S; a
negative d, the measured torque leading, is tried without a lag only and says the sources' loop
delays are off)
and lags T (0 and LAG_GRID_S), the pair with the least residual kept. Rows where the measured
torque stays at its extreme while the fit asks for more are a saturation: their level is
reported and they are left out of the fit. A delay and lag that lower the residual by less
than the diagnosis's MIN_REDUCTION (relative) are not reported (0: the motion is too slow to
time the path); a delay or lag under RESOLVABLE_INTERVALS of the
sample interval is reported as 0 (the samples cannot resolve it; hil.diagnose.findings). The
residual's RMS is the path's noise, and its NRMSE against the measured torque says how much of
it the path explains.

Imports drivers.recording and profiles.recording_format (to read a file's torque sources);
numpy only otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drivers.recording import Recording, read_signals, recording_names
from hil.diagnose.columns import first_order_states
from hil.diagnose.finding import rounded
from hil.diagnose.findings import RESOLVABLE_INTERVALS
from hil.diagnose.selection import MIN_REDUCTION
from profiles.recording_format import load_format

MAX_DELAY_S = 0.03  # longest delay (or lead) searched: a few bus or current-loop periods
LAG_GRID_S = np.geomspace(2e-4, 0.05, 60)  # 10 % steps: lag and delay trade off sharply
SATURATION_ROWS = 5  # at least this many rows at the extreme make a saturation
SATURATION_SIGMAS = 3.0  # ... where the fit asks for this many noise RMS more


@dataclass(frozen=True)
class TorquePath:
    """One joint's path from the commanded to the measured torque (module doc)."""

    joint: int  # 1-based
    gain: float
    offset_Nm: float
    delay_s: float
    delay_rows: int
    lag_s: float
    noise_rms_Nm: float
    nrmse: float
    saturation_Nm: float | None
    saturated_rows: int
    rows: int

    def as_dict(self) -> dict[str, Any]:
        return {
            "joint": self.joint,
            "gain": rounded(self.gain),
            "offset_Nm": rounded(self.offset_Nm),
            "delay_s": rounded(self.delay_s),
            "delay_rows": self.delay_rows,
            "lag_s": rounded(self.lag_s),
            "noise_rms_Nm": rounded(self.noise_rms_Nm),
            "nrmse": rounded(self.nrmse),
            "saturation_Nm": None if self.saturation_Nm is None else rounded(self.saturation_Nm),
            "saturated_rows": self.saturated_rows,
            "rows": self.rows,
        }


def _lagged(c: np.ndarray, dt: np.ndarray, lag_s: float) -> np.ndarray:
    """The command ``c`` through a first-order lag, exact per interval: out_0 = c_0,
    out_k = a out_{k−1} + (1 − a) c_k with a = e^{−dt_{k−1}/T} (c_k held over the interval
    before it)."""
    if lag_s <= 0.0:
        return c
    ahead = np.append(c[1:], c[-1])[:, None]  # c_{k+1}, the command of the step to x_{k+1}
    return first_order_states(np.exp(-dt / lag_s), ahead, c[:1])[:, 0]


def _search(
    xs: list[np.ndarray], m: np.ndarray, keep: np.ndarray, delays: range
) -> tuple[float, int, int, float, float]:
    """The least-squares m ≈ g x[k − d] + b over ``keep`` for every lagged command in ``xs``
    and delay d: (SSE, d, index in xs, g, b) of the best."""
    best = (np.inf, 0, 0, 1.0, 0.0)
    for i, x_all in enumerate(xs):
        # a lead (d < 0) only without a lag: a lag shifted earlier is no causal path, and
        # trades its time constant against the lead (the same residual at many pairs)
        for d in delays if i == 0 else (d for d in delays if d >= 0):
            x = np.roll(x_all, d)
            k = keep.copy()
            if d > 0:
                k[:d] = False
            elif d < 0:
                k[d:] = False
            xk, mk = x[k], m[k]
            n = len(xk)
            sx, sm = xk.sum(), mk.sum()
            sxx, sxm = xk @ xk, xk @ mk
            det = n * sxx - sx * sx
            if n < 3 or det <= 0:
                continue
            g = (n * sxm - sx * sm) / det  # the 2×2 normal equations of (g, b)
            b = (sm - g * sx) / n
            r = mk - g * xk - b
            sse = float(r @ r)
            if sse < best[0]:
                best = (sse, d, i, float(g), float(b))
    return best


def _kept(n: int, saturated: np.ndarray, d: int) -> np.ndarray:
    keep = ~saturated
    if d > 0:
        keep[:d] = False
    elif d < 0:
        keep[d:] = False
    return keep


def fit_path(t: np.ndarray, commanded: np.ndarray, measured: np.ndarray, joint: int) -> TorquePath:
    """The path of one joint from rows of commanded and measured torque on the same stamps."""
    dt = np.diff(t, append=t[-1] + np.median(np.diff(t)))
    h = float(np.median(dt))
    c, m = np.asarray(commanded, float), np.asarray(measured, float)
    n = len(c)
    rows = max(1, round(MAX_DELAY_S / h))
    lags = (0.0, *(float(x) for x in LAG_GRID_S))
    xs = [_lagged(c, dt, lag) for lag in lags]
    saturated = np.zeros(n, bool)
    for _ in range(2):  # fit, find the saturated rows, fit again without them
        sse, d, i, g, b = _search(xs, m, ~saturated, range(-rows, rows + 1))
        if i > 0:  # a finer grid between the best lag's neighbours
            fine = np.linspace(lags[i - 1], lags[min(i + 1, len(lags) - 1)], 11)
            fx = [xs[0], *(_lagged(c, dt, float(x)) for x in fine)]
            sse, d, k, g, b = _search(fx, m, ~saturated, range(0, rows + 1))
            lags_used, x_best = (0.0, *fine), fx[k]
            lag = float(lags_used[k])
        else:
            lag, x_best = 0.0, xs[0]
        pred = g * np.roll(x_best, d) + b
        sigma = float(np.sqrt(sse / max(int((~saturated).sum()) - 2, 1)))
        at_extreme = np.abs(m) >= np.max(np.abs(m)) - 0.5 * sigma
        new = at_extreme & (np.abs(pred) - np.abs(m) > SATURATION_SIGMAS * sigma)
        if new.sum() < SATURATION_ROWS or np.array_equal(new, saturated):
            break
        saturated = new
    resolvable = RESOLVABLE_INTERVALS * h
    sse0 = _search(xs[:1], m, ~saturated, range(0, 1))[0]  # neither delay nor lag
    timed = sse0 > 0 and (sse0 - sse) / sse0 >= MIN_REDUCTION
    if not timed:  # the timing changes the residual by less than the diagnosis's threshold
        sse, d, lag, g, b = sse0, 0, 0.0, *_search(xs[:1], m, ~saturated, range(0, 1))[3:]
    delay = d * h if abs(d) * h >= resolvable else 0.0
    keep = _kept(n, saturated, d)
    spread = float(np.std(m[keep]))
    noise = float(np.sqrt(sse / max(int(keep.sum()), 1)))
    return TorquePath(
        joint=joint,
        gain=g,
        offset_Nm=b,
        delay_s=delay,
        delay_rows=d if delay else 0,
        lag_s=lag if lag >= resolvable else 0.0,
        noise_rms_Nm=noise,
        nrmse=noise / spread if spread > 0 else float("nan"),
        saturation_Nm=float(np.max(np.abs(m[saturated]))) if saturated.any() else None,
        saturated_rows=int(saturated.sum()),
        rows=int(keep.sum()),
    )


def torque_sources(path: str | Path, fmt: str | None) -> tuple[str, ...]:
    """The torque sources the format offers for this file's header (empty without a format)."""
    if not fmt:
        return ()
    layout = load_format(fmt).layout_for(recording_names(path, fmt))
    return () if layout is None else tuple(layout.torques)


def torque_path_of(judged: Recording, fmt: str | None) -> dict[str, Any] | None:
    """The commanded → measured path of the file ``judged`` was read from, when its format
    offers both sources; None otherwise. Says which torque the diagnosis judges."""
    sources = torque_sources(judged.path, fmt)
    if not {"commanded", "measured"} <= set(sources):
        return None
    recs = {s: read_signals(judged.path, fmt=fmt, torque=s, extra_columns=False)
            for s in ("commanded", "measured")}  # fmt: skip
    t, ic, im = np.intersect1d(recs["commanded"].t, recs["measured"].t, return_indices=True)
    paths = [
        fit_path(t, recs["commanded"].tau[ic, j], recs["measured"].tau[im, j], j + 1)
        for j in range(judged.n_joints)
    ]
    return {
        "recording": str(judged.path),
        "judged": judged.torque_source,
        "sources": list(sources),
        "joints": [p.as_dict() for p in paths],
    }


def describe(doc: dict[str, Any]) -> list[str]:
    """Report lines of :func:`torque_path_of`'s document."""
    other = "measured" if doc["judged"] == "commanded" else "commanded"
    lines = [f"Torque path of {Path(doc['recording']).name} (the {doc['judged']} torque is "
             f"judged; the {other} one is compared with it):"]  # fmt: skip
    for p in doc["joints"]:
        sat = (
            f", saturates at {p['saturation_Nm']:.3g} Nm ({p['saturated_rows']} rows)"
            if p["saturation_Nm"] is not None
            else ""
        )
        lines.append(
            f"  joint {p['joint']}: measured = {p['gain']:.3f} x commanded "
            f"{p['offset_Nm']:+.3g} Nm, delay {1e3 * p['delay_s']:.3g} ms, lag "
            f"{1e3 * p['lag_s']:.3g} ms, noise {p['noise_rms_Nm']:.3g} Nm RMS "
            f"(NRMSE {100 * p['nrmse']:.1f} %){sat}"
        )
    return lines
