"""An object for the hand optimizer: a signed-distance grid of fixed shape and surface points.

The grid (:data:`RESOLUTION` cubed, over the object's bounding cube with a margin) and a fixed
number of surface points are pytree *data*: objects of different meshes run the same compiled
program. Distances are trilinear in the grid (outside it: the grid's value at the closest grid
point plus the distance to it); negative inside. Normals are trilinear in a second grid of the
exact distance's gradient (the direction from the mesh's closest point: the face normal over a
face, turning around an edge), which follows the faces that ``gj.evaluate`` reads where the
optimizer puts contacts more closely than the distance grid's own gradient. Grids are cached in
memory and on disk
(``$XDG_CACHE_HOME/grasp_jax/sdf``, keyed by a hash of the mesh and the layout).
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import trimesh
from scipy.spatial import cKDTree

from ..storage import write_atomically

#: Grid points per axis, surface points kept, and the grid's margin around the object (m, at
#: least, or this share of its radius).
RESOLUTION = 64
SURFACE_POINTS = 64
MARGIN, MARGIN_SHARE = 0.02, 0.3
#: Surface samples of the nearest-sample distance; grid points closer than this many cells to the
#: surface get trimesh's exact closest point instead.
DENSE_SAMPLES = 200_000
BAND_CELLS = 2.0
#: Grid points farther than NEAR (m) from every dense sample take their distance from every
#: COARSE-th sample (at most about a millimetre more; a fifth of the time on a sphere).
NEAR, COARSE = 0.015, 10

_MEMORY: dict = {}
#: Bumped when the cached arrays change.
_LAYOUT = 2


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ObjectGeometry:
    """Attributes: ``grid: (R, R, R)`` signed distances (m) at ``origin + cell * (i, j, k)``;
    ``normal_grid: (R, R, R, 3)`` the distance's unit gradient there; ``origin: (3,)``;
    ``cell: ()``; ``center: (3,)`` and ``scale: ()`` the object's centre and radius;
    ``points, normals: (P, 3)`` surface points and outward normals."""

    grid: jax.Array
    normal_grid: jax.Array
    origin: jax.Array
    cell: jax.Array
    center: jax.Array
    scale: jax.Array
    points: jax.Array
    normals: jax.Array


def _cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "grasp_jax" / "sdf"


def _key(mesh: trimesh.Trimesh, center, radius) -> str:
    h = hashlib.sha256()
    for a in (mesh.vertices, mesh.faces, center, [_LAYOUT, radius, RESOLUTION, SURFACE_POINTS, MARGIN, MARGIN_SHARE,
                                                  DENSE_SAMPLES, BAND_CELLS, NEAR, COARSE]):
        h.update(np.ascontiguousarray(np.asarray(a, dtype=np.float64)).tobytes())
    return h.hexdigest()[:32]


def geometry(obj) -> ObjectGeometry:
    """The :class:`ObjectGeometry` of a :class:`grasp_jax.objects.Mesh` (or any 3D object of
    :mod:`grasp_jax.objects` with a ``mesh``), from the caches when they hold it."""
    mesh = getattr(obj, "mesh", None)
    if getattr(obj, "dim", 3) != 3 or not isinstance(mesh, trimesh.Trimesh):
        raise ValueError(f"a hand grasps a 3D mesh object (grasp_jax.objects.load of a mesh file or 'glass'); "
                         f"got {type(obj).__name__}")
    center, radius = np.asarray(obj.center, dtype=np.float64), float(obj.radius)
    key = _key(mesh, center, radius)
    if key not in _MEMORY:
        path = _cache_dir() / f"{key}.npz"
        arrays = None
        if path.is_file():
            try:
                with np.load(path) as f:
                    arrays = {k: f[k] for k in f.files}
            except (OSError, ValueError):
                arrays = None
        if arrays is None:
            arrays = _build(mesh, center, radius)
            _store(path, arrays)
        _MEMORY[key] = ObjectGeometry(**arrays)
    return _MEMORY[key]


def _store(path: Path, arrays: dict) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomically(path, lambda f: np.savez(f, **arrays), mode="wb", what="SDF cache file")
    except (OSError, ValueError):  # an unwritable cache is no error
        pass


def _build(mesh: trimesh.Trimesh, center: np.ndarray, radius: float) -> dict:
    half = radius + max(MARGIN, MARGIN_SHARE * radius)
    cell = 2 * half / (RESOLUTION - 1)
    origin = center - half
    axis = np.arange(RESOLUTION) * cell
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3) + origin
    samples, faces = trimesh.sample.sample_surface(mesh, DENSE_SAMPLES, seed=0)
    normals = mesh.face_normals[faces]
    dist, nearest = cKDTree(samples).query(grid, workers=-1, distance_upper_bound=NEAR)
    far = ~np.isfinite(dist)
    if far.any():
        dist[far], coarse = cKDTree(samples[::COARSE]).query(grid[far], workers=-1)
        nearest[far] = coarse * COARSE
    sign = np.sign(np.einsum("ij,ij->i", grid - samples[nearest], normals[nearest]))
    away, face = grid - samples[nearest], normals[nearest]  # the gradient's direction, as sign
    band = np.flatnonzero(dist < BAND_CELLS * cell)
    if len(band):
        closest, exact, tri = trimesh.proximity.closest_point(mesh, grid[band])
        side = np.einsum("ij,ij->i", grid[band] - closest, mesh.face_normals[tri])
        # on an edge or corner the face normal can be tangent: keep the samples' sign there
        sign[band] = np.where(np.abs(side) > 1e-3 * exact, np.sign(side), sign[band])
        dist[band] = exact
        away[band], face[band] = grid[band] - closest, mesh.face_normals[tri]
    sign = np.where(sign == 0, 1.0, sign)
    sdf = sign * dist
    length = np.linalg.norm(away, axis=1, keepdims=True)
    direction = sign[:, None] * away / np.maximum(length, 1e-300)
    normal = np.where(length > 1e-9 * cell, direction, face)  # on the surface: the face's normal
    rng = np.random.default_rng(0)
    pick = rng.choice(len(samples), SURFACE_POINTS, replace=False)
    return {"grid": sdf.reshape((RESOLUTION,) * 3), "normal_grid": normal.reshape((RESOLUTION,) * 3 + (3,)),
            "origin": origin, "cell": np.asarray(cell),
            "center": center, "scale": np.asarray(radius), "points": samples[pick], "normals": normals[pick]}


def distance(geom: ObjectGeometry, x) -> jax.Array:
    """Signed distance ``()`` of one point ``x: (3,)`` to the object (negative inside)."""
    u = (x - geom.origin) / geom.cell
    inside = jnp.clip(u, 0.0, geom.grid.shape[0] - 1.0)
    outside = jnp.sqrt(jnp.sum((u - inside) ** 2) + 1e-30) * geom.cell
    value = _trilinear(geom.grid, geom.origin, geom.cell, x)
    return value + jnp.where(jnp.any(u != inside), outside, 0.0)


def _trilinear(grid, origin, cell, x):
    """``grid: (R, R, R, ...)`` trilinear at ``x: (3,)``, clamped to the grid."""
    size = grid.shape[0]
    inside = jnp.clip((x - origin) / cell, 0.0, size - 1.0)
    base = jnp.clip(jnp.floor(inside), 0, size - 2).astype(jnp.int32)
    t = inside - base
    g = jax.lax.dynamic_slice(grid, (*base, *(jnp.int32(0),) * (grid.ndim - 3)),
                              (2, 2, 2) + grid.shape[3:])
    g = g[0] * (1 - t[0]) + g[1] * t[0]
    g = g[0] * (1 - t[1]) + g[1] * t[1]
    return g[0] * (1 - t[2]) + g[1] * t[2]


def distance_and_normal(geom: ObjectGeometry, x) -> tuple[jax.Array, jax.Array]:
    """``(distance (), outward unit normal (3,))`` at one point: the normal of the mesh's closest
    point, interpolated in ``normal_grid``."""
    d = distance(geom, x)
    g = _trilinear(geom.normal_grid, geom.origin, geom.cell, x)
    norm = jnp.sqrt(jnp.sum(g * g))
    safe = norm > 1e-12
    return d, jnp.where(safe, g / jnp.where(safe, norm, 1.0), jnp.zeros_like(g).at[2].set(1.0))
