"""What the client-library tests of the drives with their own loop share (MIT mode: test_mit.py,
ODrive: test_odrive.py, moteus: test_moteus.py): a server of the virtual robot running in a
thread for the length of a ``with`` block, on the bus it was given or on python-can's in-process
``virtual`` bus."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator
from typing import TypeVar

import can

from virtual_robot.loop_server import LoopDriveServer
from virtual_robot.robot import VirtualRobot

S = TypeVar("S", bound=LoopDriveServer)


@contextlib.contextmanager
def serving(server: S) -> Iterator[S]:
    """``server`` answering frames in a thread until the block ends; its bus is shut down."""
    stop = threading.Event()
    thread = threading.Thread(target=server.serve_forever, args=(stop,), daemon=True)
    thread.start()
    try:
        yield server
    finally:
        stop.set()
        thread.join()
        server.bus.shutdown()


def served_on(
    server_class: type[S], core: VirtualRobot, channel: str, **kw: object
) -> contextlib.AbstractContextManager[S]:
    """``server_class`` serving ``core`` on python-can's virtual bus ``channel`` (kw: the
    server's idle_timeout_s, log)."""
    bus = can.Bus(interface="virtual", channel=channel)
    return serving(server_class(core, bus, **kw))  # type: ignore[arg-type]
