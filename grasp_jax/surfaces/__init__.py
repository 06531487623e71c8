"""Contacts that stay on an object's surface and move over it, in pure JAX.

Every surface is a pytree (pass it to ``jit``-compiled functions as an argument) whose methods
take **one** :class:`Contact` (batch with ``jax.vmap``): ``embed``, ``chart``, ``retract``,
``sample`` and, on the host, ``locate``. See :class:`Surface`.

>>> import jax
>>> from grasp_jax import objects, surfaces
>>> surface = surfaces.for_object(objects.quad())
>>> contacts = surface.sample(jax.random.key(0), 4)
>>> points, normals = jax.vmap(surface.embed)(contacts)
"""

from ._analytic import BoxSurface as BoxSurface
from ._analytic import CylinderSurface as CylinderSurface
from ._analytic import EllipsoidSurface as EllipsoidSurface
from ._analytic import SphereSurface as SphereSurface
from ._base import Contact as Contact
from ._base import Surface as Surface
from ._for_object import CREASE_ANGLE as CREASE_ANGLE
from ._for_object import as_surface as as_surface
from ._for_object import for_object as for_object
from ._simplicial import SimplicialSurface as SimplicialSurface
from ._simplicial import from_simplices as from_simplices

__all__ = [
    "CREASE_ANGLE",
    "BoxSurface",
    "Contact",
    "CylinderSurface",
    "EllipsoidSurface",
    "SimplicialSurface",
    "SphereSurface",
    "Surface",
    "as_surface",
    "for_object",
    "from_simplices",
]
