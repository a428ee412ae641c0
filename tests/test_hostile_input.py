"""Hostile and extreme input (issue 31): strict JSON everywhere, numbers out of range named by
file, line and column before any solver sees them, readers bounded in line length and memory,
a UTF-8 BOM header, bad profiles and options exit 2 leaving --out empty, non-physical θ never
offered, `--attach` checked as an address, progress on long stages."""

from __future__ import annotations

import argparse
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_run import ROOT, hil

from drivers.recording import (
    MAX_ABS_VALUE,
    MAX_LINE_CHARS,
    RecordingError,
    dumps_strict,
    read_signals,
    strict_json,
    write_json_atomic,
)

H = 0.002


def _reject_constant(name: str) -> None:
    raise ValueError(f"not strict JSON: {name}")


def strict_loads(text: str) -> object:
    """json.loads as a strict parser (RFC 8259): NaN and Infinity refused."""
    return json.loads(text, parse_constant=_reject_constant)


def rows(n: int = 3000) -> np.ndarray:
    t = np.arange(n) * H
    return np.column_stack(
        [
            t,
            0.5 * np.sin(2 * np.pi * 0.7 * t),
            0.8 * np.sin(2 * np.pi * 1.1 * t),
            5 * np.sin(2 * np.pi * 0.9 * t),
            np.sin(2 * np.pi * 1.3 * t),
        ]
    )


def write_csv(path: Path, data: np.ndarray, *, bom: bool = False) -> Path:
    text = "t,q1,q2,tau1,tau2\n" + "".join(",".join(map(repr, map(float, r))) + "\n" for r in data)
    path.write_text(text, encoding="utf-8-sig" if bom else "utf-8")
    return path


# ---- strict JSON -------------------------------------------------------------------------------


def test_strict_json_nulls_non_finite_numbers_with_a_reason(tmp_path):
    doc = {
        "a": math.nan,
        "b": [1.0, math.inf],
        "c": {"d": np.array([0.5, -np.inf])},
        "e": np.float64("nan"),
        "ok": 2.5,
    }
    text = dumps_strict(doc)
    back = strict_loads(text)
    assert back["a"] is None and back["a_null_reason"].endswith("NaN")
    assert back["b"] == [1.0, None] and "Infinity at index 1" in back["b_null_reason"]
    assert back["c"]["d"] == [0.5, None] and "-Infinity" in back["c"]["d_null_reason"]
    assert back["e"] is None and back["ok"] == 2.5 and "ok_null_reason" not in back
    assert strict_json([math.nan]) == [None]
    write_json_atomic(tmp_path / "x.json", doc)
    assert strict_loads((tmp_path / "x.json").read_text()) == back


def test_print_document_is_strict_json(capsys):
    from hil.cli_options import print_document

    print_document(argparse.Namespace(json=True), {"x": math.inf, "y": np.float32(1.5)}, "")
    back = strict_loads(capsys.readouterr().out)
    assert back["x"] is None and back["y"] == 1.5 and "Infinity" in back["x_null_reason"]


def test_every_json_writer_goes_through_the_strict_dumper():
    """No json.dump(s) of a document outside drivers.recording.dumps_strict (a new writer would
    bring NaN back): the tree is grepped."""
    offenders = []
    for package in ("hil", "drivers", "virtual_robot", "profiles", "plots"):
        for path in (ROOT / package).rglob("*.py"):
            for no, line in enumerate(path.read_text().splitlines(), 1):
                if "json.dump(" in line or (
                    "json.dumps(" in line and "allow_nan=False" not in line
                ):
                    offenders.append(f"{path.relative_to(ROOT)}:{no}: {line.strip()}")
    allowed = (
        "profiles/bench.py",  # a TOML string literal, a str
        "hil/bench/variant.py",  # a TOML basic string, a str
        "drivers/recording/reader.py",  # the meta field named in a reader error (parsed JSON)
        "virtual_robot/serve.py",  # a log line of timing fault names
    )
    assert [o for o in offenders if not o.startswith(allowed)] == []


# ---- numbers out of range ----------------------------------------------------------------------


