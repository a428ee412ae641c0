"""Recording formats beyond one CSV (docs/recordings.md, issue 27): numpy .npz archives, one CSV
per quantity joined on time, MCAP (JSON and ROS 2 CDR), raw effort units with a conversion,
joints left out, ignored columns, the controller's targets; and hil run --mcap written and read
back. Every bad input is one line (exit 2 from the CLI)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from realdata import realdata

from drivers.containers import write_mcap
from drivers.recording import RecordingError, read_signals
from hil.cli import main as hil_main
from profiles import ProfileError
from profiles.recording_format import load_format

N = 400
H = 0.005


def motion(n: int = N, joints: int = 3, t0: float = 100.0) -> tuple[np.ndarray, ...]:
    t = t0 + H * np.arange(n)
    q = np.column_stack([0.5 * np.sin((j + 1) * 1.3 * (t - t0)) for j in range(joints)])
    tau = np.column_stack([2.0 * np.cos((j + 1) * 0.7 * (t - t0)) + j for j in range(joints)])
    return t, q, tau


NPZ_FORMAT = """
name = "lab-npz"
[[layouts]]
time = "stamps"
positions = "q"
ignore = ["notes"]
[layouts.torques.current]
columns = "current"
loop_delay = 0
gear_ratio = [100, 100, 50]
torque_constant = 0.1
[layouts.targets]
positions = "q_ref"
velocities = "qd_ref"
"""


def write_npz(tmp_path: Path, **over) -> tuple[Path, Path]:
    t, q, tau = motion()
    arrays = {
        "stamps": t,
        "q": q,
        "current": tau / np.array([10.0, 10.0, 5.0]),  # raw A: tau = A × 100 × 0.1, × 50 × 0.1
        "q_ref": q + 0.01,
        "qd_ref": np.gradient(q, t, axis=0),
        "notes": np.arange(N, dtype=float),
        "scalar_gain": np.array(3.0),
        "calibration": np.ones((5, 3)),  # another length: not part of the recording
    }
    arrays.update(over)
    path = tmp_path / "run.npz"
    np.savez(path, **arrays)
    fmt = tmp_path / "lab-npz.toml"
    fmt.write_text(NPZ_FORMAT)
    return path, fmt


def run_hil(argv: list[str], capsys) -> tuple[int, str]:
    code = hil_main(argv)
    return code, capsys.readouterr().err


def assert_one_line(code: int, err: str, *words: str) -> None:
    lines = [ln for ln in err.splitlines() if ln.strip() and ": note:" not in ln]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err, err
    for word in words:
        assert word in lines[0], err


def identify(path: Path, tmp_path: Path, *extra: str) -> list[str]:
    return ["identify", "--from", str(path), "--out", str(tmp_path / "id"), "--no-plot", *extra]


# --- npz ----------------------------------------------------------------------------------------


def test_npz_reads_groups_conversion_targets_and_ignored_arrays(tmp_path):
    path, fmt = write_npz(tmp_path)
    rec = read_signals(path, fmt=str(fmt))
    t, q, tau = motion()
    assert rec.n_joints == 3 and len(rec) == N and rec.torque_source == "current"
    np.testing.assert_array_equal(rec.t, t)
    np.testing.assert_array_equal(rec.q, q)
    np.testing.assert_allclose(rec.tau, tau, rtol=1e-12)
    np.testing.assert_array_equal(rec.q_target, q + 0.01)
    assert rec.qd_target is not None and rec.qd_target.shape == (N, 3)
    assert "notes" not in rec.columns and "calibration[0]" not in rec.columns
    assert any("converted" in f and "[10, 10, 5]" in f for f in rec.findings_on_read)
    lean = read_signals(path, fmt=str(fmt), extra_columns=False)
    assert set(lean.columns) == {
        "t",
        *(f"{p}{j}" for p in ("q", "tau", "q_target", "qd_target") for j in (1, 2, 3)),
    }


def test_npz_effort_scale_option_over_the_format_and_leave_out(tmp_path):
    path, fmt = write_npz(tmp_path)
    rec = read_signals(path, fmt=str(fmt), effort_scale=[1.0], leave_out=[2])
    _, q, tau = motion()
    assert rec.n_joints == 2 and rec.file_joints == (1, 3)
    np.testing.assert_array_equal(rec.q, q[:, [0, 2]])
    np.testing.assert_allclose(rec.tau, (tau / [10.0, 10.0, 5.0])[:, [0, 2]])
    np.testing.assert_array_equal(rec.q_target, q[:, [0, 2]] + 0.01)
    assert any("left out joint(s) 2" in f for f in rec.findings_on_read)


def test_npz_without_format_reads_our_column_names(tmp_path):
    t, q, tau = motion(joints=2)
    path = tmp_path / "plain.npz"
    np.savez(path, t=t, q1=q[:, 0], q2=q[:, 1], tau1=tau[:, 0], tau2=tau[:, 1])
    rec = read_signals(path)
    np.testing.assert_array_equal(rec.tau, tau)


@pytest.mark.parametrize(
    "over, expect",
    [
        ({"current": None}, "not a lab-npz file (missing layout: current[...])"),
        ({"q": motion()[1][:-3]}, "array q has 397 rows, the time stamps 400"),
        ({"current": motion()[2][:, :2]}, "torque 'current' has 2 column(s)"),
        ({"stamps": motion()[0][::-1].copy()}, "row 1: t steps back"),
        ({"q_ref": np.where(np.arange(N)[:, None] == 7, np.nan, motion()[1])}, "row 7: q_ref[0]"),
    ],
)
def test_npz_bad_input_is_one_line(tmp_path, capsys, over, expect):
    path, fmt = write_npz(tmp_path, **{k: v for k, v in over.items() if v is not None})
    if any(v is None for v in over.values()):  # an array missing from the archive
        arrays = dict(np.load(path))
        for k in [k for k, v in over.items() if v is None]:
            del arrays[k]
        np.savez(path, **arrays)
    with pytest.raises(RecordingError, match=None) as info:
        read_signals(path, fmt=str(fmt))
    assert expect in str(info.value) and "\n" not in str(info.value), str(info.value)
    code, err = run_hil(identify(path, tmp_path, "--format", str(fmt)), capsys)
    assert_one_line(code, err, expect)


def test_wrong_conversion_vector_length_is_one_line(tmp_path, capsys):
    path, fmt = write_npz(tmp_path)
    with pytest.raises(RecordingError, match=r"1 or 3 nonzero factors.*got 2"):
        read_signals(path, fmt=str(fmt), effort_scale=[1.0, 2.0])
    code, err = run_hil(
        identify(path, tmp_path, "--format", str(fmt), "--effort-scale", "1,2"), capsys
    )
    assert_one_line(code, err, "got 2")
    for bad in ("x", "0", "1,nan"):
        code, err = run_hil(
            identify(path, tmp_path, "--format", str(fmt), "--effort-scale", bad), capsys
        )
        assert_one_line(code, err, "--effort-scale")
    code, err = run_hil(
        identify(path, tmp_path, "--format", str(fmt), "--leave-out-joints", "4"), capsys
    )
    assert_one_line(code, err, "cannot leave out joint 4")
    bad_fmt = tmp_path / "bad.toml"
    bad_fmt.write_text(NPZ_FORMAT.replace("gear_ratio = [100, 100, 50]", "gear_ratio = [1, 2]"))
    with pytest.raises(RecordingError, match="conversion has 2 factors for 3 joints"):
        read_signals(path, fmt=str(bad_fmt))


def test_format_profile_fields_are_checked(tmp_path):
    cases = {
        "torque_constant = 0.1": "",  # gear_ratio without torque_constant
        'positions = "q"': 'positions = ["q[0]", "q[1]"]\nleave_out = [3]',
        "loop_delay = 0": "loop_delay = 0\nscale = 2.0",  # scale and gear_ratio both
        'velocities = "qd_ref"': 'velocities = "qd_ref"\nspeeds = "x"',
    }
    for old, new in cases.items():
        bad = tmp_path / "bad.toml"
        bad.write_text(NPZ_FORMAT.replace(old, new))
        with pytest.raises(ProfileError) as info:
            load_format(bad)
        assert "\n" not in str(info.value)


def test_mostly_zero_effort_is_named(tmp_path):
    _, _, tau = motion()
    tau[:, 1] = np.where(np.arange(N) % 10 == 0, 0.3, 0.0)
    path, fmt = write_npz(tmp_path, current=tau)
    rec = read_signals(path, fmt=str(fmt))
    notes = [f for f in rec.findings_on_read if "exactly 0" in f]
    assert len(notes) == 1 and notes[0].startswith("joint 2 (current[1])") and "90%" in notes[0]
    assert "--leave-out-joints 2" in notes[0]
    assert not any("exactly 0" in f for f in read_signals(path, fmt=str(fmt), leave_out=[2])
                   .findings_on_read)  # fmt: skip


# --- one CSV per quantity, joined on time --------------------------------------------------------

SPLIT_FORMAT = """
name = "split"
[[layouts]]
time = "pos.time"
positions = ["pos.q1", "pos.q2"]
[layouts.torques.measured]
columns = ["eff.tau_a", "eff.tau_b"]
loop_delay = 0
[layouts.streams.pos]
file = "positions.csv"
time = "time"
[layouts.streams.eff]
file = "efforts.csv"
time = "stamp"
[layouts.join]
on = "pos"
rule = "RULE"
tolerance_s = 0.001
"""


def write_split(tmp_path: Path, rule: str = "nearest", shift: float = 0.0004) -> Path:
    d = tmp_path / "split"
    d.mkdir(exist_ok=True)
    t, q, tau = motion(joints=2)
    np.savetxt(d / "positions.csv", np.column_stack([t, q]), delimiter=",", comments="",
               header="time,q1,q2", fmt="%.17g")  # fmt: skip
    te = t + shift  # another logger: its own clock, a little later
    np.savetxt(d / "efforts.csv", np.column_stack([te, tau, te * 0]), delimiter=",",
               comments="", header="stamp,tau_a,tau_b,status", fmt="%.17g")  # fmt: skip
    # linear: the samples around each row at most 6 ms apart (the 5 ms of the efforts' logger)
    tolerance = "0.006" if rule == "linear" else "0.001"
    (tmp_path / "split.toml").write_text(
        SPLIT_FORMAT.replace("RULE", rule).replace("0.001", tolerance)
    )
    return d


@pytest.mark.parametrize("rule", ["nearest", "linear"])
def test_split_csvs_joined_on_time(tmp_path, rule):
    d = write_split(tmp_path, rule)
    rec = read_signals(d, fmt=str(tmp_path / "split.toml"))
    t, q, tau = motion(joints=2)
    np.testing.assert_array_equal(rec.t, t)
    np.testing.assert_array_equal(rec.q, q)
    if rule == "nearest":
        np.testing.assert_array_equal(rec.tau, tau)
    else:  # interpolated 0.4 ms back: between the samples, never past the end
        tau_at = np.column_stack([np.interp(t, t + 0.0004, tau[:, j]) for j in range(2)])
        np.testing.assert_allclose(rec.tau, tau_at, rtol=0, atol=1e-12)
    assert "eff.status" in rec.columns


def test_split_csvs_refused_when_times_do_not_match(tmp_path, capsys):
    d = write_split(tmp_path, shift=0.003)
    fmt = str(tmp_path / "split.toml")
    with pytest.raises(RecordingError, match=r"efforts.csv: no sample within 1 ms of pos.time"):
        read_signals(d, fmt=fmt)
    code, err = run_hil(identify(d, tmp_path, "--format", fmt), capsys)
    assert_one_line(code, err, "times do not match")
    lines = (d / "efforts.csv").read_text().splitlines()
    lines[1] = "nan," + lines[1].split(",", 1)[1]
    (d / "efforts.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordingError, match=r"efforts.csv:2: eff.stamp = nan is not a finite"):
        read_signals(d, fmt=fmt)
    (d / "efforts.csv").write_text("when,tau_a,tau_b\n100.0,1.0,2.0\n")
    with pytest.raises(RecordingError, match=r"efforts.csv: no time column stamp \(when, tau_a"):
        read_signals(d, fmt=fmt)
    (d / "efforts.csv").write_text("stamp,tau_a\n100.0,1.0\n")  # a column missing
    code, err = run_hil(identify(d, tmp_path, "--format", fmt), capsys)
    assert_one_line(code, err, "not a split file (missing layout: eff.tau_b)")
    (d / "efforts.csv").unlink()
    code, err = run_hil(identify(d, tmp_path, "--format", fmt), capsys)
    assert_one_line(code, err, "missing", "efforts.csv")


def test_ignored_text_column_of_a_csv(tmp_path):
    t, q, tau = motion(joints=2)
    lines = ["when,t,q1,q2,tau1,tau2"] + [
        "2026-12-04T15:00:00," + ",".join(repr(float(x)) for x in (t[k], *q[k], *tau[k]))
        for k in range(50)
    ]
    path = tmp_path / "with_text.csv"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordingError, match="not a number"):
        read_signals(path)
    rec = read_signals(path, ignore=["when"])
    np.testing.assert_array_equal(rec.tau, tau[:50])
    assert "when" not in rec.columns
    with pytest.raises(RecordingError, match="q1 is both read and ignored"):
        read_signals(path, ignore=["when", "q1"])
    path.write_text("\n".join(lines[:10]) + "\n2026,1.0,2\n")
    with pytest.raises(RecordingError, match=r"with_text.csv:11: 3 fields, header has 6"):
        read_signals(path, ignore=["when"])


# --- MCAP ---------------------------------------------------------------------------------------


def write_foreign_mcap(path: Path, msgs: list[dict], topic: str = "/joint_states") -> None:
    from mcap.writer import Writer

    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        schema = w.register_schema("sensor_msgs/JointState", "jsonschema", b"{}")
        channel = w.register_channel(topic, "json", schema)
        for k, m in enumerate(msgs):
            w.add_message(channel, log_time=k, publish_time=k, data=json.dumps(m).encode())
        w.finish()


def joint_state(k: int, names=("a", "b")) -> dict:
    t = 5.0 + 0.002 * k
    return {
        "header": {"stamp": {"sec": int(t), "nanosec": round((t - int(t)) * 1e9)}},
        "name": list(names),
        "position": [math.sin(t), 0.1 * t],
        "velocity": [],
        "effort": [0.3 * k, -1.0],
    }


def test_foreign_json_mcap_reads_with_the_shipped_format(tmp_path):
    path = tmp_path / "bag.mcap"
    write_foreign_mcap(path, [joint_state(k) for k in range(100)])
    rec = read_signals(path)
    assert rec.n_joints == 2 and len(rec) == 100 and rec.torque_source == "effort"
    np.testing.assert_allclose(rec.t, 5.0 + 0.002 * np.arange(100), atol=1e-9)
    np.testing.assert_array_equal(rec.tau[:, 0], 0.3 * np.arange(100))
    assert not rec.torque_held
    msgs = [joint_state(k) for k in range(100)]
    write_foreign_mcap(path, [*msgs[:11], msgs[10], *msgs[11:]])  # a message logged twice
    twice = read_signals(path)
    np.testing.assert_array_equal(twice.tau, rec.tau)
    assert "dropped 1 exact duplicate row(s) (first at /joint_states message 12)" in (
        twice.findings_on_read
    )


@pytest.mark.parametrize(
    "change, expect",
    [
        ("topic", "(missing /joint_states: /joint_states); topics in the file: /other"),
        ("names", "message 51: name changes from ('a', 'b') to ('b', 'a')"),
        ("length", "message 51 has other fields than message 1"),
        ("nan", "/joint_states message 51: state.effort[0] = nan"),
        ("no-effort", "not a ros2-joint-state file (missing /joint_states: state.effort[...])"),
    ],
)
def test_bad_mcap_is_one_line(tmp_path, capsys, change, expect):
    msgs = [joint_state(k) for k in range(100)]
    topic = "/other" if change == "topic" else "/joint_states"
    if change == "names":
        msgs[50]["name"] = ["b", "a"]
    elif change == "length":
        msgs[50]["position"].append(0.0)
    elif change == "nan":
        msgs[50]["effort"][0] = float("nan")
    elif change == "no-effort":
        for m in msgs:
            del m["effort"]
    path = tmp_path / "bag.mcap"
    write_foreign_mcap(path, msgs, topic)
    with pytest.raises(RecordingError) as info:
        read_signals(path)
    assert expect in str(info.value) and "\n" not in str(info.value), str(info.value)
    code, err = run_hil(identify(path, tmp_path), capsys)
    assert_one_line(code, err, expect)


def test_ros2_cdr_mcap(tmp_path):
    pytest.importorskip("mcap_ros2", reason="mcap-ros2-support not installed")
    from mcap_ros2.writer import Writer

    msgdef = "\n".join(
        [
            "std_msgs/Header header", "string[] name", "float64[] position",
            "float64[] velocity", "float64[] effort", "=" * 80, "MSG: std_msgs/Header",
            "builtin_interfaces/Time stamp", "string frame_id", "=" * 80,
            "MSG: builtin_interfaces/Time", "int32 sec", "uint32 nanosec",
        ]
    )  # fmt: skip
    path = tmp_path / "ros2.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        schema = w.register_msgdef("sensor_msgs/msg/JointState", msgdef)
        for k in range(60):
            m = joint_state(k)
            m["header"]["frame_id"] = ""
            w.write_message("/joint_states", schema, m, log_time=k, publish_time=k, sequence=k)
        w.finish()
    rec = read_signals(path)
    assert len(rec) == 60 and rec.n_joints == 2
    np.testing.assert_array_equal(rec.tau[:, 0], 0.3 * np.arange(60))


def test_write_mcap_round_trip_in_memory(tmp_path):
    t, q, tau = motion(joints=2, t0=0.0)
    path = tmp_path / "x.mcap"
    write_mcap(path, t, q, tau, {"period_s": H}, torque_source="commanded")
    rec = read_signals(path)
    np.testing.assert_allclose(rec.t, t, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(rec.q, q)
    np.testing.assert_array_equal(rec.tau, tau)
    assert rec.torque_held and rec.meta["period_s"] == H


def test_hil_run_mcap_round_trip(tmp_path, capsys):
    """hil run --mcap on the in-process virtual bench: run.mcap read back equals signals.csv,
    and hil identify gives the same θ from either."""
    out = tmp_path / "run"
    code = hil_main(["run", "--bench", "virtual-inprocess", "--duration", "1.5", "--out",
                     str(out), "--mcap", "--no-plot", "--json"])  # fmt: skip
    summary = json.loads(capsys.readouterr().out)
    assert code == 0 and summary["mcap"] == str(out / "run.mcap")
    csv, mcap = read_signals(out), read_signals(out / "run.mcap")
    np.testing.assert_allclose(mcap.t, csv.t, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(mcap.q, csv.q)
    np.testing.assert_array_equal(mcap.tau, csv.tau)
    assert mcap.torque_held and mcap.period_s == csv.period_s
    thetas = []
    for i, src in enumerate((out, out / "run.mcap")):
        code = hil_main(["identify", "--from", str(src), "--out", str(tmp_path / f"id{i}"),
                         "--no-plot", "--json", "-q"])  # fmt: skip
        doc = json.loads(capsys.readouterr().out)
        assert code == 0
        thetas.append(doc["discretizations"]["exact"]["schemes"]["filtered_dynamic"]["theta"])
    assert thetas[0] == thetas[1]


# --- the KUKA LWR4+ (LGPL-3, read from ../shared) ----------------------------------------------

KUKA = realdata("kuka-lwr4-flobaroid")


@pytest.mark.skipif(not KUKA.is_dir(), reason=f"KUKA LWR4+ data not found ({KUKA})")
@pytest.mark.parametrize("run", ["measurements_1.npz", "measurements_3.npz"])
def test_kuka_lwr4_npz_reads(run):
    rec = read_signals(KUKA / run, fmt="kuka-lwr4", extra_columns=False)
    raw = np.load(KUKA / run)
    assert rec.n_joints == 7 and len(rec) == len(raw["times"]) and rec.torque_source == "measured"
    np.testing.assert_array_equal(rec.tau, raw["torques"])
    np.testing.assert_array_equal(rec.q_target, raw["target_positions"])
    np.testing.assert_array_equal(rec.qd_target, raw["target_velocities"])
    assert 0.004 < rec.period_s < 0.006  # ~200 Hz


@pytest.mark.skipif(not KUKA.is_dir(), reason=f"KUKA LWR4+ data not found ({KUKA})")
def test_kuka_lwr4_reaches_identify(tmp_path, capsys):
    """The reader plumbing only (the kuka-lwr4 robot profile is another branch's): a 7-joint
    profile reads it; what the identification then says is not checked here."""
    hil_main(identify(KUKA / "measurements_1.npz", tmp_path, "--format", "kuka-lwr4",
                      "--robot", "panda", "--json"))  # fmt: skip
    err = capsys.readouterr().err
    assert "Traceback" not in err and "cannot read" not in err and "not a kuka" not in err, err


TWO_TOPICS = """
name = "ros2-with-reference"
[[layouts]]
time = "state.header.stamp"
positions = "state.position"
[layouts.torques.effort]
columns = "state.effort"
loop_delay = 0
[layouts.targets]
positions = "ref.q"
[layouts.streams.state]
topic = "/joint_states"
time = "header.stamp"
[layouts.streams.ref]
topic = "/controller/reference"
time = "stamp"
[layouts.join]
on = "state"
rule = "linear"
tolerance_s = 0.004
"""


def test_mcap_two_topics_joined_with_the_reference_as_targets(tmp_path):
    """The controller's reference on its own topic at half the rate, interpolated onto the
    joint states' stamps and kept as q_target."""
    from mcap.writer import Writer

    path = tmp_path / "two.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        schema = w.register_schema("any", "jsonschema", b"{}")
        js = w.register_channel("/joint_states", "json", schema)
        ref = w.register_channel("/controller/reference", "json", schema)
        for k in range(100):
            w.add_message(js, log_time=k, publish_time=k, data=json.dumps(joint_state(k)).encode())
            if k % 2 == 0:
                t = 5.0 + 0.002 * k
                msg = {"stamp": {"sec": 5, "nanosec": round((t - 5) * 1e9)}, "q": [t, -t]}
                w.add_message(ref, log_time=k, publish_time=k, data=json.dumps(msg).encode())
        w.finish()
    fmt = tmp_path / "two.toml"
    fmt.write_text(TWO_TOPICS)
    rec = read_signals(path, fmt=str(fmt))
    t = 5.0 + 0.002 * np.arange(100)
    assert len(rec) == 100 and rec.q_target is not None
    inside = rec.t <= t[98]  # past the reference's last sample: held (within the tolerance)
    np.testing.assert_allclose(rec.q_target[inside, 0], rec.t[inside], atol=1e-9)
    np.testing.assert_allclose(rec.q_target[:, 1], -rec.q_target[:, 0], atol=1e-12)
    fmt.write_text(TWO_TOPICS.replace("0.004", "0.0039"))  # the reference's 4 ms interval
    with pytest.raises(
        RecordingError,
        match=r"topic /controller/reference: the samples around state.header.stamp = 5.002 s "
        r"\(.*/joint_states message 2\) are 4 ms apart, over the 3.9 ms the join",
    ):
        read_signals(path, fmt=str(fmt))
    fmt.write_text(TWO_TOPICS.replace('"linear"', '"nearest"'))  # 2 ms from the nearest: read
    np.testing.assert_array_equal(read_signals(path, fmt=str(fmt)).q_target[:2, 0], [5.0, 5.0])
    fmt.write_text(TWO_TOPICS.replace('"linear"', '"nearest"').replace("0.004", "0.0015"))
    with pytest.raises(RecordingError, match=r"no sample within 1.5 ms of state.header.stamp"):
        read_signals(path, fmt=str(fmt))


def test_mcap_cut_short_reads_its_whole_chunks_and_says_so(tmp_path, capsys):
    from mcap.writer import Writer

    path = tmp_path / "whole.mcap"
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=4000)  # several chunks, as a long bag has
        w.start()
        schema = w.register_schema("any", "jsonschema", b"{}")
        channel = w.register_channel("/joint_states", "json", schema)
        for k in range(300):
            w.add_message(
                channel, log_time=k, publish_time=k, data=json.dumps(joint_state(k)).encode()
            )
        w.finish()
    whole = read_signals(path)
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    rec = read_signals(torn)
    assert 0 < len(rec) < len(whole) and "ends without its summary" in rec.findings_on_read[0]
    np.testing.assert_array_equal(rec.q, whole.q[: len(rec)])
    (tmp_path / "text.mcap").write_text("t,q1,q2,tau1,tau2\n")
    code, err = run_hil(identify(tmp_path / "text.mcap", tmp_path), capsys)
    assert_one_line(code, err, "not an MCAP file")
    torn.write_bytes(path.read_bytes()[:200])  # not one whole chunk
    code, err = run_hil(identify(torn, tmp_path), capsys)
    assert_one_line(code, err, "not a readable MCAP file")


