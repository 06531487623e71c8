"""grasp_jax: batched, differentiable force-closure tests and grasp quality in JAX.

Implements Bounab, Sidobre and Zaatri, "Central Axis Approach for Computing n-Finger
Force-closure Grasps": linearized friction cones, primitive wrenches, central axes, the
force-closure test of Proposition 2 posed as linear programs, and the quality Q of eq. (23), with
the Ferrari-Canny epsilon as baseline.

Conventions: ``points`` and ``normals`` are ``(..., n, d)`` arrays, ``d`` in {2, 3}, normals
**outward**, the reference contact ``c_1`` is index 0. Importing grasp_jax changes no JAX
configuration. Concrete float64 inputs are computed in float64 (scoped to the call), float32 inputs
in float32, traced inputs in the tracers' dtype: the rules are in ``grasp_jax._precision``.
"""

from ._api import critical_friction as critical_friction
from ._api import evaluate as evaluate
from ._api import force_closure as force_closure
from ._api import friction_label as friction_label
from ._api import min_weight as min_weight
from ._api import quality as quality
from ._baseline import ferrari_canny as ferrari_canny
from ._cones import cone_edges as _cone_edges  # noqa: F401
from ._contact import CONTACTS as CONTACTS
from ._contact import dexnet_torsion as dexnet_torsion
from ._contact import patch_torsion as patch_torsion
from ._friction import FrictionStatus as FrictionStatus
from ._noise import Noise as Noise
from ._objectives import OBJECTIVES as OBJECTIVES
from ._objectives import objective as objective
from ._optimize import EndReason as EndReason
from ._optimize import OptimizeResult as OptimizeResult
from ._optimize import optimize as optimize
from ._result import GraspEvaluation as GraspEvaluation
from ._robust import RobustResult as RobustResult
from ._robust import perturb as perturb
from ._robust import robust as robust
from ._wrench import CentralAxis as CentralAxis
from ._wrench import central_axis as central_axis
from .lp import Status as Status

__version__ = "0.1.0"

__all__ = [
    "evaluate",
    "force_closure",
    "quality",
    "min_weight",
    "ferrari_canny",
    "critical_friction",
    "friction_label",
    "FrictionStatus",
    "CONTACTS",
    "patch_torsion",
    "dexnet_torsion",
    "central_axis",
    "CentralAxis",
    "GraspEvaluation",
    "robust",
    "perturb",
    "Noise",
    "RobustResult",
    "Status",
    "optimize",
    "OptimizeResult",
    "EndReason",
    "OBJECTIVES",
    "objective",
]
