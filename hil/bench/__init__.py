"""Running experiments over a bench: the loop runner, one recorded run, the virtual robot's
process, and executors for batches of runs.

What lives here: the loop (:mod:`.loop`, one command per period over any
:class:`drivers.arm.Arm`, not knowing the transport) with its deadline scheduler
(:mod:`.scheduler`) and per-cycle timing statistics (:mod:`.timing_stats`); ``hil run``
(:mod:`.run`); starting and stopping the virtual robot (:mod:`.launch`); a bench profile with
fields changed (:mod:`.variant`); serial, process-pool and Dask executors for batches of runs
(:mod:`.jobs`, :mod:`.executors`, :mod:`.executors_dask`).

Imports: :mod:`drivers`, :mod:`profiles`, :mod:`plots` (a run's positions.png); nothing from
the other ``hil`` packages (they all run over a bench through this one).

Public API (``from hil.bench import ...``, docs/api.md): ``run_experiment`` (record an
experiment over a bench, as ``hil run`` does), ``run_loop`` (any command function over any
``Arm``), the virtual robot's process, executors and the rest of ``__all__``; each loads on
first use.
"""

from hil import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "hil.bench.run": [
            "run_experiment",
            "record_over_bench",
            "check_bench",
            "BenchRun",
            "UsageError",
        ],
        "hil.bench.loop": ["run_loop", "LoopResult", "DriveFaultError"],
        "hil.bench.launch": ["VirtualRobotProcess", "LaunchError"],
        "hil.bench.variant": ["write_bench_variant"],
        "hil.bench.scheduler": ["DeadlineScheduler", "realtime_scheduling"],
        "hil.bench.timing_stats": ["timing_statistics", "jitter_summary"],
        "hil.bench.executors": ["make_executor", "SerialExecutor", "LocalProcessExecutor"],
    },
)
