"""The virtual robot: plant physics, effects, drive emulation and protocol servers.

What lives here: the world (:mod:`.plant`, :mod:`.dynamics`, :mod:`.effects`; the n-joint
:mod:`.urdf_plant` with its compiled RK4 step, :mod:`.compiled_step`; the stick–slip step both
plants take, :mod:`.stick_slip`), the CiA 402
drive model (:mod:`.drive`), the drives with their own loop (:mod:`.loop_drive`: the MIT-mode
one, :mod:`.mit_drive`, stepped offline by :mod:`.mit_simulate`, and the ODrive axis,
:mod:`.odrive_drive`, stepped offline by :mod:`.odrive_simulate`, and the moteus controller,
:mod:`.moteus_drive`, stepped offline by :mod:`.moteus_simulate`; their lockstep core and
offline recording, :mod:`.loop_offline`), the robot behind any
transport in lockstep or realtime (:mod:`.robot`), the transports (:mod:`.can_server`,
:mod:`.loop_server` with :mod:`.mit_server`, :mod:`.odrive_server` and :mod:`.moteus_server`,
their shared host-silence check :mod:`.host_silence`, :mod:`.slcan_device`,
:mod:`.fdcanusb_device`,
:mod:`.socketcand_hub`, :mod:`.serial_server`, :mod:`.raw_pty`), robot-side timing faults and
CAN bit time (:mod:`.timing_faults`, :mod:`.bus_pacing`), and the ``virtual-robot`` command
(:mod:`.serve`, :mod:`.simulate`, :mod:`.cli`).

Imports: :mod:`drivers` (the protocol codecs, units, the recording format, transports) and
:mod:`profiles`, :mod:`plots` (a simulation's positions.png); never ``hil``, and ``hil`` never
imports it (the plant is the world; the in-process bench loads :mod:`.serve` by name).
"""

__version__ = "0.1.0"
