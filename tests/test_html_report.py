"""``--report FILE`` (issue 30): one self-contained HTML page per command, opened in headless
Chromium (Debian's ``chromium``; .ci/run installs it) and checked to render its plots with no
console error. Skips, saying why, where Chromium is missing."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from cli_run import ROOT, hil

from hil.report.page import MAX_POINTS, Page, decimate

DFKI = ROOT / "tests/data/dfki/design_A.0__20220815__sys_id__trajectory_00.csv"
CHROMIUM = next((c for c in ("chromium", "chromium-browser") if shutil.which(c)), None)


def render(page: Path, shot: Path) -> tuple[str, list[str]]:
    """Open ``page`` in headless Chromium: the DOM after its script ran, the console lines it
    logged; a screenshot saved to ``shot`` (its path printed)."""
    if CHROMIUM is None:
        pytest.skip("chromium is not installed (apt-get install chromium; .ci/run does)")
    cmd = [
        CHROMIUM, "--headless", "--disable-gpu", "--no-sandbox", "--enable-logging=stderr",
        "--v=0", "--window-size=1200,2400", f"--screenshot={shot}", "--dump-dom",
        page.resolve().as_uri(),
    ]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    print(f"screenshot: {shot}")
    return done.stdout, [line for line in done.stderr.splitlines() if ":CONSOLE" in line]


def check_renders(report: Path, tmp_path: Path, *, plots: int) -> str:
    """The page is one file with nothing fetched, and Chromium draws ``plots`` plots (at
    least) with no console message."""
    text = report.read_text()
    assert not re.search(r"<(link|img|iframe)\b|\bsrc=|https?://(?!www\.w3\.org/2000/svg)", text)
    dom, console = render(report, tmp_path / f"{report.stem}.png")
    assert not console, console
    drawn = int(re.search(r'data-plots="(\d+)"', dom).group(1))
    assert drawn == text.count('<figure class="plot">') >= plots
    assert dom.count("<polyline") >= plots
    assert (tmp_path / f"{report.stem}.png").stat().st_size > 10_000
    return dom


def test_diagnose_report_on_the_dfki_recording(tmp_path):
    report = tmp_path / "diagnose.html"
    done = hil(
        "diagnose", str(DFKI), "--format", "dfki", "--robot", "dfki-a0", "--report", str(report),
        "--json",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    doc = json.loads(done.stdout)
    assert f"report: {report}" in done.stderr
    dom = check_renders(report, tmp_path, plots=2)  # the recording's positions and torques
    assert "Mismatch diagnosis report" in dom
    # the findings in words: the document's summary and every note are on the page
    assert doc["summary"].split(":")[0] in dom
    assert "I cannot say the model is complete" in doc["summary"]
    assert "I cannot say the model is complete" in dom
    assert any(note.startswith("Held at zero in every fit") for note in doc["notes"])
    for note in doc["notes"]:
        assert note.split(":")[0] in dom, note


def test_identify_report_on_the_dfki_recording(tmp_path):
    report = tmp_path / "out" / "identify.html"  # its directory is made
    done = hil(
        "identify", "--from", str(DFKI), "--format", "dfki", "--robot", "dfki-a0",
        "--out", str(tmp_path / "id"), "--no-plot", "--report", str(report),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    dom = check_renders(report, tmp_path, plots=2)
    doc = json.loads((tmp_path / "id" / "identify.json").read_text())
    for p in doc["identification"]["parameters"]:
        assert f">{p['parameter']}<" in dom
    assert "Validation (NRMSE per joint)" in dom and "As printed" in dom


def test_identify_report_of_a_urdf_arm(tmp_path):
    """The n-joint identification document (base parameters, the held-out verdict) too."""
    sim = tmp_path / "c3"
    done = subprocess.run(
        [sys.executable, "-m", "virtual_robot.cli", "simulate", "--robot", "cicese3",
         "--experiment", "cicese3-excitation", "--duration", "4", "--out", str(sim), "--no-plot"],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    report = tmp_path / "c3.html"
    done = hil(
        "identify", "--from", str(sim), "--robot", "cicese3", "--out", str(tmp_path / "id"),
        "--no-plot", "--report", str(report),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    dom = check_renders(report, tmp_path, plots=2)
    assert "Base parameters" in dom and "Held-out validation" in dom and ">beta18<" in dom


def test_control_compare_report(tmp_path):
    report = tmp_path / "compare.html"
    done = hil(
        "control", "--compare", "--bench", "virtual-inprocess", "--duration", "1",
        "--schemes", "pd,ct", "--out", str(tmp_path / "cmp"), "--no-plot",
        "--report", str(report),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    dom = check_renders(report, tmp_path, plots=5)  # errors + 2 joints × (q, τ)
    assert "profile / PD" in dom and "profile / CT" in dom


def test_control_report_is_for_compare_only(tmp_path):
    done = hil("control", "--scheme", "pd", "--report", str(tmp_path / "r.html"))
    assert done.returncode == 2
    assert "--report: an HTML report is written for --compare" in done.stderr
    assert not (tmp_path / "r.html").exists()


def test_a_directory_as_report_is_refused_before_the_work(tmp_path):
    done = hil("diagnose", str(DFKI), "--format", "dfki", "--report", str(tmp_path))
    assert done.returncode == 2
    assert "is a directory; give the HTML file's name" in done.stderr
    assert "diagnose:" not in done.stderr.replace("hil diagnose:", "")  # nothing ran


def test_the_page_is_self_contained_and_escapes_its_data():
    page = Page("a </script> title")
    page.paragraph("<b>not bold</b>")
    page.plot("p", "t", "y", [("</script><script>alert(1)//", [0, 1], [1.0, float("nan")])])
    text = page.render()
    assert "<b>not bold</b>" not in text and "&lt;b&gt;" in text
    assert text.count("<script") == 2  # the data island and the page's one script
    island = re.search(r'<script type="application/json">(.*?)</script>', text, re.S).group(1)
    data = json.loads(island)
    assert data["series"][0]["name"].startswith("</script>")
    assert data["series"][0]["y"] == [1.0, None]  # NaN is a gap, not invalid JSON


def test_a_long_series_is_cut_to_its_extremes():
    n = 100_000
    x = list(range(n))
    y = [0.0] * n
    y[12_345], y[67_890] = 5.0, -7.0  # one-sample spikes
    xs, ys = decimate(x, y)
    assert len(xs) <= MAX_POINTS and xs == sorted(xs)
    assert 5.0 in ys and -7.0 in ys


def test_an_unknown_command_is_refused():
    from hil.report.documents import build_report

    with pytest.raises(ValueError, match="no HTML report for 'jitter'"):
        build_report("jitter", {})
