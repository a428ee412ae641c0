"""Running experiments over a bench: the loop runner, one recorded run, the virtual robot's
process, and executors for batches of runs.

What lives here: the loop (:mod:`.loop`, one command per period over any
:class:`drivers.arm.Arm`, not knowing the transport) with its deadline scheduler
(:mod:`.scheduler`) and per-cycle timing statistics (:mod:`.timing_stats`); ``hil run``
(:mod:`.run`); starting and stopping the virtual robot (:mod:`.launch`); a bench profile with
fields changed (:mod:`.variant`); serial, process-pool and Dask executors for batches of runs
(:mod:`.jobs`, :mod:`.executors`, :mod:`.executors_dask`).

Imports: :mod:`drivers`, :mod:`profiles`; nothing from the other ``hil`` packages (they all
run over a bench through this one).
"""
