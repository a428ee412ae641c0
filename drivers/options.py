"""Values of command-line options that both command lines (``hil``, ``virtual-robot``) parse.

The virtual robot may not import ``hil``, so a parser both sides need lives here once.

Imports: the standard library only.
"""

from __future__ import annotations

import math
from collections.abc import Callable

__all__ = ["float_list", "host_port"]


def host_port(text: str, option: str) -> tuple[str, int]:
    """``HOST:PORT`` (HOST may be empty: 127.0.0.1; PORT an integer in 1..65535) from option
    ``option``'s ``text``; anything else is a ValueError of one line saying what is expected."""
    host, sep, port = str(text).strip().rpartition(":")
    problem = (
        f"{option} takes HOST:PORT with PORT an integer in 1..65535 (what `virtual-robot "
        f"serve` announced, e.g. 127.0.0.1:29536), got {text!r}"
    )
    if not sep or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(problem)
    return host or "127.0.0.1", int(port)


def float_list(
    text: str, option: str, count: int, what: str, valid: Callable[[float], bool]
) -> tuple[float, ...]:
    """``count`` comma-separated finite numbers, each ``valid``, from option ``option``'s
    ``text``; anything else is a ValueError of one line: ``OPTION takes COUNT WHAT,
    comma-separated, got 'TEXT'`` (``what`` names the numbers and their range)."""
    problem = f"{option} takes {count} {what}, comma-separated, got {text!r}"
    try:
        values = tuple(float(item) for item in text.split(","))
    except ValueError:
        raise ValueError(problem) from None
    if len(values) != count or not all(math.isfinite(v) and valid(v) for v in values):
        raise ValueError(problem)
    return values
