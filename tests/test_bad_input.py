"""Bad and degenerate input into the analysis commands (issue 13): `hil identify --from`,
`hil diagnose`, `hil replay`, `hil control --params` end with a one-line error (exit 2) or a
report, never a traceback; `--out` reuse is refused without `--overwrite`."""

from __future__ import annotations

import json
import math
import random
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.recording import META, RecordingWriter
from hil.cli import main as hil_main

H = 0.002
DFKI_FILE = (
    Path(__file__).parent / "data" / "dfki" / "design_A.0__20220815__sys_id__trajectory_00.csv"
)


def moving_rows(n: int) -> list[list[float]]:
    return [
        [
            k * H,
            0.5 * math.sin(2 * math.pi * 0.7 * k * H),
            0.8 * math.sin(2 * math.pi * 1.1 * k * H),
            5 * math.sin(2 * math.pi * 0.9 * k * H),
            math.sin(2 * math.pi * 1.3 * k * H),
        ]
        for k in range(n)
    ]


def degenerate(kind: str, n: int) -> list[list[float]]:
    rows = moving_rows(n)
    if kind == "zero":
        return [[r[0], 0.0, 0.0, 0.0, 0.0] for r in rows]
    if kind == "constant":
        return [[r[0], 0.3, -0.2, 1.0, 0.5] for r in rows]
    if kind == "one-row":
        return rows[:1]
    if kind == "header-only":
        return []
    if kind == "shuffled":
        times = [r[0] for r in rows]
        random.Random(n).shuffle(times)
        return [[t, *r[1:]] for t, r in zip(times, rows, strict=True)]
    if kind == "duplicated":
        return [r for r in rows for _ in range(2)]
    if kind == "cut":
        return rows[: n // 3] + rows[2 * n // 3 :]
    if kind == "nan":
        rows[n // 2][2] = math.nan
        return rows
    raise AssertionError(kind)


def write_run(out: Path, rows: list[list[float]], **meta) -> Path:
    with RecordingWriter(out, {"period_s": H, "robot": "cicese", **meta}) as w:
        for row in rows:
            w.write(row)
    return out


def run_hil(argv: list[str], capsys) -> tuple[int, str]:
    """`hil ARGV` in this process: its exit status and stderr (an exception fails the test)."""
    code = hil_main(argv)
    return code, capsys.readouterr().err


def assert_identified_or_failed(code: int, err: str, out: Path) -> None:
    """0 with params.json, 2 (refused), or 1 when the θ is no arm: FAILED in one line and no
    params.json offered (issue 31)."""
    assert "Traceback" not in err
    if code == 1:
        assert "FAILED" in err.strip().splitlines()[-1] and not (out / "params.json").exists()
    else:
        assert code in (0, 2), err


def assert_one_line_error(code: int, err: str) -> None:
    assert code == 2, err
    last = [ln for ln in err.splitlines() if ln.strip()][-1]
    assert "Traceback" not in err and ("error" in last or last.startswith("hil ")), err


# kinds that the read/CLI boundary refuses: identical for every command reading a recording
REFUSED = ["zero", "constant", "one-row", "header-only", "shuffled", "cut", "nan"]


# rows cut out are a gap, which the 2-DOF identification takes segment by segment
# (tests/test_identify.py: ..._with_a_gap_fits_each_segment_never_across)
@pytest.mark.parametrize("kind", [k for k in REFUSED if k != "cut"])
def test_identify_refuses_degenerate_recordings(tmp_path, capsys, kind):
    run = write_run(tmp_path / "rec", degenerate(kind, 300))
    code, err = run_hil(
        ["identify", "--from", str(run), "--out", str(tmp_path / "id"), "--no-plot"], capsys
    )
    assert_one_line_error(code, err)
    assert str(run) in err
    assert not (tmp_path / "id").exists()  # a refused run leaves nothing


@pytest.mark.parametrize("kind", REFUSED)
def test_diagnose_refuses_degenerate_recordings(tmp_path, capsys, kind):
    run = write_run(tmp_path / "rec", degenerate(kind, 300))
    code, err = run_hil(["diagnose", str(run), "--no-plots"], capsys)
    assert_one_line_error(code, err)
    assert str(run) in err


def test_every_row_duplicated_identifies_as_the_original(tmp_path, capsys):
    """Issue 13: every row written twice gave θ1 four times too large (time read as k·h)."""
    from profiles.experiment import load_experiment
    from profiles.robot import load_robot
    from virtual_robot.simulate import simulate

    a = tmp_path / "a"
    simulate(load_robot("cicese"), load_experiment("reyes-kelly"), a, duration_s=4.0, plot=False)
    b = tmp_path / "b"
    b.mkdir()
    (b / META).write_text((a / META).read_text())
    lines = (a / "signals.csv").read_text().splitlines(keepends=True)
    (b / "signals.csv").write_text(lines[0] + "".join(ln + ln for ln in lines[1:]))
    theta = []
    for run in (a, b):
        out = tmp_path / f"id-{run.name}"
        argv = ["identify", "--from", str(run), "--out", str(out), "--no-plot"]
        argv += ["--schemes", "filtered_dynamic"]
        code, err = run_hil(argv, capsys)
        assert code == 0, err
        doc = json.loads((out / "identify.json").read_text())
        theta.append(doc["discretizations"]["exact"]["schemes"]["filtered_dynamic"]["theta"])
    assert "duplicate" in err
    assert theta[0] == theta[1]
    assert theta[0][0] == pytest.approx(2.351, rel=0.1)  # θ1 of the cicese profile


def test_replay_of_header_only_and_lockstep_runs(tmp_path, capsys):
    header = write_run(tmp_path / "rt", [], mode="realtime", kind="hil run")
    code, err = run_hil(["replay", str(header), "--out", str(tmp_path / "r1")], capsys)
    assert_one_line_error(code, err)
    assert "header only" in err
    lock = write_run(tmp_path / "lock", moving_rows(50), mode="lockstep", kind="hil run")
    code, err = run_hil(["replay", str(lock), "--out", str(tmp_path / "r2")], capsys)
    assert_one_line_error(code, err)
    assert "not a realtime run" in err


@pytest.mark.parametrize(
    "theta",
    [[0.0] * 9, [1.0, 2.0, 0.1, 0, 0, 0, 0, 0, 0], [2.35, 0.08, -0.1, 38, 1.8, 2.3, 0.17, 7, 1.7]],
    ids=["zero", "theta1-small", "theta3-negative"],
)
def test_control_refuses_unphysical_params(tmp_path, capsys, theta):
    params = tmp_path / "params.json"
    params.write_text(json.dumps({"theta": theta}))
    out = tmp_path / "c"
    argv = ["control", "--bench", "virtual-inprocess", "--scheme", "ct"]
    code, err = run_hil([*argv, "--params", str(params), "--out", str(out), "--no-plot"], capsys)
    assert_one_line_error(code, err)
    assert "not positive definite" in err
    assert not out.exists()


@pytest.mark.parametrize("index", [0, 3, 5])
@pytest.mark.parametrize("command", ["control", "diagnose"])
def test_theta_beyond_any_arm_is_refused(tmp_path, capsys, command, index):
    """θ entries of ±1e308 pass the positive-definiteness test (θ1 θ3 − θ3² − θ2² is inf) but
    make the control law inf − inf = NaN: refused, naming the file and the entry."""
    theta = [2.35, 0.08, 0.1, 38, 1.8, 2.3, 0.17, 7, 1.7]
    theta[index] = 1e308
    params = tmp_path / "params.json"
    params.write_text(json.dumps({"theta": theta}))
    out = tmp_path / "c"
    if command == "control":
        argv = ["control", "--bench", "virtual-inprocess", "--scheme", "ct", "--duration", "0.1"]
    else:
        argv = ["diagnose", str(write_run(tmp_path / "rec", moving_rows(300))), "--no-plots"]
    code, err = run_hil([*argv, "--params", str(params), "--out", str(out)], capsys)
    assert_one_line_error(code, err)
    assert str(params) in err and f"theta{index + 1} = 1e+308" in err
    assert not out.exists()


def test_out_reuse_is_refused_without_overwrite(tmp_path, capsys):
    run = write_run(tmp_path / "rec", moving_rows(300))
    out = tmp_path / "id"
    out.mkdir()
    (out / "bus.log").write_text("an earlier run's file\n")
    argv = ["identify", "--from", str(run), "--out", str(out), "--no-plot"]
    argv += ["--schemes", "supplied_energy", "--params-scheme", "supplied_energy"]
    code, err = run_hil(argv, capsys)
    assert_one_line_error(code, err)
    assert str(out) in err and "--overwrite" in err
    assert (out / "bus.log").exists()
    code, err = run_hil([*argv, "--overwrite"], capsys)
    assert not (out / "bus.log").exists()
    assert_identified_or_failed(code, err, out)
    # --overwrite never empties a directory holding the input
    code, err = run_hil(
        ["diagnose", str(run), "--out", str(tmp_path), "--overwrite", "--no-plots"], capsys
    )
    assert_one_line_error(code, err)
    assert run.is_dir() and "holds the input" in err


def test_recording_options_reach_identify(tmp_path, capsys):
    out = tmp_path / "id"
    argv = ["identify", "--from", str(DFKI_FILE), "--format", "dfki", "--out", str(out)]
    argv += ["--no-plot", "--schemes", "supplied_energy", "--params-scheme", "supplied_energy"]
    code, err = run_hil(argv, capsys)
    assert "loop delay 1" in err and "irregular sampling" in err
    if code == 0:
        doc = json.loads((out / "identify.json").read_text())
        assert doc["loop_delay"] == 1 and doc["torque_source"] == "commanded"
    for bad in (["--torque", "bogus"], ["--loop-delay", "1000"], ["--columns", "x=y"]):
        code, err = run_hil([*argv, *bad, "--overwrite"], capsys)
        assert_one_line_error(code, err)
    code, err = run_hil(["diagnose", str(DFKI_FILE), "--format", "nope"], capsys)
    assert_one_line_error(code, err)


@pytest.mark.parametrize("kind", ["one-joint", "step"])
def test_diagnose_degenerate_motion_inside_the_analysis(tmp_path, capsys, kind):
    """Data the boundary lets through (the arm moves) but the diagnosis cannot handle."""
    n = 600
    if kind == "one-joint":
        rows = [[r[0], r[1], 0.0, r[3], 0.0] for r in moving_rows(n)]
    else:
        rows = [[k * H, 0.0 if k < n // 2 else 0.1, 0.0, 0.0, 0.0] for k in range(n)]
    run = write_run(tmp_path / "rec", rows)
    code, err = run_hil(["diagnose", str(run), "--no-plots"], capsys)
    assert code in (0, 2) and "Traceback" not in err


@settings(
    max_examples=12,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(
    kind=st.sampled_from([*REFUSED, "duplicated"]),
    n=st.integers(1, 400),
    command=st.sampled_from(["identify", "diagnose"]),
)
def test_degenerate_data_never_gives_a_traceback(tmp_path_factory, capsys, kind, n, command):
    base = tmp_path_factory.mktemp("deg")
    run = write_run(base / "rec", degenerate(kind, max(n, 1)))
    if command == "identify":
        argv = ["identify", "--from", str(run), "--out", str(base / "out"), "--no-plot"]
        argv += ["--schemes", "supplied_energy", "--params-scheme", "supplied_energy"]
    else:
        argv = ["diagnose", str(run), "--no-plots"]
    code, err = run_hil(argv, capsys)
    assert_identified_or_failed(code, err, base / "out")


def test_meta_period_of_a_run_checked_by_every_reader(tmp_path, capsys):
    run = write_run(tmp_path / "rec", moving_rows(300))
    meta = json.loads((run / META).read_text())
    for period in (0, 1.0, [1], 1e9):
        meta["period_s"] = period
        (run / META).write_text(json.dumps(meta))
        for argv in (
            ["identify", "--from", str(run), "--out", str(tmp_path / "o"), "--no-plot"],
            ["diagnose", str(run), "--no-plots"],
            ["replay", str(run), "--out", str(tmp_path / "r")],
        ):
            code, err = run_hil(argv, capsys)
            assert_one_line_error(code, err)
            assert "period_s" in err


@pytest.mark.parametrize("kind", [*REFUSED, "duplicated"])
def test_replay_of_degenerate_recordings(tmp_path, capsys, kind):
    run = write_run(tmp_path / "rec", degenerate(kind, 300), mode="realtime", kind="hil run")
    code, err = run_hil(["replay", str(run), "--out", str(tmp_path / "r"), "--no-plot"], capsys)
    assert_one_line_error(code, err)
    assert not (tmp_path / "r").exists()


@settings(max_examples=80, deadline=None)
@given(
    columns=st.none() | st.text(alphabet="tqau12=,_ xyz", max_size=30),
    delay=st.none() | st.integers(-(10**6), 10**6),
    torque=st.none() | st.sampled_from(["commanded", "measured", "", " ", "bogus"]),
    fmt=st.none() | st.sampled_from(["dfki", "nope"]),
)
def test_recording_options_are_read_or_refused_in_one_line(columns, delay, torque, fmt):
    """Any --columns / --loop-delay / --torque / --format: a recording or a one-line error."""
    import argparse

    from drivers.recording import RecordingError
    from hil.cli_options import read_recording
    from profiles import ProfileError

    args = argparse.Namespace(
        recording_format=fmt, columns=columns, loop_delay=delay, torque=torque
    )
    try:
        rec = read_recording(args, DFKI_FILE, command="identify")
    except (ValueError, RecordingError, ProfileError) as exc:
        assert "\n" not in str(exc) and str(exc)
        return
    assert len(rec) > 4000 and rec.n_joints >= 1
    if delay is not None:
        assert abs(delay) <= 100 and rec.loop_delay == delay
