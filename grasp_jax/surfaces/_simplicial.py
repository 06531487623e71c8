"""Simplicial surfaces: triangle meshes (d = 3) and polygon boundaries with holes (d = 2), one
implementation.

A *face* is a simplex of ``d`` vertices (a triangle, or an edge of a ring); a contact holds its
face index and barycentric coordinates ``b >= 0, sum b = 1``. ``retract(c, v)`` moves along the
barycentric velocity ``G_f v`` until a coordinate reaches 0, steps onto the neighbouring face and
turns the rest of the displacement into its plane, up to ``max_crossings`` times (barycentrics
clipped and renormalized after each crossing; an open mesh's boundary stops the contact).

Normals: ``"flat"`` is the face normal; ``"smooth"`` interpolates per-corner normals (the
angle-weighted mean, equal-weighted in 2D, of the normals of the faces at the vertex within
``crease_angle`` of the face's), so edges sharper than the crease angle stay sharp.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import scipy.spatial

from .._validate import check_int
from ._base import Contact
from ._util import Fields, check_count, check_one, host_points, jit_method, pytree, tangent, unit

#: pairs of (corner, incidence) handled at once when building corner normals on the host
_CHUNK = 1 << 22

#: default cap on the faces one ``retract`` passes through. Under ``vmap`` a batch runs as many
#: passes as its slowest contact; a step that would cross more faces stops short (still on the
#: surface). On the glass, 16 truncates about 1e-4 of the steps of 0.01 radius and 0.8% of those
#: of 0.05 radius (0.2% of the length lost).
MAX_CROSSINGS = 16


@pytree(data=("vertices", "faces", "normals", "corners", "grads", "neighbors", "crossings", "areas"),
        meta=("max_crossings",))
class SimplicialSurface(Fields):
    """A triangle mesh (``dim = 3``) or polygon boundary (``dim = 2``) as a pytree. Build it with
    :func:`from_simplices` (or :func:`grasp_jax.surfaces.for_object`).

    Attributes:
        vertices: ``(V, d) float``.
        faces: ``(F, d) int32`` vertex indices; a 2D face runs along its ring (material on the left).
        normals: ``(F, d) float`` outward unit face normals.
        corners: ``(F, d, d) float`` unit normal at each face corner (``"smooth"``; the face
            normal repeated for ``"flat"``).
        grads: ``(F, d, d) float`` row ``i``: the gradient of barycentric ``i`` (in the face's
            plane), so ``db = grads[f] @ v``.
        neighbors: ``(F, d) int32`` the face across the sub-simplex opposite corner ``i`` (-1 at a
            boundary; one neighbour, chosen consistently, at a non-manifold edge).
        crossings: ``(F, d, 2d, d) float`` per (face, corner ``i``): rows ``:d`` the rotation
            taking the face's plane onto that neighbour's about the shared edge / vertex (for the
            rest of the displacement), rows ``d:`` the 0/1 matrix taking the barycentrics of a
            point on the shared edge / vertex into the neighbour's.
        areas: ``(F,) float`` triangle areas / edge lengths.
        center: ``(d,) float`` the object's centre.
        dim, scale, normal_kind, max_crossings: static.
    """

    vertices: jax.Array
    faces: jax.Array
    normals: jax.Array
    corners: jax.Array
    grads: jax.Array
    neighbors: jax.Array
    crossings: jax.Array
    areas: jax.Array
    normal_kind: str = "smooth"
    max_crossings: int = MAX_CROSSINGS

    # ---------------------------------------------------------------- pure JAX, one contact

    def _point(self, f, b):
        return b @ jnp.asarray(self.vertices, b.dtype)[jnp.asarray(self.faces)[f]]

    def _normal(self, f, b):
        if self.normal_kind == "flat":
            return jnp.asarray(self.normals, b.dtype)[f]
        return unit(b @ jnp.asarray(self.corners, b.dtype)[f], jnp.asarray(self.normals, b.dtype)[f])

    @jit_method()
    def embed(self, contact: Contact) -> tuple[jax.Array, jax.Array]:
        """``(point (d,), outward unit normal (d,))`` of one contact."""
        check_one("embed", contact, self.dim)
        f, b = jnp.asarray(contact.face), jnp.asarray(contact.coords)
        return self._point(f, b), self._normal(f, b)

    @jit_method()
    def chart(self, contact: Contact, v: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The point ``p + P_f v`` in face ``f``'s plane and the normal interpolated with its
        (linearly extended) barycentrics ``b + G_f v``; ``chart(c, 0) == embed(c)`` exactly."""
        check_one("chart", contact, self.dim, v)
        f, b = jnp.asarray(contact.face), jnp.asarray(contact.coords)
        bv = b + jnp.asarray(self.grads, b.dtype)[f] @ jnp.asarray(v, b.dtype)
        return self._point(f, bv), self._normal(f, bv)

    @jit_method()
    def retract(self, contact: Contact, v: jax.Array) -> Contact:
        """One contact moved by the tangent part of ``v: (d,)`` along the surface, across up to
        ``max_crossings`` edges (2D: corners); what is left of ``v`` after that many is dropped.
        A non-finite ``v`` leaves the contact where it is."""
        check_one("retract", contact, self.dim, v)
        return self.walk(contact, v)[0]

    @jit_method()
    def walk(self, contact: Contact, v: jax.Array) -> tuple[Contact, jax.Array, jax.Array]:
        """``retract`` with diagnostics: ``(contact, passes () int32, rest () float)``: the
        number of loop passes (faces crossed into, plus one) and the length of the displacement
        left when ``max_crossings`` ran out (0 otherwise, or at an open boundary)."""
        check_one("walk", contact, self.dim, v)
        f0, b0 = jnp.asarray(contact.face), jnp.asarray(contact.coords)
        dtype = b0.dtype
        grads = jnp.asarray(self.grads, dtype)
        neighbors = jnp.asarray(self.neighbors)
        crossings = jnp.asarray(self.crossings, dtype)
        d = self.dim
        v = jnp.asarray(v, dtype)
        v = jnp.where(jnp.isfinite(v).all(), v, 0.0)  # a non-finite step leaves the contact in place
        w0 = tangent(v, jnp.asarray(self.normals, dtype)[f0])
        eps = jnp.finfo(dtype).eps

        def moving(state):
            _, _, _, k, done = state
            return (k < self.max_crossings) & ~done

        def cross(state):
            f, b, w, k, _ = state
            db = grads[f] @ w
            leaving = db < -8 * eps * jnp.sum(jnp.abs(db))
            t = jnp.where(leaving, b / jnp.where(leaving, -db, 1.0), jnp.inf)
            i = jnp.argmin(t)
            crossed = t[i] < 1
            step = jnp.where(crossed, t[i], 1.0)
            b = jnp.where(crossed & (jnp.arange(d) == i), 0.0, b + step * db)
            g = neighbors[f, i]
            over = crossed & (g >= 0)
            turn = crossings[f, i]  # (2d, d): [rotation; barycentric transfer]
            b = _clean(jnp.where(over, turn[d:] @ b, b))
            w = jnp.where(over, turn[:d] @ ((1 - step) * w), jnp.zeros_like(w))
            return jnp.where(over, g, f), b, w, k + 1, ~over

        state = (f0, _clean(b0), w0, jnp.zeros((), jnp.int32), jnp.zeros((), bool))
        f, b, w, k, _ = jax.lax.while_loop(moving, cross, state)
        return Contact(f.astype(f0.dtype), b), k, jnp.sqrt(jnp.sum(w * w))

    @jit_method(static=("count",))
    def sample(self, key: jax.Array, count: int) -> Contact:
        """``count`` contacts uniform by area (2D: length): face ``(count,) int32``, coords
        ``(count, d)``."""
        count = check_count(count)
        dtype = jnp.result_type(float)
        k_face, k_bary = jax.random.split(key)
        areas = jnp.asarray(self.areas, dtype)
        face = jax.random.choice(k_face, areas.shape[0], (count,), p=areas / areas.sum())
        u = jax.random.uniform(k_bary, (count, self.dim - 1), dtype)
        if self.dim == 2:
            b = jnp.concatenate([1 - u, u], 1)
        else:
            # the gaps between two sorted uniforms are uniform barycentrics
            lo, hi = jnp.min(u, 1), jnp.max(u, 1)
            b = jnp.stack([lo, hi - lo, 1 - hi], 1)
        return Contact(face.astype(jnp.int32), b)

    # ---------------------------------------------------------------- host

    def locate(self, points) -> Contact:
        """Host side: the contacts at the surface points closest to ``points: (..., d)``
        (face ``(...) int32``, coords ``(..., d) float64``)."""
        points = host_points(points, self.dim)
        shape = points.shape[:-1]
        flat = points.reshape(-1, self.dim)
        corners = np.asarray(self.vertices, float)[np.asarray(self.faces)]
        if len(flat) == 0:
            face, b = np.zeros(0, np.int32), np.zeros((0, self.dim))
        elif self.dim == 2:
            face, b = _closest_on_segments(corners, flat)
        else:
            face, b = _closest_on_triangles(corners, np.asarray(self.vertices, float), flat)
        return Contact(face.reshape(shape).astype(np.int32), b.reshape(*shape, self.dim))


