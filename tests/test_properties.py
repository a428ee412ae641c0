"""Property tests (issue 13): whatever a user hands `hil replay` (a run's timing: the host's
stamps, the robot's event log) and `hil control --params` / `hil diagnose --params` (a θ file),
the command ends with a one-line error (exit 2) naming the file, or a valid result; never a
traceback. In-process calls (:func:`hil.cli.main`) and few examples keep them fast."""

from __future__ import annotations

import json
import math
from pathlib import Path

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from drivers.realtime_times import ROBOT_EVENTS
from drivers.recording import RecordingWriter
from hil.cli import main as hil_main
from hil.model.closed_form import ArmModel
from hil.model.params import MAX_THETA_MAGNITUDE, robot_params
from profiles.timing_faults import TRACE_COLUMNS, check_trace, read_trace

H = 0.0025
FIXTURES = [HealthCheck.function_scoped_fixture, HealthCheck.too_slow]

# interval values a timing column may hold: ordinary, tiny, zero, negative, huge, not a number
INTERVALS = st.one_of(
    st.floats(1e-4, 5e-3),
    st.sampled_from([0.0, -H, -1.0, 1e-12, 1e3, 1e9, 1e300, math.nan, math.inf, -math.inf]),
)


def run_hil(argv: list[str], capsys) -> tuple[int, str]:
    """`hil ARGV` in this process: exit status and stderr (an exception fails the test)."""
    code = hil_main(argv)
    return code, capsys.readouterr().err


def assert_one_line_error(code: int, err: str, names: str) -> None:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2, err
    assert "Traceback" not in err
    assert lines[-1].startswith("hil ") and "error" in lines[-1], err
    assert names in lines[-1], err


def realtime_run(out: Path, n: int, host: list[float] | None) -> Path:
    """A `hil run` realtime recording of ``n`` rows (a small excitation), with the host's
    stamps when ``host`` holds its intervals (sync sent, feedback 0.3 ms later)."""
    meta = {
        "period_s": H,
        "robot": "cicese",
        "mode": "realtime",
        "kind": "hil run",
        "bench": "virtual-inprocess",
        "experiment": "reyes-kelly",
    }
    extra = ("sync_sent_s", "feedback_s") if host is not None else ()
    sent = 100.0
    with RecordingWriter(out, meta, extra_columns=extra) as w:
        for k in range(n):
            row = [k * H, 0.01 * math.sin(7 * k * H), 0.01 * math.cos(5 * k * H), 0.2, -0.1]
            if host is not None:
                row += [sent, sent + 3e-4]
                sent += host[k % len(host)] if host else H
            w.write(row)
    return out


def write_events(path: Path, n: int, intervals: list[float], header: str, extra: bytes) -> None:
    """A robot event log: sample k at the sum of ``intervals``, its command 0.3 ms later."""
    lines = [header]
    t = 0.0
    for k in range(n):
        lines += [f"sample,{k},{t!r}", f"command,{k + 1},{t + 3e-4!r}"]
        t += intervals[k % len(intervals)] if intervals else H
    path.write_bytes(("\n".join(lines) + "\n").encode() + extra)


def assert_replayed_or_refused(code: int, err: str, run: Path, out: Path) -> None:
    """Replayed (exit 0, replay.json); or replayed and the replay run failed, e.g. a trace of
    5 s intervals lets the arm fall into its limits (exit 1, one line saying so); or refused
    before anything ran (exit 2, one line naming the run)."""
    last = [ln for ln in err.splitlines() if ln.strip()][-1:]
    if code == 0:
        doc = json.loads((out / "replay.json").read_text())
        assert doc["comparison"]["rows_compared"] >= 1
    elif code == 1:
        assert "Traceback" not in err and last[0].startswith("hil replay: error: replay run ")
        assert (out / "run" / "meta.json").is_file()
    else:
        assert_one_line_error(code, err, str(run))
        assert not (out / "run").exists()


@settings(max_examples=25, deadline=None, suppress_health_check=FIXTURES)
@given(
    n=st.integers(0, 40),
    intervals=st.lists(INTERVALS, max_size=4),
)
@example(n=30, intervals=[H, 0.0031, 0.0004])  # a valid run: replayed
@example(n=2, intervals=[0.0])  # found: a trace the replay's robot refused (exit 3, its path)
@example(n=5, intervals=[1e9])  # found: a replay integrating the plant for 1e9 s
def test_replay_of_any_host_stamps(tmp_path_factory, capsys, n, intervals) -> None:
    """Host stamps (sync_sent_s, feedback_s) with NaN, negative, zero or huge intervals."""
    base = tmp_path_factory.mktemp("host")
    run = realtime_run(base / "rt", n, intervals)
    out = base / "replay"
    code, err = run_hil(["replay", str(run), "--out", str(out), "--no-plot"], capsys)
    assert_replayed_or_refused(code, err, run, out)


