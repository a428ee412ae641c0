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


def test_drag_column_is_the_interval_mean_of_v_abs_v() -> None:
    from hil.diagnose.columns import drag_column

    k = 6
    v_nodes = np.zeros((4, k, 2))  # the Gauss–Legendre nodes of each interval
    v_nodes[:, :, 1] = -2.0
    rows = SimpleNamespace(v_nodes=v_nodes, window=1, n_joints=2, rows=k)
    col = drag_column(rows, 1)
    assert col.shape == (k, 2, 1)
    np.testing.assert_allclose(col[:, 1, 0], -4.0)  # q̇|q̇| at −2 rad/s
    np.testing.assert_allclose(col[:, 0, 0], 0.0)
    assert "velocity_squared_drag" in REGISTRY
