"""A hand's collision geometry sampled for the optimizer: fingers, spheres, contact candidates.

* fingers: the leaf links reached through a moving joint; a finger's distal body is the link of
  its last moving joint with the links fixed to it;
* which way a joint closes: towards its larger limit (from 0, or the middle of the range);
* collision spheres: inside each collision element, touching its surface, spread by
  farthest-point sampling (the object's points into the hand; finger-finger collision);
* surface samples: points of each element's surface about :data:`SPACING` apart (the hand into
  the object);
* contact candidates: points of the distal body's surface whose outward normal faces the flexion
  direction of the finger's last joint, a few per finger;
* the palm frame: centre, normal (where the fingers close to) and the fingers' direction.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import trimesh

from ._hand import FIXED, Collision

#: Surface samples drawn per link (spheres) and per distal body (candidates).
SAMPLES = 1000
#: Largest collision-sphere radius (m); spheres per collision element, at least and at most (by
#: its area over the area a sphere covers).
MAX_RADIUS = 0.012
SPHERES = (3, 12)
#: Spacing (m) of the surface samples, and their number per element, at least and at most. A flat
#: face pressed on a convex object of radius R hides a depth of about SPACING^2 / (8 R) between
#: samples (0.06 mm at R = 3 cm).
SPACING = 0.004
SURFACE = (16, 512)
#: Surface samples per patch: an element's samples come in patches of neighbours, PATCH each.
PATCH = 16
#: A joint whose range about 0 has sides within this ratio of each other is a side joint.
SIDE_SYMMETRY = 0.8
#: Contact candidates per finger, and the cosine between a candidate's normal and the flexion
#: direction above which a surface point counts as palm-facing.
CANDIDATES = 32
FACING_COS = 0.6
#: A candidate touching a ball of radius OBJECT_RADIUS (m) lets the rest of its body enter the
#: ball by at most EXPOSED (m): touching there does not push another part of the fingertip in.
EXPOSED, OBJECT_RADIUS = 5e-4, 0.1


@functools.cache
def _mesh_file(filename: str) -> trimesh.Trimesh:
    loaded = trimesh.load(filename, force="mesh")
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise ValueError(f"{filename}: a hand collision mesh with no triangles")
    return loaded


def element_mesh(c: Collision) -> trimesh.Trimesh:
    """The element as a triangle mesh in its link's frame."""
    if c.kind == "box":
        m = trimesh.creation.box(extents=c.size)
    elif c.kind == "cylinder":
        m = trimesh.creation.cylinder(radius=c.size[0], height=c.size[1], sections=24)
    elif c.kind == "sphere":
        m = trimesh.creation.icosphere(subdivisions=2, radius=c.size[0])
    elif c.kind == "capsule":
        m = trimesh.creation.capsule(height=c.size[1], radius=c.size[0], count=(16, 16))
    else:
        m = _mesh_file(c.filename).copy()
        m.apply_scale(c.size)
    m.apply_transform(c.transform)
    return m


def _thickness(c: Collision, mesh: trimesh.Trimesh) -> float:
    """Half the element's smallest extent: the largest sphere that fits inside it, about."""
    if c.kind == "box":
        return 0.5 * min(c.size)
    if c.kind in ("cylinder", "capsule", "sphere"):
        return c.size[0] if c.kind != "cylinder" else min(c.size[0], 0.5 * c.size[1])
    return 0.5 * float(np.min(mesh.bounding_box_oriented.primitive.extents))


def farthest(points: np.ndarray, count: int, first: int = 0) -> np.ndarray:
    """Indices of ``count`` points spread by farthest-point sampling, from ``first``."""
    count = min(count, len(points))
    chosen = [first]
    square = np.einsum("ij,ij->i", points - points[first], points - points[first])  # squared distances
    for _ in range(count - 1):
        k = int(np.argmax(square))
        chosen.append(k)
        step = points - points[k]
        np.minimum(square, np.einsum("ij,ij->i", step, step), out=square)
    return np.asarray(chosen)


def _sample(meshes, count: int, seed: int):
    """``(points, normals)`` on the union of ``meshes``, by area, with outward face normals."""
    mesh = trimesh.util.concatenate(meshes) if len(meshes) > 1 else meshes[0]
    points, faces = trimesh.sample.sample_surface(mesh, count, seed=seed)
    return np.asarray(points), np.asarray(mesh.face_normals[faces])


