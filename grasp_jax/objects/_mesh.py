"""3D objects: triangle meshes from files or ``trimesh.Trimesh``, cleaned and oriented outward.

Real meshes are messy. Every mesh is re-merged by position (UV seams of textured scans split
vertices), loses its zero-area faces, and gets consistent outward normals: ``trimesh``'s
``fix_normals`` for a closed volume; otherwise the winding is made consistent across shared
edges and each connected body is flipped so that its normals point away from its centroid on
average. What could make results unreliable is said in ``Mesh.warnings``.
"""

from __future__ import annotations

import functools
import warnings as _warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import ClassVar

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
import trimesh

from ._base import ObjectError, Picker, check_count


def center_radius(tm: trimesh.Trimesh, closed: bool) -> tuple[np.ndarray, float]:
    """An object's centre and radius from its triangles: the centre of mass of a ``closed`` volume,
    else the area centroid; the largest distance from it to a vertex."""
    if closed:
        center = np.asarray(tm.center_mass, dtype=float)
    else:
        center = (tm.area_faces[:, None] * tm.triangles_center).sum(0) / tm.area
    return center, float(np.linalg.norm(tm.vertices - center, axis=1).max())


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh. Build it with :meth:`from_file` or :meth:`from_trimesh`.

    Attributes:
        name: short name (the file's stem).
        mesh: the cleaned ``trimesh.Trimesh``, normals outward.
        center: ``(3,) float`` centre of mass of the enclosed volume, or the area centroid of the
            surface when the mesh is open (has boundary edges) or encloses no positive volume.
        radius: largest distance from ``center`` to a vertex.
        warnings: reasons results may be unreliable.
        source: the file it was read from, absolute (``""`` when built from a ``trimesh``).
    """

    name: str
    mesh: trimesh.Trimesh
    center: np.ndarray
    radius: float
    warnings: tuple[str, ...] = ()
    source: str = ""
    dim: ClassVar[int] = 3

    @classmethod
    def from_file(cls, path, *, name: str | None = None) -> Mesh:
        """Any file ``trimesh`` loads (OBJ, STL, PLY, OFF, GLB, ...), in the file's units."""
        path = Path(path)
        if not path.is_file():
            raise ObjectError(f"{path}: file not found; check the path.")
        with _warnings.catch_warnings(record=True) as caught:
            _warnings.simplefilter("always")
            try:
                loaded = trimesh.load(path, force="mesh", process=True, merge_tex=True, merge_norm=True)
            except Exception as exc:  # noqa: BLE001 - every loader failure is an unreadable file
                message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                raise ObjectError(f"{path}: trimesh cannot read it ({message}); give a mesh file "
                                  "such as OBJ, STL, PLY or OFF.") from None
        if not isinstance(loaded, trimesh.Trimesh):
            raise ObjectError(f"{path}: holds no triangle mesh (got {type(loaded).__name__}); give a "
                              "file with faces.")
        notes = [f"trimesh: {w.message}" for w in caught if not issubclass(w.category, DeprecationWarning)]
        mesh = cls.from_trimesh(loaded, name=name or path.stem, where=str(path), notes=notes)
        return replace(mesh, source=str(path.resolve()))

    @classmethod
    def from_trimesh(cls, mesh: trimesh.Trimesh, *, name: str = "mesh", where: str | None = None,
                     notes=()) -> Mesh:
        """A cleaned, outward-oriented copy of ``mesh`` (the input is not modified).

        ``where`` names the mesh in error messages (default ``mesh 'name'``); ``notes`` are
        warnings to keep in ``.warnings``."""
        where = where or f"mesh {name!r}"
        vertices = np.asarray(mesh.vertices, dtype=float)
        faces = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
        if len(faces) == 0:
            raise ObjectError(f"{where}: has no triangles; give a mesh with faces, not a point cloud "
                              "or curve.")
        if not np.isfinite(vertices).all():
            raise ObjectError(f"{where}: has non-finite vertex coordinates; repair or re-export the mesh.")
        tm = trimesh.Trimesh(vertices, faces, process=True)  # merge vertices by position
        notes = list(notes)
        scale = float(np.linalg.norm(tm.extents))
        keep = tm.area_faces > 1e-12 * scale**2
        if not keep.any():
            raise ObjectError(f"{where}: all {len(faces)} triangles have zero area; give a mesh with "
                              "a surface.")
        if not keep.all():
            notes.append(f"removed {int((~keep).sum())} zero-area triangles")
            tm.update_faces(keep)
            tm.remove_unreferenced_vertices()
        if len(tm.face_adjacency) == 0 and len(tm.faces) > 1:
            raise ObjectError(f"{where}: none of its {len(tm.faces)} triangles share an edge (a triangle "
                              "soup), so no outward side can be found; give a connected surface.")
        labels = _bodies(tm)
        if tm.is_volume:
            trimesh.repair.fix_normals(tm, multibody=True)
        else:
            flipped = _fix_winding(tm, labels)
            if flipped:
                notes.append(f"face winding was inconsistent: flipped {flipped} of {len(tm.faces)} triangles")
            if not tm.is_winding_consistent:
                notes.append("face winding cannot be made consistent (non-orientable or non-manifold "
                             "surface)")
            _orient_bodies(tm, labels)
        counts = np.unique(tm.edges_sorted, axis=0, return_counts=True)[1]
        notes.extend(_reliability(counts, labels))
        closed = (counts >= 2).all() and tm.is_winding_consistent and tm.volume > 0
        center, radius = center_radius(tm, closed)
        return cls(name=name, mesh=tm, center=center, radius=radius, warnings=tuple(notes))

    @functools.cached_property
    def _sampler(self) -> tuple[Picker, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Face picker, first corners, two edge vectors and normals of the faces, ``(F, 3)``."""
        tri = np.asarray(self.mesh.triangles, dtype=float)
        return (Picker(self.mesh.area_faces), tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0],
                np.asarray(self.mesh.face_normals, dtype=float))

    def facets(self) -> tuple[np.ndarray, np.ndarray]:
        """Triangle centroids ``(F, 3) float`` and outward unit normals ``(F, 3) float``."""
        return np.asarray(self.mesh.triangles_center, float), np.asarray(self.mesh.face_normals, float)

    def sample_surface(self, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """``count`` points uniform by area and their faces' outward unit normals,
        ``(count, 3) float`` each."""
        pick, corner, edge1, edge2, normals = self._sampler
        index = pick(check_count(count), rng)
        s, t = rng.random((2, count))
        # the gaps (lo, hi - lo, 1 - hi) between two sorted uniforms are uniform barycentrics
        lo, hi = np.minimum(s, t)[:, None], np.maximum(s, t)[:, None]
        points = corner[index]
        points += (hi - lo) * edge1[index]
        points += (1.0 - hi) * edge2[index]
        return points, normals[index]

def _bodies(tm: trimesh.Trimesh) -> np.ndarray:
    """Connected-component label of every face (faces joined by shared edges), ``(F,) int``."""
    n = len(tm.faces)
    pairs = tm.face_adjacency
    graph = scipy.sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return scipy.sparse.csgraph.connected_components(graph, directed=False)[1]


def _fix_winding(tm: trimesh.Trimesh, labels: np.ndarray) -> int:
    """Flip faces so that every shared edge is traversed in opposite directions by its two faces
    (trimesh's ``fix_winding`` needs networkx); returns how many faces were flipped."""
    if tm.is_winding_consistent:
        return 0
    faces, pairs, edges = tm.faces.copy(), tm.face_adjacency, tm.face_adjacency_edges

    def forward(f):  # whether face f runs edges[:, 0] -> edges[:, 1]
        pos0 = np.argmax(faces[f] == edges[:, :1], axis=1)
        pos1 = np.argmax(faces[f] == edges[:, 1:], axis=1)
        return (pos1 - pos0) % 3 == 1

    differ = forward(pairs[:, 0]) == forward(pairs[:, 1])  # True: one of the two must flip
    n = len(faces)
    rel = scipy.sparse.coo_matrix((differ + 1.0, (pairs[:, 0], pairs[:, 1])), shape=(n, n)).tocsr()
    rel = rel + rel.T
    flip = np.zeros(n, dtype=bool)
    for body in range(labels.max() + 1):
        root = int(np.argmax(labels == body))
        order, parent = scipy.sparse.csgraph.breadth_first_order(rel, root, directed=False)
        child = order[1:]
        step = np.asarray(rel[parent[child], child]).ravel() == 2.0
        for node, s in zip(child, step):
            flip[node] = flip[parent[node]] ^ s
    faces[flip] = faces[flip][:, ::-1]
    tm.faces = faces
    return int(flip.sum())


def _orient_bodies(tm: trimesh.Trimesh, labels: np.ndarray) -> None:
    """Flip each body whose normals point towards its area centroid on average (for a closed
    body: whose signed volume is negative)."""
    area = tm.area_faces
    total = np.bincount(labels, weights=area)
    centroid = np.stack([np.bincount(labels, weights=area * x) for x in tm.triangles_center.T], 1)
    centroid /= total[:, None]
    offset = tm.triangles_center - centroid[labels]
    flux = np.bincount(labels, weights=area * np.einsum("ij,ij->i", offset, tm.face_normals))
    flip = flux[labels] < 0
    if flip.any():
        faces = tm.faces.copy()
        faces[flip] = faces[flip][:, ::-1]
        tm.faces = faces


def _reliability(counts: np.ndarray, labels: np.ndarray) -> list[str]:
    """Warnings about an open surface, non-manifold edges and several bodies, from the number of
    faces at each edge ``counts: (E,) int`` and the body of each face ``labels: (F,) int``."""
    notes = []
    open_edges, non_manifold = int((counts == 1).sum()), int((counts > 2).sum())
    if open_edges:
        notes.append(f"surface is open ({open_edges} boundary edges): the centre is the surface "
                     "centroid and which side is outward is a guess")
    if non_manifold:
        notes.append(f"{non_manifold} non-manifold edges (shared by more than two triangles)")
    bodies = labels.max() + 1
    if bodies > 1:
        notes.append(f"{bodies} separate bodies treated as one rigid object (overlapping bodies "
                     "bias the centre of mass)")
    return notes
