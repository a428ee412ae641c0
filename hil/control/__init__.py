"""Tracking control over a bench: PD, computed torque, feedforward, reduced feedforward
(Khosla & Kanade 1987).

What lives here: the controllers (:mod:`.controllers`), reference trajectories
(:mod:`.trajectory`), one run and the comparison of schemes (:mod:`.tracking`), their plots
(:mod:`.plots`) and the ``hil control`` command (:mod:`.cli`).

Imports: :mod:`hil.model`, :mod:`hil.bench`, :mod:`hil.cli_options`; plots import results.
"""