def _outer_samples(meshes, seed: int):
    """Samples of the union's outer surface: those of each mesh not inside another one."""
    points, normals = _sample(meshes, SAMPLES, seed)
    if len(meshes) == 1:
        return points, normals
    outside = np.ones(len(points), bool)
    for m in meshes:
        if m.is_watertight:
            outside &= trimesh.proximity.signed_distance(m, points) < 1e-6  # trimesh: positive inside
    return (points[outside], normals[outside]) if outside.sum() >= CANDIDATES else (points, normals)


def link_spheres(collisions, num_links: int, seed: int = 0):
    """``(centers (S, 3), radii (S,), links (S,))``: spheres inside each collision element,
    touching its surface, spread by farthest-point sampling, in the link frames."""
    centers, radii, links = [], [], []
    for c in collisions:
        m = element_mesh(c)
        r = min(MAX_RADIUS, _thickness(c, m))
        p, n = _sample([m], SAMPLES // 4, seed)
        count = int(np.clip(round(m.area / (2 * np.pi * r * r)), *SPHERES))
        keep = farthest(p - r * n, count)
        centers.append((p - r * n)[keep])
        radii.append(np.full(len(keep), r))
        links.append(np.full(len(keep), c.link))
    if not centers:
        return np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int32)
    return np.concatenate(centers), np.concatenate(radii), np.concatenate(links).astype(np.int32)


def surface_samples(collisions, seed: int = 0):
    """``(points (N, 3), links (N,))``: points of each collision element's surface about
    :data:`SPACING` apart (farthest-point sampling, from a corner of its hull), in the link frames,
    in patches of :data:`PATCH` neighbours (``N`` is a multiple of ``PATCH``)."""
    points, links = [], []
    for c in collisions:
        m = element_mesh(c)
        count = PATCH * round(np.clip(m.area / SPACING**2, *SURFACE) / PATCH)
        p, _ = _sample([m], 40 * count, seed)
        p = np.concatenate([np.asarray(m.convex_hull.vertices), p])
        points.append(_patches(p[farthest(p, count)]))
        links.append(np.full(count, c.link))
    if not points:
        return np.zeros((0, 3)), np.zeros(0, np.int32)
    return np.concatenate(points), np.concatenate(links).astype(np.int32)


@functools.lru_cache(maxsize=8)
def dense_samples(collisions: tuple, count: int) -> tuple[np.ndarray, np.ndarray]:
    """``(points (G, PATCH, 3), links (G,))``: about ``count`` random samples of every collision
    element and 32 vertices of its convex hull, in its link's frame, in patches of neighbours (the
    final penetration check)."""
    points, links = [], []
    for c in collisions:
        m = element_mesh(c)
        corners = np.asarray(m.convex_hull.vertices)
        corners = corners[np.resize(farthest(corners, 32), 32)]
        p, _ = trimesh.sample.sample_surface(m, PATCH * math.ceil((count + 32) / PATCH) - 32, seed=0)
        p = _patches(np.concatenate([np.asarray(p), corners])).reshape(-1, PATCH, 3)
        points.append(p)
        links.append(np.full(len(p), c.link))
    return np.concatenate(points), np.concatenate(links).astype(np.int32)


def _patches(points: np.ndarray) -> np.ndarray:
    """``points`` (a multiple of :data:`PATCH`) reordered into patches of neighbours: split along
    the widest axis at a multiple of ``PATCH`` until each part is one patch."""
    if len(points) <= PATCH:
        return points
    order = np.argsort(points[:, np.argmax(np.ptp(points, axis=0))], kind="stable")
    half = PATCH * math.ceil(len(points) / (2 * PATCH))
    return np.concatenate([_patches(points[order[:half]]), _patches(points[order[half:]])])


def fingers(parent: tuple, kind: tuple, collisions) -> tuple[list[int], list[int]]:
    """``(distal links, finger of each link)``: one finger per distinct distal body of a leaf
    reached through a moving joint; ``finger[l] = -1`` for the palm's links."""
    count = len(parent)
    children = [[c for c in range(count) if parent[c] == i] for i in range(count)]
    owner = list(range(count))  # the link of the last moving joint at or above each link
    for i in range(count):
        owner[i] = i if kind[i] != FIXED or parent[i] < 0 else owner[parent[i]]
    distal = []
    for leaf in (i for i in range(count) if not children[i]):
        body = owner[leaf]
        if kind[body] == FIXED or body in distal:
            continue
        distal.append(body)
    finger = [-1] * count
    for f, body in enumerate(distal):
        link = body  # up to the branch point (the palm), which stays the palm's
        while True:
            finger[link] = f
            up = parent[link]
            if up < 0 or parent[up] < 0 or len(children[up]) > 1:
                break
            link = up
    for i in range(count):  # links below a finger's link belong to it (parents come first)
        if finger[i] < 0 and parent[i] >= 0 and finger[parent[i]] >= 0:
            finger[i] = finger[parent[i]]
    return distal, finger


