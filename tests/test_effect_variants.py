"""Which joints an effect is tested on (issue 26): a torque gain only where torque is recorded."""

from types import SimpleNamespace

import numpy as np

from hil.diagnose.effects.base import REGISTRY, Context


def _ctx(tau: np.ndarray) -> Context:
    rows = [SimpleNamespace(tau=tau)]
    return Context(rows=rows, model=None, theta0=np.zeros(3), Psi_raw=np.zeros((len(tau), 2, 3)))


def test_gain_not_tested_on_an_unactuated_joint() -> None:
    # DFKI design C.0 records τ = 0 on its passive second joint: a gain there fitted β → 1,
    # reported as a gain of 100
    tau = np.column_stack([np.linspace(-1, 1, 50), np.zeros(50)])
    assert REGISTRY["torque_gain"].variants(_ctx(tau)) == [0]
    tau[3, 1] = 0.2
    assert REGISTRY["torque_gain"].variants(_ctx(tau)) == [0, 1]
