"""Drawing helpers shared by the figures and the pages: colours, polygons, meshes, grasp checks."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

#: Colours used throughout: contacts, cones, the reference contact c_1, the object (matplotlib
#: faces, plotly meshes), central axes, contact paths, jaws.
CONTACT = "#1f4e9c"
CONE = "#e8833a"
FIRST = "#c0262d"
OBJECT = "#c9d3df"
OBJECT_MESH = "#9fb3cc"
AXIS = "#2c8a3c"
PATH = "#7b3fa0"
JAW = "#5d6d7e"


def check_grasp(points, normals, d: int | None = None):
    points = np.asarray(points, dtype=float)
    normals = np.asarray(normals, dtype=float)
    if points.ndim != 2 or points.shape != normals.shape or points.shape[-1] not in (2, 3):
        raise ValueError(
            "points and normals must be (n, d) arrays of one grasp with d in {2, 3}; "
            f"got {points.shape} and {normals.shape}"
        )
    if d is not None and points.shape[-1] != d:
        raise ValueError(f"expected a {d}D grasp; got points of shape {points.shape}")
    if len(points) < 1:
        raise ValueError("a grasp needs at least one contact")
    normals = normals / np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-300)
    return points, normals


def as_rings(rings_or_vertices) -> list[np.ndarray]:
    """A polygon given as one ``(k, 2)`` vertex array or a list of rings (outer first, then holes)."""
    if isinstance(rings_or_vertices, np.ndarray) and rings_or_vertices.ndim == 2:
        rings = [rings_or_vertices]
    elif hasattr(rings_or_vertices, "rings"):
        rings = list(rings_or_vertices.rings)
    else:
        rings = list(rings_or_vertices)
        if rings and np.ndim(rings[0]) == 1:  # a list of (x, y) pairs: one ring
            rings = [np.asarray(rings)]
    rings = [np.asarray(r, dtype=float) for r in rings]
    for r in rings:
        if r.ndim != 2 or r.shape[1] != 2 or len(r) < 3:
            raise ValueError(f"each polygon ring must be a (k >= 3, 2) array; got {r.shape}")
    return rings


def signed_area(ring: np.ndarray) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def decimate(vertices, faces, max_faces: int = 10000):
    """Coarsen a triangle mesh to at most ``max_faces`` faces by vertex clustering (for drawing only).

    Vertices are snapped to a cubic grid whose cell grows until few enough distinct, non-degenerate
    triangles remain. Topology is not preserved exactly; the silhouette is.

    Args:
        vertices: ``(V, 3)``; faces: ``(F, 3)`` int.
        max_faces: face budget.

    Returns:
        ``(vertices (V', 3), faces (F', 3))``, unchanged when ``F <= max_faces``.
    """
    vertices = np.asarray(vertices, dtype=float)
    faces = np.asarray(faces, dtype=np.int64)
    if len(faces) <= max_faces:
        return vertices, faces
    extent = float(np.max(vertices.max(0) - vertices.min(0)))
    cell = extent * math.sqrt(2.0 * 1.2 / max_faces)  # a closed surface of area ~ extent^2 * 1.2
    for _ in range(40):
        keys = np.floor((vertices - vertices.min(0)) / cell).astype(np.int64)
        uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        sums = np.zeros((len(uniq), 3))
        np.add.at(sums, inverse, vertices)
        new_v = sums / np.bincount(inverse, minlength=len(uniq))[:, None]
        f = inverse[faces]
        f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
        _, first = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
        f = f[np.sort(first)]
        if len(f) <= max_faces:
            return new_v, f
        cell *= 1.25
    return new_v, f


def mesh_arrays(mesh_or_vertices_faces):
    if hasattr(mesh_or_vertices_faces, "vertices") and hasattr(mesh_or_vertices_faces, "faces"):
        return np.asarray(mesh_or_vertices_faces.vertices, float), np.asarray(mesh_or_vertices_faces.faces)
    if hasattr(mesh_or_vertices_faces, "mesh"):
        return mesh_arrays(mesh_or_vertices_faces.mesh)
    vertices, faces = mesh_or_vertices_faces
    vertices, faces = np.asarray(vertices, float), np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"expected (V, 3) vertices and (F, 3) faces; got {vertices.shape}, {faces.shape}")
    return vertices, faces


def unit(v):
    v = np.asarray(v, float)
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-300)


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (non-interactive, thread-safe enough for scripts)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig, path):
    if path is not None:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=fig.dpi, bbox_inches="tight")
    return fig
