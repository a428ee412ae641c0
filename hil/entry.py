"""The ``hil`` console entry point: exit signals first, then the command line.

SIGTERM and SIGHUP are set to behave like Ctrl-C before anything heavy is imported, and a
Ctrl-C (or either signal) that lands while the command line is still being imported ends with
one line, not a traceback (:func:`drivers.process.run_command_line`, which ``python -m hil.cli``
passes through too). Everything else is :func:`hil.cli.main`.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence

from drivers.process import run_command_line


def _load_cli() -> Callable[[Sequence[str] | None], int]:
    from hil.cli import main as cli_main

    return cli_main


def main(argv: Sequence[str] | None = None) -> int:
    return run_command_line("hil", _load_cli, argv)


if __name__ == "__main__":
    sys.exit(main())
