"""Does the grasp hold? A MuJoCo check of jaw (and hand) grasps, after DexGraspBench's protocol.

The object is the convex decomposition of its mesh (cached per mesh), free and weightless; the
gripper closes, squeezes, and a force pulls the object along each of six directions in turn
(:class:`Protocol`). :func:`simulate_jaws` checks parallel-jaw grasps of :mod:`grasp_jax.grippers`
and :func:`simulate_hand` the hand grasps of :mod:`grasp_jax.hands`, over all cores;
:func:`add_sim_columns` writes the outcome beside the labels of a result file. Nothing here imports
JAX: the simulation needs MuJoCo, NumPy and trimesh (``pip install 'grasp_jax[sim]'``).
"""

from __future__ import annotations

from ._columns import DIRECTION_COLUMNS as DIRECTION_COLUMNS
from ._columns import SIM_COLUMNS as SIM_COLUMNS
from ._columns import add_hand_sim_columns as add_hand_sim_columns
from ._columns import add_sim_columns as add_sim_columns
from ._columns import sim_columns as sim_columns
from ._hands import simulate_hand as simulate_hand
from ._jaws import DEFAULT_GRIPPER as DEFAULT_GRIPPER
from ._jaws import simulate_jaws as simulate_jaws
from ._object import MASS as MASS
from ._object import Decomposition as Decomposition
from ._object import SimObject as SimObject
from ._object import cache_dir as cache_dir
from ._object import decompose as decompose
from ._object import sim_object as sim_object
from ._protocol import DIRECTIONS as DIRECTIONS
from ._protocol import Protocol as Protocol
from ._protocol import SimResult as SimResult
from ._protocol import SimStatus as SimStatus

__all__ = [
    "DEFAULT_GRIPPER",
    "DIRECTIONS",
    "DIRECTION_COLUMNS",
    "MASS",
    "SIM_COLUMNS",
    "Decomposition",
    "Protocol",
    "SimObject",
    "SimResult",
    "SimStatus",
    "add_sim_columns",
    "add_hand_sim_columns",
    "cache_dir",
    "decompose",
    "sim_columns",
    "sim_object",
    "simulate_hand",
    "simulate_jaws",
]
