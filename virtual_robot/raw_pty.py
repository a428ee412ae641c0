"""A raw pseudo-terminal for the virtual robot's serial-style transports (slcan, Gemini dialect)."""

from __future__ import annotations

import os
import tty


def open_raw_pty(*, keep_slave_open: bool) -> tuple[int, int | None, str]:
    """A new pty: (non-blocking master fd, slave fd or None, slave path).

    The slave is raw (no echo, no CR/LF translation), which persists while the master lives.
    ``keep_slave_open=False`` closes our handle on the slave, so a host closing the port shows as
    EIO on the master; ``True`` keeps it, so reads between host sessions see no EIO at all.
    """
    master, slave = os.openpty()
    try:
        path = os.ttyname(slave)
        tty.setraw(slave)
        os.set_blocking(master, False)
    except OSError:
        os.close(master)
        os.close(slave)
        raise
    if not keep_slave_open:
        os.close(slave)
        return master, None, path
    return master, slave, path
