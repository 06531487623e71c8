"""MJCF text of the parts every scene shares: options, the object's convex parts and its body."""

from __future__ import annotations

import numpy as np

from ._object import SimObject
from ._protocol import Protocol

#: Collision bits: the object collides with the gripper only, the gripper's parts not with each other.
OBJECT_BITS = 'contype="1" conaffinity="2"'
GRIPPER_BITS = 'contype="2" conaffinity="1"'


def _floats(a) -> str:
    return " ".join(f"{x:.9g}" for x in np.asarray(a, float).ravel())


def option(protocol: Protocol) -> str:
    """The ``<option>`` block: no gravity, elliptic friction cones, several contacts between convex
    shapes (``multiccd``: a flat jaw on a flat face touches over an area, not at one point)."""
    return (f'<option timestep="{protocol.timestep:.9g}" gravity="0 0 0" integrator="implicitfast" '
            'cone="elliptic" impratio="10"><flag multiccd="enable"/></option>')


def object_assets(obj: SimObject) -> str:
    """One ``<mesh>`` per convex part."""
    return "\n".join(f'<mesh name="part{i}" vertex="{_floats(v)}" face="{" ".join(map(str, f.ravel()))}"/>'
                     for i, (v, f) in enumerate(obj.parts))


def contact(protocol: Protocol) -> str:
    """The contact attributes of every geom: friction, stiffness (``solref``, ``solimp``)."""
    return (f'condim="4" friction="{protocol.friction:.9g} {protocol.torsion:.9g} 0.0001" '
            f'solref="{_floats(protocol.solref)}" solimp="{_floats(protocol.solimp)}"')


def object_body(obj: SimObject, protocol: Protocol) -> str:
    """The object's body at the origin of the world, with a free joint and its inertia."""
    geoms = "\n".join(f'<geom type="mesh" mesh="part{i}" {contact(protocol)} {OBJECT_BITS}/>'
                      for i in range(len(obj.parts)))
    i = obj.inertia
    full = _floats([i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]])
    return (f'<body name="object"><freejoint/>'
            f'<inertial pos="{_floats(obj.com)}" mass="{obj.mass:.9g}" fullinertia="{full}"/>\n'
            f'{geoms}</body>')


def gripper_geom_defaults(protocol: Protocol) -> str:
    """Friction and collision bits of every gripper geom (a ``<default class="gripper">``)."""
    return f'<default class="gripper"><geom {contact(protocol)} {GRIPPER_BITS}/></default>'
