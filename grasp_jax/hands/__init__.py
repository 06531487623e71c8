"""Hands: grasps synthesized as a wrist pose and joint angles of a URDF hand.

>>> from grasp_jax import hands
>>> hand = hands.load("default")          # or hands.load("path/to/hand.urdf")
>>> frames = hands.forward(hand, pose, joints)   # (L, 4, 4); pose = position + quaternion wxyz
"""

from ._builtin import DEFAULT_NAME as DEFAULT_NAME
from ._hand import Collision as Collision
from ._hand import Hand as Hand
from ._kinematics import forward as forward
from ._load import builtin as builtin
from ._load import load as load
