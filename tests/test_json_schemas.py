"""Every JSON document the commands write or print matches its schema in docs/schemas/ (issue 30
item 2) and is strict JSON (no NaN or Infinity, which Python's json writes by default and other
readers refuse).

Each document is produced here by the command a user runs, on short in-process benches, the
shipped DFKI recordings (tests/data) and a simulated recording of the 2-DOF arm with a concealed
torque gain (so the drift findings are filled in); the schemas are validated with the
``jsonschema`` library (Draft 2020-12). A field the code writes that its schema does not allow,
or a required field it stops writing, fails here.
"""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from cli_run import ROOT, hil
from diagnose_cases import make_recording

# one worker runs the whole module under `pytest -n` (`--dist loadgroup`): its module
# fixtures are built once, not once per worker
pytestmark = pytest.mark.xdist_group("json_schemas")

jsonschema = pytest.importorskip("jsonschema", reason="the test extra's jsonschema is missing")

SCHEMAS = ROOT / "docs" / "schemas"
DATA = ROOT / "tests" / "data"
DFKI = DATA / "dfki" / "design_A.0__20220815__sys_id__trajectory_00.csv"
PENDULUM = DATA / "dfki-pendulum" / "control_method_ilqr__data_measured.csv"
PENDULUM_COLUMNS = "t=time,q1=position,tau1=torque"


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"not strict JSON: {name}")


def strict_load(text: str) -> Any:
    """``text`` parsed as strict JSON: NaN, Infinity and -Infinity are refused."""
    return json.loads(text, parse_constant=_refuse_constant)


def validator(schema: str) -> jsonschema.Draft202012Validator:
    doc = json.loads((SCHEMAS / schema).read_text(encoding="utf-8"))
    jsonschema.Draft202012Validator.check_schema(doc)
    return jsonschema.Draft202012Validator(doc)


def check(schema: str, text: str, what: str) -> dict:
    """``text`` (one document, ``what`` names it) is strict JSON and valid against ``schema``;
    the parsed document."""
    try:
        doc = strict_load(text)
    except ValueError as e:
        pytest.fail(f"{what}: {e}")
    errors = sorted(validator(schema).iter_errors(doc), key=lambda e: list(e.absolute_path))
    if errors:
        lines = [
            f"{'/'.join(map(str, e.absolute_path)) or '(top)'}: {e.message[:300]}" for e in errors
        ]
        pytest.fail(f"{what} does not match {schema}:\n" + "\n".join(lines[:10]))
    # objects may grow, but a key the command writes at the top is described in its schema
    undescribed = set(doc) - set(_top_properties(schema, doc))
    assert not undescribed, f"{what}: top-level keys not described in {schema}: {undescribed}"
    return doc


def _top_properties(schema: str, doc: dict) -> dict:
    """The top-level ``properties`` of ``schema``, of the ``oneOf`` variant ``doc`` matches."""
    root = json.loads((SCHEMAS / schema).read_text(encoding="utf-8"))
    for variant in root.get("oneOf", []):
        name = variant["$ref"].removeprefix("#/$defs/")
        own = {**root["$defs"][name], "$defs": root["$defs"]}
        if jsonschema.Draft202012Validator(own).is_valid(doc):
            return own["properties"]
    return root["properties"]


def run_hil(*args: str) -> str:
    """``hil ARGS --json`` (a subprocess, as a user runs it): its stdout, the printed document."""
    proc = hil(*args, "--json")
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout


def check_file(schema: str, path: Path) -> dict:
    return check(schema, path.read_text(encoding="utf-8"), str(path.name))


# ---- the schemas themselves ------------------------------------------------------------------
def test_every_schema_is_a_valid_draft_2020_12_schema_listed_in_the_reference():
    names = sorted(p.name for p in SCHEMAS.glob("*.schema.json"))
    assert names, SCHEMAS
    page = (ROOT / "docs" / "schemas.md").read_text(encoding="utf-8")
    for name in names:
        schema = json.loads((SCHEMAS / name).read_text(encoding="utf-8"))
        assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema", name
        jsonschema.Draft202012Validator.check_schema(schema)
        assert f"schemas/{name}" in page, f"{name} is not listed in docs/schemas.md"


