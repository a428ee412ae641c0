"""The ``virtual-robot`` console entry point: exit signals first, then the command line.

SIGTERM and SIGHUP are set to behave like Ctrl-C before :mod:`virtual_robot.cli` and what it
imports (numpy, the profiles, the recording format) load, so a signal that lands during that
import ends with one line and 128 + its number (:func:`drivers.process.run_command_line`), not
a traceback or, for SIGHUP, a silent death. Everything else is :func:`virtual_robot.cli.run`.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence

from drivers.process import run_command_line


def _load_cli() -> Callable[[Sequence[str] | None], int]:
    from virtual_robot.cli import run

    return run


def main(argv: Sequence[str] | None = None) -> int:
    return run_command_line("virtual-robot", _load_cli, argv)


if __name__ == "__main__":
    sys.exit(main())
