"""The three paths of `hil identify`, each from its options to its report, its text and the
parameter files to write (:class:`Outcome`); :mod:`hil.identify.cli` parses, calls one, prints
and writes. Every path fits through :func:`hil.identify.identification.identify`:

* the Table II path (:func:`run_table_ii`): a 2-DOF arm without model terms, a run over a bench
  or a recording in this project's layout; the paper's three schemes and recursive estimators,
  its two discretizations, Table II, validation on the fit and a held-out recording, and over a
  bench the online RLS (:class:`hil.identify.online.OnlineIdentifier`) with its check against
  the batch computation. A realtime run is read as `--from` reads it, on its real sample times
  (drivers/realtime_times.py); the online RLS takes each row on its real interval too, from the
  host's stamps as they come (:class:`drivers.realtime_times.HostStampRows`);
* the model-object path (:func:`run_identify_model`): a 2-DOF arm with model terms or a foreign
  recording; bounded estimate, uncertainty, the profile's θ side by side;
* the URDF path (:func:`run_identify_urdf`): the base parameters of an n-joint arm by each scheme,
  each validated on the same held-out torque rows.

One module per path (:mod:`.table_ii`, :mod:`.model_path`, :mod:`.urdf_path`) and what they
share (:mod:`.outcome`); they import :mod:`hil.bench` (to record over a bench),
:mod:`hil.cli_options`, :mod:`hil.model` and :mod:`drivers`, and write plots
(:mod:`hil.identify.plots`), not identify.json or params.json.
"""

from hil.identify.model_path import (
    bench_model_path,
    model_path,
    record_then_identify_model,
    run_identify_model,
)
from hil.identify.outcome import PAPER_LAMBDA_NOTE, Outcome
from hil.identify.table_ii import run_table_ii
from hil.identify.urdf_path import run_identify_urdf, urdf_robot

__all__ = [
    "PAPER_LAMBDA_NOTE",
    "Outcome",
    "bench_model_path",
    "model_path",
    "record_then_identify_model",
    "run_identify_model",
    "run_identify_urdf",
    "run_table_ii",
    "urdf_robot",
]
