"""What the host drivers of drives that run their own loop share (MIT mode: :mod:`.mit_arm`,
ODrive CANSimple: :mod:`.odrive_arm`, moteus: :mod:`.moteus_arm`): the constructor (the link's
settings, one bus opened by a factory, each drive checked to speak the protocol), the bus's
life cycle, and the safe stop's rule: every drive is sent its stop steps, each on its own, and
the first failure is raised after all were tried (one drive that does not answer does not keep
the others powered).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from typing import Any, Unpack

import can

from drivers.arm import Arm, LinkError, LinkSettings
from profiles.drive import DriveProfile


class BusArm(Arm):
    """N drives of one protocol on one bus; joint j is ``drives[j]`` at id ``node_id``.
    A subclass names its protocol's table (:attr:`table`: the drive profile's attribute that
    only drives of that protocol have) and its :attr:`label`."""

    table = ""  # "mit", "odrive", "moteus": DriveProfile's table of the protocol
    label = ""  # how errors name the arm

    def __init__(
        self,
        bus_factory: Callable[[], can.BusABC],
        drives: Sequence[DriveProfile],
        **link: Unpack[LinkSettings],
    ) -> None:
        self._init_link(drives, **link)
        for p in self.drives:
            if getattr(p, self.table) is None:
                raise ValueError(f"{p.source}: drive {p.model} does not speak {self.label}")
        self._bus_factory = bus_factory
        self.bus: can.BusABC | None = None
        self.ids: tuple[int, ...] = tuple(p.node_id for p in self.drives)
        self._errors = [0] * self.n_joints
        self._started = False

    # ---- link ---------------------------------------------------------------------------------
    def open(self) -> None:
        self.bus = self._bus_factory()
        self.opened_at = time.monotonic()

    def close(self) -> None:
        bus, self.bus = self.bus, None
        if bus is not None:
            bus.shutdown()

    def _bus(self) -> can.BusABC:
        if self.bus is None:
            raise LinkError(f"{self.label} arm: link not open")
        return self.bus

    # ---- safe stop ----------------------------------------------------------------------------
    def _stop_each(self, steps: Callable[[int], Iterable[Callable[[], Any]]]) -> None:
        """Run ``steps(j)`` (callables) for every drive j, every step tried; the first failure
        is raised after all were."""
        first: Exception | None = None
        for j in range(self.n_joints):
            for step in steps(j):
                try:
                    step()
                except Exception as exc:
                    first = first or exc
        if first is not None:
            raise first

    def traffic_log(self) -> str | None:
        return None

    def __repr__(self) -> str:
        return f"{type(self).__name__}(ids={self.ids}, mode={self.mode!r})"


__all__ = ["BusArm"]
