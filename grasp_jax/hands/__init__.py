"""Hands: grasps synthesized as a wrist pose and joint angles of a URDF hand.

>>> from grasp_jax import hands
>>> hand = hands.load("default")          # or hands.load("path/to/hand.urdf")
>>> frames = hands.forward(hand, pose, joints)   # (L, 4, 4); pose = position + quaternion wxyz
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
