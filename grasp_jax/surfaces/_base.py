"""What every surface offers: how one contact sits on, and moves over, one object kind.

A *contact* (:class:`Contact`, a small pytree) pins a point to the surface: on simplicial surfaces
(meshes, polygon boundaries) a ``face`` index and its barycentric ``coords``; on analytic shapes
the point itself in ``coords``, kept on the surface by closed-form maps.

A :class:`Surface` is a pytree (arrays as data, sizes and flags static), passed to compiled
functions as an argument; every method is a pure JAX function of **one** contact. ``chart(c, v)``
is a smooth local parametrization around ``c`` by an ambient displacement ``v: (d,)``, with
``chart(c, 0) == embed(c)``: ``jax.grad`` through it at ``v = 0`` is the Riemannian gradient.
``retract(c, v)`` moves the contact by the tangent part of ``v`` along the surface, across edges
(at most ``max_crossings`` faces on a simplicial surface; ``walk`` also returns the passes and
the displacement left over). On a simplicial surface both work in the plane of the contact's face.
``jax.device_put(surface)`` once, inside the optimizer's precision scope, avoids copying its NumPy
leaves on every call.
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
