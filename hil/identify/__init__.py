"""Identification: θ from recordings (Reyes & Kelly 1997) and excitation design.

What lives here: the three schemes, Table II and validation (:mod:`.schemes`); online RLS
while a run records (:mod:`.online`); base parameters of a URDF arm (:mod:`.urdf`); optimal
periodic excitation (:mod:`.excitation`); instrumental variables on a closed-loop
recording's reference (:mod:`.iv`); the ``hil identify`` and ``hil excite`` commands
(:mod:`.cli`, :mod:`.excite_cli`) and their plots (:mod:`.plots`).

Imports: :mod:`hil.model`, :mod:`hil.bench` (to record over a bench), :mod:`hil.cli_options`.

Public API (``from hil.identify import ...``, docs/api.md): ``identify`` (the three schemes of
the paper on one recording), ``validate`` (held-out position and torque NRMSE),
``identify_model`` (any :class:`hil.model.ArmModel`, bounded and with uncertainty),
``OnlineIdentifier``, ``design_excitation``, ``identify_torque`` and ``identify_energy`` (a URDF
arm) and the rest of ``__all__``; each loads on first use.
"""

from hil import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "hil.identify.schemes": [
            "identify",
            "validate",
            "SchemeResult",
            "table_ii_rows",
            "format_table_ii",
            "irregular_times",
            "identify_model",
            "ModelIdentification",
            "torque_prediction_error",
        ],
        "hil.identify.online": ["OnlineIdentifier"],
        "hil.identify.excitation": [
            "ExcitationLimits",
            "FourierTrajectory",
            "DesignResult",
            "design_excitation",
        ],
        "hil.identify.urdf": [
            "TorqueIdentification",
            "identify_torque",
            "EnergyIdentification",
            "identify_energy",
        ],
    },
)
