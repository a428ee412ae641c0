"""The ``hil`` console entry point: exit signals first, then the command line.

SIGTERM and SIGHUP are set to behave like Ctrl-C before anything heavy is imported, and a
Ctrl-C (or either signal) that lands while the command line is still being imported ends with
one line, not a traceback. Everything else is :func:`hil.cli.main`.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from drivers.process import install_exit_signals, interrupt_exit_code, interrupt_reason


def main(argv: Sequence[str] | None = None) -> int:
    install_exit_signals()
    try:
        from hil.cli import main as cli_main

        code = cli_main(argv)
    except KeyboardInterrupt:
        print(f"hil: {interrupt_reason()}; nothing was running yet", file=sys.stderr)
        return interrupt_exit_code()
    # the commands return 130 for an interrupted run; a shell reports 128 + the signal's number
    return interrupt_exit_code() if code == 130 else code


if __name__ == "__main__":
    sys.exit(main())
