"""The pieces every offline run of drives with their own loop shares (virtual_robot.offline:
drive_loop_rows, record_drive_loop), as simulate_mit and simulate_odrive use them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from profiles.experiment import load_experiment
from profiles.robot import load_any_robot
from virtual_robot.mit_simulate import simulate_mit
from virtual_robot.odrive_simulate import simulate_odrive
from virtual_robot.offline import SW_ENABLED, drive_loop_rows


def test_rows_follow_the_duration_and_refuse_a_joint_mismatch() -> None:
    robot = load_any_robot("dfki-a0")
    experiment = load_experiment("reyes-kelly")
    drives, h, n_rows, torque = drive_loop_rows(robot, experiment, 0.05)
    assert len(drives) == 2
    assert n_rows == max(1, round(0.05 / h))
    assert len(torque) == n_rows and len(torque[0]) == 2
    assert drive_loop_rows(robot, experiment, 0.0)[2] == 1  # at least one row
    with pytest.raises(ValueError, match="3"):  # a 2-joint experiment on a 3-joint arm
        drive_loop_rows(load_any_robot("cicese3"), experiment, 0.05)


@pytest.mark.parametrize(
    ("robot", "simulate", "protocol"),
    [("dfki-a0", simulate_mit, "mit"), ("dfki-a0-odrive", simulate_odrive, "odrive")],
)
def test_both_protocols_write_the_same_recording_layout(
    tmp_path: Path, robot: str, simulate, protocol: str
) -> None:
    experiment = load_experiment("reyes-kelly")
    result = simulate(load_any_robot(robot), experiment, tmp_path, duration_s=0.1)
    meta = json.loads((tmp_path / "meta.json").read_text())
    assert meta["protocol"] == protocol and meta["mode"] == "offline"
    assert [d["protocol"] for d in meta["drives"]] == [protocol, protocol]
    assert meta["duration_s"] == pytest.approx(result.rows * experiment.period_s)
    rows = np.genfromtxt(tmp_path / "signals.csv", delimiter=",", names=True)
    assert len(rows) == result.rows
    assert np.allclose(np.diff(rows["t"]), experiment.period_s)
    assert (rows["status1"] == SW_ENABLED).all() and (rows["status2"] == SW_ENABLED).all()
    assert result.plant_steps > 0
