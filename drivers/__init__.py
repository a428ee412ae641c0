"""Drive protocol codecs, host-side drive classes, transports and safety limits.

What lives here: shared by both ends, the protocol codecs (:mod:`.protocol`: CiA 402, the Gemini
serial dialect, the MIT mode of AK actuators and ODrive CANSimple), units (:mod:`.units`), the
recording format and reader (:mod:`.recording`), recordings in other containers (.npz, MCAP, CSVs
joined on time: :mod:`.containers`), a realtime run's real sample and command times
(:mod:`.realtime_times`), exit signals and run status (:mod:`.process`), logging
(:mod:`.logsetup`), option values both command lines parse (:mod:`.options`), the candump writer
(:mod:`.candump`); on the host side, the drive API and safety limits (:mod:`.arm`), CiA 402 over
python-can (:mod:`.can_arm`), MIT mode over python-can (:mod:`.mit_arm`), ODrive CANSimple over
python-can (:mod:`.odrive_arm`), moteus over an fdcanusb (:mod:`.moteus_arm`,
:mod:`.fdcanusb`; the base of these three: :mod:`.bus_arm`), the Gemini dialect over pyserial
(:mod:`.serial_arm`), bench
profile to transport to ``Arm`` (:mod:`.links`), python-can's slcan without its busy-wait
(:mod:`.slcan`) and host-side timing faults (:mod:`.fault_injection`).

No package-level API: import from the modules (``from drivers.recording import read_signals,
Recording``; docs/api.md), each of which lists its public names in ``__all__``.

Imports: :mod:`profiles`; nothing of ``hil`` or ``virtual_robot`` (tests/test_layout.py).
"""
