"""A compiler that fails, for the compiled kernels' fallback tests (tests/test_compiled_step.py,
tests/test_openloop_compiled.py): a script that notes each run and prints one error."""

from __future__ import annotations

import stat
from pathlib import Path


def failing_compiler(where: Path, error: str) -> tuple[Path, Path]:
    """(the compiler's path, the file it appends "run" to on each call); it prints ``error``
    on stderr and exits 1."""
    calls = where / "calls"
    compiler = where / "failing-compiler"
    compiler.write_text(f'#!/bin/sh\necho run >> "{calls}"\necho "{error}" >&2\nexit 1\n')
    compiler.chmod(compiler.stat().st_mode | stat.S_IXUSR)
    return compiler, calls
