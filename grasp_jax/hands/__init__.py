"""Hands: grasps synthesized as a wrist pose and joint angles of a URDF or MJCF hand.

* :func:`load` (``"default"``, a ``.urdf`` or an MJCF ``.xml`` file) -> :class:`Hand`; :func:`builtin`;
* :func:`forward` (one configuration; pose = position + quaternion **wxyz**) -> ``(L, 4, 4)``;
* :func:`geometry`: an object as a fixed-shape SDF grid and surface points (pytree data);
* :func:`synthesize` -> :class:`HandGraspResult` (``.save(path)``, :func:`load_result`).

>>> from grasp_jax import hands, objects
>>> hand = hands.load("default")
>>> result = hands.synthesize(hand, objects.load("glass"), starts=64, steps=80)
"""

from ._builtin import DEFAULT_NAME as DEFAULT_NAME
from ._energy import Weights as Weights
from ._hand import Collision as Collision
from ._hand import Hand as Hand
from ._kinematics import forward as forward
from ._load import builtin as builtin
from ._load import load as load
from ._result import HandGraspResult as HandGraspResult
from ._result import HandStatus as HandStatus
from ._result import load as load_result  # noqa: F401 - re-exported
from ._sdf import ObjectGeometry as ObjectGeometry
from ._sdf import geometry as geometry
from ._synthesize import synthesize as synthesize
