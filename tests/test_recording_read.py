"""Reading recordings, real and our own (drivers/recording/ read_signals; docs/recordings.md):
format profiles, column maps, torque sources, loop delay, real time stamps, the checks on read
(t, meta.json, duplicates, gaps, NaN), the shared CLI options and ``--out`` reuse."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from realdata import realdata

from drivers.outdir import held_out_dirs, release_out_dirs
from drivers.recording import (
    BASE_COLUMNS,
    META,
    SIGNALS,
    RecordingError,
    RecordingWriter,
    parse_column_map,
    read_signals,
)
from hil.cli_options import prepare_out_dir
from profiles import ProfileError
from profiles.recording_format import load_format

DATA = Path(__file__).parent / "data" / "dfki"
DFKI_FILE = DATA / "design_A.0__20220815__sys_id__trajectory_00.csv"
SHARED = realdata("dfki-double-pendulum") / "records"
H = 0.0025


def write_run(out: Path, rows: list[list[float]], **meta) -> Path:
    with RecordingWriter(out, {"period_s": H, **meta}) as w:
        for row in rows:
            w.write(row)
    return out


def lockstep_rows(n: int = 200) -> list[list[float]]:
    return [
        [k * H, math.sin(k / 9), math.cos(k / 13), 0.3 * math.sin(k / 5), -0.1] for k in range(n)
    ]


def set_meta(run: Path, **fields) -> None:
    meta = json.loads((run / META).read_text())
    meta.update(fields)
    (run / META).write_text(json.dumps(meta))


def one_line_error(exc: pytest.ExceptionInfo) -> str:
    msg = str(exc.value)
    assert "\n" not in msg and msg
    return msg


def raw_table(path: Path) -> tuple[list[str], np.ndarray]:
    lines = path.read_text().splitlines()
    return lines[0].split(","), np.array([[float(x) for x in ln.split(",")] for ln in lines[1:]])


# --- the committed DFKI file ---------------------------------------------------------------------


def test_dfki_file_reads_with_the_format_profile():
    header, raw = raw_table(DFKI_FILE)
    col = {name: raw[:, j] for j, name in enumerate(header)}
    rec = read_signals(DFKI_FILE, fmt="dfki")
    assert rec.n_joints == 2 and rec.torque_source == "commanded" and rec.loop_delay == 1
    assert rec.time_source == "stamps" and rec.time_column == "time"
    assert list(rec.columns)[:5] == list(BASE_COLUMNS)
    # loop delay 1: tau_con of file row i acts between rows i+1 and i+2, so row k (file row k)
    # holds tau_con of file row k-1 and the first row, with no torque known, is dropped
    assert len(rec) == len(raw) - 1
    np.testing.assert_array_equal(rec.t, col["time"][1:])
    np.testing.assert_array_equal(rec.q, np.column_stack([col["pos_meas1"], col["pos_meas2"]])[1:])
    np.testing.assert_array_equal(rec.tau[:, 0], col["tau_con1"][:-1])
    np.testing.assert_array_equal(rec.tau[:, 1], col["tau_con2"][:-1])
    # the real, non-uniform time stamps are kept, never replaced by k·h
    assert rec.dt.max() > 1.5 * np.median(rec.dt)
    assert not np.allclose(rec.t, rec.t[0] + np.arange(len(rec)) * rec.period_s)
    assert rec.period_s == pytest.approx(float(np.median(np.diff(col["time"][1:]))))
    assert any("irregular sampling" in f for f in rec.findings_on_read)
    assert any("loop delay 1" in f for f in rec.findings_on_read)
    assert rec.segments() == [slice(0, len(rec))]


def test_dfki_measured_torque_and_its_loop_delay():
    header, raw = raw_table(DFKI_FILE)
    col = {name: raw[:, j] for j, name in enumerate(header)}
    rec = read_signals(DFKI_FILE, fmt="dfki", torque="measured")
    assert rec.torque_source == "measured" and rec.loop_delay == -1
    # tau_meas of file row i is the torque that acted up to row i: held over [t_{i-1}, t_i)
    assert len(rec) == len(raw) - 1
    np.testing.assert_array_equal(rec.t, col["time"][:-1])
    np.testing.assert_array_equal(rec.tau[:, 0], col["tau_meas1"][1:])
    np.testing.assert_array_equal(rec.q[:, 1], col["pos_meas2"][:-1])


def test_column_map_and_loop_delay_option_equal_the_profile():
    by_profile = read_signals(DFKI_FILE, fmt="dfki")
    by_map = read_signals(
        DFKI_FILE,
        columns="t=time,q1=pos_meas1,q2=pos_meas2,tau1=tau_con1,tau2=tau_con2",
        loop_delay=1,
    )
    assert by_map.torque_source == "columns"
    for name in BASE_COLUMNS:
        np.testing.assert_array_equal(by_map.columns[name], by_profile.columns[name])
    # without the delay the map reads the file's rows as they are
    as_is = read_signals(DFKI_FILE, columns={"t": "time", "q1": "pos_meas1", "q2": "pos_meas2",
                                             "tau1": "tau_con1", "tau2": "tau_con2"})  # fmt: skip
    assert len(as_is) == len(by_profile) + 1 and as_is.loop_delay == 0
    # --loop-delay overrides the format's
    zero = read_signals(DFKI_FILE, fmt="dfki", loop_delay=0)
    np.testing.assert_array_equal(zero.tau, as_is.tau)


def test_dfki_profile_second_layout_and_its_single_torque(tmp_path):
    csv_path = tmp_path / "x_measured.csv"
    rows = [
        f"{k * 0.002!r},{0.001 * k!r},{-0.002 * k!r},0,0,{0.1 * k!r},{-0.1 * k!r}" for k in range(6)
    ]
    csv_path.write_text("time,pos1,pos2,vel1,vel2,tau1,tau2\n" + "\n".join(rows) + "\n")
    rec = read_signals(csv_path, fmt="dfki")
    assert rec.loop_delay == 1 and len(rec) == 5
    np.testing.assert_allclose(rec.tau[:, 0], [0.1 * k for k in range(5)])
    np.testing.assert_allclose(rec.q[:, 0], [0.001 * k for k in range(1, 6)])
    with pytest.raises(RecordingError) as exc:
        read_signals(csv_path, fmt="dfki", torque="measured")
    assert "offers commanded" in one_line_error(exc)


def test_format_and_map_errors_are_one_line(tmp_path):
    with pytest.raises(RecordingError) as exc:
        read_signals(DFKI_FILE, fmt="dfki", torque="bogus")
    assert "offers commanded, measured" in one_line_error(exc)
    run = write_run(tmp_path / "run", lockstep_rows(10))
    with pytest.raises(RecordingError) as exc:
        read_signals(run, fmt="dfki")
    assert "not a dfki file" in one_line_error(exc)
    with pytest.raises(ProfileError):
        read_signals(run, fmt="no-such-format")
    for bad in ("t=", "x=t", "t=time,t=t", "q1", "q3=q1"):
        with pytest.raises(RecordingError) as exc:
            read_signals(run, columns=bad)
        one_line_error(exc)
    with pytest.raises(RecordingError) as exc:
        read_signals(run, columns="q1=nope")
    assert "nope" in one_line_error(exc)
    for delay in (101, -101, 1.5, True):
        with pytest.raises(RecordingError) as exc:
            read_signals(run, loop_delay=delay)
        one_line_error(exc)
    with pytest.raises(RecordingError) as exc:
        read_signals(run, torque="measured")
    one_line_error(exc)


def test_parse_column_map():
    assert parse_column_map(" t = time , q1=a,tau1=b,") == {"t": "time", "q1": "a", "tau1": "b"}
    with pytest.raises(ValueError):
        parse_column_map("")


def test_profile_validation(tmp_path):
    bad = tmp_path / "f.toml"
    bad.write_text(
        'name = "f"\n[[layouts]]\ntime = "t"\npositions = ["a", "b"]\n'
        '[layouts.torques.c]\ncolumns = ["x"]\nloop_delay = 0\n'
    )
    with pytest.raises(ProfileError, match="must name 2 columns"):
        load_format(bad)
    bad.write_text(
        'name = "f"\n[[layouts]]\ntime = "t"\npositions = ["a"]\n'
        '[layouts.torques.c]\ncolumns = ["x"]\nloop_delay = 1000\n'
    )
    with pytest.raises(ProfileError, match="loop_delay"):
        load_format(bad)


@pytest.mark.skipif(not SHARED.is_dir(), reason=f"{SHARED} not present (the shared real data)")
def test_every_shared_dfki_file_reads():
    files = sorted(SHARED.glob("*.csv"))
    assert files
    for path in files:
        rec = read_signals(path, fmt="dfki")
        assert rec.n_joints == 2 and len(rec) > 1000, path
        assert np.all(rec.dt > 0) and np.all(np.isfinite(rec.tau)), path


# --- this bench's recordings ---------------------------------------------------------------------


def test_lockstep_recording_reads_as_before(tmp_path):
    rows = lockstep_rows()
    rec = read_signals(write_run(tmp_path / "run", rows))
    table = np.array(rows)
    np.testing.assert_array_equal(rec.t, table[:, 0])
    np.testing.assert_array_equal(rec.q, table[:, 1:3])
    np.testing.assert_array_equal(rec.tau, table[:, 3:5])
    assert rec.findings_on_read == [] and rec.loop_delay == 0 and rec.period_s == H
    assert rec.segments() == [slice(0, len(rows))]


def test_q_and_tau_are_stacked_once_and_shared_read_only(tmp_path):
    """rec.q and rec.tau are one array each, not a new copy per access (a long recording's q is
    ten megabytes, read in per-chunk code); read-only, since every caller shares it; stacked
    anew when a column is replaced, and a segment stacks its own rows."""
    rec = read_signals(write_run(tmp_path / "run", lockstep_rows()))
    q, tau = rec.q, rec.tau
    assert rec.q is q and rec.tau is tau
    assert not q.flags.writeable and not tau.flags.writeable
    with pytest.raises(ValueError):
        q[0, 0] = 1.0
    seg = rec.segment(slice(10, 50))
    np.testing.assert_array_equal(seg.q, q[10:50])
    assert seg.q is not q and seg.q is seg.q
    rec.columns["q2"] = rec.columns["q2"] + 1.0
    np.testing.assert_array_equal(rec.q[:, 1], q[:, 1] + 1.0)
    np.testing.assert_array_equal(rec.q[:, 0], q[:, 0])


def test_n_joints(tmp_path):
    csv_path = tmp_path / "three.csv"
    csv_path.write_text(
        "t,q1,q2,q3,tau1,tau2,tau3\n"
        + "\n".join(f"{k * 0.01!r},1,2,3,4,5,6" for k in range(5))
        + "\n"
    )
    rec = read_signals(csv_path)
    assert rec.n_joints == 3 and rec.q.shape == (5, 3) and rec.tau[0].tolist() == [4, 5, 6]
    one = tmp_path / "one.csv"
    one.write_text("time,angle,torque\n0,0.1,1\n0.01,0.2,2\n")
    rec = read_signals(one, columns="t=time,q1=angle,tau1=torque")
    assert rec.n_joints == 1 and rec.q.shape == (2, 1)


@pytest.mark.parametrize(
    ("change", "expect"),
    [
        (lambda t: t * 1000, "t in ms"),
        (lambda t: t + 1.0, "t starts at 1.0"),
        (lambda t: t * 1.01, "not a multiple"),
    ],
    ids=["ms", "shift", "stretched"],
)
def test_t_inconsistent_with_meta_period(tmp_path, change, expect):
    rows = lockstep_rows()
    rows = [[change(r[0]), *r[1:]] for r in rows]
    with pytest.raises(RecordingError) as exc:
        read_signals(write_run(tmp_path / "run", rows))
    assert expect in one_line_error(exc)


def test_t_step_back_names_the_line(tmp_path):
    rows = lockstep_rows()
    rows[10][0], rows[11][0] = rows[11][0], rows[10][0]
    run = write_run(tmp_path / "run", rows)
    with pytest.raises(RecordingError) as exc:
        read_signals(run)
    assert f"{run / SIGNALS}:13: t steps back" in one_line_error(exc)


@pytest.mark.parametrize(
    "period", [0, 1.0, [1], 1e9, float("nan"), "0.0025", True, None, -H], ids=repr
)
def test_bad_meta_period(tmp_path, period):
    run = write_run(tmp_path / "run", lockstep_rows(10))
    set_meta(run, period_s=period)
    with pytest.raises(RecordingError) as exc:
        read_signals(run)
    assert "period_s" in one_line_error(exc) and str(run / META) in str(exc.value)


@pytest.mark.parametrize(
    ("field", "value"),
    [("rows", "12"), ("rows", -1), ("rows", 1.5), ("status", 3), ("robot", [1]), ("seed", "x")],
)
def test_bad_meta_field_types(tmp_path, field, value):
    run = write_run(tmp_path / "run", lockstep_rows(10))
    set_meta(run, **{field: value})
    with pytest.raises(RecordingError) as exc:
        read_signals(run)
    assert field in one_line_error(exc)


def test_every_row_duplicated_reads_as_the_original(tmp_path):
    rows = lockstep_rows()
    original = read_signals(write_run(tmp_path / "a", rows))
    doubled = read_signals(write_run(tmp_path / "b", [r for r in rows for _ in range(2)]))
    for name in BASE_COLUMNS:
        np.testing.assert_array_equal(doubled.columns[name], original.columns[name])
    assert any("duplicate" in f for f in doubled.findings_on_read)


def test_same_t_with_other_values_is_an_error(tmp_path):
    rows = lockstep_rows()
    rows.insert(5, [rows[4][0], 9.0, 9.0, 9.0, 9.0])
    with pytest.raises(RecordingError) as exc:
        read_signals(write_run(tmp_path / "run", rows))
    assert ":7:" in one_line_error(exc)


def test_rows_cut_out_are_a_gap_with_segments(tmp_path):
    rows = lockstep_rows(1000)
    rec = read_signals(write_run(tmp_path / "run", rows[:300] + rows[700:]))
    assert rec.segments() == [slice(0, 300), slice(300, 600)]
    assert any("1 gap(s)" in f and "~400 rows" in f for f in rec.findings_on_read)
    part = rec.segment(rec.segments()[1])
    assert len(part) == 300 and part.t[0] == rows[700][0] and part.segments() == [slice(0, 300)]
    # without meta.json: the real stamps show the same gap
    bare = read_signals(rec.path / SIGNALS)
    assert bare.segments() == rec.segments()


def test_loop_delay_never_carries_a_torque_across_a_gap(tmp_path):
    rows = lockstep_rows(100)
    rec = read_signals(write_run(tmp_path / "run", rows[:40] + rows[60:]), loop_delay=2)
    assert rec.segments() == [slice(0, 38), slice(38, 76)]
    np.testing.assert_array_equal(rec.t[38], rows[62][0])
    assert rec.tau[38, 0] == rows[60][3]


@pytest.mark.parametrize("bad", ["nan", "inf", "-inf", "1e999"])
def test_non_finite_value_names_the_line(tmp_path, bad):
    run = write_run(tmp_path / "run", lockstep_rows(20))
    lines = (run / SIGNALS).read_text().splitlines()
    cells = lines[8].split(",")
    cells[3] = bad
    lines[8] = ",".join(cells)
    (run / SIGNALS).write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordingError) as exc:
        read_signals(run)
    assert f"{run / SIGNALS}:9: tau1" in one_line_error(exc)


def test_non_finite_extra_column_is_kept(tmp_path):
    with RecordingWriter(tmp_path / "run", {"period_s": H}, extra_columns=("feedback_s",)) as w:
        for k in range(5):
            w.write([k * H, 0.0, 0.0, 0.0, 0.0, math.nan if k == 2 else 1.0])
    rec = read_signals(tmp_path / "run")
    assert math.isnan(rec.columns["feedback_s"][2])
    assert list(read_signals(tmp_path / "run", extra_columns=False).columns) == list(BASE_COLUMNS)


def test_header_only_and_one_row_with_min_rows(tmp_path):
    empty = write_run(tmp_path / "empty", [])
    assert len(read_signals(empty)) == 0
    with pytest.raises(RecordingError) as exc:
        read_signals(empty, min_rows=2)
    assert "header only" in one_line_error(exc)
    with pytest.raises(RecordingError):
        read_signals(write_run(tmp_path / "one", lockstep_rows(1)), min_rows=2)


def test_chunked_parse_equals_one_pass(tmp_path, monkeypatch):
    import drivers.recording.reader as recording

    rows = lockstep_rows(1000)
    run = write_run(tmp_path / "run", rows)
    whole = read_signals(run)
    monkeypatch.setattr(recording, "CHUNK_CHARS", 100)
    chunked = read_signals(run)
    for name in BASE_COLUMNS:
        assert whole.columns[name].tobytes() == chunked.columns[name].tobytes()
    lines = (run / SIGNALS).read_text().splitlines()
    lines[500] = "0.1,x,0,0,0,0,0"
    (run / SIGNALS).write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordingError, match=":501: "):
        read_signals(run)


# --- properties ----------------------------------------------------------------------------------


def _csv(path: Path, t: np.ndarray, seed: int = 0) -> Path:
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(len(t), 2))
    tau = rng.normal(size=(len(t), 2))
    lines = ["t,q1,q2,tau1,tau2"] + [
        ",".join(repr(float(x)) for x in (t[k], *q[k], *tau[k])) for k in range(len(t))
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


increasing_t = st.lists(st.floats(1e-4, 5e-3, allow_nan=False), min_size=1, max_size=60).map(
    lambda d: np.cumsum([0.0, *d])
)


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(t=increasing_t, offset=st.floats(-1e3, 1e3, allow_nan=False))
def test_real_time_stamps_are_kept_exactly(tmp_path, t, offset):
    t = t + offset
    if np.any(np.diff(t) <= 0):
        return  # the offset rounded two stamps together: not a strictly increasing input
    rec = read_signals(_csv(tmp_path / "s.csv", t))
    assert rec.t.tobytes() == t.tobytes()
    np.testing.assert_array_equal(rec.dt, np.diff(t))
    slices = rec.segments()
    assert slices[0].start == 0 and slices[-1].stop == len(t)
    assert sum(s.stop - s.start for s in slices) == len(t)


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(t=increasing_t, data=st.data())
def test_t_out_of_order_is_an_error(tmp_path, t, data):
    if len(t) < 2:
        return
    i = data.draw(st.integers(0, len(t) - 2))
    t = t.copy()
    t[i], t[i + 1] = t[i + 1], t[i]
    with pytest.raises(RecordingError) as exc:
        read_signals(_csv(tmp_path / "s.csv", t))
    assert f":{i + 3}: t steps back" in one_line_error(exc)


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(t=increasing_t, d=st.integers(-3, 3))
@example(t=np.cumsum([0.0, 0.00390625, 0.00021, 0.00021]), d=1)  # a gap after row 0
def test_loop_delay_aligns_rows(tmp_path, t, d):
    path = _csv(tmp_path / "s.csv", t)
    raw = read_signals(path)
    rec = read_signals(path, loop_delay=d)
    # each segment (between gaps) loses |d| rows; a torque never comes from another segment
    segments = raw.segments()
    assert len(rec) == sum(max(0, s.stop - s.start - abs(d)) for s in segments)
    segment_of = np.zeros(len(t), dtype=int)
    for number, s in enumerate(segments):
        segment_of[s] = number
    for k in range(len(rec)):
        i = int(np.searchsorted(t, rec.t[k]))  # the file row of output row k
        assert rec.q[k].tolist() == raw.q[i].tolist()
        assert rec.tau[k].tolist() == raw.tau[i - d].tolist()
        assert segment_of[i] == segment_of[i - d]


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5),
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=3), inner, max_size=3)
    ),
    max_leaves=5,
)


@settings(
    max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(field=st.sampled_from(["period_s", "rows", "status", "robot", "seed", "columns", "kind"]),
       value=json_values)  # fmt: skip
def test_meta_fields_of_any_type_read_or_fail_in_one_line(tmp_path, field, value):
    run = tmp_path / "run"
    if not run.exists():
        write_run(run, lockstep_rows(20))
        (run / "pristine.json").write_text((run / META).read_text())
    meta = json.loads((run / "pristine.json").read_text())
    meta[field] = value
    (run / META).write_text(json.dumps(meta))
    try:
        rec = read_signals(run)
    except RecordingError as exc:
        assert "\n" not in str(exc) and field in str(exc)
        return
    assert len(rec) == 20 and rec.period_s == pytest.approx(H)


# --- --out reuse ---------------------------------------------------------------------------------


def test_out_dir_refused_when_not_empty_unless_overwrite(tmp_path):
    """Each prepare_out_dir is one command's start; release_out_dirs its end (run_command)."""
    out = tmp_path / "out"
    assert prepare_out_dir(out, False) == out and out.is_dir()  # taken: locked, so it exists
    release_out_dirs(2)  # a start refused before anything was recorded: nothing left behind
    assert not out.exists()
    out.mkdir()
    prepare_out_dir(out, False)  # empty: fine
    release_out_dirs(0)
    (out / "bus.log").write_text("old run")
    (out / "sub").mkdir()
    with pytest.raises(ValueError) as exc:
        prepare_out_dir(out, False)
    assert str(out) in one_line_error(exc) and "--overwrite" in str(exc.value)
    assert (out / "bus.log").is_file()  # the refused start removed nothing
    prepare_out_dir(out, True)
    assert out.is_dir() and not any(out.iterdir())
    release_out_dirs(0)
    (out / "rec").mkdir()
    with pytest.raises(ValueError, match="holds the input"):
        prepare_out_dir(out, True, inputs=[out / "rec"])
    assert (out / "rec").is_dir()
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="not a directory"):
        prepare_out_dir(tmp_path / "file", True)
    assert held_out_dirs() == []


