"""The :class:`Hand` container: a kinematic tree, collision geometry and contact candidates.

Arrays are pytree data (so one compiled program serves every hand of the same sizes); the tree's
structure, names and joint kinds are static. Links are in topological order (a parent before its
children); link 0 is the root, whose frame is the wrist pose.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

#: Joint kinds of :attr:`Hand.joint_kind`.
FIXED, REVOLUTE, PRISMATIC = 0, 1, 2


@dataclasses.dataclass(frozen=True)
class Collision:
    """One collision element of a link (static; for drawing and exact checks).

    Attributes:
        link: index of the link it belongs to.
        kind: ``"box"``, ``"cylinder"``, ``"sphere"``, ``"capsule"`` or ``"mesh"``.
        size: box sizes ``(x, y, z)``; cylinder / capsule ``(radius, length)``; sphere ``(radius,)``;
            mesh: its scale ``(sx, sy, sz)``.
        origin: the element's pose in the link frame, a 4x4 matrix flattened row by row (16 floats).
        filename: the mesh file, absolute (``""`` for primitives).
    """

    link: int
    kind: str
    size: tuple
    origin: tuple
    filename: str = ""

    @property
    def transform(self) -> np.ndarray:
        """``(4, 4)`` the element's pose in its link's frame."""
        return np.asarray(self.origin, dtype=np.float64).reshape(4, 4)


class Tree:
    """A parsed description before geometry is sampled (NumPy; see :class:`Hand` for the fields),
    as the URDF and MJCF readers give it."""

    def __init__(self, **fields):
        self.__dict__.update(fields)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Hand:
    """A hand: ``L`` links, ``J`` actuated joints, ``F`` fingers with ``K`` contact candidates each,
    ``S`` collision spheres, ``N`` surface samples.

    Attributes:
        origin: ``(L, 4, 4)`` each link's joint frame in its parent's frame (identity for the root).
        axis: ``(L, 3)`` unit joint axis in the joint frame (unused for fixed joints).
        multiplier, offset: ``(L,)`` the link's joint value is ``multiplier * q[source] + offset``
            (``1, 0`` for an actuated joint; a mimic joint's own values).
        lower, upper: ``(J,)`` limits of the actuated joints (``-inf, inf`` for continuous ones).
        sphere_center: ``(S, 3)`` collision spheres in their links' frames; ``sphere_radius: (S,)``.
        sphere_link: ``(S,) int32`` link of each sphere; ``sphere_finger: (S,) int32`` the finger
            it belongs to (``-1``: palm).
        surface_point: ``(N, 3)`` samples of the collision surfaces in their links' frames, about
            4 mm apart; ``surface_link: (N,) int32`` their links.
        candidate_point, candidate_normal: ``(F, K, 3)`` contact candidates and outward normals in
            the frame of link ``finger_link[f]``.
        palm: ``(3, 3)`` rows: the palm's centre, its normal (the side the fingers close towards)
            and the fingers' direction, in the root frame, at the opened configuration.
        open_joints: ``(J,)`` the opened pre-grasp configuration starts jitter (half-way from 0
            to the opening limits).
        closing: ``(J,)`` +1 or -1: the sign of the joint motion that closes the hand (the side
            of the larger limit: positive on Allegro and LEAP, negative on the Barrett file); 0
            for a side (abduction) joint, whose range is about symmetric about 0.
        parent: static ``(L,)`` parent link of each link (``-1`` for the root).
        joint_kind: static ``(L,)`` :data:`FIXED`, :data:`REVOLUTE` or :data:`PRISMATIC`.
        source: static ``(L,)`` actuated joint that drives the link's joint (``-1`` if fixed).
        finger_link: static ``(F,)`` distal link of each finger.
        link_names, joint_names: static names (``joint_names``: the ``J`` actuated joints).
        collisions: static :class:`Collision` elements.
        name, path: static; ``path`` is the URDF or MJCF file (``""`` for a built-in hand).
    """

    origin: jax.Array
    axis: jax.Array
    multiplier: jax.Array
    offset: jax.Array
    lower: jax.Array
    upper: jax.Array
    sphere_center: jax.Array
    sphere_radius: jax.Array
    sphere_link: jax.Array
    sphere_finger: jax.Array
    surface_point: jax.Array
    surface_link: jax.Array
    candidate_point: jax.Array
    candidate_normal: jax.Array
    palm: jax.Array
    open_joints: jax.Array
    closing: jax.Array
    parent: tuple = dataclasses.field(metadata={"static": True}, default=())
    joint_kind: tuple = dataclasses.field(metadata={"static": True}, default=())
    source: tuple = dataclasses.field(metadata={"static": True}, default=())
    finger_link: tuple = dataclasses.field(metadata={"static": True}, default=())
    link_names: tuple = dataclasses.field(metadata={"static": True}, default=())
    joint_names: tuple = dataclasses.field(metadata={"static": True}, default=())
    collisions: tuple = dataclasses.field(metadata={"static": True}, default=())
    name: str = dataclasses.field(metadata={"static": True}, default="hand")
    path: str = dataclasses.field(metadata={"static": True}, default="")

    @property
    def num_links(self) -> int:
        return len(self.parent)

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    @property
    def num_fingers(self) -> int:
        return len(self.finger_link)

    def link_index(self, name: str) -> int:
        """The index of link ``name`` (``ValueError`` if the hand has none)."""
        try:
            return self.link_names.index(name)
        except ValueError:
            raise ValueError(f"hand {self.name!r} has no link {name!r}; links: {', '.join(self.link_names)}") from None

    def with_candidates(self, points, normals) -> Hand:
        """This hand with other contact candidates: ``points, normals: (F, K, 3)`` in the frames of
        :attr:`finger_link` (normals are normalized)."""
        points = np.asarray(points, dtype=np.float64)
        normals = np.asarray(normals, dtype=np.float64)
        f = self.num_fingers
        if points.ndim != 3 or points.shape[0] != f or points.shape[2] != 3 or normals.shape != points.shape:
            raise ValueError(f"candidates must be points and normals of shape ({f}, K, 3) for the {f} fingers "
                             f"of hand {self.name!r}; got {points.shape} and {normals.shape}")
        if not (np.isfinite(points).all() and np.isfinite(normals).all()):
            raise ValueError("candidate points and normals must be finite")
        length = np.linalg.norm(normals, axis=-1, keepdims=True)
        if (length < 1e-12).any():
            raise ValueError("candidate normals must be non-zero")
        return dataclasses.replace(self, candidate_point=points, candidate_normal=normals / length)

    def __repr__(self) -> str:
        return (f"Hand({self.name!r}, {self.num_links} links, {self.num_joints} joints, {self.num_fingers} fingers, "
                f"{len(self.collisions)} collision elements)")
