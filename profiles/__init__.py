"""Profiles: TOML data (robots, drives, effects, experiments, benches) and their typed views.

A profile is named by a bare name (``cicese``), looked up among the package's own TOML files, or
by a path to any TOML file. Every field is checked on load; a bad one raises :class:`ProfileError`
whose message is one line naming the file and the field.

What lives here: the lookup and checked reading (:mod:`.loader`); one module per kind with its
typed view and loader: robots (:mod:`.robot`, ``load_robot``, ``load_urdf_robot``), drives
(:mod:`.drive`), benches (:mod:`.bench`), effects (:mod:`.effects`), experiments
(:mod:`.experiment`), recording formats (:mod:`.recording_format`), tracking
(:mod:`.tracking`), timing faults and traces (:mod:`.timing_faults`); the host limits per joint
that a bench's or a URDF robot's ``[limits]`` holds (:mod:`.limits`).

Public API (``from profiles import load_robot``, docs/api.md): the loaders and profile types
below. They are imported eagerly: every module here is small and needs only numpy.

Imports: the standard library and numpy; nothing of ``hil``, ``drivers`` or ``virtual_robot``
(a robot profile names the model terms its arm has; :mod:`hil.model` builds the model object).
"""

from profiles.bench import BenchProfile, load_bench
from profiles.drive import DriveProfile, load_drive
from profiles.effects import EffectsProfile, load_effects
from profiles.experiment import ExperimentProfile, load_experiment
from profiles.loader import KINDS, ProfileError, available, load_toml, resolve
from profiles.recording_format import RecordingFormat, load_format
from profiles.robot import RobotProfile, UrdfRobotProfile, load_robot, load_urdf_robot
from profiles.timing_faults import TimingFaults, TimingTrace, read_trace
from profiles.tracking import TrackingProfile, load_tracking

__all__ = [
    "KINDS",
    "BenchProfile",
    "DriveProfile",
    "EffectsProfile",
    "ExperimentProfile",
    "ProfileError",
    "RecordingFormat",
    "RobotProfile",
    "TimingFaults",
    "TimingTrace",
    "TrackingProfile",
    "UrdfRobotProfile",
    "available",
    "load_bench",
    "load_drive",
    "load_effects",
    "load_experiment",
    "load_format",
    "load_robot",
    "load_toml",
    "load_tracking",
    "load_urdf_robot",
    "read_trace",
    "resolve",
]
