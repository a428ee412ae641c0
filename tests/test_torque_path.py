"""The torque path from commanded to measured torque (hil/diagnose/torque_path.py, issue 26
item 3): a known path is recovered; the committed DFKI file's path is read from its two sources;
`hil diagnose` says which torque it judges."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from drivers.recording import read_signals
from hil.diagnose.torque_path import _lagged, fit_path, torque_path_of

DFKI_FILE = (
    Path(__file__).parent / "data" / "dfki" / "design_A.0__20220815__sys_id__trajectory_00.csv"
)


def _command(n: int, h: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.cumsum(np.full(n, h) * (1 + 0.02 * rng.uniform(-1, 1, n)))
    amp, freq, phase = rng.uniform(0.2, 0.6, 6), rng.uniform(0.3, 12, 6), rng.uniform(0, 6, 6)
    c = sum(a * np.sin(2 * np.pi * f * t + p) for a, f, p in zip(amp, freq, phase, strict=True))
    return t, c


@pytest.mark.parametrize("gain, rows, lag_s", [(0.9, 3, 0.0), (1.08, 0, 0.008), (0.95, 2, 0.004)])
def test_a_known_path_is_recovered(gain, rows, lag_s):
    h = 0.002
    t, c = _command(6000, h)
    dt = np.diff(t, append=t[-1] + h)
    rng = np.random.default_rng(1)
    m = gain * np.roll(_lagged(c, dt, lag_s), rows) + 0.01 + rng.normal(0, 0.01, len(c))
    p = fit_path(t[rows:], c[rows:], m[rows:], 1)
    assert p.gain == pytest.approx(gain, rel=0.01)
    assert p.delay_rows == rows and p.offset_Nm == pytest.approx(0.01, abs=0.003)
    assert p.lag_s == pytest.approx(lag_s, rel=0.35, abs=1e-3)
    assert p.noise_rms_Nm == pytest.approx(0.01, rel=0.2) and p.saturation_Nm is None


def test_the_lagged_command_is_the_exact_first_order_lag_step_by_step():
    """The path's lagged command (a prefix scan) equals the lag stepped interval by interval:
    out_k = out_{k−1} + (1 − e^{−dt_{k−1}/T}) (c_k − out_{k−1}), on unequal intervals."""
    rng = np.random.default_rng(3)
    c = rng.normal(size=3000)
    dt = 0.002 * (1.0 + 0.5 * rng.random(3000))
    for lag_s in (1e-4, 0.004, 0.05):
        step = np.empty_like(c)
        step[0] = c[0]
        for k in range(1, len(c)):
            step[k] = step[k - 1] + (1.0 - np.exp(-dt[k - 1] / lag_s)) * (c[k] - step[k - 1])
        np.testing.assert_allclose(_lagged(c, dt, lag_s), step, rtol=0, atol=1e-12)
    assert _lagged(c, dt, 0.0) is c


def test_saturation_is_found_and_left_out():
    h = 0.002
    t, c = _command(6000, h, seed=2)
    limit = 0.7 * np.max(np.abs(c))
    rng = np.random.default_rng(3)
    m = np.clip(c, -limit, limit) + rng.normal(0, 0.005, len(c))
    p = fit_path(t, c, m, 2)
    assert p.saturation_Nm == pytest.approx(limit, rel=0.05) and p.saturated_rows > 20
    assert p.gain == pytest.approx(1.0, rel=0.01) and p.delay_rows == 0


def test_the_dfki_file_path_and_the_report_section(capsys):
    rec = read_signals(DFKI_FILE, fmt="dfki")
    doc = torque_path_of(rec, "dfki")
    assert doc is not None and doc["judged"] == "commanded"
    assert {"commanded", "measured"} <= set(doc["sources"]) and len(doc["joints"]) == 2
    for p in doc["joints"]:
        # the motor's current-based torque follows the command to within tens of percent
        assert 0.5 < p["gain"] < 1.5 and p["nrmse"] < 0.5, p
    assert torque_path_of(read_signals(DFKI_FILE, fmt="dfki"), None) is None

    from hil.cli import main

    assert main(["diagnose", str(DFKI_FILE), "--format", "dfki", "--robot", "dfki-a0",
                 "--json"]) == 0  # fmt: skip
    out = json.loads(capsys.readouterr().out)
    assert out["torque_path"][0]["judged"] == "commanded"
    assert [p["joint"] for p in out["torque_path"][0]["joints"]] == [1, 2]
