"""Drift patterns: how a recording departs from a nominal model, one module per pattern.

Each module defines one :class:`~hil.diagnose.effects.base.Effect` and registers it
(:func:`~hil.diagnose.effects.base.register`); :mod:`hil.diagnose.drift` selects among the
registered effects with blocked cross-validation against the residual of the nominal model,
reads each accepted one as a finding, and simulates it on held-out data. Adding a pattern is one
file here plus its import below (the registry order is the order the effects are tested in).

Imports: :mod:`hil.diagnose.columns`, :mod:`hil.model`, the resolution floor of
:mod:`hil.diagnose.findings` and the cogging periods of :mod:`hil.diagnose.candidates`;
never the pipeline or the report.
"""

from hil.diagnose.effects import (  # noqa: F401  (each module registers its effect)
    asymmetry,
    cogging,
    com_offset,
    delay,
    drag,
    encoder,
    friction,
    gain,
    offset,
    payload,
    rotor,
)
from hil.diagnose.effects.base import REGISTRY, Context, Effect, SimInput, register

__all__ = ["REGISTRY", "Context", "Effect", "SimInput", "register"]