def test_a_document_that_breaks_its_schema_is_caught():
    """The schemas are not vacuous: a missing required field, a wrong type and a NaN fail."""
    good = {"out_dir": "d", "signals": "d/signals.csv", "rows": 10, "status": "complete",
            "reason": None, "bench": "b", "mode": "lockstep", "timing": {}}  # fmt: skip
    v = validator("run.schema.json")
    assert v.is_valid(good)
    assert not v.is_valid({k: x for k, x in good.items() if k != "rows"})
    assert not v.is_valid({**good, "rows": "10"})
    with pytest.raises(ValueError, match="NaN"):
        strict_load('{"rows": NaN}')


# ---- hil run, hil jitter, hil control --compare ----------------------------------------------
def test_hil_run_summary_and_meta(tmp_path):
    out = tmp_path / "run"
    text = run_hil("run", "--bench", "virtual-inprocess", "--duration", "1", "--out", str(out),
                   "--no-plot")  # fmt: skip
    summary = check("run.schema.json", text, "hil run --json")
    meta = check_file("meta.schema.json", out / "meta.json")
    assert summary["rows"] == meta["rows"] > 0 and meta["kind"] == "hil run"


def test_virtual_robot_simulate_meta(tmp_path):
    out = tmp_path / "sim"
    proc = subprocess.run(
        [sys.executable, "-m", "virtual_robot.cli", "simulate", "--duration", "0.5", "--out",
         str(out), "--no-plot"],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert check_file("meta.schema.json", out / "meta.json")["kind"] == "simulate"


def test_virtual_robot_simulate_summary(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "virtual_robot.cli", "simulate", "--duration", "0.3", "--out",
         str(tmp_path / "sim"), "--no-plot", "--json"],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert check("simulate.schema.json", proc.stdout, "virtual-robot simulate --json")["rows"] > 0


@pytest.mark.parametrize("bench", ["virtual-slcan", "virtual-socketcand", "virtual-serial"])
def test_virtual_robot_serve_ready_line(bench):
    proc = subprocess.Popen(
        [sys.executable, "-m", "virtual_robot.cli", "serve", "--bench", bench],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    try:
        line = proc.stdout.readline()  # the ready line, once the transport is open
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    doc = check("serve.schema.json", line, f"virtual-robot serve --bench {bench}")
    assert doc["pid"] == proc.pid and doc["bench"] == bench


def test_hil_excite_summary(tmp_path):
    out = tmp_path / "design.toml"
    text = hil("excite", "--starts", "1", "--time-budget", "1", "--no-simulate", "--no-plot",
               "--out", str(out), "--json").stdout  # fmt: skip
    doc = check("excite.schema.json", text, "hil excite --json")
    assert doc["profile"] == str(out) and out.is_file()


def test_hil_jitter_summary_and_meta(tmp_path):
    out = tmp_path / "jitter"
    text = run_hil("jitter", "--bench", "virtual-inprocess", "--duration", "1", "--out",
                   str(out), "--no-plot")  # fmt: skip
    summary = check("jitter.schema.json", text, "hil jitter --json")
    meta = check_file("meta.schema.json", out / "meta.json")
    assert meta["kind"] == "hil jitter"
    # meta.json keeps the printed summary under "jitter", less its own paths
    paths = ("out_dir", "signals")
    assert meta["jitter"] == {k: v for k, v in summary.items() if k not in paths}
    assert summary["timing"]["cycles"] > 0


def test_hil_run_realtime_with_mcap(tmp_path):
    """A realtime run fills the timing statistics; --mcap adds its path. The summary is printed
    whatever the run's status (a loaded machine may end it early): it is checked either way."""
    out = tmp_path / "rt"
    proc = hil("run", "--bench", "virtual-inprocess", "--mode", "realtime", "--duration", "1",
               "--mcap", "--out", str(out), "--no-plot", "--json")  # fmt: skip
    summary = check("run.schema.json", proc.stdout, "hil run --mode realtime --json")
    meta = check_file("meta.schema.json", out / "meta.json")
    assert summary["mode"] == meta["mode"] == "realtime" and "mcap" in summary
    if summary["status"] != "complete":
        return  # nothing to replay
    assert summary["timing"]["cycles"] > 0 and "jitter" in meta["timing"]
    replay = tmp_path / "replay"
    text = run_hil("replay", str(out), "--out", str(replay), "--no-plot")
    doc = check("replay.schema.json", text, "hil replay --json")
    assert doc == check_file("replay.schema.json", replay / "replay.json")


def test_hil_jitter_sweep(tmp_path):
    """A two-level latency sweep (control and identification at each level, 1 s runs)."""
    out = tmp_path / "sweep"
    text = run_hil("jitter", "--bench", "virtual-inprocess", "--sweep", "latency=0:2ms:2",
                   "--study-duration", "1", "--executor", "serial", "--out", str(out),
                   "--no-plot")  # fmt: skip
    doc = check("sweep.schema.json", text, "hil jitter --sweep --json")
    assert doc == check_file("sweep.schema.json", out / "sweep.json")
    assert doc["identify"] and len(doc["points"]) == 2
    for point in doc["points"]:
        path = Path(point["out_dir"]) / "point.json"
        assert check_file("sweep-point.schema.json", path) == point["result"]


def test_hil_control_one_scheme(tmp_path):
    out = tmp_path / "ct"
    text = run_hil("control", "--scheme", "ct", "--bench", "virtual-inprocess", "--duration",
                   "1", "--out", str(out), "--no-plot")  # fmt: skip
    doc = check("control.schema.json", text, "hil control --json")
    assert doc["run"] == check_file("control-run.schema.json", out / "control.json")
    check_file("meta.schema.json", out / "meta.json")


def test_hil_control_compare(tmp_path):
    out = tmp_path / "compare"
    text = run_hil("control", "--compare", "--bench", "virtual-inprocess", "--duration", "1",
                   "--out", str(out), "--no-plot")  # fmt: skip
    doc = check("compare.schema.json", text, "hil control --compare --json")
    assert doc == check_file("compare.schema.json", out / "compare.json")
    for scheme in doc["schemes"]:  # each controller's run directory
        run = Path(doc["results"]["profile"][scheme]["out_dir"])
        check_file("meta.schema.json", run / "meta.json")
        assert (
            check_file("control-run.schema.json", run / "control.json")
            == (doc["results"]["profile"][scheme])
        )


# ---- hil identify (three layouts) and params.json --------------------------------------------
@pytest.fixture(scope="module")
def identified(tmp_path_factory) -> dict[str, Path]:
    """`hil identify` on each path: the 2-DOF Table II path over a 2 s in-process bench run, the
    model-object path on the DFKI double-pendulum file, the URDF path on the DFKI pendulum."""
    root = tmp_path_factory.mktemp("identify")
    runs = {
        "table_ii": ["--bench", "virtual-inprocess", "--duration", "2",
                     "--validation-experiment", "none"],
        "model": ["--from", str(DFKI), "--format", "dfki", "--robot", "dfki-a0"],
        "urdf": ["--from", str(PENDULUM), "--robot", "dfki-pendulum", "--columns",
                 PENDULUM_COLUMNS],
    }  # fmt: skip
    for name, argv in runs.items():
        text = run_hil("identify", *argv, "--out", str(root / name), "--no-plot")
        (root / f"{name}.stdout").write_text(text, encoding="utf-8")
    return {name: root / name for name in runs}


@pytest.mark.parametrize("layout", ["table_ii", "model", "urdf"])
def test_identify_json_and_its_printed_copy(identified, layout):
    out = identified[layout]
    doc = check_file("identify.schema.json", out / "identify.json")
    printed = check("identify.schema.json", (out.parent / f"{layout}.stdout").read_text(), "--json")
    assert printed == doc
    # the layout is told by its own keys: exactly one of the schema's variants matches
    schema = json.loads((SCHEMAS / "identify.schema.json").read_text(encoding="utf-8"))
    own = {**schema["$defs"][layout], "$defs": schema["$defs"]}
    assert jsonschema.Draft202012Validator(own).is_valid(doc)
    if layout == "urdf":  # its identify.json is its parameter file
        assert not (out / "params.json").exists()
    else:
        params = check_file("params.schema.json", out / "params.json")
        assert params["selected"] in params["schemes"]
    if layout == "table_ii":
        check_file("meta.schema.json", out / "fit" / "meta.json")


# ---- hil diagnose ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def gain_recording(tmp_path_factory) -> Path:
    """The 2-DOF arm with a 7 % torque gain concealed on joint 1: a drift the profile's model
    is judged to have (nominal used, drift findings filled in)."""
    root = tmp_path_factory.mktemp("gain")
    return make_recording(
        root / "rec", "diagnosis", {"torque_gain_error": {"relative": [0.07, 0.0]}}
    )


def test_diagnosis_with_drift_against_the_profile(gain_recording, tmp_path):
    out = tmp_path / "d"
    text = run_hil("diagnose", str(gain_recording), "--robot", "cicese", "--out", str(out),
                   "--no-plots")  # fmt: skip
    doc = check("diagnosis.schema.json", text, "hil diagnose --json")
    assert doc == check_file("diagnosis.schema.json", out / "diagnosis.json")
    assert doc["nominal"]["used"] and doc["nominal"]["findings"], doc["summary"]
    # docs/schemas.md's command, as written, accepts it and refuses it broken
    page = (ROOT / "docs" / "schemas.md").read_text(encoding="utf-8")
    line = next(ln for ln in page.splitlines() if ln.startswith("python -c "))
    argv = [sys.executable, *shlex.split(line)[1:]]
    argv[-1] = argv[-1].replace("OUT", str(out), 1)
    ok = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, check=False)
    assert ok.returncode == 0 and not ok.stdout, ok.stderr
    broken = out / "diagnosis.json"
    broken.write_text(json.dumps({**doc, "findings": "none"}), encoding="utf-8")
    bad = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, check=False)
    assert bad.returncode != 0 and "'none' is not of type 'array'" in bad.stderr, bad.stderr