def _clean(b):
    """Barycentrics clipped to >= 0 and renormalized."""
    b = jnp.maximum(b, 0.0)
    total = jnp.sum(b)
    return jnp.where(total > 0, b / jnp.where(total > 0, total, 1.0), jnp.full_like(b, 1.0 / b.shape[0]))


# -------------------------------------------------------------------- host-side construction


def from_simplices(vertices, faces, normals, *, center, scale: float, normal_kind: str = "smooth",
                   crease_angle: float = 45.0, max_crossings: int = MAX_CROSSINGS) -> SimplicialSurface:
    """Precompute a :class:`SimplicialSurface` on the host.

    Args:
        vertices: ``(V, d) float``, d = 2 or 3.
        faces: ``(F, d) int`` simplices (triangles / ring edges), non-degenerate.
        normals: ``(F, d) float`` outward unit face normals.
        center: ``(d,) float``; scale: the object's radius.
        normal_kind: ``"smooth"`` or ``"flat"``.
        crease_angle: degrees; faces whose normals differ by more are not smoothed together.
        max_crossings: the most faces one ``retract`` passes through.
    """
    if normal_kind not in ("smooth", "flat"):
        raise ValueError(f"normals must be 'smooth' or 'flat'; got {normal_kind!r}")
    crease_angle = float(crease_angle)
    if not 0.0 <= crease_angle <= 180.0:
        raise ValueError(f"crease_angle must be in [0, 180] degrees; got {crease_angle!r}")
    max_crossings = check_int("max_crossings", max_crossings)
    vertices = np.asarray(vertices, dtype=float)
    faces = np.asarray(faces, dtype=np.int64)
    normals = np.asarray(normals, dtype=float)
    d = vertices.shape[1]
    corner = vertices[faces]  # (F, d, d)
    if d == 3:
        edges = np.stack([corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0]], 1)  # (F, 2, 3)
        areas = 0.5 * np.linalg.norm(np.cross(edges[:, 0], edges[:, 1]), axis=1)
        g12 = np.linalg.pinv(edges @ edges.transpose(0, 2, 1)) @ edges  # (F, 2, 3)
        grads = np.concatenate([-g12.sum(1, keepdims=True), g12], 1)
    else:
        edge = corner[:, 1] - corner[:, 0]
        areas = np.linalg.norm(edge, axis=1)
        g1 = edge / (areas**2)[:, None]
        grads = np.stack([-g1, g1], 1)
    neighbors, partner = _neighbors(faces)
    crossings = _crossings(vertices, faces, normals, neighbors, partner)
    if normal_kind == "smooth":
        corners = _corner_normals(vertices, faces, normals, np.cos(np.radians(crease_angle)))
    else:
        corners = np.repeat(normals[:, None], d, 1)
    return SimplicialSurface(
        vertices=vertices, faces=faces.astype(np.int32), normals=normals, corners=corners,
        grads=grads, neighbors=neighbors.astype(np.int32), crossings=crossings, areas=areas,
        center=np.asarray(center, float).reshape(d), dim=d, scale=float(scale),
        normal_kind=normal_kind, max_crossings=int(max_crossings))


