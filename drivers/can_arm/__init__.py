"""CiA 402 drives over CAN: the :class:`~drivers.arm.Arm` of the host on any python-can bus.

The package, by capability (:class:`CanArm` in :mod:`.arm` is composed of the mixins):

* :mod:`.objects`: the object dictionary for canopen, the PDO layout and codecs, frame
  decoding (pure);
* :mod:`.setup`: connect, confirm each drive against its profile, configure the PDOs by SDO,
  NMT start, close; the SDO helpers;
* :mod:`.power`: the CiA 402 power state machine from the host (enable, disable, faults, fault
  reset): the safe stop;
* :mod:`.cycle`: RPDOs + SYNC and the feedback of every drive (lockstep and realtime), counts
  to rad, the safety limits;
* :mod:`.link`: sending, the traffic log, the receive thread and the dispatch of what arrives.

Set-up uses the ``canopen`` library the way a CANopen tool would: a :class:`canopen.Network` on
the bus, one :class:`canopen.RemoteNode` per drive with an object dictionary built from
:data:`drivers.protocol.cia402.OBJECTS`, NMT through ``node.nmt`` and every configuration
object (identity, rated torque, encoder resolution, the PDO map, the mode) by SDO.

The cyclic path packs PDOs directly (precompiled structs, not canopen's PdoMap): per period one
RPDO1 per drive (controlword + target torque), then SYNC, then TPDO1 (statusword + position)
and TPDO2 (velocity + torque actual) from every drive. Frames go out through the bus's
``send_frames`` where it has one (:class:`drivers.slcan.SelectSlcanBus`: one write for all),
else one ``send`` each.

Who reads the bus: a receive thread (python-can's Notifier's job) reads every frame and feeds
canopen and the feedback collector. In lockstep the cycle sends RPDOs and SYNC in one write
and reads the feedback in its own thread: the receive thread is paused from :meth:`start` on,
which saves a thread hand-over per cycle, and gets the bus back as soon as canopen sends
anything (the SDO of faults(), disable(), ...; from another thread, after the cycle in
progress). Realtime keeps the receive thread: RPDOs go out at once, the SYNC at the deadline.

Measured with ``tests/benchmarks/bench_can_cycle.py`` (python-can ``virtual`` bus, lockstep
virtual robot + CanDriveServer in threads of the same process, 2 drives, traffic log off; 8
alternating blocks of 250 cycles, medians of two runs on the 2-core machine, quiet; µs per
cycle):

    path                                          wall       host CPU (main + receive thread)
    raw (CanArm.cycle, incl. clamp, units,        305-312    124-134  (124-134 + 0)
      limit checks; reads the bus itself)
    canopen PDO machinery (PdoMap vars,           390-394    198-209  (150-162 + 46-48)
      transmit(), sync.transmit(), callbacks)

The server thread costs another 185-190 µs per cycle either way. The raw path costs the host
about 35 % less CPU and the cycle about 80 µs less wall time, and it also does more (clamp,
limits). The cycle uses the raw path; canopen does NMT, SDO and the 402 set-up. Over slcan to
the virtual robot process see docs/benchmarks.md.

Time: ``Sample`` times are host seconds since :meth:`open` connected (``Arm.now()``). Lockstep:
``t`` = k·h and ``sent_at`` = ``received_at`` = ``deadline`` = ``t`` (the link's clock);
realtime: RPDOs go out at once (the drive applies them on arrival), SYNC at ``deadline``,
``t`` = SYNC send time; feedback later than one period is a timing event
(``stats.late_feedback``), later than ``feedback_budget_s`` (bench profile) a dead link; a
receive error (closed pty or socket) or a dead robot process ends the wait at once.

Log: every frame sent and received goes to ``log_path`` in ``candump -L`` format, the lines
python-can's :class:`can.CanutilsLogWriter` writes (:class:`drivers.candump.CandumpWriter`,
readable with :class:`can.LogReader`), flushed every 50 frames and on close. Sent frames are
marked ``T`` (``is_rx = False``), received ones ``R``, stamped when sent or read. In lockstep a
cycle's lines are written just after the next write to the bus, while the drives work on it.

Imports: :mod:`drivers.arm`, :mod:`drivers.candump`, :mod:`drivers.protocol`,
:mod:`drivers.units`, :mod:`profiles`; canopen, python-can.
"""

from drivers.can_arm.arm import CanArm
from drivers.can_arm.objects import (
    EMCY,
    HEARTBEAT,
    PDO_LAYOUT,
    TPDO1,
    TPDO2,
    Frame,
    build_object_dictionary,
    fault_text,
    frame_routes,
    parse_frame,
)

__all__ = [
    "EMCY",
    "HEARTBEAT",
    "PDO_LAYOUT",
    "TPDO1",
    "TPDO2",
    "CanArm",
    "Frame",
    "build_object_dictionary",
    "fault_text",
    "frame_routes",
    "parse_frame",
]