def test_value_out_of_range_names_file_line_and_column(tmp_path):
    data = rows()
    data[1500, 1] = 1e300
    path = write_csv(tmp_path / "big.csv", data)
    with pytest.raises(RecordingError) as exc:
        read_signals(path)
    msg = str(exc.value)
    assert f"{path}:1502: q1 = 1e+300: value out of range" in msg and "\n" not in msg
    data[1500, 1] = 0.0
    data[10, 4] = -2 * MAX_ABS_VALUE
    with pytest.raises(RecordingError, match=r":12: tau2 = -2000000.0: value out of range"):
        read_signals(write_csv(tmp_path / "tau.csv", data))


def test_identify_on_an_absurd_value_is_one_line_and_nothing_on_stdout(tmp_path):
    """Before: LAPACK's "On entry to DLASCL parameter number 4" on stdout (in --json mode too)
    and "SVD did not converge" with no file, row or cause."""
    data = rows()
    data[1500, 1] = 1e300
    path = write_csv(tmp_path / "big.csv", data)
    proc = hil("identify", "--from", str(path), "--json", "--no-plot", "--out", str(tmp_path / "o"))
    assert proc.returncode == 2, proc.stderr
    assert proc.stdout == ""
    last = proc.stderr.strip().splitlines()[-1]
    assert "big.csv:1502: q1 = 1e+300: value out of range" in last
    assert not (tmp_path / "o").exists()


def test_solvers_refuse_non_finite_rows_before_lapack():
    from hil.model.estimators import least_squares, solve_normal_equations

    Psi = np.ones((4, 1, 2))
    y = np.ones((4, 1))
    Psi[2, 0, 1] = np.nan
    with pytest.raises(ValueError, match="non-finite number"):
        least_squares(Psi, y)
    with pytest.raises(ValueError, match="non-finite number"):
        solve_normal_equations(np.array([[1.0, 0.0], [0.0, np.inf]]), np.ones(2))


# ---- bounded readers, BOM ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "kind, line",
    [("no-newline", 1), ("nul-bytes", 1), ("huge-field", 2), ("huge-last-line", 3)],
)
def test_lines_past_the_bound_end_in_one_line(tmp_path, kind, line):
    path = tmp_path / f"{kind}.csv"
    big = MAX_LINE_CHARS + 10
    if kind == "no-newline":
        path.write_text("t,q1,q2,tau1,tau2" + ",x" * big)
    elif kind == "nul-bytes":
        path.write_bytes(b"\0" * (3 * big))
    elif kind == "huge-field":
        path.write_text("t,q1,q2,tau1,tau2\n0," + "1" * big + ",0,0,0\n")
    else:  # a torn last line of megabytes
        path.write_text("t,q1,q2,tau1,tau2\n0,0,0,0,0\n" + "9" * big)
    with pytest.raises(RecordingError) as exc:
        read_signals(path)
    assert f"{path}:{line}: line longer than 128 KiB" in str(exc.value)


def test_a_line_at_the_bound_is_read(tmp_path):
    """The bound is the bound: a header of MAX_LINE_CHARS characters is taken."""
    pad = MAX_LINE_CHARS - len("t,q1,q2,tau1,tau2,")
    data = rows(50)
    path = tmp_path / "wide.csv"
    body = "".join(",".join(map(repr, map(float, r))) + ",0\n" for r in data)
    path.write_text("t,q1,q2,tau1,tau2," + "x" * pad + "\n" + body)
    assert len(read_signals(path)) == 50


@pytest.mark.skipif(not Path("/dev/zero").exists(), reason="no /dev/zero")
def test_diagnose_dev_zero_ends_quickly_in_one_line():
    """Before: the reader grew to 8 GB in 15 s."""
    proc = hil("diagnose", "/dev/zero", "--out", "/nonexistent/never-written", timeout=30)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0, proc.stderr
    assert "line longer than 128 KiB" in proc.stderr


def test_a_bom_header_reads(tmp_path):
    rec = read_signals(write_csv(tmp_path / "excel.csv", rows(20), bom=True))
    assert len(rec) == 20 and rec.n_joints == 2


# ---- non-physical parameters are never offered -------------------------------------------------


def _noise_csv(path: Path, seed: int = 1) -> Path:
    rng = np.random.default_rng(seed)
    data = rng.normal(size=(3000, 5))
    data[:, 0] = np.arange(3000) * H
    return write_csv(path, data)


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory) -> Path:
    """8 s of the CICESE arm's excitation, simulated."""
    from profiles.experiment import load_experiment
    from profiles.robot import load_robot
    from virtual_robot.simulate import simulate

    run = tmp_path_factory.mktemp("sim") / "run"
    simulate(load_robot("cicese"), load_experiment("reyes-kelly"), run, duration_s=8, plot=False)
    return run