def _neighbors(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per (face, corner i): the face sharing the sub-simplex opposite corner i and the corner of
    that face opposite it, ``(F, d) int`` each (-1 where none). Where more than two faces share
    it, each takes the next one in index order, cyclically."""
    n, d = faces.shape
    keep = ~np.eye(d, dtype=bool)
    keys = np.sort(np.stack([faces[:, keep[i]] for i in range(d)], 1), axis=2).reshape(n * d, d - 1)
    _, group = np.unique(keys, axis=0, return_inverse=True)
    group = group.ravel()
    order = np.argsort(group, kind="stable")
    sorted_group = group[order]
    start = np.searchsorted(sorted_group, sorted_group, side="left")
    size = np.searchsorted(sorted_group, sorted_group, side="right") - start
    pos = np.arange(n * d) - start
    nxt = np.empty(n * d, dtype=np.int64)
    nxt[order] = order[start + (pos + 1) % size]
    alone = np.empty(n * d, dtype=bool)
    alone[order] = size == 1
    neighbor = np.where(alone, -1, nxt // d).reshape(n, d)
    partner = np.where(alone, -1, nxt % d).reshape(n, d)
    return neighbor, partner


def _crossings(vertices, faces, normals, neighbors, partner) -> np.ndarray:
    """``(F, d, 2d, d)``: per (face, corner i) the rotation taking the face's plane to the
    neighbour's across the sub-simplex opposite corner i, stacked on the matrix taking
    barycentrics of the face into the neighbour's (rows ``k``: the neighbour's corner ``k`` is
    the face's corner ``j``); identities at a boundary."""
    n, d = faces.shape
    out = np.broadcast_to(np.concatenate([np.eye(d), np.eye(d)]), (n, d, 2 * d, d)).copy()
    rot = out[:, :, :d]
    f, i = np.nonzero(neighbors >= 0)
    g, k = neighbors[f, i], partner[f, i]
    apex_f = vertices[faces[f, i]]
    apex_g = vertices[faces[g, k]]
    base = vertices[faces[f, (i + 1) % d]]  # a vertex of the shared sub-simplex
    if d == 3:
        e = vertices[faces[f, (i + 2) % 3]] - base
        e /= np.linalg.norm(e, axis=1, keepdims=True)
        out_f = base - apex_f
        out_f -= np.einsum("ij,ij->i", out_f, e)[:, None] * e
        in_g = apex_g - base
        in_g -= np.einsum("ij,ij->i", in_g, e)[:, None] * e
        edge_part = e[:, :, None] * e[:, None, :]
    else:
        out_f, in_g = base - apex_f, apex_g - base
        edge_part = 0.0
    out_f /= np.linalg.norm(out_f, axis=1, keepdims=True)
    in_g /= np.linalg.norm(in_g, axis=1, keepdims=True)
    rot[f, i] = (edge_part + in_g[:, :, None] * out_f[:, None, :]
                 + normals[g][:, :, None] * normals[f][:, None, :])
    out[:, :, :d] = rot
    out[f, i, d:] = (faces[g][:, :, None] == faces[f][:, None, :]).astype(float)
    return out


def _corner_normals(vertices, faces, normals, cos_crease: float) -> np.ndarray:
    """``(F, d, d)`` unit normal at each face corner: the weighted mean of the normals of the
    faces at that vertex whose normal is within the crease angle of this face's (weights: the
    faces' angles at the vertex in 3D, 1 in 2D)."""
    n, d = faces.shape
    if d == 3:
        c = vertices[faces]
        a = c[:, [1, 2, 0]] - c
        b = c[:, [2, 0, 1]] - c
        cos = np.einsum("fij,fij->fi", a, b) / (np.linalg.norm(a, axis=2) * np.linalg.norm(b, axis=2))
        weight = np.arccos(np.clip(cos, -1.0, 1.0)).ravel()
    else:
        weight = np.ones(n * d)
    vert = faces.ravel()
    face = np.repeat(np.arange(n), d)
    order = np.argsort(vert, kind="stable")
    sv = vert[order]
    start = np.searchsorted(sv, sv, side="left")
    size = np.searchsorted(sv, sv, side="right") - start
    total = np.zeros((n * d, d))
    pairs = np.cumsum(size)  # pairs up to and including each sorted incidence
    lo = 0
    while lo < n * d:  # blocks of sorted incidences with about _CHUNK (corner, incidence) pairs
        done = pairs[lo - 1] if lo else 0
        hi = max(lo + 1, int(np.searchsorted(pairs, done + _CHUNK, side="right")))
        me = np.repeat(np.arange(lo, hi), size[lo:hi])
        within = np.arange(len(me)) - np.repeat(pairs[lo:hi] - size[lo:hi] - done, size[lo:hi])
        other = start[me] + within
        fa, fb = face[order[me]], face[order[other]]
        near = np.einsum("ij,ij->i", normals[fa], normals[fb]) >= cos_crease
        contrib = (weight[order[other]] * near)[:, None] * normals[fb]
        np.add.at(total, order[me], contrib)
        lo = hi
    length = np.linalg.norm(total, axis=1, keepdims=True)
    own = np.repeat(normals, d, 0)
    total = np.where(length > 0, total / np.where(length > 0, length, 1.0), own)
    return total.reshape(n, d, d)


def _closest_on_segments(corners: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest point on segments ``corners: (E, 2, 2)`` to each of ``points: (n, 2)``: edge index
    and barycentrics ``(n, 2)``."""
    a, e = corners[:, 0], corners[:, 1] - corners[:, 0]
    ee = np.einsum("ij,ij->i", e, e)
    face, b = np.zeros(len(points), np.int64), np.zeros((len(points), 2))
    step = max(1, _CHUNK // len(a))
    for lo in range(0, len(points), step):
        p = points[lo:lo + step, None, :]
        t = np.clip(np.einsum("pij,ij->pi", p - a, e) / ee, 0.0, 1.0)
        dist = np.linalg.norm(a + t[..., None] * e - p, axis=2)
        best = np.argmin(dist, axis=1)
        tb = t[np.arange(len(best)), best]
        face[lo:lo + step], b[lo:lo + step] = best, np.stack([1 - tb, tb], 1)
    return face, b


def _closest_on_triangles(corners: np.ndarray, vertices: np.ndarray,
                          points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest point on triangles ``corners: (F, 3, 3)`` to each of ``points: (n, 3)``: face index
    and barycentrics ``(n, 3)``. Candidates: triangles whose bounding ball is within the distance
    to the nearest vertex (an upper bound), found with KD-trees; then exact distances."""
    centroid = corners.mean(1)
    reach = np.linalg.norm(corners - centroid[:, None], axis=2).max(1).max() * (1 + 1e-9)
    trees = scipy.spatial.cKDTree(vertices), scipy.spatial.cKDTree(centroid)
    found = [_closest_candidates(corners, trees, reach, points[lo:lo + 256])
             for lo in range(0, len(points), 256)]  # bounded candidate lists for far points
    return np.concatenate([f for f, _ in found]), np.concatenate([b for _, b in found])


def _closest_candidates(corners, trees, reach, points):
    """:func:`_closest_on_triangles` for a block of points, with ``trees`` the KD-trees of the
    vertices and of the triangle centroids and ``reach`` the largest centroid-corner distance."""
    near, _ = trees[0].query(points)
    lists = trees[1].query_ball_point(points, near + reach)
    count = np.array([len(c) for c in lists])
    tri = np.concatenate([np.asarray(c, dtype=np.int64) for c in lists])
    who = np.repeat(np.arange(len(points)), count)
    dist, bary = np.empty(len(tri)), np.empty((len(tri), 3))
    step = _CHUNK // 8
    for lo in range(0, len(tri), step):
        sl = slice(lo, lo + step)
        bary[sl] = _triangle_barycentrics(corners[tri[sl]], points[who[sl]])
        closest = np.einsum("ni,nij->nj", bary[sl], corners[tri[sl]])
        dist[sl] = np.linalg.norm(closest - points[who[sl]], axis=1)
    first = np.concatenate([[0], np.cumsum(count)[:-1]])
    best = first + np.array([np.argmin(dist[s:s + c]) for s, c in zip(first, count)])
    b = np.clip(bary[best], 0.0, None)
    return tri[best], b / b.sum(1, keepdims=True)


def _triangle_barycentrics(tri: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Barycentrics ``(n, 3)`` of the closest point of each triangle ``tri: (n, 3, 3)`` to the
    matching ``p: (n, 3)`` (Ericson, Real-Time Collision Detection 5.1.5: Voronoi regions of the
    corners, edges and face)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac = b - a, c - a

    def dot(x, y):
        return np.einsum("ij,ij->i", x, y)

    d1, d2 = dot(ab, p - a), dot(ac, p - a)
    d3, d4 = dot(ab, p - b), dot(ac, p - b)
    d5, d6 = dot(ab, p - c), dot(ac, p - c)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        total = va + vb + vc
        v, w = vb / total, vc / total
        face = np.stack([1 - v - w, v, w], 1)
        t = d1 / (d1 - d3)
        on_ab = np.stack([1 - t, t, 0 * t], 1)
        t = d2 / (d2 - d6)
        on_ac = np.stack([1 - t, 0 * t, t], 1)
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        on_bc = np.stack([0 * t, 1 - t, t], 1)
    eye = np.eye(3)
    cases = [
        ((d1 <= 0) & (d2 <= 0), np.broadcast_to(eye[0], face.shape)),
        ((d3 >= 0) & (d4 <= d3), np.broadcast_to(eye[1], face.shape)),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), on_ab),
        ((d6 >= 0) & (d5 <= d6), np.broadcast_to(eye[2], face.shape)),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), on_ac),
        ((va <= 0) & (d4 >= d3) & (d5 >= d6), on_bc),
    ]
    out = face
    for where, value in cases[::-1]:  # the first matching region wins
        out = np.where(where[:, None], value, out)
    return np.nan_to_num(out, nan=1.0 / 3.0)


