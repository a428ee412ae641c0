"""Several hosts on one bus (shared by tests/test_attach.py, on the socketcand hub, and
tests/test_host_claim.py, on buses without one)."""

from __future__ import annotations

import threading

from drivers.arm import Arm, LinkError


def open_together(arms: list[Arm]) -> list[str]:
    """Open every arm at once (a barrier releases their threads together): each's outcome,
    "open" or its LinkError."""
    barrier = threading.Barrier(len(arms))
    outcomes = [""] * len(arms)

    def attach(i: int) -> None:
        barrier.wait()
        try:
            arms[i].open()
            outcomes[i] = "open"
        except LinkError as exc:
            outcomes[i] = str(exc)

    threads = [threading.Thread(target=attach, args=(i,)) for i in range(len(arms))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=120)
    return outcomes