def test_diagnosis_against_params_and_refit(identified, tmp_path):
    fit = identified["table_ii"] / "fit"
    # the fit's own recording, which params.json fingerprints: found, and the model
    # re-identified from it (source "reference")
    for extra, source in (
        (["--params", str(identified["table_ii"] / "params.json")], "reference"),
        (["--refit"], "refit"),
    ):
        text = run_hil("diagnose", str(fit), "--no-plots", *extra)
        doc = check("diagnosis.schema.json", text, f"hil diagnose {extra[0]}")
        assert doc["nominal"]["source"] == source


def test_diagnosis_of_real_recordings(tmp_path):
    """The DFKI double pendulum (a format with commanded and measured torque: torque_path, the
    timing read from its stamps) and the DFKI pendulum (a URDF arm)."""
    out = tmp_path / "dfki"
    text = run_hil("diagnose", str(DFKI), "--format", "dfki", "--robot", "dfki-a0", "--out",
                   str(out), "--no-plots")  # fmt: skip
    doc = check("diagnosis.schema.json", text, "hil diagnose --json (DFKI)")
    assert doc == check_file("diagnosis.schema.json", out / "diagnosis.json")
    assert doc["torque_path"] and doc["timing"] and doc["nominal_model"]["terms"]
    text = run_hil("diagnose", str(PENDULUM), "--robot", "dfki-pendulum", "--columns",
                   PENDULUM_COLUMNS, "--no-plots")  # fmt: skip
    check("diagnosis.schema.json", text, "hil diagnose --json (pendulum)")
