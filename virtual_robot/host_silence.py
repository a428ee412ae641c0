"""The host-silence check the CAN servers share (virtual_robot.can_server,
virtual_robot.loop_server): a host silent for ``timeout_s`` of wall time fires once, and again
only after the host has spoken since.

Imports: the standard library only.
"""

from __future__ import annotations

import time


class HostSilence:
    """When the host was last heard, and whether its silence has already fired."""

    def __init__(self, timeout_s: float | None) -> None:
        self.timeout_s = timeout_s  # None: never fires
        self.last_rx: float | None = None  # time.monotonic() of the last frame; None: none yet
        self.fired = False

    def heard(self, now: float | None = None) -> None:
        """A frame from the host arrived (at ``now``, default time.monotonic())."""
        self.last_rx = time.monotonic() if now is None else now
        self.fired = False

    def expired(self, now: float) -> bool:
        """True once when the host has been silent for more than ``timeout_s`` at ``now``
        (after having spoken at least once); the caller then stops the drives."""
        if (
            self.timeout_s is None
            or self.last_rx is None
            or self.fired
            or now - self.last_rx <= self.timeout_s
        ):
            return False
        self.fired = True
        return True


__all__ = ["HostSilence"]