def body_links(body: int, parent: tuple, kind: tuple) -> list[int]:
    """The links rigidly attached to ``body`` (by fixed joints below it), ``body`` first."""
    links = [body]
    for i in range(len(parent)):
        if kind[i] == FIXED and parent[i] in links:
            links.append(i)
    return links


def closing_signs(lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """``(J,)`` +1 where a joint closes the hand as its value rises, -1 where as it falls: the
    side of its range farther from 0 (from the middle when 0 is outside the range; continuous
    joints +1); 0 for a side joint (abduction: a range about 0 whose sides are within
    :data:`SIDE_SYMMETRY` of each other), which neither opens nor closes the hand."""
    ref = np.clip(0.0, lower, upper)
    ref = np.where((ref == lower) | (ref == upper), np.where(np.isfinite(lower + upper), 0.5 * (lower + upper), 0.0),
                   ref)
    ref = np.where((lower <= 0) & (upper >= 0), 0.0, ref)
    up, down = upper - ref, ref - lower
    with np.errstate(invalid="ignore", divide="ignore"):
        side = (lower < 0) & (upper > 0) & (np.minimum(up, down) >= SIDE_SYMMETRY * np.maximum(up, down))
    return np.where(side & np.isfinite(up + down), 0.0, np.where(np.isfinite(up) & (down > up), -1.0, 1.0))


def opened(lower: np.ndarray, upper: np.ndarray, closing: np.ndarray, share: float = 0.5) -> np.ndarray:
    """``(J,)`` the opened configuration: from 0 (clipped to the limits) ``share`` of the way to
    the opening limit."""
    ref = np.clip(0.0, lower, upper)
    room = np.where(closing > 0, ref - lower, upper - ref)
    return ref - closing * share * np.where(np.isfinite(room), room, 0.0)


def candidates(body_meshes, joint_origin, joint_axis, prismatic: bool, seed: int = 0):
    """``(points (K, 3), normals (K, 3))`` palm-facing candidates of one distal body.

    ``body_meshes``: its collision meshes in its own frame; ``joint_origin, joint_axis``: its last
    moving joint's origin and axis in that frame (the joint value rises as the finger closes)."""
    points, normals = _outer_samples(body_meshes, seed)
    arm = points - joint_origin
    flex = np.broadcast_to(joint_axis, points.shape) if prismatic else np.cross(joint_axis, arm)
    flex = flex / np.maximum(np.linalg.norm(flex, axis=1, keepdims=True), 1e-12)
    facing = np.sum(normals * flex, axis=1)
    reach = np.linalg.norm(arm, axis=1)
    # how deep the rest of the body enters a ball of radius OBJECT_RADIUS touching each point
    # (about: its height over the tangent plane less the ball's drop there)
    offset = points[None] - points[:, None]
    proud = np.max(np.einsum("kij,kj->ki", offset, normals) - np.sum(offset**2, axis=-1) / (2 * OBJECT_RADIUS), axis=1)
    keep = np.flatnonzero((facing > FACING_COS) & (reach >= np.median(reach)) & (proud <= EXPOSED))
    if len(keep) < CANDIDATES:
        keep = np.argsort(-(facing + reach / reach.max()) + proud / EXPOSED)[: 4 * CANDIDATES]
    pick = keep[farthest(points[keep], CANDIDATES, int(np.argmax(reach[keep])))]
    if len(pick) < CANDIDATES:
        pick = np.resize(pick, CANDIDATES)
    return points[pick], normals[pick]


def palm_frame(joint_points: np.ndarray, tips: np.ndarray, closing: np.ndarray) -> np.ndarray:
    """``(3, 3)`` rows: palm centre, normal, fingers' direction in the root frame, from the
    fingers' first moving joints ``(F, 3)``, their candidates' centres ``(F, 3)`` and closing
    directions ``(F, 3)`` there (at the opened configuration)."""
    center = joint_points.mean(axis=0)
    along = tips.mean(axis=0) - center
    along = along / max(np.linalg.norm(along), 1e-12)
    close = closing.sum(axis=0)
    normal = close - np.dot(close, along) * along
    if np.linalg.norm(normal) < 1e-9:  # fingers closing symmetrically about their direction
        normal, along = along, _any_perpendicular(along)
    normal = normal / np.linalg.norm(normal)
    return np.stack([center, normal, along])


def _any_perpendicular(v: np.ndarray) -> np.ndarray:
    other = np.eye(3)[int(np.argmin(np.abs(v)))]
    w = np.cross(v, other)
    return w / np.linalg.norm(w)
