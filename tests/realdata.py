"""Where the real recordings of ../shared/realdata are: beside the repository (or beside a folder
holding it, for a git worktree), or under $DDBENCH_REALDATA. Tests that need them skip with a
message when they are absent (the Panda data is GPL-3 and never enters this tree)."""

from __future__ import annotations

import os
from pathlib import Path


def realdata(name: str) -> Path:
    """``shared/realdata/<name>``, found as the module docstring says (may not exist)."""
    if os.environ.get("DDBENCH_REALDATA"):
        return Path(os.environ["DDBENCH_REALDATA"]) / name
    repo = Path(__file__).resolve().parents[1]
    for parent in repo.parents:
        if (parent / "shared" / "realdata" / name).is_dir():
            return parent / "shared" / "realdata" / name
    return repo.parent / "shared" / "realdata" / name
