"""The host's models of an arm and the estimation core, with no I/O.

What lives here: the closed-form 2-DOF model of Reyes & Kelly (1997) (:mod:`.closed_form`,
``ArmModel``) and the n-joint model of any URDF through Pinocchio (:mod:`.urdf`,
``UrdfArmModel``; the bodies of one θ and their torques, :mod:`.urdf_dynamics`) behind one
interface (:mod:`.protocol`, ``ArmDynamics``: names, units, M(q), regressors); the regression
builders of eqs. (24), (28), (30) (:mod:`.regressors`); RLS, batch
and weighted least squares (:mod:`.estimators`); the open-loop simulator, rigid and with the
diagnosis' extra physics (:mod:`.openloop`; its one stick–slip integrator
:mod:`.openloop_core`, the effects :mod:`.openloop_effects`); fit metrics (:mod:`.metrics`);
parameter files (:mod:`.params`).

Imports: numpy, scipy, pinocchio, :mod:`drivers` (recordings) and :mod:`profiles`. Nothing
from the other ``hil`` packages: they all build on this one.

Public API (``from hil.model import ...``, docs/api.md): ``ArmModel``, ``UrdfArmModel``,
``simulate_open_loop``, ``nrmse``, ``load_params``, ``robot_params`` and the rest of
``__all__``; each loads on first use, so ``import hil.model`` loads neither scipy nor Pinocchio.
"""

from hil import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "hil.model.closed_form": [
            "ArmModel",
            "robot_model",
            "THETA_NAMES",
            "THETA_UNITS",
            "mass_matrix",
            "coriolis_vector",
            "gravity_vector",
            "friction_torque",
            "inverse_dynamics",
            "forward_dynamics",
            "physical_consistency",
        ],
        "hil.model.urdf": ["UrdfArmModel", "BaseParameters"],
        "hil.model.protocol": ["ArmDynamics"],
        "hil.model.regressors": ["SCHEMES", "DISCRETIZATIONS", "Regression", "build_regression"],
        "hil.model.estimators": [
            "RecursiveLeastSquares",
            "recursive_least_squares",
            "least_squares",
            "weighted_least_squares",
        ],
        "hil.model.openloop": [
            "OpenLoopResult",
            "OpenLoopExtras",
            "simulate_open_loop",
            "simulate_windows",
        ],
        "hil.model.metrics": ["nrmse"],
        "hil.model.params": [
            "ParamSet",
            "ParamsError",
            "load_params",
            "save_params",
            "robot_params",
        ],
    },
)
