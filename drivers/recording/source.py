"""The recording a parameter file was identified from: its fingerprint, written beside the
parameters (`hil identify`), and the file found again by it (`hil diagnose --params`, which
then compares a new recording with that one: docs/diagnosis.md, "Against the model you have").

A fingerprint is the SHA-256 of the recording's data (the CSV file, or a run directory's
signals.csv) and its absolute path when identified. The file is looked for where the
parameter file says it was (as given, then beside the parameter file, then the absolute path)
and used only when its data are unchanged.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from drivers.recording.format import SIGNALS

SHA256 = "recording_sha256"
RESOLVED = "recording_resolved"


def _data_file(path: Path) -> Path | None:
    data = path / SIGNALS if path.is_dir() else path
    return data if data.is_file() else None


def _sha256(data: Path) -> str:
    digest = hashlib.sha256()
    with data.open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def fingerprint(path: str | Path | None) -> dict[str, str]:
    """``{recording_sha256, recording_resolved}`` of the recording at ``path`` (a CSV file or a
    run directory); empty when there is none (a bench run that wrote no file)."""
    if path is None:
        return {}
    data = _data_file(Path(path))
    if data is None:
        return {}
    return {SHA256: _sha256(data), RESOLVED: str(Path(path).resolve())}


def find_source(document: Mapping[str, Any], beside: str | Path) -> Path | None:
    """The recording a parameter ``document`` (params.json, identify.json) was identified from,
    unchanged since (its fingerprint matches), else None: looked for as the document names it
    (from the working directory), then in the directory of the file ``beside`` (the parameter
    file), then at its absolute path when identified."""
    named, sha = document.get("recording"), document.get(SHA256)
    if not (isinstance(named, str) and isinstance(sha, str)):
        return None
    places = [Path(named), Path(beside).parent / Path(named).name]
    if isinstance(document.get(RESOLVED), str):
        places.append(Path(document[RESOLVED]))
    for place in places:
        data = _data_file(place)
        if data is not None and _sha256(data) == sha:
            return place
    return None
