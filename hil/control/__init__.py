"""Tracking control over a bench: PD, computed torque, feedforward, reduced feedforward
(Khosla & Kanade 1987).

What lives here: the controllers (:mod:`.controllers`, each law written once over a model
object: the 2-DOF closed form or an n-joint URDF arm's, so any number of joints), reference
trajectories
(:mod:`.trajectory`), one run and the comparison of schemes (:mod:`.tracking`), their plots
(:mod:`.plots`) and the ``hil control`` command (:mod:`.cli`).

Imports: :mod:`hil.model`, :mod:`hil.bench`, :mod:`hil.cli_options`; plots import results.

Public API (``from hil.control import ...``, docs/api.md): ``run_control`` (one scheme over a
bench), ``compare_schemes`` (Table 2 of Khosla & Kanade), the controllers and trajectories, and
the rest of ``__all__``; each loads on first use.
"""

from hil import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "hil.control.tracking": [
            "run_control",
            "compare_schemes",
            "format_table",
            "LabelledParams",
            "parse_params_spec",
        ],
        "hil.control.controllers": [
            "SCHEMES",
            "SCHEME_TITLES",
            "Gains",
            "Controller",
            "PDGravity",
            "ComputedTorque",
            "Feedforward",
            "ReducedFeedforward",
            "make_controller",
        ],
        "hil.control.trajectory": ["PointToPoint", "khosla_kanade_moves"],
    },
)