@settings(max_examples=25, deadline=None, suppress_health_check=FIXTURES)
@given(
    n=st.integers(0, 40),
    logged=st.integers(0, 45),
    intervals=st.lists(INTERVALS, max_size=4),
    header=st.sampled_from(["event,n,t", "event,n", "t,event,n", "", "event,n,t,extra"]),
    extra=st.sampled_from(
        [b"", b"sample,1", b"sample,x,0.1\n", b"command,-5,1e308\n", b"\x00\xff"]
    ),
)
def test_replay_of_any_robot_event_log(
    tmp_path_factory, capsys, n, logged, intervals, header, extra
) -> None:
    """The robot's event log: wrong header, too few rows, torn or non-numeric rows, NaN,
    negative or huge intervals."""
    base = tmp_path_factory.mktemp("events")
    run = realtime_run(base / "rt", n, None)
    write_events(run / ROBOT_EVENTS, logged, intervals, header, extra)
    out = base / "replay"
    code, err = run_hil(["replay", str(run), "--out", str(out), "--no-plot"], capsys)
    assert_replayed_or_refused(code, err, run, out)


COLUMNS = ["t", "q1", "q2", "tau1", "tau2", "sync_sent_s", "feedback_s"]


@settings(max_examples=30, deadline=None, suppress_health_check=FIXTURES)
@given(
    header=st.lists(st.sampled_from([*COLUMNS, "x", "", "t"]), max_size=8),
    rows=st.integers(0, 30),
    cell=st.sampled_from(["", "nan", "1e999", "x", "-1"]),
    blank=st.integers(0, 40),
)
@example(header=COLUMNS, rows=30, cell="", blank=40)  # the run as written: replayed
def test_replay_of_signals_with_any_columns(tmp_path_factory, capsys, header, rows, cell, blank):
    """signals.csv with columns missing, repeated, unknown or reordered, empty or header only,
    and one cell replaced: replayed or refused in one line."""
    base = tmp_path_factory.mktemp("cols")
    run = realtime_run(base / "rt", 30, [H])
    lines = (run / "signals.csv").read_text().splitlines()
    index = {name: i for i, name in enumerate(lines[0].split(","))}
    body = []
    for k, line in enumerate(lines[1 : rows + 1]):
        values = line.split(",")
        cells = [values[index[c]] if c in index else "0" for c in header]
        if k == blank and cells:
            cells[0] = cell
        body.append(",".join(cells))
    (run / "signals.csv").write_text("\n".join([",".join(header), *body]) + "\n" if header else "")
    out = base / "replay"
    code, err = run_hil(["replay", str(run), "--out", str(out), "--no-plot"], capsys)
    assert_replayed_or_refused(code, err, run, out)


CELLS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["", "x", "1e999", "-0", " 1", "nan"]),
)


@settings(max_examples=150, deadline=None)
@given(
    header=st.sampled_from([",".join(TRACE_COLUMNS), "k,sample_s,command_s", "", "t"]),
    rows=st.lists(st.lists(CELLS, min_size=0, max_size=5), max_size=6),
)
@example(
    header=",".join(TRACE_COLUMNS),
    rows=[["0", "0", "1e-3", "2e-3"], ["1", "2.5e-3", "3e-3", "3e-3"]],
)
@example(header=",".join(TRACE_COLUMNS), rows=[["0", "0", "0", "0"], ["1", "11", "11", "11"]])
def test_timing_trace_file_of_any_rows(tmp_path_factory, header, rows) -> None:
    """A `[timing_faults.trace]` file (what `hil replay` writes and its robot reads): a trace
    that passes every check, or one ValueError line naming the file."""
    path = tmp_path_factory.mktemp("trace") / "trace.csv"
    path.write_text("\n".join([header, *(",".join(r) for r in rows)]) + "\n")
    try:
        trace = read_trace(path)
    except ValueError as exc:
        assert "\n" not in str(exc) and str(path) in str(exc)
        return
    check_trace(trace.sample_s, trace.first_command_s, trace.command_s, "again")
    assert len(trace) >= 1


# ---- θ files ----------------------------------------------------------------------------------
THETA = robot_params("cicese").theta.tolist()
NUMBERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(10**30), 10**30),
    st.sampled_from([0.0, -1.0, 1e308, -1e308]),
)
JSON_VALUES = st.one_of(
    NUMBERS, st.none(), st.booleans(), st.text(max_size=4), st.lists(st.integers(), max_size=2)
)


