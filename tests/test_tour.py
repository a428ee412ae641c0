"""The README's five-minute tour and the tutorial (docs/tutorial.md), run as written (issue 30).

Their ``sh`` blocks are taken from the files themselves, in order, and run by bash in a temporary
directory: the README's beside links to this checkout's ``.venv`` and ``tests`` (its commands
start with ``. .venv/bin/activate`` and read ``tests/data/dfki``); the tutorial's in a fresh
``git clone`` of this checkout, install included. The whole tour and the tutorial take minutes
(marked slow); the tour's real-data block alone runs in ``make test``.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from cli_run import ROOT

README = ROOT / "README.md"
TUTORIAL = ROOT / "docs" / "tutorial.md"
ADD_AN_ARM = ROOT / "docs" / "howto-add-an-arm.md"


def section(path: Path, heading: str | None) -> str:
    """The text of ``path`` under the ``## heading`` (up to the next ``## ``); all if None."""
    text = path.read_text()
    if heading is None:
        return text
    m = re.search(rf"^## {re.escape(heading)}\n(.*?)(?=^## |\Z)", text, re.S | re.M)
    assert m, f"{path.name} has no section '## {heading}'"
    return m.group(1)


def sh_blocks(text: str) -> list[str]:
    """The fenced ``sh`` blocks of ``text``, in order."""
    return re.findall(r"^```sh\n(.*?)^```", text, re.S | re.M)


def run_blocks(blocks: list[str], cwd: Path, *, timeout: float) -> None:
    """Run the blocks in one bash (``set -e``: the first failing command fails), so what one
    block sets up (the activated venv) the next one has."""
    script = "set -euo pipefail\n" + "\n".join(blocks)
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH")}
    env["MPLBACKEND"] = "Agg"
    done = subprocess.run(
        ["bash", "-c", script], cwd=cwd, env=env, capture_output=True, text=True,
        timeout=timeout, check=False,
    )  # fmt: skip
    assert done.returncode == 0, (
        f"exit {done.returncode}\n--- script\n{script}\n--- stdout\n{done.stdout[-3000:]}"
        f"\n--- stderr\n{done.stderr[-3000:]}"
    )


def tour_dir(tmp_path: Path) -> Path:
    """A directory like the repository's root for the README's commands: ``.venv`` (the one
    running the tests) and ``tests`` linked in, everything written there."""
    (tmp_path / ".venv").symlink_to(Path(sys.prefix), target_is_directory=True)
    (tmp_path / "tests").symlink_to(ROOT / "tests", target_is_directory=True)
    (tmp_path / "profiles").symlink_to(ROOT / "profiles", target_is_directory=True)
    return tmp_path


def readme_tour() -> list[str]:
    blocks = sh_blocks(section(README, "A five-minute tour"))
    assert blocks[0].strip() == ". .venv/bin/activate"
    return blocks


def test_the_tour_has_its_steps():
    """The extraction sees every step (a tour the test cannot find would pass empty)."""
    text = "\n".join(readme_tour())
    for command in ("virtual-robot simulate", "hil run", "hil identify", "hil control --compare",
                    "hil diagnose", "--format dfki"):  # fmt: skip
        assert command in text, command
    tutorial = "\n".join(sh_blocks(section(TUTORIAL, None)))
    for command in ("pip install", "virtual-robot simulate", "hil identify", "hil diagnose",
                    "tests/data/dfki"):  # fmt: skip
        assert command in tutorial, command


def test_the_tours_real_data_block(tmp_path):
    """The tour's last step on its own: the shipped DFKI recording identified and diagnosed,
    its HTML report written."""
    blocks = readme_tour()
    real = [b for b in blocks if "tests/data/dfki" in b]
    assert len(real) == 1
    cwd = tour_dir(tmp_path)
    run_blocks([blocks[0], *real], cwd, timeout=300)
    assert (cwd / "runs/tour/dfki-identify/identify.json").is_file()
    html = (cwd / "runs/tour/dfki-diagnosis.html").read_text()
    assert "I cannot say the model is complete" in html and "Held at zero" in html


@pytest.mark.slow
def test_readme_tour_runs_as_written(tmp_path):
    cwd = tour_dir(tmp_path)
    run_blocks(readme_tour(), cwd, timeout=1800)
    for report in ("identify", "compare", "diagnosis", "dfki-diagnosis"):
        assert (cwd / f"runs/tour/{report}.html").stat().st_size > 10_000
    assert "coulomb_asymmetry" in (cwd / "runs/tour/diagnosis.html").read_text()


@pytest.mark.slow
def test_tutorial_runs_from_a_fresh_clone(tmp_path):
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout: the tutorial test clones it")
    clone = tmp_path / "ddbench"
    subprocess.run(["git", "clone", "--quiet", str(ROOT), str(clone)], check=True, timeout=300)
    blocks = sh_blocks(section(TUTORIAL, None))
    assert "python3 -m venv .venv" in blocks[0]
    run_blocks(blocks, clone, timeout=3000)
    assert (clone / "runs/tutorial/identify/params.json").is_file()
    assert "coulomb_asymmetry" in (clone / "runs/tutorial/diagnosis.html").read_text()


def test_the_add_an_arm_guide_runs_as_written(tmp_path):
    """docs/howto-add-an-arm.md: a profile of the user's own URDF simulated, driven over a
    bench, identified and diagnosed, each block as written (about 15 s of CPU)."""
    import json

    blocks = sh_blocks(section(ADD_AN_ARM, None))
    assert blocks[0].startswith(". .venv/bin/activate") and len(blocks) == 4
    cwd = tour_dir(tmp_path)
    run_blocks(blocks, cwd, timeout=600)
    arm = cwd / "runs/howto-arm"
    assert json.loads((arm / "hil/meta.json").read_text())["status"] == "complete"
    identified = json.loads((arm / "identify/identify.json").read_text())
    assert identified["model"] == "urdf"
    assert json.loads((arm / "diagnosis.json").read_text())["findings"] == []
