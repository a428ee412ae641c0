"""MkDocs hook: the page ``cli-reference.md``, generated at build time from the commands' own
argparse help (``hil COMMAND --help``, ``virtual-robot COMMAND --help``), so the reference
cannot drift from the code. Listed under ``hooks:`` in mkdocs.yml; not a page itself."""

from __future__ import annotations

import os
import subprocess
import sys

from mkdocs.config.defaults import MkDocsConfig
from mkdocs.structure.files import File, Files

COMMANDS = {
    "hil": ["run", "demo", "identify", "control", "excite", "diagnose", "jitter", "replay"],
    "virtual-robot": ["simulate", "serve"],
}
MODULES = {"hil": "hil.cli", "virtual-robot": "virtual_robot.cli"}


def _help(program: str, command: str | None) -> str:
    args = [sys.executable, "-m", MODULES[program], *([command] if command else []), "--help"]
    env = {**os.environ, "COLUMNS": "100"}
    done = subprocess.run(args, capture_output=True, text=True, env=env, check=True, timeout=120)
    return done.stdout.replace(f"usage: {MODULES[program].replace('.', '/')}", "usage: ")


def render() -> str:
    parts = [
        "# Command-line reference",
        "",
        "Generated from each command's `--help` when the site is built "
        "(`docs/hooks/cli_reference.py`). How the commands are built: [cli.md](cli.md); "
        "examples: [usage.md](usage.md).",
    ]
    for program, commands in COMMANDS.items():
        parts += ["", f"## `{program}`", "", "```text", _help(program, None).rstrip(), "```"]
        for command in commands:
            parts += ["", f"### `{program} {command}`", ""]
            parts += ["```text", _help(program, command).rstrip(), "```"]
    return "\n".join(parts) + "\n"


def on_files(files: Files, config: MkDocsConfig) -> Files:
    files.append(File.generated(config, "cli-reference.md", content=render()))
    return files
