"""Identification: θ from recordings (Reyes & Kelly 1997) and excitation design.

What lives here: the three schemes, Table II and validation (:mod:`.schemes`); online RLS
while a run records (:mod:`.online`); base parameters of a URDF arm (:mod:`.urdf`); optimal
periodic excitation (:mod:`.excitation`); the ``hil identify`` and ``hil excite`` commands
(:mod:`.cli`, :mod:`.excite_cli`) and their plots (:mod:`.plots`).

Imports: :mod:`hil.model`, :mod:`hil.bench` (to record over a bench), :mod:`hil.cli_options`.
"""
