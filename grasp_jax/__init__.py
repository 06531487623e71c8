"""grasp_jax: batched, differentiable force-closure tests and grasp quality in JAX.

Implements Bounab, Sidobre and Zaatri, "Central Axis Approach for Computing n-Finger
Force-closure Grasps": linearized friction cones, primitive wrenches, central axes, the
force-closure test of Proposition 2 posed as linear programs, and the quality Q of eq. (23), with
the Ferrari-Canny epsilon as baseline.

Conventions: ``points`` and ``normals`` are ``(..., n, d)`` arrays, ``d`` in {2, 3}, normals
**outward**, the reference contact ``c_1`` is index 0. Importing grasp_jax turns on JAX's 64-bit
mode (``jax_enable_x64``): results are float64 unless the inputs are float32.
"""

import jax as _jax

_jax.config.update("jax_enable_x64", True)

from ._api import evaluate as evaluate  # noqa: E402
from ._api import force_closure as force_closure  # noqa: E402
from ._api import min_weight as min_weight  # noqa: E402
from ._api import quality as quality  # noqa: E402
from ._baseline import ferrari_canny as ferrari_canny  # noqa: E402
from ._cones import cone_edges as _cone_edges  # noqa: E402,F401
from ._lp import Status as Status  # noqa: E402
from ._result import GraspEvaluation as GraspEvaluation  # noqa: E402
from ._wrench import CentralAxis as CentralAxis  # noqa: E402
from ._wrench import central_axis as central_axis  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "evaluate",
    "force_closure",
    "quality",
    "min_weight",
    "ferrari_canny",
    "central_axis",
    "CentralAxis",
    "GraspEvaluation",
    "Status",
]