@st.composite
def theta_documents(draw) -> object:
    """A θ file's document: the profile's θ with some entries replaced, wrong lengths, wrong
    types, all zero, in a bare file or in `hil identify`'s layout."""
    kind = draw(st.sampled_from(["perturbed", "zero", "length", "types", "shape"]))
    if kind == "perturbed":
        theta: object = list(THETA)
        for i in draw(st.lists(st.integers(0, 8), max_size=3)):
            theta[i] = draw(NUMBERS)  # type: ignore[index]
    elif kind == "zero":
        theta = [0.0] * 9
    elif kind == "length":
        theta = THETA[: draw(st.integers(0, 12))] + [1.0] * draw(st.integers(0, 3))
    elif kind == "types":
        theta = [draw(JSON_VALUES) for _ in range(9)]
    else:
        theta = draw(JSON_VALUES | st.dictionaries(st.text(max_size=6), NUMBERS, max_size=3))
    if draw(st.booleans()):
        return {"theta": theta}
    scheme = draw(st.sampled_from(["filtered_dynamic", "supplied_energy"]))
    return {"kind": "ddbench parameters", "selected": scheme, "schemes": {scheme: {"theta": theta}}}


def physical(doc: object) -> bool:
    """Would `--params` accept this document: 9 finite numbers within an arm's magnitude, M(q)
    positive definite."""
    entry = doc if "theta" in doc else next(iter(doc["schemes"].values()))  # type: ignore[operator]
    theta = entry["theta"]  # type: ignore[index]
    if not isinstance(theta, list) or len(theta) != 9:
        return False
    if not all(isinstance(x, int | float) and not isinstance(x, bool) for x in theta):
        return False
    if not all(math.isfinite(x) and abs(x) <= MAX_THETA_MAGNITUDE for x in theta):
        return False
    violations = ArmModel(()).physical_consistency(theta)["violations"]
    return not any(v.startswith("M(q)") for v in violations)


@settings(max_examples=40, deadline=None, suppress_health_check=FIXTURES)
@given(doc=theta_documents())
@example(doc={"theta": THETA})
@example(doc={"theta": [1.0, *THETA[1:]]})  # M(q) singular near q2 = 0: the message named no field
@example(doc={"theta": [1e308, *THETA[1:]]})  # M(q) "positive" as inf > 0, law inf − inf = NaN
def test_control_params_of_any_theta_file(tmp_path_factory, capsys, doc) -> None:
    base = tmp_path_factory.mktemp("ctl")
    params = base / "params.json"
    params.write_text(json.dumps(doc))  # NaN and ±Infinity written as JSON's extensions
    out = base / "c"
    argv = ["control", "--bench", "virtual-inprocess", "--scheme", "ct", "--duration", "0.02"]
    code, err = run_hil([*argv, "--params", str(params), "--out", str(out), "--no-plot"], capsys)
    if physical(doc):  # accepted: the run completes
        meta = json.loads((out / "meta.json").read_text())
        assert code == 0, err
        assert meta["status"] == "complete"
        return
    assert_one_line_error(code, err, str(params))
    assert "theta" in err  # the field
    assert not out.exists()


DIAGNOSE_RUN: dict[str, Path] = {}


def diagnose_run(tmp_path_factory) -> Path:
    """One short lockstep run of the default robot, shared by the examples."""
    if "run" not in DIAGNOSE_RUN:
        from hil.bench.run import run_experiment

        out = tmp_path_factory.mktemp("diag") / "run"
        run_experiment("virtual-inprocess", "reyes-kelly", out, duration_s=2.0, plot=False,
                       progress=False)  # fmt: skip
        DIAGNOSE_RUN["run"] = out
    return DIAGNOSE_RUN["run"]


@settings(max_examples=30, deadline=None, suppress_health_check=FIXTURES)
@given(doc=theta_documents())
def test_diagnose_params_of_any_theta_file(tmp_path_factory, capsys, doc) -> None:
    run = diagnose_run(tmp_path_factory)
    params = tmp_path_factory.mktemp("dp") / "params.json"
    params.write_text(json.dumps(doc))
    if physical(doc):
        return  # a physical θ diagnoses (tests/test_diagnose.py); too slow to do per example
    code, err = run_hil(["diagnose", str(run), "--params", str(params), "--no-plots"], capsys)
    assert_one_line_error(code, err, str(params))
    assert "theta" in err


def test_diagnose_accepts_a_physical_theta_file(tmp_path_factory, capsys) -> None:
    """The other side of the property: the profile's θ, bare and in `hil identify`'s layout."""
    run = diagnose_run(tmp_path_factory)
    for doc in ({"theta": THETA}, {"schemes": {"filtered_dynamic": {"theta": THETA}}}):
        params = tmp_path_factory.mktemp("dp") / "params.json"
        params.write_text(json.dumps(doc))
        code, err = run_hil(["diagnose", str(run), "--params", str(params), "--no-plots"], capsys)
        assert code == 0, err