def test_realtime_run_read_on_its_host_stamps(tmp_path):
    """A realtime run's t column is k·h; `--columns t=sync_sent_s` reads it on the host's
    stamps instead, checked against meta.json's period_s."""
    rng = np.random.default_rng(3)
    stamps = 1234.5 + np.arange(100) * H + rng.uniform(0, 0.3 * H, 100)
    with RecordingWriter(tmp_path / "rt", {"period_s": H, "mode": "realtime"},
                         extra_columns=("sync_sent_s",)) as w:  # fmt: skip
        for k in range(100):
            w.write([k * H, 0.01 * k, 0.0, 1.0, 0.0, float(stamps[k])])
    rec = read_signals(tmp_path / "rt", columns="t=sync_sent_s")
    assert rec.t.tobytes() == stamps.tobytes() and rec.time_column == "sync_sent_s"
    assert rec.period_s == H
    set_meta(tmp_path / "rt", period_s=10 * H)
    with pytest.raises(RecordingError) as exc:
        read_signals(tmp_path / "rt", columns="t=sync_sent_s")
    assert "inconsistent with meta.json's period_s" in one_line_error(exc)


def test_realtime_run_with_a_stall_past_every_budget_reads_as_a_gap(tmp_path):
    """A realtime run whose host stopped for 20 s (longer than any feedback budget: Ctrl-Z,
    say) keeps its rows for analysis: run_trace reads the stall as one long interval, which the
    reader splits the run at; a replay's bounded reading refuses to integrate over it."""
    from drivers.realtime_times import host_stamp_trace, on_real_times, run_trace

    sent = np.arange(100) * H
    sent[60:] += 20.0
    with RecordingWriter(tmp_path / "rt", {"period_s": H, "mode": "realtime"},
                         extra_columns=("sync_sent_s", "feedback_s")) as w:  # fmt: skip
        for k in range(100):
            w.write([k * H, 0.01 * k, 0.0, 1.0, 0.0, float(sent[k]), float(sent[k] + 1e-3)])
    rec = read_signals(tmp_path / "rt")
    trace, source = run_trace(rec)
    assert "host's stamps" in source
    moved = on_real_times(rec, trace, source)
    assert len(moved) == 100 and moved.t[60] - moved.t[59] == pytest.approx(20.0 + H)
    assert len(moved.segments()) == 2  # the stall is a gap, never bridged
    with pytest.raises(RecordingError) as exc:
        host_stamp_trace(rec, 2e-4)  # bounded, as hil replay reads it
    assert "beyond the longest feedback budget" in one_line_error(exc)
