"""The object of a simulation: convex parts of its mesh, cached on disk, and its mass.

MuJoCo collides each mesh geom as its convex hull, so a concave object is given as the convex parts
of a decomposition (CoACD by default, V-HACD through ``vhacdx`` as the faster, coarser choice).
CoACD remeshes its input first, which inflates the parts by up to a voxel; each part is therefore
replaced by the convex hull of the mesh's own vertices within ``fit`` of it. A decomposition is
cached per mesh in :func:`cache_dir` under a key made of a hash of the vertices and faces and of the
parameters. The mass is spread uniformly over the union of the parts.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..grippers._contacts import as_trimesh
from ..storage import write_atomically

#: Default total mass of an object, kg (DexGraspBench's main branch: 100 g for every object).
MASS = 0.1
#: A mesh whose convex hull holds less than this fraction of its bounding-box diagonal cubed is flat.
FLAT = 1e-6
#: Version of the cache's layout; a change makes earlier entries unused.
_CACHE_VERSION = 2


@dataclass(frozen=True)
class Decomposition:
    """Parameters of a convex decomposition (part of the cache key).

    Attributes:
        method: ``"coacd"`` (CoACD: tighter parts, slower) or ``"vhacd"`` (V-HACD via ``vhacdx``).
        threshold: CoACD's concavity threshold (larger: fewer, coarser parts; CoACD's own default
            is 0.05: on the YCB mug 67 parts in 68 s, on the cups 98 in 132 s; 0.1: 29 parts in 28 s and
            35 in 22 s).
        resolution: CoACD's sampling resolution / V-HACD's voxel count.
        max_parts: at most this many parts (-1: no limit for CoACD; V-HACD's ``maxConvexHulls``).
        max_vertices: at most this many vertices per part.
        mcts_iterations, mcts_nodes: CoACD's search budget (its defaults: 150 and 20).
        preprocess_resolution: CoACD's manifold preprocessing resolution (its default: 50).
        seed: CoACD's random seed.
        fit: each part becomes the convex hull of the mesh vertices within this fraction of the
            mesh's bounding-box diagonal of it (about 1 mm for a 17 cm mug); 0: parts as given.
    """

    method: str = "coacd"
    threshold: float = 0.1
    resolution: int = 1000
    max_parts: int = -1
    max_vertices: int = 64
    mcts_iterations: int = 60
    mcts_nodes: int = 10
    preprocess_resolution: int = 30
    seed: int = 0
    fit: float = 0.006

    def __post_init__(self):
        if self.method not in ("coacd", "vhacd"):
            raise ValueError(f"method must be 'coacd' or 'vhacd'; got {self.method!r}")
        if not (isinstance(self.threshold, (int, float)) and 0 < self.threshold <= 1):
            raise ValueError(f"threshold must be in (0, 1]; got {self.threshold!r}")
        if not (isinstance(self.fit, (int, float)) and 0 <= self.fit < 1):
            raise ValueError(f"fit must be in [0, 1); got {self.fit!r}")
        if self.max_vertices < 4:
            raise ValueError(f"max_vertices must be at least 4; got {self.max_vertices!r}")


@dataclass(frozen=True)
class SimObject:
    """An object ready for MuJoCo: its convex parts, mass and inertia (object frame, SI units).

    Attributes:
        parts: tuple of ``(vertices (v_i, 3) float64, faces (f_i, 3) int32)``, each convex.
        mass: total mass, kg.
        com: ``(3,)`` centre of mass.
        inertia: ``(3, 3)`` inertia tensor about the centre of mass.
        scale: the object's size (the diagonal of its bounding box), for thresholds.
    """

    parts: tuple
    mass: float
    com: np.ndarray
    inertia: np.ndarray
    scale: float


def cache_dir() -> Path:
    """Where decompositions are cached: ``$GRASP_JAX_CONVEX_CACHE``, else
    ``~/.cache/grasp_jax/convex``."""
    env = os.environ.get("GRASP_JAX_CONVEX_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "grasp_jax" / "convex"


def _key(vertices: np.ndarray, faces: np.ndarray, params: Decomposition) -> str:
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(vertices, np.float64).tobytes())
    h.update(np.ascontiguousarray(faces, np.int64).tobytes())
    h.update(json.dumps({"v": _CACHE_VERSION, **asdict(params)}, sort_keys=True).encode())
    return h.hexdigest()[:32]


def _run(vertices, faces, params: Decomposition) -> list:
    if params.method == "coacd":
        import coacd

        coacd.set_log_level("error")
        parts = coacd.run_coacd(
            coacd.Mesh(vertices, faces), threshold=params.threshold, resolution=params.resolution,
            max_convex_hull=params.max_parts, preprocess_resolution=params.preprocess_resolution,
            mcts_iterations=params.mcts_iterations, mcts_nodes=params.mcts_nodes,
            max_ch_vertex=params.max_vertices, seed=params.seed)
    else:
        import vhacdx

        parts = vhacdx.compute_vhacd(
            np.asarray(vertices, np.float64), np.asarray(faces, np.uint32),
            maxConvexHulls=params.max_parts if params.max_parts > 0 else 32,
            resolution=params.resolution * 100,
            maxNumVerticesPerCH=params.max_vertices, asyncACD=False)
    return [(np.asarray(v, np.float64), np.asarray(f, np.int32)) for v, f in parts]


def _hull(points: np.ndarray):
    """The convex hull of ``points`` as a trimesh, or ``None`` where it has no volume."""
    import trimesh

    if len(points) < 4:
        return None
    try:
        hull = trimesh.Trimesh(points).convex_hull
    except Exception:  # noqa: BLE001 - qhull fails on flat point sets, which have no volume
        return None
    return hull if hull.volume > 0 and np.isfinite(hull.volume) else None


def _hulls(parts: list, vertices: np.ndarray, tol: float) -> list:
    """Each part as a convex trimesh, fitted to the mesh ``vertices`` within ``tol`` (> 0), dropping
    parts without volume."""
    out = []
    for v, _ in parts:
        hull = _hull(v)
        if hull is None:
            continue
        if tol > 0:
            offsets = np.einsum("ij,ij->i", hull.face_normals, hull.triangles[:, 0])
            inside = (vertices @ hull.face_normals.T - offsets <= tol).all(axis=1)
            fitted = _hull(vertices[inside])
            hull = hull if fitted is None else fitted
        out.append(hull)
    return out


def decompose(mesh, params: Decomposition | None = None, *, cache: bool = True) -> list:
    """The convex parts of ``mesh`` (a ``trimesh.Trimesh`` or :class:`grasp_jax.objects.Mesh`):
    a list of ``(vertices (v, 3) float64, faces (f, 3) int32)``, read from the cache when there.

    Raises:
        ValueError: the mesh has no triangles, or the decomposition gives no part with volume.
    """
    params = Decomposition() if params is None else params
    tm = as_trimesh(mesh)
    vertices, faces = np.asarray(tm.vertices, np.float64), np.asarray(tm.faces, np.int64)
    if not np.isfinite(vertices).all():
        raise ValueError("mesh has non-finite vertices; it cannot be decomposed")
    diagonal = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    outline = _hull(vertices)
    if outline is None or outline.volume <= FLAT * diagonal**3:
        raise ValueError("the mesh cannot be decomposed into convex parts: it encloses no volume (flat or "
                         "degenerate)")
    path = cache_dir() / f"{_key(vertices, faces, params)}.npz"
    if cache and path.exists():
        with np.load(path) as f:
            count = int(f["count"])
            return [(f[f"v{i}"], f[f"f{i}"]) for i in range(count)]
    try:
        tol = params.fit * diagonal
        hulls = _hulls(_run(vertices, faces, params), vertices, tol)
    except (RuntimeError, ValueError) as e:
        raise ValueError(f"the mesh cannot be decomposed into convex parts ({params.method}: {e})") from None
    if not hulls:
        raise ValueError(f"the mesh cannot be decomposed into convex parts: {params.method} gave no part "
                         "with volume (a flat or degenerate mesh?)")
    parts = [(np.asarray(h.vertices, np.float64), np.asarray(h.faces, np.int32)) for h in hulls]
    if cache:
        arrays = {"count": np.int64(len(parts))}
        for i, (v, f) in enumerate(parts):
            arrays[f"v{i}"], arrays[f"f{i}"] = v, f
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomically(path, lambda fh: np.savez(fh, **arrays), mode="wb", what="decomposition cache file")
    return parts


def sim_object(mesh, *, mass: float = MASS, params: Decomposition | None = None,
               cache: bool = True) -> SimObject:
    """The :class:`SimObject` of a mesh: :func:`decompose`, then ``mass`` kg spread uniformly over
    the parts (their overlaps counted twice, a small error for a decomposition's thin overlaps).

    Raises:
        ValueError: ``mass`` not > 0, or as :func:`decompose`.
    """
    import trimesh

    if not (isinstance(mass, (int, float)) and math.isfinite(mass) and mass > 0):
        raise ValueError(f"mass must be a finite number of kg > 0; got {mass!r}")
    parts = decompose(mesh, params, cache=cache)
    hulls = [trimesh.Trimesh(v, f) for v, f in parts]
    volumes = np.array([h.volume for h in hulls])
    density = mass / volumes.sum()
    com = sum(h.center_mass * w for h, w in zip(hulls, volumes)) / volumes.sum()
    inertia = np.zeros((3, 3))
    for h, vol in zip(hulls, volumes):
        d = h.center_mass - com
        inertia += density * h.moment_inertia + density * vol * (d @ d * np.eye(3) - np.outer(d, d))
    bounds = np.concatenate([v for v, _ in parts])
    scale = float(np.linalg.norm(bounds.max(0) - bounds.min(0)))
    return SimObject(tuple(parts), float(mass), com, inertia, scale)
