"""The identification targets of the 3-DOF example arm (cicese3), shared by the tests that
identify it from a simulation (tests/test_urdf_plant.py) and from a bus recording
(tests/test_urdf_bus.py)."""

from __future__ import annotations

from typing import Any


def check_cicese3_identified(report: dict[str, Any]) -> None:
    """``identify.json`` of `hil identify --robot cicese3` within the CICESE targets of
    docs/identification.md (inertial and gravity parameters within 2 %, viscous and Coulomb
    within 10 %), the centre-of-mass offsets (nominal 0) within 1 % of the joint's gravity
    parameter, and a held-out last quarter predicted as well as by the true model."""
    assert report["torque"].startswith("held") and report["smoothing_cutoff_hz"] > 20
    p = {x["meaning"]: (x["identified"], x["nominal"]) for x in report["parameters"]}
    inertial = [m for m in p if ("I" in m or "mz" in m)]
    assert len(inertial) == 6
    for m in inertial:
        got, want = p[m]
        assert abs(got - want) < 0.02 * abs(want), (m, got, want)
    for j, gravity in ((1, "mz1 - 0.45 m3 - 0.45 m2"), (2, "mz2 - 0.3 m3"), (3, "mz3")):
        assert abs(p[f"mx{j}"][0]) < 0.01 * abs(p[gravity][1]), j
        for name in (f"fv{j}", f"fc{j}"):
            got, want = p[name]
            assert abs(got - want) < 0.10 * want, (name, got, want)
    fit = report["validation"]["torque_nrmse_identified"]
    true = report["validation"]["torque_nrmse_nominal"]
    assert all(a < b + 0.01 for a, b in zip(fit, true, strict=True)), (fit, true)
