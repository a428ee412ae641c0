"""Figure margins without a draw.

``tight_layout`` (and the constrained layout) draw a figure once to measure its labels, then
``savefig`` draws it again: twice the cost of a figure, which a run directory of a dozen
figures pays a dozen times (the demo's identification step: 45 s of plots under load, 16 s with
fixed margins). Fixed margins, in inches, hold the tick and axis labels of this project's
figures at every size they are drawn at.
"""

from __future__ import annotations

from typing import Any


def fixed_margins(
    fig: Any,
    *,
    left_in: float = 0.9,
    right_in: float = 0.2,
    bottom_in: float = 0.6,
    top_in: float = 0.8,
    wspace: float = 0.3,
    hspace: float = 0.4,
) -> None:
    """Set ``fig``'s subplot margins in inches (room for tick labels, an axis label, a title
    and a suptitle) and the space between axes as a fraction of their size."""
    width, height = fig.get_size_inches()
    fig.subplots_adjust(
        left=left_in / width,
        right=1.0 - right_in / width,
        bottom=bottom_in / height,
        top=1.0 - top_in / height,
        wspace=wspace,
        hspace=hspace,
    )