def test_recording_options_reach_the_reader(tmp_path, capsys):
    import argparse

    from hil.cli_options import add_recording_options, read_recording

    parser = argparse.ArgumentParser()
    add_recording_options(parser)
    path, fmt = write_npz(tmp_path)
    args = parser.parse_args(
        ["--format", str(fmt), "--effort-scale", "1", "--leave-out-joints", "3"]
    )
    rec = read_recording(args, path, command="identify")
    tau = motion()[2]
    assert rec.n_joints == 2 and rec.q_target is not None
    np.testing.assert_allclose(rec.tau, tau[:, :2] / 10.0)
    assert "left out joint(s) 3" in capsys.readouterr().err
    args = parser.parse_args(["--format", str(fmt), "--ignore-columns", "qd_ref"])
    with pytest.raises(RecordingError, match=r"qd_ref\[0\] is both read and ignored"):
        read_recording(args, path, command="identify")


def test_torque_path_of_an_npz_with_two_torque_sources(tmp_path):
    """The diagnosis's commanded → measured torque path reads the sources a format offers from
    the container's own column names (an .npz is no text: its header was read as a CSV line)."""
    from drivers.recording import recording_names
    from hil.diagnose.torque_path import torque_path_of, torque_sources

    t, q, tau = motion()
    path = tmp_path / "two.npz"
    np.savez(path, stamps=t, q=q, cmd=tau, meas=0.9 * tau + 0.1)
    fmt = tmp_path / "two.toml"
    fmt.write_text(
        'name = "two"\n[[layouts]]\ntime = "stamps"\npositions = "q"\n'
        'default_torque = "commanded"\n'
        '[layouts.torques.commanded]\ncolumns = "cmd"\nloop_delay = 0\n'
        '[layouts.torques.measured]\ncolumns = "meas"\nloop_delay = 0\n'
    )
    assert recording_names(path, str(fmt))[:2] == ["stamps", "q[0]"]
    assert set(torque_sources(path, str(fmt))) == {"commanded", "measured"}
    doc = torque_path_of(read_signals(path, fmt=str(fmt)), str(fmt))
    assert doc is not None and doc["judged"] == "commanded"
    gains = [j["gain"] for j in doc["joints"]]
    np.testing.assert_allclose(gains, 0.9, rtol=1e-6)
    csv = tmp_path / "plain.csv"
    csv.write_text("t,q1,tau1\n0,0,0\n")
    assert recording_names(csv) == ["t", "q1", "tau1"]
