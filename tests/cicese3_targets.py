"""The identification targets of the 3-DOF example arm (cicese3), shared by the tests that
identify it from a simulation (tests/test_urdf_plant.py) and from a bus recording
(tests/test_urdf_bus.py)."""

from __future__ import annotations

from typing import Any

from hil.model.regressors import SCHEMES


def check_cicese3_identified(report: dict[str, Any]) -> None:
    """``identify.json`` of `hil identify --robot cicese3` within the CICESE targets of
    docs/identification.md (inertial and gravity parameters within 2 %, viscous and Coulomb
    within 10 %), the centre-of-mass offsets (nominal 0) within 1 % of the joint's gravity
    parameter, and a held-out last quarter predicted as well as by the true model: the reported
    parameters and, each on its own, every scheme's (all three run by default)."""
    assert report["torque"].startswith("held") and report["smoothing_cutoff_hz"] > 20
    assert sorted(report["schemes"]) == sorted(SCHEMES)
    nominal = [x["nominal"] for x in report["parameters"]]
    true = report["validation"]["torque_nrmse_nominal"]
    check_targets(report, [x["estimate"] for x in report["parameters"]], nominal)
    fit = report["validation"]["torque_nrmse_identified"]
    assert all(a < b + 0.01 for a, b in zip(fit, true, strict=True)), (fit, true)
    for scheme, entry in report["schemes"].items():
        check_targets(report, entry["theta"], nominal, scheme)
        assert [x["schemes"][scheme] for x in report["parameters"]] == entry["theta"]
        fit = entry["validation"]["torque_nrmse"]
        assert all(a < b + 0.01 for a, b in zip(fit, true, strict=True)), (scheme, fit, true)
        assert entry["physical_consistency"]["consistent"], scheme


def check_targets(
    report: dict[str, Any], theta: list[float], nominal: list[float], scheme: str = ""
) -> None:
    """One θ of cicese3's 18 base parameters against the targets (``scheme`` names failures)."""
    meanings = [x["meaning"] for x in report["parameters"]]
    p = dict(zip(meanings, zip(theta, nominal, strict=True), strict=True))
    inertial = [m for m in p if ("I" in m or "mz" in m)]
    assert len(inertial) == 6
    for m in inertial:
        got, want = p[m]
        assert abs(got - want) < 0.02 * abs(want), (scheme, m, got, want)
    for j, gravity in ((1, "mz1 - 0.45 m3 - 0.45 m2"), (2, "mz2 - 0.3 m3"), (3, "mz3")):
        assert abs(p[f"mx{j}"][0]) < 0.01 * abs(p[gravity][1]), (scheme, j)
        for name in (f"fv{j}", f"fc{j}"):
            got, want = p[name]
            assert abs(got - want) < 0.10 * want, (scheme, name, got, want)


def energy_balance_over_excitation(plant: Any, periods: int) -> float:
    """Drive an n-joint plant with ``periods`` periods of cicese3-excitation and return its
    energy balance E(t) − E(0) − (W_in − W_f), which the plant keeps to round-off."""
    from profiles.experiment import load_experiment

    e0 = plant.energy_J()
    experiment = load_experiment("cicese3-excitation")
    h = experiment.period_s
    for k in range(periods):
        plant.command(experiment.torque(k * h))
        plant.advance_to((k + 1) * h)
    return plant.energy_J() - e0 - (plant.work_in_J - plant.dissipated_J)
