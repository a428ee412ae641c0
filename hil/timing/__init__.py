"""Realtime timing studies: jitter measurement, timing-fault sweeps, replay, bus load.

What lives here: the ``hil jitter`` command (:mod:`.jitter_cli`, :mod:`.jitter_plots`), CAN bus
load from a traffic log (:mod:`.bus_load`), sweeps of injected timing faults over control and
identification (:mod:`.sweep`, :mod:`.sweep_plots`) and replay of a realtime run in lockstep
with its timing imposed (:mod:`.replay`, :mod:`.replay_cli`). The scheduler the loop runs on and
the per-cycle statistics live in :mod:`hil.bench` (the loop needs them; studies read them).

Imports: :mod:`hil.bench`, :mod:`hil.model`, :mod:`hil.control` and :mod:`hil.identify` (a
sweep tracks and identifies), :mod:`hil.cli_options`. Nothing imports this package but the
command line.

Public API (``from hil.timing import ...``): ``replay_run`` (``hil replay``) and
``cyclic_bus_load`` (bus load from a ``bus.log``); the sweeps run from the command line
(``hil jitter --sweep``). Each loads on first use.
"""

from hil import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "hil.timing.replay": ["replay_run", "format_replay"],
        "hil.timing.bus_load": ["cyclic_bus_load", "read_candump"],
    },
)
