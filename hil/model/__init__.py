"""The host's models of an arm and the estimation core, with no I/O.

What lives here: the closed-form 2-DOF model of Reyes & Kelly (1997) (:mod:`.closed_form`,
``ArmModel``) and the n-joint model of any URDF through Pinocchio (:mod:`.urdf`,
``UrdfArmModel``) behind one interface (names, units, M(q), regressors); the regression
builders of eqs. (24), (28), (30) (:mod:`.regressors`); RLS, batch and weighted least squares
(:mod:`.estimators`); the open-loop simulator, rigid and with the diagnosis' extra physics
(:mod:`.openloop`; its one stick–slip integrator :mod:`.openloop_core`, the effects
:mod:`.openloop_effects`); fit metrics (:mod:`.metrics`); parameter files
(:mod:`.params`).

Imports: numpy, scipy, pinocchio, :mod:`drivers` (recordings) and :mod:`profiles`. Nothing
from the other ``hil`` packages: they all build on this one.
"""