@pytest.fixture(scope="module")
def swapped_run(sim_run) -> Path:
    """The simulated run with its two torque columns swapped."""
    rec = read_signals(sim_run)
    data = np.column_stack([rec.t, rec.q, rec.tau[:, ::-1]])
    return write_csv(sim_run.parent / "swapped.csv", data)


@pytest.mark.parametrize("source", ["noise", "swapped"])
@pytest.mark.parametrize("path", ["table-ii", "model"])
def test_identify_never_offers_a_non_physical_theta(tmp_path, swapped_run, source, path):
    """Before: every scheme NOT PHYSICAL, yet exit 0, params.json written, "selected:
    filtered_dynamic"."""
    rec = _noise_csv(tmp_path / "noise.csv") if source == "noise" else swapped_run
    out = tmp_path / "id"
    extra = ["--terms", ""] if path == "model" else []
    proc = hil("identify", "--from", str(rec), "--out", str(out), "--no-plot", "--json", *extra)
    assert proc.returncode == 1, proc.stderr
    assert "FAILED" in proc.stderr.strip().splitlines()[-1]
    assert not (out / "params.json").exists()
    doc = strict_loads(proc.stdout)
    assert doc["selection"]["usable"] is False and doc["selection"]["reason"]
    assert strict_loads((out / "identify.json").read_text())["selection"] == doc["selection"]
    if path == "table-ii":
        schemes = doc["discretizations"]["exact"]["schemes"]
        assert all(not s["usable"] and s["failed_reason"] for s in schemes.values())


def test_control_refuses_a_scheme_identify_marked_not_physical(tmp_path):
    """A params.json written before identify withheld such schemes: its selected θ marked
    not physically consistent is refused (exit 2), --out left unwritten."""
    params = tmp_path / "params.json"
    theta = [2.35, 0.08, 0.1, 38, 1.8, 2.3, 0.17, 7, -1.7]  # M(q) > 0, a negative Coulomb level
    consistency = {"consistent": False, "violations": ["negative friction coefficient"]}
    params.write_text(
        json.dumps(
            {
                "selected": "filtered_dynamic",
                "schemes": {
                    "filtered_dynamic": {"theta": theta, "physical_consistency": consistency}
                },
            }
        )
    )
    out = tmp_path / "c"
    proc = hil("control", "--bench", "virtual-inprocess", "--scheme", "ct", "--params",
               str(params), "--out", str(out), "--no-plot")  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert "not physically consistent" in last and str(params) in last
    assert not out.exists()


