"""The surface of any grasp_jax object, and the one place an optimizer gets it from."""

from __future__ import annotations

import dataclasses
import weakref

from . import _simplicial
from ._base import Surface

#: default crease angle (degrees) of smooth normals: sharper edges stay sharp
CREASE_ANGLE = 45.0


#: Surfaces of immutable meshes and polygons already built, per object.
_BUILT: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def for_object(obj, *, normals: str = "smooth", crease_angle: float = CREASE_ANGLE,
               max_crossings: int = _simplicial.MAX_CROSSINGS):
    """The :class:`~grasp_jax.surfaces.Surface` of ``obj``.

    Args:
        obj: a :class:`grasp_jax.objects.Polygon`, :class:`~grasp_jax.objects.Mesh` (the built-in
            ``glass`` and ``part`` too) or analytic shape (``Sphere``, ``Ellipsoid``, ``Box``,
            ``Cylinder``); any object with ``rings`` (2D) or a trimesh ``mesh`` (3D), ``center``
            and ``radius``.
        normals: meshes and polygons: ``"smooth"`` (corner normals interpolated, edges sharper
            than ``crease_angle`` kept sharp) or ``"flat"`` (face normals). Analytic shapes always
            have exact normals (``normal_kind == "exact"``).
        crease_angle: degrees.
        max_crossings: the most faces (polygon edges) one ``retract`` passes through.

    Raises:
        TypeError: an object of another kind.
        ValueError: a bad ``normals``, ``crease_angle`` or ``max_crossings``.
    """
    if normals not in ("smooth", "flat"):
        raise ValueError(f"normals must be 'smooth' or 'flat'; got {normals!r}")
    exact = getattr(obj, "exact_surface", None)
    if callable(exact):
        return exact()
    options = {"normals": normals, "crease_angle": crease_angle, "max_crossings": max_crossings}
    if getattr(obj, "dim", None) == 2 and hasattr(obj, "rings"):
        build = _simplicial.for_polygon
    elif getattr(obj, "dim", 3) == 3 and hasattr(obj, "mesh"):
        build = _simplicial.for_mesh
    else:
        raise TypeError(f"for_object: no surface for {type(obj).__name__}; give a grasp_jax object "
                        "(Polygon, Mesh, Sphere, Ellipsoid, Box, Cylinder).")
    key = (normals, crease_angle, max_crossings)
    if not _immutable(obj) or not _hashable(key):
        return build(obj, **options)
    built = _BUILT.setdefault(obj, {})
    if key not in built:
        built[key] = build(obj, **options)
    return built[key]


def as_surface(obj, normals: str) -> Surface:
    """``obj`` itself if it is a :class:`Surface`, else :func:`for_object` of it; a ``ValueError``
    naming what is expected for anything else."""
    if isinstance(obj, Surface) and not hasattr(obj, "sample_surface"):
        return obj
    if normals not in ("smooth", "flat"):
        raise ValueError(f"normals must be 'smooth' or 'flat'; got {normals!r}")
    if obj is None or not hasattr(obj, "dim"):
        raise ValueError(f"obj must be an object of grasp_jax.objects (for example grasp_jax.objects.load('glass')) "
                         f"or a grasp_jax.surfaces.Surface; got {type(obj).__name__}")
    return for_object(obj, normals=normals)


def _immutable(obj) -> bool:
    """Frozen dataclasses (the library's meshes and polygons): safe to cache a surface for."""
    return dataclasses.is_dataclass(obj) and obj.__dataclass_params__.frozen


def _hashable(key) -> bool:
    try:
        hash(key)
    except TypeError:
        return False
    return True
