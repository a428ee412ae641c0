"""Issue 27: two more real arms, the DFKI simple pendulum (1 joint, profile dfki-pendulum) and the
KUKA LWR4+ (7 joints with torque sensors, profile kuka-lwr4): their profiles, and `hil identify`
and `hil diagnose` on their real recordings ending in a report (docs/real-data.md). The KUKA data
(LGPL-3) and all but one pendulum file are read from ../shared (tests/realdata.py); those tests
skip with a message when it is absent."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from realdata import KUKA, kuka_csv, realdata

from hil.cli import main as hil_main
from hil.model.urdf import UrdfArmModel
from profiles.robot import load_urdf_robot

PENDULUM_FILE = (
    Path(__file__).parent / "data" / "dfki-pendulum" / "control_method_ilqr__data_measured.csv"
)
COLUMNS = "t=time,q1=position,tau1=torque"


def _identify(argv: list[str], capsys) -> tuple[int, dict]:
    """`hil identify ... --json`: exit 0, or 1 only for a failed held-out validation (its
    report printed all the same, the reason on stderr in one line)."""
    capsys.readouterr()
    code = hil_main(["identify", *argv, "--no-plot", "--json"])
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    report = json.loads(out)
    assert code == 0 or (code == 1 and "failed held-out validation" in err), (code, err)
    assert report["validation"]["passed"] == (code == 0)
    return code, report


def _diagnose(paths: list[Path], robot: str, capsys, *extra: str) -> dict:
    capsys.readouterr()
    argv = ["diagnose", *map(str, paths), "--robot", robot, *extra, "--json", "--no-plots"]
    assert hil_main(argv) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["summary"]
    return doc


def test_profiles_of_the_two_arms():
    """The pendulum's base parameters are the owners' CAD body (m·cx = 0.2930 kg m,
    J = 0.1304 kg m² about the axis, plus the rotor 36 Ir = 0.0022 kg m² merged with it: one
    joint) and friction (Fv, Fc·π/2, offset); the KUKA has 7 joints; each URDF ships with its
    licence beside it."""
    pendulum = UrdfArmModel.from_profile("dfki-pendulum")
    assert pendulum.n_joints == 1 and pendulum.n_params == 6
    theta = pendulum.base_theta()
    expected = [0.2930, 0.0, 0.1304 + 0.0021859, 0.04707, 0.1839 * np.pi / 2, -0.07586]
    assert np.allclose(theta, expected, atol=6e-4), theta
    kuka = UrdfArmModel.from_profile("kuka-lwr4")
    assert kuka.n_joints == 7
    for name in ("dfki-pendulum", "kuka-lwr4"):
        urdf = Path(load_urdf_robot(name).urdf)
        assert urdf.with_name(urdf.name + ".LICENSE").is_file()
    text = Path(load_urdf_robot("kuka-lwr4").urdf + ".LICENSE").read_text()
    assert "GNU LESSER GENERAL PUBLIC LICENSE" in text and "GNU GENERAL PUBLIC LICENSE" in text


def test_pendulum_file_in_the_tree_is_identified_and_diagnosed(tmp_path, capsys):
    """The committed iLQR swing-up (20 ms samples, one joint): identified with held-out
    validation passed, its gravity moment above twice the owners' identified 0.1022 kg m (the
    recordings follow the CAD body; docs/real-data.md), and diagnosed to a report."""
    code, report = _identify(
        ["--from", str(PENDULUM_FILE), "--robot", "dfki-pendulum", "--columns", COLUMNS,
         "--out", str(tmp_path / "id")], capsys)  # fmt: skip
    assert code == 0
    m_cx = report["parameters"][0]["estimate"]
    assert m_cx > 2 * 0.1022, m_cx
    # least squares puts the Coulomb level (fc1) below 0 here; what is offered is an arm: the
    # fit bounded to friction >= 0, least squares' θ beside it (issue 29 item 2a)
    pendulum = UrdfArmModel.from_profile("dfki-pendulum")
    for name, scheme in report["schemes"].items():
        theta = np.array(scheme["theta"])
        assert scheme["usable"] == scheme["validation"]["passed"], name
        assert pendulum.physical_consistency(theta)["consistent"], (name, theta)
        assert np.all(theta[list(pendulum.friction_columns)] >= 0), (name, theta)
    fd = report["schemes"]["filtered_dynamic"]
    assert fd["theta_least_squares"][4] < 0 and fd["theta"][4] == 0.0, fd
    assert "friction >= 0" in fd["method"] and report["selection"]["usable"]
    doc = _diagnose([PENDULUM_FILE], "dfki-pendulum", capsys, "--columns", COLUMNS)
    assert "1 joints" not in doc["summary"]
    # the profile's rotor_inertia term is in the model: not offered as a missing candidate
    assert doc["not_tested"]["rotor_inertia"].startswith("the nominal model has an armature")
    # one joint: a torque gain is not told from the parameters' scale, and the report says so
    assert doc["not_tested"]["gain"].startswith("one joint moves")
    assert "Not tested: torque_gain: one joint moves" in doc["summary"]


def _pendulum_records() -> list[Path]:
    folder = realdata("dfki-simple-pendulum") / "records"
    if not folder.is_dir():
        pytest.skip(f"{folder} not present (the DFKI simple pendulum recordings)")
    return sorted(folder.glob("*.csv"))


@pytest.mark.slow
def test_every_pendulum_recording_ends_in_reports(tmp_path, capsys):
    """`hil identify` and `hil diagnose` on each of the five controllers' recordings (1-20 ms
    samples): no traceback, a report each; DDP and PD diagnosed together (either held out): no
    finding. The gravity-compensation run's torque is its
    controller's m·l·g·sin q: its gravity moment is 0.338 kg m, three times the owners'
    identified 0.1022 (docs/real-data.md). About 15 s CPU."""
    records = _pendulum_records()
    for path in records:
        _, report = _identify(
            ["--from", str(path), "--robot", "dfki-pendulum", "--columns", COLUMNS,
             "--out", str(tmp_path / "id"), "--overwrite"], capsys)  # fmt: skip
        if "gravity_compensation" in path.name:
            assert abs(report["parameters"][0]["estimate"] - 0.338) < 0.01
        _diagnose([path], "dfki-pendulum", capsys, "--columns", COLUMNS)
    # two runs of the unchanged pendulum, fit on one and held out on the other: no finding
    pair = [p for p in records if "ddp" in p.name or "_pd_" in p.name]
    assert len(pair) == 2, records
    for paths in (pair, pair[::-1]):
        doc = _diagnose(paths, "dfki-pendulum", capsys, "--columns", COLUMNS)
        assert doc["findings"] == [], doc["summary"]


@pytest.mark.slow
def test_kuka_runs_identified_against_each_other_and_diagnosed(tmp_path, capsys):
    """The KUKA LWR4+: identified from measurements_1 (physically consistent fit) and validated
    on measurements_3, it predicts every joint's held-out torque better than the profile's a
    priori URDF. Diagnosed, run 1 alone, run 3 alone, the two together and each run against
    the other (`--reference`, the .npz files read with `--format kuka-lwr4`) end in a report
    that says what the model leaves out or why it cannot tell; the two runs of the unchanged
    arm give no finding. 280 s wall on the 2-core VM under a load of 4 (run 3 alone and the
    pair about 45 s user CPU each: docs/real-data.md)."""
    if not (realdata(KUKA) / "measurements_1.npz").is_file():
        pytest.skip(f"{realdata(KUKA)} not present (LGPL-3 data, kept out of the tree)")
    runs = [kuka_csv(r, tmp_path) for r in (1, 3)]
    _, report = _identify(
        ["--from", str(runs[0]), "--validate", str(runs[1]), "--robot", "kuka-lwr4",
         "--schemes", "filtered_dynamic", "--consistent", "--out", str(tmp_path / "id")],
        capsys)  # fmt: skip
    val = report["validation"]
    ours, nominal = np.array(val["torque_nrmse_identified"]), np.array(val["torque_nrmse_nominal"])
    assert np.all(ours < nominal), (ours, nominal)
    assert report["physical_consistency"]["consistent"]
    npz = [realdata(KUKA) / f"measurements_{r}.npz" for r in (1, 3)]
    for judged in ([runs[0]], [runs[1]], runs):  # run 1 alone, run 3 alone, both together
        doc = _diagnose(judged, "kuka-lwr4", capsys)
        assert len(doc["fit"]["before"]["torque_nrmse"]) == 7
        assert doc["findings"] or "cannot tell" in doc["summary"], doc["summary"]
    for judged, ref in ((npz[1], npz[0]), (npz[0], npz[1])):
        extra = ["--reference", str(ref), "--format", "kuka-lwr4"]
        doc = _diagnose([judged], "kuka-lwr4", capsys, *extra)
        assert doc["nominal"]["source"] == "reference" and doc["nominal"]["decision"]
        assert doc["findings"] == [], doc["summary"]  # nothing changed: no finding


def test_a_one_joint_recording_in_the_standard_columns(tmp_path, capsys):
    """t,q1,tau1 is a recording (one joint): `hil identify --robot dfki-pendulum` reads it
    without a column map and gives the same parameters as the original file through one; a
    2-DOF command refuses it in one line naming "1 joint (q1)"."""
    data = np.loadtxt(PENDULUM_FILE, delimiter=",", skiprows=1)
    bare = tmp_path / "one.csv"
    np.savetxt(bare, data[:, [0, 1, 3]], delimiter=",", header="t,q1,tau1", comments="",
               fmt="%.17g")  # fmt: skip
    common = ["--robot", "dfki-pendulum", "--schemes", "filtered_dynamic"]
    _, plain = _identify(["--from", str(bare), *common, "--out", str(tmp_path / "a")], capsys)
    _, mapped = _identify(["--from", str(PENDULUM_FILE), *common, "--columns", COLUMNS,
                           "--out", str(tmp_path / "b")], capsys)  # fmt: skip
    assert [p["estimate"] for p in plain["parameters"]] == [
        p["estimate"] for p in mapped["parameters"]
    ]
    assert hil_main(["diagnose", str(bare), "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert "one.csv: 1 joint (q1); hil diagnose takes 2" in err and err.count("\n") == 1, err
