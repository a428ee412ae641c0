"""Mismatch diagnosis: find the physics a model leaves out, checked on held-out data.

What lives here: the candidate terms (:mod:`.columns`), blocked cross-validation
(:mod:`.stats`), the term selection with its physical and held-out gates (:mod:`.selection`),
where the residual lives (:mod:`.locate`), findings with magnitudes (:mod:`.findings`), the
whole report (:mod:`.report`), its plots (:mod:`.plots`) and the ``hil diagnose`` command
(:mod:`.cli`).

Imports: :mod:`hil.model`, :mod:`hil.cli_options`; plots import the report, never the reverse.
"""
