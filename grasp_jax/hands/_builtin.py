"""The built-in default hand: three two-joint fingers around a round palm, made of primitives.

Described here as a URDF generated in code (no third-party file), so that everything runs on a
fresh machine. The palm's normal is +z of the root link; each finger stands along +z at joint
values 0 and closes towards the palm's axis as its joint values increase.
"""

from __future__ import annotations

import math

#: Name :func:`grasp_jax.hands.load` knows for the built-in hand.
DEFAULT_NAME = "default"

_PALM_RADIUS = 0.05
_PALM_HALF = 0.01
_FINGER_RADIUS = 0.045
_PROXIMAL, _DISTAL, _TIP = 0.06, 0.04, 0.009
_WIDTH = 0.016


def _finger(i: int, azimuth: float) -> str:
    x, y = _FINGER_RADIUS * math.cos(azimuth), _FINGER_RADIUS * math.sin(azimuth)
    return f"""
  <link name="f{i}_proximal">
    <collision><origin xyz="0 0 {_PROXIMAL / 2}" rpy="0 0 0"/>
      <geometry><box size="{_WIDTH} {_WIDTH} {_PROXIMAL}"/></geometry></collision>
  </link>
  <joint name="f{i}_j0" type="revolute">
    <parent link="palm"/><child link="f{i}_proximal"/>
    <origin xyz="{x:.9f} {y:.9f} {_PALM_HALF}" rpy="0 0 {azimuth:.9f}"/>
    <axis xyz="0 -1 0"/><limit lower="-0.5" upper="1.6" effort="5" velocity="3"/>
  </joint>
  <link name="f{i}_distal">
    <collision><origin xyz="0 0 {_DISTAL / 2}" rpy="0 0 0"/>
      <geometry><box size="{_WIDTH} {_WIDTH} {_DISTAL}"/></geometry></collision>
  </link>
  <joint name="f{i}_j1" type="revolute">
    <parent link="f{i}_proximal"/><child link="f{i}_distal"/>
    <origin xyz="0 0 {_PROXIMAL}" rpy="0 0 0"/>
    <axis xyz="0 -1 0"/><limit lower="0" upper="1.6" effort="5" velocity="3"/>
  </joint>
  <link name="f{i}_tip">
    <collision><origin xyz="0 0 0" rpy="0 0 0"/><geometry><sphere radius="{_TIP}"/></geometry></collision>
  </link>
  <joint name="f{i}_tip_joint" type="fixed">
    <parent link="f{i}_distal"/><child link="f{i}_tip"/><origin xyz="0 0 {_DISTAL}" rpy="0 0 0"/>
  </joint>"""


def default_urdf() -> str:
    """The built-in hand as URDF text."""
    fingers = "".join(_finger(i, math.radians(90 + 120 * i)) for i in range(3))
    return f"""<?xml version="1.0"?>
<robot name="{DEFAULT_NAME}">
  <link name="palm">
    <collision><origin xyz="0 0 0" rpy="0 0 0"/>
      <geometry><cylinder radius="{_PALM_RADIUS}" length="{2 * _PALM_HALF}"/></geometry></collision>
  </link>{fingers}
</robot>
"""
