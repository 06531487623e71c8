"""The surface of any grasp_jax object."""

from __future__ import annotations

import weakref

from . import _analytic, _simplicial

#: default crease angle (degrees) of smooth normals: sharper edges stay sharp
CREASE_ANGLE = 45.0


#: Surfaces of meshes and polygons already built, per object (they are immutable; building the
#: glass's takes about 60 ms, a tenth of a 1,024-start x 20-step ``gj.optimize`` call).
_BUILT: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def for_object(obj, *, normals: str = "smooth", crease_angle: float = CREASE_ANGLE,
               max_crossings: int = _simplicial.MAX_CROSSINGS):
    """The :class:`~grasp_jax.surfaces.Surface` of ``obj``.

    Args:
        obj: a :class:`grasp_jax.objects.Polygon`, :class:`~grasp_jax.objects.Mesh` (the built-in
            ``glass`` and ``part`` too) or analytic shape (``Sphere``, ``Ellipsoid``, ``Box``,
            ``Cylinder``).
        normals: meshes and polygons: ``"smooth"`` (corner normals interpolated, edges sharper
            than ``crease_angle`` kept sharp) or ``"flat"`` (face normals). Analytic shapes always
            have exact normals (``normal_kind == "exact"``).
        crease_angle: degrees.
        max_crossings: the most faces (polygon edges) one ``retract`` passes through.

    Raises:
        TypeError: an object of another kind.
        ValueError: a bad ``normals``, ``crease_angle`` or ``max_crossings``.
    """
    from .. import objects

    if normals not in ("smooth", "flat"):
        raise ValueError(f"normals must be 'smooth' or 'flat'; got {normals!r}")
    kind = {objects.Sphere: _analytic.for_sphere, objects.Ellipsoid: _analytic.for_ellipsoid,
            objects.Box: _analytic.for_box, objects.Cylinder: _analytic.for_cylinder}
    for cls, build in kind.items():
        if isinstance(obj, cls):
            return build(obj)
    options = {"normals": normals, "crease_angle": crease_angle, "max_crossings": max_crossings}
    if isinstance(obj, objects.Polygon):
        build = _simplicial.for_polygon
    elif isinstance(obj, objects.Mesh) or hasattr(obj, "mesh") and getattr(obj, "dim", 3) == 3:
        build = _simplicial.for_mesh
    else:
        raise TypeError(f"for_object: no surface for {type(obj).__name__}; give a grasp_jax object "
                        "(Polygon, Mesh, Sphere, Ellipsoid, Box, Cylinder).")
    key = (normals, crease_angle, max_crossings)
    if not isinstance(obj, (objects.Polygon, objects.Mesh)) or not _hashable(key):  # duck-typed: may be mutable
        return build(obj, **options)
    built = _BUILT.setdefault(obj, {})
    if key not in built:
        built[key] = build(obj, **options)
    return built[key]


def _hashable(key) -> bool:
    try:
        hash(key)
    except TypeError:
        return False
    return True
