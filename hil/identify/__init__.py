"""Identification: θ from recordings (Reyes & Kelly 1997) and excitation design.

What lives here: one identification API for every arm (:mod:`.identification`: ``identify``,
``Identification``); its engines, the three schemes, Table II and validation of the 2-DOF arm
(:mod:`.schemes`) and the base parameters of a URDF arm (:mod:`.urdf`); online RLS while a run
records (:mod:`.online`); optimal periodic excitation (:mod:`.excitation`); instrumental
variables on a closed-loop recording's reference (:mod:`.iv`); the ``hil identify``
and ``hil excite`` commands (:mod:`.cli`, :mod:`.excite_cli`), the three paths of
``hil identify`` (:mod:`.pipelines`) and their plots (:mod:`.plots`).

Imports: :mod:`hil.model`, :mod:`hil.bench` (to record over a bench), :mod:`hil.cli_options`.

Public API (``from hil.identify import ...``, docs/api.md): ``identify(model, recording,
scheme, ...)`` returning an ``Identification`` (any arm, any scheme, the paper's discretization
an option; one ``Uncertainty`` type), ``validate`` (held-out position and torque NRMSE of a
2-DOF θ), ``OnlineIdentifier``, ``design_excitation`` and the rest of ``__all__``; each loads on
first use. The engines (``hil.identify.schemes.identify``, ``identify_model``,
``hil.identify.urdf.identify_torque``, ``identify_energy``) stay importable from their modules.
"""

from hil import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "hil.identify.identification": ["identify", "Identification"],
        "hil.identify.schemes": [
            "validate",
            "Uncertainty",
            "SchemeResult",
            "table_ii_rows",
            "format_table_ii",
            "irregular_times",
            "torque_prediction_error",
        ],
        "hil.identify.online": ["OnlineIdentifier"],
        "hil.identify.excitation": [
            "ExcitationLimits",
            "FourierTrajectory",
            "DesignResult",
            "design_excitation",
        ],
    },
)