# ---- --attach ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "bench, channel, expected",
    [
        ("virtual-socketcand", "foo", "HOST:PORT"),  # before: invalid literal for int()
        ("virtual-socketcand", "127.0.0.1:99999", "1..65535"),  # before: nothing listens there
        ("virtual-socketcand", "127.0.0.1:", "HOST:PORT"),
        ("virtual-slcan", "no-such-pty", "does not exist"),
    ],
)
def test_attach_to_a_malformed_channel_is_a_usage_error(tmp_path, capsys, bench, channel, expected):
    from hil.cli import main as hil_main

    out = tmp_path / "run"
    code = hil_main(["run", "--bench", bench, "--attach", channel, "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert "--attach" in err and expected in err and repr(channel) in err
    assert not out.exists()


def test_host_port():
    from drivers.options import host_port

    assert host_port("127.0.0.1:29536", "--attach") == ("127.0.0.1", 29536)
    assert host_port(":80", "--attach") == ("127.0.0.1", 80)
    with pytest.raises(ValueError, match="got '0'"):
        host_port("0", "--attach")


# ---- bad profiles: exit 2, the field named, nothing in --out -----------------------------------


def _cicese_with(tmp_path: Path, old: str, new: str) -> Path:
    text = (ROOT / "profiles" / "robots" / "cicese.toml").read_text()
    assert old in text
    path = tmp_path / "robot.toml"
    path.write_text(text.replace(old, new))
    (tmp_path / "cicese.urdf").write_text(
        (ROOT / "profiles" / "robots" / "cicese.urdf").read_text()
    )
    return path


@pytest.mark.parametrize("command", ["simulate", "identify", "diagnose"])
def test_a_robot_value_that_overflows_is_refused_naming_the_field(tmp_path, command):
    """Before: com_m = 1e300 passed validation and ended in OverflowError tracebacks."""
    robot = _cicese_with(tmp_path, "com_m = 0.091", "com_m = 1e300")
    out = tmp_path / "out"
    rec = write_csv(tmp_path / "rec.csv", rows())
    if command == "simulate":
        argv = [sys.executable, "-m", "virtual_robot.cli", "simulate", "--robot", str(robot),
                "--experiment", "reyes-kelly", "--duration", "0.1", "--out", str(out)]  # fmt: skip
        proc = subprocess.run(argv, capture_output=True, text=True, check=False, timeout=120)
    elif command == "identify":
        proc = hil("identify", "--from", str(rec), "--robot", str(robot), "--out", str(out))
    else:
        proc = hil("diagnose", str(rec), "--robot", str(robot), "--out", str(out))
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and proc.stderr.strip().count("\n") == 0, proc.stderr
    assert "'link1.com_m': 1e+300 is out of range" in proc.stderr
    assert not out.exists()


@pytest.mark.parametrize(
    "kind", ["unknown-name", "nan", "cogging-1e300", "drive-watchdog", "robot-inertia"]
)
def test_a_bad_profile_for_the_virtual_robot_exits_2_leaving_out_empty(tmp_path, capsys, kind):
    """Before: exit 3 (link failure: the robot did not start, the cause in its log) with
    virtual-robot.log left in --out, or "no feedback ... stalled or gone" after 2 s."""
    from hil.cli import main as hil_main

    argv = ["run", "--bench", "virtual-slcan", "--duration", "0.2", "--out", str(tmp_path / "o")]
    effects = tmp_path / "effects.toml"
    cogging = "[cogging]\nperiods_per_rev = [120, 96]\nphase_rad = [0.0, 0.0]\n"
    if kind == "unknown-name":
        argv += ["--effects", "no-such-effect"]
        field = "no effects profile of that name"
    elif kind in ("nan", "cogging-1e300"):
        value = "nan" if kind == "nan" else "1e300"
        effects.write_text(f'name = "x"\n{cogging}amplitude_Nm = [{value}, 0.1]\n')
        argv += ["--effects", str(effects)]
        field = "'cogging.amplitude_Nm[0]'"
    elif kind == "drive-watchdog":
        drive = tmp_path / "drive.toml"
        text = (ROOT / "profiles" / "drives" / "dm1015b.toml").read_text()
        drive.write_text(text.replace("watchdog_s = 0.5", "watchdog_s = 1e9"))
        robot = _cicese_with(tmp_path, '"dm1015b"]', f'"{drive}"]')
        argv += ["--robot", str(robot)]
        field = "'watchdog_s'"
    else:
        argv += [
            "--robot",
            str(_cicese_with(tmp_path, "inertia_kgm2 = 0.093", "inertia_kgm2 = -1")),
        ]
        field = "'link2.inertia_kgm2'"
    code = hil_main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and field in err, err
    assert not (tmp_path / "o").exists()


# ---- progress ------------------------------------------------------------------------------------


def test_diagnose_tells_its_progress_on_stderr_only(sim_run):
    """Before: a 200 MB recording's diagnosis was silent for 100 s between stage lines (the
    candidates' cross-validated fits). With --progress-every 0 every tick is a line."""
    proc = hil("diagnose", str(sim_run), "--progress-every", "0", "--json", "--no-plots")
    assert proc.returncode == 0, proc.stderr
    strict_loads(proc.stdout)  # stdout stays one document
    err = proc.stderr.splitlines()
    assert any(ln.startswith("hil diagnose: reading signals.csv: ") for ln in err), err
    ticks = [ln for ln in err if ln.startswith("hil diagnose: testing candidates, round 1: ")]
    last = re.search(r": (\d+) of (\d+) candidates \(", ticks[-1]) if ticks else None
    assert len(ticks) >= 2 and last and int(last[1]) == int(last[2]) - 1, err
    # throttled: none within the interval (the default is 5 s)
    quiet = hil("diagnose", str(sim_run), "--progress-every", "3600", "--json", "--no-plots")
    assert not any(ln.startswith("hil diagnose: ") for ln in quiet.stderr.splitlines())
