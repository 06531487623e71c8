"""Objects to grasp: 2D polygons, 3D meshes from files, analytic shapes and built-in demos.

Every object follows :class:`GraspObject`: ``name``, ``dim``, ``center``, ``radius``,
``warnings``, ``sample_surface(count, rng)`` and ``facets()``, normals outward and unit. Objects
keep the units of their file; ``center`` and ``radius`` give the scale. User mistakes raise
:class:`ObjectError` (a ``ValueError``) with one sentence.

>>> from grasp_jax import objects
>>> objects.load("glass").mesh.faces.shape
(9486, 3)
"""

from __future__ import annotations

from pathlib import Path

from ._base import GraspObject as GraspObject
from ._base import ObjectError as ObjectError
from ._builtin import glass as glass
from ._builtin import part as part
from ._builtin import quad as quad
from ._builtin import star as star
from ._mesh import Mesh as Mesh
from ._polygon import Polygon as Polygon
from ._shapes import Box as Box
from ._shapes import Cylinder as Cylinder
from ._shapes import Ellipsoid as Ellipsoid
from ._shapes import Sphere as Sphere

_BUILTINS = {
    "glass": glass,
    "part": part,
    "quad": quad,
    "star": star,
    "sphere": Sphere,
    "box": Box,
    "cylinder": Cylinder,
    "ellipsoid": Ellipsoid,
}

#: Names :func:`load` understands besides file paths.
BUILTIN_NAMES: tuple[str, ...] = tuple(_BUILTINS)


def load(spec, holes=()) -> GraspObject:
    """A built-in object by name (:data:`BUILTIN_NAMES`) or an object from a file: ``.csv`` ->
    :class:`Polygon` (x,y rows), anything else -> :class:`Mesh` (any format trimesh reads).

    ``holes``: CSV files of x,y rows, one per hole of a polygon read from a ``.csv`` ``spec``.

    Raises:
        ObjectError: unknown name, missing or unreadable file, or unusable geometry.
    """
    text = str(spec)
    holes = [Path(h).expanduser() for h in (holes or ())]
    is_csv = Path(text).suffix.lower() == ".csv"
    if holes and not is_csv:
        raise ObjectError(f"{text!r}: holes can only be cut from a polygon read from a .csv file; "
                          "give the polygon's exterior as a CSV of x,y rows.")
    for hole in holes:
        if hole.suffix.lower() != ".csv" or not hole.is_file():
            what = "not found" if not hole.is_file() else "not a .csv file"
            raise ObjectError(f"hole {str(hole)!r}: {what}; give a CSV file of x,y rows.")
    if text.lower() in _BUILTINS and not Path(text).is_file():
        return _BUILTINS[text.lower()]()
    path = Path(text).expanduser()
    if path.is_dir():
        raise ObjectError(f"{text!r} is a directory; give a mesh or CSV file in it or one of: "
                          f"{', '.join(BUILTIN_NAMES)}.")
    if not path.is_file():
        raise ObjectError(f"{text!r} is neither a file nor a built-in object; give a mesh or CSV path "
                          f"or one of: {', '.join(BUILTIN_NAMES)}.")
    if is_csv:
        return Polygon.from_csv(path, holes=holes)
    return Mesh.from_file(path)


__all__ = [
    "BUILTIN_NAMES",
    "Box",
    "Cylinder",
    "Ellipsoid",
    "GraspObject",
    "Mesh",
    "ObjectError",
    "Polygon",
    "Sphere",
    "glass",
    "load",
    "part",
    "quad",
    "star",
]
