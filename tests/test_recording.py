"""Tests for the recording format (drivers/recording/): writer, reader, partial and bad files."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from drivers.recording import (
    BASE_COLUMNS,
    MAX_ABS_VALUE,
    META,
    SIGNALS,
    Recording,
    RecordingError,
    RecordingWriter,
    read_signals,
)

EXTRA = ("q1_ref", "energy_J")
H = 0.0025


def sample_rows(n: int = 12) -> list[list[float]]:
    """Rows whose values do not survive a careless float → text → float round trip."""
    specials = [
        0.1,
        1 / 3,
        -2.5e-7,
        2.0 / 3.0,
        math.pi,
        -0.0,
        5e-324,
        1.7976931348623157e308,
        1e-300,
        123456789.123456789,
        -1e22,
        0.30000000000000004,
    ]
    rows = []
    for k in range(n):
        s = specials[k % len(specials)]
        # q within the reader's bound (|q| <= MAX_ABS_VALUE); the extremes in the extra columns
        q = s if abs(s) <= MAX_ABS_VALUE else 1.0 / s
        rows.append([k * H, q, -q / 7.0, 0.1 * k, 1 / (k + 3), s * 3.0, s])
    return rows


def bits(a: np.ndarray | list[float]) -> bytes:
    return np.asarray(a, dtype=np.float64).tobytes()


def write_run(out: Path, rows: list[list[float]], extra=EXTRA, **meta) -> Path:
    with RecordingWriter(out, {"period_s": H, **meta}, extra_columns=extra) as w:
        for row in rows:
            w.write(row)
    return out


def read_meta(out: Path) -> dict:
    return json.loads((out / META).read_text())


# --- round trip ---------------------------------------------------------------------------------


def test_round_trip_is_bit_exact(tmp_path):
    rows = sample_rows()
    out = write_run(tmp_path / "run", rows, robot="cicese")
    rec = read_signals(out)
    assert isinstance(rec, Recording)
    assert rec.path == out
    assert list(rec.columns) == [*BASE_COLUMNS, *EXTRA]
    assert len(rec) == len(rows)
    table = np.array(rows)
    for j, name in enumerate(rec.columns):
        assert bits(rec.columns[name]) == bits(table[:, j]), name
    assert bits(rec.q) == bits(table[:, 1:3])
    assert bits(rec.tau) == bits(table[:, 3:5])
    assert not rec.dropped_partial_row
    meta = read_meta(out)
    assert meta == rec.meta
    assert meta["status"] == "complete"
    assert meta["rows"] == len(rows)
    assert meta["columns"] == [*BASE_COLUMNS, *EXTRA]
    assert meta["robot"] == "cicese"
    assert rec.period_s == H


def test_round_trip_of_numpy_and_integer_values(tmp_path):
    row = [np.float64(0.1), np.float32(1 / 3), np.int64(-7), 3, True]
    with RecordingWriter(tmp_path / "run", {}) as w:
        w.write(row)
    rec = read_signals(tmp_path / "run")
    assert bits([rec.columns[c][0] for c in BASE_COLUMNS]) == bits(
        [0.1, float(np.float32(1 / 3)), -7.0, 3.0, 1.0]
    )


def test_rows_of_plain_values_are_written_as_any_other(tmp_path):
    """RecordingWriter.write joins a row of plain floats and ints by repr (its fast path): the
    same text as a row with a numpy value or a bool in it (which goes value by value), for
    -0.0, subnormals, huge ints and the shortest round-trip forms."""
    plain = [-0.0, 5e-324, 2**70, 0.1 + 0.2, 1e16]
    mixed = [np.float64(-0.0), 5e-324, 2**70, 0.1 + 0.2, np.float64(1e16)]
    for name, row in (("plain", plain), ("mixed", mixed)):
        with RecordingWriter(tmp_path / name, {}) as w:
            w.write(row)
    plain_text = (tmp_path / "plain" / SIGNALS).read_text()
    assert plain_text == (tmp_path / "mixed" / SIGNALS).read_text()
    assert (
        plain_text.splitlines()[1] == "-0.0,5e-324,1180591620717411303424,0.30000000000000004,1e+16"
    )
    with RecordingWriter(tmp_path / "bool", {}) as w:
        w.write([0.5, True, False, 1, 2])
    assert (tmp_path / "bool" / SIGNALS).read_text().splitlines()[1] == "0.5,1,0,1,2"


def test_write_rejects_a_row_of_the_wrong_width(tmp_path):
    with RecordingWriter(tmp_path / "run", {}, extra_columns=EXTRA) as w:
        with pytest.raises(ValueError):
            w.write([0.0, 1.0, 2.0, 3.0, 4.0])
        w.write([0.0] * 7)
    assert read_meta(tmp_path / "run")["rows"] == 1


def test_meta_says_running_while_open_and_close_is_idempotent(tmp_path):
    w = RecordingWriter(tmp_path / "run", {"period_s": H}, flush_every=1)
    assert read_meta(tmp_path / "run")["status"] == "running"
    w.write([0.0, 0.1, 0.2, 0.3, 0.4])
    # a crash now leaves a readable recording with the rows so far
    rec = read_signals(tmp_path / "run")
    assert len(rec) == 1 and rec.meta["status"] == "running"
    w.close()
    w.close("failed")
    assert read_meta(tmp_path / "run")["status"] == "complete"
    assert not list((tmp_path / "run").glob("*.tmp"))


# --- context manager: final status --------------------------------------------------------------


def test_exception_inside_marks_failed(tmp_path):
    rows = sample_rows(5)
    with (
        pytest.raises(RuntimeError, match="drive fault"),
        RecordingWriter(tmp_path / "run", {"period_s": H}, extra_columns=EXTRA) as w,
    ):
        for row in rows:
            w.write(row)
        raise RuntimeError("drive fault")
    meta = read_meta(tmp_path / "run")
    assert meta["status"] == "failed"
    assert meta["error"] == "RuntimeError: drive fault"
    assert meta["rows"] == 5
    rec = read_signals(tmp_path / "run")
    assert bits(rec.t) == bits([r[0] for r in rows])
    assert bits(rec.columns["energy_J"]) == bits([r[6] for r in rows])


def test_keyboard_interrupt_marks_interrupted(tmp_path):
    rows = sample_rows(4)
    with (
        pytest.raises(KeyboardInterrupt),
        RecordingWriter(tmp_path / "run", {"period_s": H}, extra_columns=EXTRA) as w,
    ):
        for row in rows:
            w.write(row)
        raise KeyboardInterrupt
    meta = read_meta(tmp_path / "run")
    assert meta["status"] == "interrupted"
    assert "error" not in meta
    assert meta["rows"] == 4
    rec = read_signals(tmp_path / "run")
    assert len(rec) == 4
    assert bits(rec.q) == bits(np.array(rows)[:, 1:3])


# --- partial and malformed files ----------------------------------------------------------------


@pytest.mark.parametrize("cut", [1, 5, 12])
def test_torn_last_line_is_dropped_and_flagged(tmp_path, cut):
    rows = sample_rows(10)
    out = write_run(tmp_path / "run", rows)
    csv_path = out / SIGNALS
    data = csv_path.read_bytes()
    assert data.endswith(b"\n")
    csv_path.write_bytes(data[:-cut])  # cut inside the last row (rows are > 12 bytes long)
    rec = read_signals(out)
    assert rec.dropped_partial_row
    assert len(rec) == 9
    table = np.array(rows[:9])
    for j, name in enumerate(rec.columns):
        assert bits(rec.columns[name]) == bits(table[:, j]), name


def test_cut_on_a_row_boundary_drops_nothing(tmp_path):
    out = write_run(tmp_path / "run", sample_rows(10))
    csv_path = out / SIGNALS
    lines = csv_path.read_text().splitlines(keepends=True)
    csv_path.write_text("".join(lines[:-3]))
    rec = read_signals(out)
    assert not rec.dropped_partial_row
    assert len(rec) == 7


def test_header_only(tmp_path):
    out = write_run(tmp_path / "run", [])
    rec = read_signals(out)
    assert len(rec) == 0 and list(rec.columns) == [*BASE_COLUMNS, *EXTRA]
    assert rec.period_s == H  # from meta.json
    del rec.meta["period_s"]
    with pytest.raises(RecordingError, match="fewer than two rows"):
        _ = rec.period_s


@pytest.mark.parametrize(
    "bad",
    ["0.1,abc,0,0,0,0,0", "0.1,0,0,0,0,0", "0.1,0,0,0,0,0,0,0", ""],
    ids=["not-a-number", "too-few", "too-many", "empty"],
)
def test_malformed_middle_row_names_file_and_line(tmp_path, bad):
    out = write_run(tmp_path / "run", sample_rows(10))
    csv_path = out / SIGNALS
    lines = csv_path.read_text().splitlines()
    lines[5] = bad  # file line 6: header is line 1
    csv_path.write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordingError) as exc:
        read_signals(out)
    msg = str(exc.value)
    assert "\n" not in msg
    assert f"{csv_path}:6:" in msg


def test_missing_base_columns_are_listed(tmp_path):
    """t and a q and a tau per joint: a joint with half its columns is named, not dropped; one
    joint is a recording (a pendulum's)."""
    csv_path = tmp_path / "short.csv"
    for header, absent in (("t,q1,x", "tau1"), ("t,q1,q2,tau1", "tau2"), ("q1,tau1", "t")):
        csv_path.write_text(header + "\n" + ",".join(["0.1"] * (header.count(",") + 1)) + "\n")
        with pytest.raises(RecordingError) as exc:
            read_signals(csv_path)
        msg = str(exc.value)
        assert str(csv_path) in msg and f"missing column(s) {absent} " in msg, msg
        assert "\n" not in msg
    csv_path.write_text("t,q1,tau1,x\n0.0,0.1,0.2,0.3\n0.01,0.2,0.2,0.3\n")
    rec = read_signals(csv_path)
    assert rec.n_joints == 1 and rec.q.shape == (2, 1)


@pytest.mark.parametrize(
    "content",
    [b"", b"\n", b"\n\nt,q1,q2,tau1,tau2\n"],
    ids=["empty", "blank-line", "blank-before-header"],
)
def test_empty_or_headerless_file(tmp_path, content):
    csv_path = tmp_path / "signals.csv"
    csv_path.write_bytes(content)
    with pytest.raises(RecordingError) as exc:
        read_signals(csv_path)
    assert str(csv_path) in str(exc.value)


def test_missing_file_and_missing_directory(tmp_path):
    with pytest.raises(RecordingError, match="cannot read"):
        read_signals(tmp_path / "nothing.csv")
    (tmp_path / "empty-run").mkdir()
    with pytest.raises(RecordingError) as exc:
        read_signals(tmp_path / "empty-run")
    assert str(tmp_path / "empty-run" / SIGNALS) in str(exc.value)


def test_not_utf8_signals(tmp_path):
    out = write_run(tmp_path / "run", sample_rows(3))
    with open(out / SIGNALS, "ab") as f:
        f.write(b"0.1,\xff\xfe,0,0,0,0,0\n")
    with pytest.raises(RecordingError) as exc:
        read_signals(out)
    assert str(out / SIGNALS) in str(exc.value)


@pytest.mark.parametrize(
    "content",
    [b"{not json", b"\xff\xfe{}", b"[1, 2]", b'"period_s"'],
    ids=["invalid-json", "not-utf8", "array", "string"],
)
def test_bad_meta_json(tmp_path, content):
    out = write_run(tmp_path / "run", sample_rows(3))
    (out / META).write_bytes(content)
    with pytest.raises(RecordingError) as exc:
        read_signals(out)
    assert str(out / META) in str(exc.value)


def test_bare_csv_without_meta(tmp_path):
    csv_path = tmp_path / "bench-log.csv"
    h = 0.002
    lines = ["t,q1,q2,tau1,tau2"]
    lines += [f"{k * h!r},{0.01 * k!r},{-0.02 * k!r},{1.5!r},{-0.25!r}" for k in range(50)]
    csv_path.write_text("\n".join(lines) + "\n")
    rec = read_signals(csv_path)
    assert rec.path == csv_path
    assert rec.meta == {}
    assert len(rec) == 50
    assert list(rec.columns) == list(BASE_COLUMNS)
    assert rec.period_s == pytest.approx(h, rel=1e-12)
    assert bits(rec.t) == bits([k * h for k in range(50)])
    assert rec.q.shape == (50, 2) and rec.tau.shape == (50, 2)


def test_bare_csv_with_spaces_and_reordered_columns(tmp_path):
    csv_path = tmp_path / "log.csv"
    csv_path.write_text("tau2, tau1, q2, q1, t, extra\n4,3,2,1,0.0,9\n8,7,6,5,0.5,9\n")
    rec = read_signals(csv_path)
    assert list(rec.t) == [0.0, 0.5]
    assert rec.q.tolist() == [[1.0, 2.0], [5.0, 6.0]]
    assert rec.tau.tolist() == [[3.0, 4.0], [7.0, 8.0]]
    assert rec.period_s == 0.5


# --- fuzz: garbage appended to or inserted into a valid signals.csv -----------------------------


def _valid_signals(tmp_path_factory) -> tuple[Path, bytes]:
    out = write_run(tmp_path_factory.mktemp("rec") / "run", sample_rows(6))
    return out, (out / SIGNALS).read_bytes()


garbage = (
    st.binary(max_size=40)
    | st.text(max_size=40).map(lambda s: s.encode("utf-8"))
    | st.text(alphabet="0123456789.,-+eE\n\r naif", max_size=40).map(str.encode)
)


@settings(max_examples=150, deadline=None)
@given(junk=garbage, where=st.floats(0.0, 1.0), append=st.booleans())
@example(junk=b"\n", where=0.0, append=False)
@example(junk=b"\xff", where=0.5, append=False)
@example(junk=b"\x00", where=0.0, append=False)
@example(junk=b'"', where=0.0, append=False)
@example(junk=b"\r", where=1.0, append=True)
@example(junk=b"nan,inf,-inf,1e999,0\n", where=1.0, append=True)
def test_garbage_in_signals_reads_or_raises_recording_error(tmp_path_factory, junk, where, append):
    out, valid = _valid_signals(tmp_path_factory)
    if append:
        data = valid + junk
    else:
        i = round(where * len(valid))
        data = valid[:i] + junk + valid[i:]
    (out / SIGNALS).write_bytes(data)
    try:
        rec = read_signals(out)
    except RecordingError as exc:
        assert "\n" not in str(exc)
        return
    assert isinstance(rec, Recording)
    assert set(BASE_COLUMNS) <= set(rec.columns)
    n = len(rec)
    assert all(len(col) == n for col in rec.columns.values())
    assert rec.q.shape == (n, 2) and rec.tau.shape == (n, 2)


def test_the_recording_a_parameter_file_names_is_found_only_unchanged(tmp_path, monkeypatch):
    """`hil identify` fingerprints the recording it identified from (drivers.recording.source);
    `hil diagnose --params` looks for it as named, beside the parameter file, then at its
    absolute path, and uses it only while its data are unchanged."""
    from drivers.recording.source import find_source, fingerprint

    data = tmp_path / "runs" / "a.csv"
    data.parent.mkdir()
    data.write_text("t,q1,q2,tau1,tau2\n0,0,0,0,0\n")
    run = tmp_path / "run"
    run.mkdir()
    (run / "signals.csv").write_text(data.read_text())
    assert fingerprint(tmp_path / "nothing.csv") == {} and fingerprint(None) == {}
    monkeypatch.chdir(data.parent)
    doc = {"recording": "a.csv", **fingerprint("a.csv")}
    assert doc["recording_resolved"] == str(data)
    params = tmp_path / "id" / "params.json"
    assert find_source(doc, params) == Path("a.csv")  # as named, from the working directory
    monkeypatch.chdir(tmp_path)
    assert find_source(doc, params) == data  # at its absolute path
    moved = tmp_path / "id" / "a.csv"
    moved.parent.mkdir()
    data.rename(moved)
    assert find_source(doc, params) == moved  # beside the parameter file
    moved.write_text(moved.read_text() + "0.1,0,0,0,0\n")
    assert find_source(doc, params) is None  # changed since: not the same recording
    assert find_source({"recording": "a.csv"}, params) is None  # no fingerprint
    same = {"recording": str(run), **fingerprint(run)}  # a run directory: its signals.csv
    assert find_source(same, params) == run


def test_params_whose_recording_changed_say_so_and_fall_back_to_theta(tmp_path, capsys):
    """`hil diagnose --params F` whose fingerprinted recording is not found unchanged says so in
    one line and judges against F's θ alone; a file without a fingerprint says nothing."""
    import argparse

    from drivers.recording.source import fingerprint
    from hil.diagnose.cli import _references

    data = tmp_path / "a.csv"
    data.write_text("t,q1,q2,tau1,tau2\n0,0,0,0,0\n")
    params = tmp_path / "params.json"
    doc = {"recording": str(data), **fingerprint(data)}
    data.write_text(data.read_text() + "0.1,0,0,0,0\n")  # changed since
    params.write_text(json.dumps(doc))
    args = argparse.Namespace(reference=None, params=str(params))
    never = pytest.fail  # nothing is read
    refs, why = _references(args, never)
    assert refs == [] and "not found unchanged" in why
    err = capsys.readouterr().err
    assert "not found unchanged" in err and "θ alone" in err and str(data) in err
    params.write_text(json.dumps({"recording": str(data)}))
    assert _references(args, never) == ([], "")
    assert capsys.readouterr().err == ""
