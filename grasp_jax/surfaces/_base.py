"""What every surface offers: how one contact sits on, and moves over, one object kind.

A *contact* is a small pytree (:class:`Contact`) that pins a point to the surface exactly:

* simplicial surfaces (triangle meshes, polygon boundaries): ``face`` is the index of a triangle
  (or polygon edge) and ``coords`` its barycentric coordinates, ``(3,)`` (or ``(2,)``), >= 0,
  summing to 1, so the point is on the surface up to rounding of one convex combination;
* analytic shapes: ``face`` is unused (0) and ``coords`` is the point itself, ``(3,)``, which
  closed-form maps keep on the surface.

A :class:`Surface` is a pytree too (arrays as data, sizes and flags static), so it can be passed
to ``jit``-compiled functions as an argument and every method is a pure JAX function of **one**
contact (batch with ``jax.vmap``).

The optimizer uses three methods. ``chart(c, v)`` is a smooth local parametrization of the
surface around ``c`` by an ambient displacement ``v: (d,)`` (only its tangent part matters), with
``chart(c, 0) == embed(c)``; ``jax.grad`` of an objective of ``chart(c, v)`` at ``v = 0`` is the
objective's Riemannian gradient, in ambient coordinates. ``retract(c, v)`` moves the contact by
the tangent part of ``v`` along the surface (across edges onto neighbouring faces, around
polygon corners). Optax updates are ambient ``(n, d)`` arrays, so any optax transformation works.

On a simplicial surface ``chart`` moves in the plane of the contact's face, so the Riemannian
gradient is tangent to the face (not to the interpolated normal); ``retract`` takes the part of
``v`` in that plane. A surface's leaves are NumPy arrays (float64 vertices etc., which take the
caller's precision when traced); ``jax.device_put(surface)`` once, inside the precision scope the
optimizer runs in, avoids copying them to the device on every call of a compiled step. The
methods are compiled once per surface structure, so calling them outside ``jit`` is cheap too.
A simplicial surface stops a ``retract`` after ``max_crossings`` faces (static, 16 by default;
``for_object(..., max_crossings=)``); its ``walk(c, v)`` is ``retract`` plus the number of passes
and the length of displacement left over, for diagnostics.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol, runtime_checkable

import jax
import numpy as np


class Contact(NamedTuple):
    """One contact on a surface (or a batch of them, with leading axes).

    Attributes:
        face: ``() int32`` triangle / edge index (0 on analytic shapes).
        coords: ``(k,) float`` barycentric coordinates (simplicial surfaces, ``k = d``) or the
            point itself (analytic shapes, ``k = 3``).
    """

    face: jax.Array
    coords: jax.Array


@runtime_checkable
class Surface(Protocol):
    """How contacts live on one object.

    Attributes:
        dim: 2 or 3 (static).
        scale: the object's radius (static float): steps are taken in units of it.
        center: ``(d,) float`` the object's centre (torques of scale-free objectives are about it).
        normal_kind: which normals ``embed`` reports (static): ``"exact"`` (analytic shapes),
            ``"smooth"`` (vertex normals interpolated across each face, sharp edges kept) or
            ``"flat"`` (one normal per face).
    """

    dim: int
    scale: float
    center: jax.Array
    normal_kind: str

    def embed(self, contact: Contact) -> tuple[jax.Array, jax.Array]:
        """``(point (d,), outward unit normal (d,))`` of one contact."""
        ...

    def chart(self, contact: Contact, v: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``embed`` of the surface point reached from ``contact`` by ``v: (d,)``, smooth in ``v``
        near 0 and equal to ``embed(contact)`` at ``v = 0``."""
        ...

    def retract(self, contact: Contact, v: jax.Array) -> Contact:
        """The contact moved by the tangent part of ``v: (d,)`` along the surface."""
        ...

    def sample(self, key: jax.Array, count: int) -> Contact:
        """``count`` contacts uniform by area (length in 2D); leaves have leading ``(count,)``."""
        ...

    def locate(self, points: np.ndarray) -> Contact:
        """Host side (NumPy): the contacts at the surface points closest to ``points: (..., d)``;
        leaves have the leading shape ``points.shape[:-1]``."""
        ...
