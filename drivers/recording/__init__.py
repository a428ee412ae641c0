"""The recording format (docs/design.md): a run directory with signals.csv, meta.json, plots.

Row k of signals.csv: t = k·h; q = encoder reading sampled at t; tau = torque commanded at t and
held over [t, t + h) (zero-order hold), after quantization. Base columns t,q1,q2,tau1,tau2 in
s, rad, Nm (an n-joint arm: t,q1..qn,tau1..taun, :func:`base_columns`); more columns may
follow. Rows are written as they happen and flushed often, so a
crash leaves a readable partial recording; :func:`read_signals` reads one, dropping at most a
torn last line.

Shared by the host (``hil``) and the virtual robot's offline simulation, like the protocol codecs.
One module per piece: :mod:`.format` (file names, base columns, the error type, strict JSON),
:mod:`.writer` (:class:`RecordingWriter`, the run's .mcap), :mod:`.data` (the
:class:`Recording` type and the reader's limits), :mod:`.columns` (column maps and the torque
plan), :mod:`.reader` (:func:`read_signals`), :mod:`.checks` (time stamps, values, assembly),
:mod:`.source` (the fingerprint of the recording a parameter file was identified from, and
finding it again).
The plot of a recording is :func:`plots.positions.plot_positions` (plots stay out of drivers/).
Imports: :mod:`drivers.containers`, :mod:`drivers.process`, :mod:`profiles`.
"""

from drivers.recording.checks import reassemble
from drivers.recording.columns import parse_column_map
from drivers.recording.data import GAP_FACTOR, MAX_ABS_VALUE, MAX_LINE_CHARS, Recording
from drivers.recording.format import (
    BASE_COLUMNS,
    META,
    SIGNALS,
    RecordingError,
    base_columns,
    dumps_strict,
    strict_json,
    write_json_atomic,
)
from drivers.recording.reader import read_signals, recording_names
from drivers.recording.writer import RecordingWriter, write_run_mcap

__all__ = [
    "BASE_COLUMNS",
    "GAP_FACTOR",
    "MAX_ABS_VALUE",
    "MAX_LINE_CHARS",
    "META",
    "SIGNALS",
    "Recording",
    "RecordingError",
    "RecordingWriter",
    "base_columns",
    "dumps_strict",
    "parse_column_map",
    "read_signals",
    "reassemble",
    "recording_names",
    "strict_json",
    "write_json_atomic",
    "write_run_mcap",
]