def for_mesh(obj, *, normals: str = "smooth", crease_angle: float = 45.0,
             max_crossings: int = MAX_CROSSINGS) -> SimplicialSurface:
    """The surface of a :class:`grasp_jax.objects.Mesh` (or any object with a trimesh ``.mesh``,
    ``.center`` and ``.radius``)."""
    mesh = obj.mesh
    return from_simplices(np.asarray(mesh.vertices, float), np.asarray(mesh.faces),
                          np.asarray(mesh.face_normals, float), center=obj.center,
                          scale=float(obj.radius), normal_kind=normals, crease_angle=crease_angle,
                          max_crossings=max_crossings)


def for_polygon(obj, *, normals: str = "smooth", crease_angle: float = 45.0,
                max_crossings: int = MAX_CROSSINGS) -> SimplicialSurface:
    """The boundary of a :class:`grasp_jax.objects.Polygon`: its rings' edges, in the order and
    with the outward normals of the polygon's own facets."""
    rings = [np.asarray(r, float) for r in obj.rings]
    offsets = np.cumsum([0] + [len(r) for r in rings])
    faces = np.concatenate([np.stack([o + np.arange(len(r)), o + (np.arange(len(r)) + 1) % len(r)], 1)
                            for o, r in zip(offsets, rings)])
    _, edge_normals = obj.facets()  # one per edge, in the rings' order
    return from_simplices(np.concatenate(rings), faces, np.asarray(edge_normals, float), center=obj.center,
                          scale=float(obj.radius), normal_kind=normals, crease_angle=crease_angle,
                          max_crossings=max_crossings)
