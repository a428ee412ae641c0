"""Mismatch diagnosis: find the physics a model leaves out, checked on held-out data.

What lives here: the candidate terms' columns (:mod:`.columns`), blocked cross-validation
(:mod:`.stats`), the candidate vocabulary (:mod:`.candidates`; each kind of candidate one
module of :mod:`.kinds`, a registry; one finding :mod:`.finding`), the stacked regression and its
cross-validated fits (:mod:`.problem`), the physical gate (:mod:`.physical`), the forward term
selection (:mod:`.selection`), where the residual lives (:mod:`.locate`), findings with
magnitudes (:mod:`.findings`); the diagnosis in stages with typed results: interpretation of the
accepted terms (:mod:`.interpret`), the held-out before/after fit and its simulations
(:mod:`.heldout`), the simulation gate (:mod:`.gates`), the report text (:mod:`.report`), and
:func:`diagnose` joining them into the document (:mod:`.pipeline`); its plots (:mod:`.plots`),
the judgement against the model the user has (:mod:`.drift`: the profile's θ, ``--params``,
``--reference``) with its drift patterns (:mod:`.effects`, one module per pattern, a registry)
and the ``hil diagnose`` command (:mod:`.cli`).

Imports: :mod:`hil.model`, :mod:`hil.cli_options`; plots import the pipeline's result, never the
reverse; each stage imports only those before it (interpret, heldout, report, gates, pipeline,
in that order), and so does the selection's (candidates, problem, physical, selection); the
kinds, below the candidates, only :mod:`.columns`, :mod:`.finding` and :mod:`hil.model`; the
drift imports the held-out stage, the gate and the effects, the effects only :mod:`.columns` and
:mod:`hil.model`.

Public API (``from hil.diagnose import ...``, docs/api.md): ``diagnose(recordings,
reference_theta)`` returns a ``DiagnosisResult`` whose ``document`` is what ``hil diagnose
--json`` prints; ``plot_diagnosis`` draws it (matplotlib, loaded only then).
"""

from hil import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "hil.diagnose.pipeline": ["diagnose", "DiagnosisResult"],
        "hil.diagnose.problem": ["DiagnosisError"],
        "hil.diagnose.findings": ["Finding"],
        "hil.diagnose.plots": ["plot_diagnosis"],
    },
)
