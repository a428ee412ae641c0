"""Profiles: TOML data (robots, drives, effects, experiments, benches) and their typed views.

A profile is named by a bare name (``cicese``), looked up among the package's own TOML files, or
by a path to any TOML file. Every field is checked on load; a bad one raises :class:`ProfileError`
whose message is one line naming the file and the field.

Imports: the standard library, numpy, and :mod:`hil.model.closed_form` (a robot profile names the
model
terms its arm has and builds the model object); nothing else of ``hil``.
"""

from profiles.loader import KINDS, ProfileError, available, load_toml, resolve

__all__ = ["KINDS", "ProfileError", "available", "load_toml", "resolve"]
