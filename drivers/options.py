"""Values of command-line options that both command lines (``hil``, ``virtual-robot``) parse.

The virtual robot may not import ``hil``, so a parser both sides need lives here once.

Imports: the standard library only.
"""

from __future__ import annotations

import math
from collections.abc import Callable

__all__ = ["float_list"]


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
