"""The CiA 402 power state machine from the host, and the safe stop: enable (shutdown, switch
on, enable operation, each confirmed by SDO 0x6041; a keep-alive thread feeds the command
watchdog in realtime), disable (torque 0 and controlword 0 by RPDO, then by SDO with short
timeouts), the drives' faults (0x603F, EMCY where SDO fails) and fault reset.

:class:`PowerStates` is a mixin of :class:`~drivers.can_arm.CanArm`.

Imports: :mod:`drivers.can_arm.objects`, :mod:`drivers.arm`.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator, Sequence

import can

from drivers.arm import Fault, LinkError
from drivers.can_arm.objects import REALTIME, RPDO1_CODEC, fault_text, one_line
from drivers.protocol import cia402 as co


class PowerStates:
    """Enable, disable, faults, fault reset (a mixin of CanArm)."""

    def _rpdo_frames(self, controlword: int, permille: Sequence[int]) -> list[tuple[int, bytes]]:
        pack = RPDO1_CODEC.pack  # cia402.pack_pdo(RPDO1_MAP, ...), precompiled
        return [
            (cob_id, pack(controlword, value))
            for cob_id, value in zip(self._rpdo_ids, permille, strict=True)
        ]

    def _send_rpdos(self, controlword: int, permille: Sequence[int]) -> None:
        self._send_frames(self._rpdo_frames(controlword, permille))

    def enable(self) -> None:
        """Shutdown, switch on, enable operation (RPDO, torque 0); each confirmed by SDO 0x6041.

        Realtime: the drives' command watchdog runs on their own period timer from the moment
        they are enabled, and an SDO round trip may outlast its periods (socketcand,
        a busy adapter); so while the last step is being confirmed, a keep-alive thread sends
        RPDO (enable operation, torque 0) every period. It stops before enable() returns.
        """
        self._require_open()
        zero = (0,) * self.n_joints
        steps = (
            (co.CW_SHUTDOWN, co.State.READY_TO_SWITCH_ON),
            (co.CW_SWITCH_ON, co.State.SWITCHED_ON),
            (co.CW_ENABLE_OPERATION, co.State.OPERATION_ENABLED),
        )
        for controlword, state in steps:
            try:
                self._send_rpdos(controlword, zero)
            except (can.CanError, RuntimeError) as exc:
                raise LinkError(f"cannot send RPDO: {one_line(exc)}") from exc
            if state is co.State.OPERATION_ENABLED and self.mode == REALTIME:
                with self._keep_alive():
                    self._wait_state(state)
            else:
                self._wait_state(state)

    @contextlib.contextmanager
    def _keep_alive(self) -> Iterator[None]:
        """RPDO enable operation + torque 0 to every drive once a period, in a thread."""
        stop = threading.Event()
        zero = (0,) * self.n_joints

        def run() -> None:
            while not stop.wait(self.period_s):
                try:
                    self._send_rpdos(co.CW_ENABLE_OPERATION, zero)
                except Exception as exc:  # the main thread's SDO will fail and say why
                    self._note_error(f"keep-alive RPDO: {one_line(exc)}")
                    return

        thread = threading.Thread(target=run, name="can-arm-keep-alive", daemon=True)
        thread.start()
        try:
            yield
        finally:
            stop.set()
            thread.join()

    def _wait_state(self, wanted: co.State) -> None:
        deadline = time.monotonic() + self.timeout_s
        pending = set(range(self.n_joints))
        while True:
            for j in sorted(pending):
                sw = self._sdo_read(j, 0x6041, 0)
                state = co.state_from_statusword(sw)
                if state is wanted:
                    pending.discard(j)
                elif state in (co.State.FAULT, co.State.FAULT_REACTION_ACTIVE):
                    code = self._sdo_read(j, 0x603F, 0)
                    raise LinkError(
                        f"node {self.node_ids[j]} in FAULT, error code 0x{code:04X} "
                        f"({fault_text(code)}): clear it with hil run --clear-faults (logged) "
                        "once its cause is gone"
                    )
            if not pending:
                return
            if time.monotonic() > deadline:
                j = min(pending)
                sw = self._sdo_read(j, 0x6041, 0)
                state = co.state_from_statusword(sw)
                raise LinkError(
                    f"node {self.node_ids[j]} not {wanted.name} within {self.timeout_s:g} s "
                    f"(statusword 0x{sw:04X}, {state.name if state else 'unknown state'})"
                )
            time.sleep(0.001)

    def disable(self) -> None:
        """RPDO torque 0 + controlword 0, then SDO 0x6040 = 0 per drive (short timeouts)."""
        if self.bus is None:
            raise LinkError("CAN link is not open")
        failures: list[str] = []
        try:
            self._send_rpdos(co.CW_DISABLE_VOLTAGE, (0,) * self.n_joints)
        except (can.CanError, RuntimeError) as exc:
            failures.append(f"RPDO: {one_line(exc)}")
        with self._short_sdo_timeouts():
            for j in range(self.n_joints):
                try:
                    self._sdo_write(j, 0x6040, 0, co.CW_DISABLE_VOLTAGE)
                except LinkError as exc:
                    failures.append(str(exc))
        if failures:
            raise LinkError("disable incomplete: " + "; ".join(failures))

    def faults(self) -> list[Fault]:
        """Active faults: 0x603F of every drive by SDO; EMCY records where SDO fails."""
        self._require_open()
        out: list[Fault] = []
        with self._short_sdo_timeouts():
            for j in range(self.n_joints):
                try:
                    code = self._sdo_read(j, 0x603F, 0)
                except LinkError:
                    fault = self._emcy.get(j)
                    if fault is not None:
                        out.append(fault)
                    continue
                if code != co.ERR_NONE:
                    out.append(Fault(j, code, fault_text(code)))
        return out

    def clear_faults(self) -> None:
        """Fault reset (controlword 0x80 then 0x00, by SDO) on every drive in FAULT."""
        self._require_open()
        for j in range(self.n_joints):
            sw = self._sdo_read(j, 0x6041, 0)
            state = co.state_from_statusword(sw)
            if state in (co.State.FAULT, co.State.FAULT_REACTION_ACTIVE) or j in self._emcy:
                self._sdo_write(j, 0x6040, 0, co.CW_FAULT_RESET)
                self._sdo_write(j, 0x6040, 0, co.CW_DISABLE_VOLTAGE)
                self._emcy.pop(j, None)


__all__ = ["PowerStates"]
