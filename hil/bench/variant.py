"""A copy of a bench profile with some top-level fields changed (e.g. the period of a timing run).

The virtual robot reads the bench profile *file* it is given, so a run at another rate (or with
another feedback timeout, or another bus setting) needs a profile file that says so: the source
text with the changed lines, every comment and table kept, written next to the recording and
checked by loading it.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

from profiles.bench import BenchProfile, load_bench


def toml_value(value: Any) -> str:
    """``value`` as a TOML value (bool, int, float, str, lists and tables of those)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)  # a TOML basic string
    if isinstance(value, list | tuple):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {toml_value(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"no TOML form for {type(value).__name__}")


def write_bench_variant(
    source: str | Path, dest: str | Path, overrides: dict[str, Any], *, by: str = "hil"
) -> BenchProfile:
    """Write ``source`` with the top-level ``overrides`` to ``dest``; return it loaded.

    A key already set at the top level is replaced on its line; a new one is added before the
    first table. Raises ProfileError (one line) if the result is not a valid bench profile.
    """
    source, dest = Path(source), Path(dest)
    lines = source.read_text(encoding="utf-8").splitlines()
    first_table = next((i for i, line in enumerate(lines) if re.match(r"\s*\[", line)), len(lines))
    for key, value in overrides.items():
        if not re.fullmatch(r"[A-Za-z0-9_-]+", key):
            raise ValueError(f"bench override key {key!r} is not a bare TOML key")
        pattern = re.compile(rf"\s*{re.escape(key)}\s*=")
        line = f"{key} = {toml_value(value)}  # set by {by}"
        at = next((i for i in range(first_table) if pattern.match(lines[i])), None)
        if at is None:
            lines.insert(first_table, line)
            first_table += 1
        else:
            lines[at] = line
    changed = ", ".join(f"{k} = {toml_value(v)}" for k, v in overrides.items())
    header = f"# {source.name} with {changed} ({by}); source: {source}"
    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_text(header + "\n" + "\n".join(lines) + "\n", encoding="utf-8")
    return load_bench(dest)


__all__ = [
    "write_bench_variant",
]
