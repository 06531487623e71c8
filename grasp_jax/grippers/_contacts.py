"""Contacts of parallel-jaw grasps: the closing line cast onto the mesh, and the collision check.

A grasp is a centre ``c``, a unit closing ``axis`` ``u``, an ``approach`` and an opening
``width`` ``w``. Jaw 0 starts at ``c - (w / 2) u`` and moves along ``+u``, jaw 1 starts at
``c + (w / 2) u`` and moves along ``-u``; each stops at the first surface it meets between the
open jaws. All surface hits of the line ``c + s u`` come from one vectorised ray query (one ray
per grasp, all grasps in one call): exactly the hits of trimesh's
``mesh.ray.intersects_location(..., multiple_hits=True)``, with a finer search of the candidate
triangles (:func:`ray_hits`: 10 to 30 times faster on slanted lines through fine meshes); hits
closer than :data:`MERGE` (relative to the mesh size) are one hit (a ray through an
edge meets both triangles), and an entry and an exit at the same place (a line grazing the
surface) cancel.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._gripper import JawStatus, ParallelJaw

#: Hits along one line closer than this times the mesh's bounding-box diagonal are one hit.
MERGE = 1e-9
#: Largest ``|approach . axis|`` accepted for unit vectors (an approach orthogonal to the axis).
ORTHOGONAL = 1e-6
#: ``collision_check`` tests this many grasps per call of FCL's manager at most (memory only).
_CHUNK = 4096
#: Each line's stretch inside the mesh's bounding box is cut into pieces of at most this fraction
#: of its diagonal; the R-tree's candidate triangles of a line are those of its pieces' boxes.
PIECE = 1 / 16
#: Lines cast together (memory only: a few hundred bytes per candidate triangle).
RAY_BLOCK = 4096


class JawContacts(NamedTuple):
    """The contacts of ``k`` parallel-jaw grasps (:func:`jaw_contacts`).

    Attributes:
        points: ``(k, 2, 3) float64``: contact 0 (jaw 0, on the ``-axis`` side) and contact 1.
            Rows whose status is ``MISSED`` or ``TOO_WIDE`` have no contacts: they hold the open
            jaws' positions ``c -/+ (width / 2) axis``.
        normals: ``(k, 2, 3) float64`` outward unit face normals at the contacts; where there are
            no contacts, ``-axis`` and ``+axis`` (the normals an ideal antipodal pair would have).
        status: ``(k,) int8`` :class:`JawStatus`.
    """

    points: np.ndarray
    normals: np.ndarray
    status: np.ndarray


def as_trimesh(mesh):
    """The ``trimesh.Trimesh`` of a :class:`grasp_jax.objects.Mesh` (or ``mesh`` itself)."""
    import trimesh

    tm = getattr(mesh, "mesh", mesh)
    if not isinstance(tm, trimesh.Trimesh):
        raise ValueError(f"mesh must be a grasp_jax.objects.Mesh or a trimesh.Trimesh; got {type(mesh).__name__}")
    if len(tm.faces) == 0:
        raise ValueError("mesh has no triangles")
    return tm


def _vectors(name: str, value, k: int | None) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3 or (k is not None and len(a) != k):
        want = "(k, 3)" if k is None else f"({k}, 3)"
        raise ValueError(f"{name} must have shape {want}; got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name} must be finite")
    return a


def _units(name: str, value, k: int) -> np.ndarray:
    a = _vectors(name, value, k)
    norm = np.linalg.norm(a, axis=1)
    bad = np.flatnonzero(~(norm > 1e-12))
    if len(bad):
        raise ValueError(f"{name} must be non-zero directions; row {int(bad[0])} is {a[bad[0]].tolist()}")
    return a / norm[:, None]


def check_poses(centers, axes, widths, approaches=None, gripper: ParallelJaw | None = None):
    """Validated ``(centers (k, 3), unit axes (k, 3), widths (k,), unit approaches (k, 3) or None)``.

    Raises:
        ValueError: one sentence on the first problem: a shape, a zero direction, a width that is
            not > 0 (or outside the gripper's range), an approach not orthogonal to its axis.
    """
    centers = _vectors("centers", centers, None)
    k = len(centers)
    axes = _units("axes", axes, k)
    widths = np.asarray(widths, dtype=np.float64)
    if widths.ndim == 0:
        widths = np.full(k, float(widths))
    if widths.shape != (k,):
        raise ValueError(f"widths must have shape ({k},) (or be one number); got {widths.shape}")
    bad = np.flatnonzero(~(np.isfinite(widths) & (widths > 0)))
    if len(bad):
        raise ValueError(f"widths must be finite and > 0; width {int(bad[0])} is {widths[bad[0]]!r}")
    if gripper is not None:
        if not isinstance(gripper, ParallelJaw):
            raise ValueError(f"gripper must be a ParallelJaw; got {type(gripper).__name__}")
        over = np.flatnonzero(widths > gripper.max_width * (1 + 1e-12))
        if len(over):
            raise ValueError(f"widths must be at most the gripper's max_width {gripper.max_width}; width "
                             f"{int(over[0])} is {widths[over[0]]!r}")
        under = np.flatnonzero(widths < gripper.min_width)
        if len(under):
            raise ValueError(f"widths must be at least the gripper's min_width {gripper.min_width}; width "
                             f"{int(under[0])} is {widths[under[0]]!r}")
    if approaches is not None:
        approaches = _units("approaches", approaches, k)
        dots = np.abs(np.einsum("ij,ij->i", approaches, axes))
        bad = np.flatnonzero(dots > ORTHOGONAL)
        if len(bad):
            raise ValueError(f"approaches must be orthogonal to their axes; grasp {int(bad[0])} has "
                             f"|approach . axis| = {dots[bad[0]]:.3g} (unit vectors)")
    return centers, axes, widths, approaches


def _pieces(tm, origins: np.ndarray, direction: np.ndarray):
    """``(ray, mins, maxs)``: the boxes of the pieces of each ray ``origins + t direction``,
    ``t >= 0``, inside the mesh's bounding box (padded), at most :data:`PIECE` of its diagonal
    long; rays that miss the box have none."""
    lo, hi = np.asarray(tm.bounds, float)
    diagonal = float(np.linalg.norm(hi - lo)) or 1.0
    pad = 1e-5 * diagonal
    lo, hi = lo - pad, hi + pad
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo - origins) / direction, (hi - origins) / direction
    inside = (origins >= lo) & (origins <= hi)  # the slabs of zero direction components
    parallel = direction == 0
    near = np.where(parallel, np.where(inside, -np.inf, np.inf), np.minimum(ta, tb)).max(axis=1)
    far = np.where(parallel, np.where(inside, np.inf, -np.inf), np.maximum(ta, tb)).min(axis=1)
    near = np.maximum(near, 0.0)
    crosses = near <= far
    length = np.where(crosses, far - near, 0.0)
    count = np.where(crosses, np.maximum(np.ceil(length / (PIECE * diagonal)), 1), 0).astype(np.int64)
    ray = np.repeat(np.arange(len(origins)), count)
    j = np.arange(len(ray)) - (np.cumsum(count) - count)[ray]
    step = length[ray] / count[ray]
    a = near[ray] + j * step
    ends = origins[ray][:, None] + np.stack([a, a + step], axis=1)[..., None] * direction[ray][:, None]
    return ray, ends.min(axis=1) - pad, ends.max(axis=1) + pad


def ray_hits(tm, origins: np.ndarray, direction: np.ndarray):
    """``(locations (H, 3), ray (H,), triangle (H,))``: every hit of the rays, exactly what
    ``tm.ray.intersects_location(origins, direction, multiple_hits=True)`` gives with trimesh's
    R-tree ray caster, found faster: its candidate triangles of a ray are those whose boxes meet
    the ray's whole box in the mesh (on a slanted line through a fine mesh, thousands), ours those
    that meet the boxes of the ray's short pieces (tens); the intersection arithmetic is
    trimesh's (``trimesh.ray.ray_triangle.ray_triangle_id``), candidate by candidate, and so are
    its tolerances and its merging of equal locations. Without ``rtree``'s bulk queries
    (``Index.intersection_v``, rtree 1.1) it is trimesh's call."""
    from trimesh import grouping, intersections, util
    from trimesh import triangles as triangles_mod
    from trimesh.constants import tol

    empty = np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64)
    if not len(origins):
        return empty
    tree = tm.triangles_tree
    if not hasattr(tree, "intersection_v"):
        loc, ray, tri = tm.ray.intersects_location(origins, direction, multiple_hits=True)
        return np.asarray(loc, float).reshape(-1, 3), np.asarray(ray, np.int64), np.asarray(tri, np.int64)
    piece_ray, mins, maxs = _pieces(tm, origins, direction)
    if not len(piece_ray):
        return empty
    ids, counts = tree.intersection_v(mins, maxs)
    faces = len(tm.faces)
    pairs = np.unique(np.repeat(piece_ray, counts.astype(np.int64)) * faces + ids.astype(np.int64))
    ray, tri = pairs // faces, pairs % faces
    candidates = np.asarray(tm.triangles, float)[tri]
    location, valid = intersections.planes_lines(plane_origins=candidates[:, 0, :],
                                                 plane_normals=np.asarray(tm.face_normals, float)[tri],
                                                 line_origins=origins[ray], line_directions=direction[ray])
    if not valid.any():
        return empty
    barycentric = triangles_mod.points_to_barycentric(candidates[valid], location)
    hit = (barycentric > -tol.zero).all(axis=1) & (barycentric < 1 + tol.zero).all(axis=1)
    tri, ray, location = tri[valid][hit], ray[valid][hit], location[hit]
    forward = util.diagonal_dot(location - origins[ray], direction[ray]) > -1e-6
    tri, ray, location = tri[forward], ray[forward], location[forward]
    if not len(tri):
        return empty
    unique = grouping.unique_rows(np.column_stack((location, ray)))[0]
    return np.asarray(location[unique], float), ray[unique].astype(np.int64), tri[unique].astype(np.int64)


class LineHits(NamedTuple):
    """The surface hits of ``k`` lines ``base + s * direction``, sorted by line, then ``s``."""

    line: np.ndarray  # (H,) int
    s: np.ndarray  # (H,) float
    points: np.ndarray  # (H, 3)
    normals: np.ndarray  # (H, 3) outward unit face normals
    exits: np.ndarray  # (H,) bool: normal . direction > 0 (the line leaves the object there)
    start: np.ndarray  # (k,) index of each line's first hit
    count: np.ndarray  # (k,) hits of each line


def line_hits(tm, base: np.ndarray, direction: np.ndarray) -> LineHits:
    """Every hit of the whole lines ``base + s * direction`` (unit ``direction``), one ray per line
    started outside the mesh's bounding box, merged as the module docstring says."""
    k = len(base)
    lo, hi = np.asarray(tm.bounds, float)
    diagonal = float(np.linalg.norm(hi - lo)) or 1.0
    back = np.linalg.norm(base - 0.5 * (lo + hi), axis=1) + diagonal
    origins = base - back[:, None] * direction
    parts = [ray_hits(tm, origins[i:i + RAY_BLOCK], direction[i:i + RAY_BLOCK]) for i in range(0, k, RAY_BLOCK)]
    if parts:
        loc = np.concatenate([a[0] for a in parts])
        ray = np.concatenate([a[1] + i * RAY_BLOCK for i, a in enumerate(parts)])
        tri = np.concatenate([a[2] for a in parts])
    else:
        loc, ray, tri = np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64)
    s = np.einsum("ij,ij->i", loc - base[ray], direction[ray])
    normals = np.asarray(tm.face_normals, float)[tri]
    along = np.einsum("ij,ij->i", normals, direction[ray])
    order = np.lexsort((s, ray))
    ray, s, loc, normals, along = ray[order], s[order], loc[order], normals[order], along[order]
    keep = along != 0.0  # a face parallel to the line: no crossing
    same = (ray[1:] == ray[:-1]) & (s[1:] - s[:-1] <= MERGE * diagonal)
    exits = along > 0
    dup = np.zeros(len(s), bool)
    dup[1:] = same & (exits[1:] == exits[:-1])  # one crossing seen on two triangles
    graze = np.zeros(len(s), bool)
    graze[1:] = same & (exits[1:] != exits[:-1])  # in and out at one place: no crossing
    graze[:-1] |= graze[1:]
    keep &= ~dup & ~graze
    ray, s, loc, normals, exits = ray[keep], s[keep], loc[keep], normals[keep], exits[keep]
    count = np.bincount(ray, minlength=k)
    start = np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64)
    return LineHits(ray, s, loc, normals, exits, start, count)


def close_jaws(hits: LineHits, offset: np.ndarray, widths: np.ndarray, min_width: float = 0.0):
    """Close the jaws of each line: jaw 0 at ``s = offset - w / 2`` moving up, jaw 1 at
    ``offset + w / 2`` moving down.

    Returns:
        ``(first, last, status)``: ``(k,)`` hit indices of the two contacts (-1 where none) and
        ``(k,) int8`` :class:`JawStatus` (``OK``, ``MISSED``, ``TOO_WIDE`` or ``TOO_NARROW``).
    """
    k = len(widths)
    lo, hi = offset - 0.5 * widths, offset + 0.5 * widths
    line = hits.line
    below0 = np.bincount(line, weights=hits.s <= lo[line], minlength=k).astype(np.int64)
    below1 = np.bincount(line, weights=hits.s < hi[line], minlength=k).astype(np.int64)
    has0 = below0 < hits.count  # a hit ahead of jaw 0
    has1 = below1 > 0  # a hit ahead of jaw 1
    first = np.where(has0, hits.start + below0, -1)
    last = np.where(has1, hits.start + below1 - 1, -1)
    n = len(hits.s)  # the sentinel appended below
    exits = np.concatenate([hits.exits, [False]])
    s = np.concatenate([hits.s, [0.0]])
    inside0 = has0 & exits[np.where(has0, first, n)]  # the first surface jaw 0 meets is an exit
    inside1 = has1 & ~exits[np.where(has1, last, n)]  # jaw 1 moves down: an entry of +axis is its exit
    between = has0 & (s[np.where(has0, first, n)] < hi)
    status = np.full(k, JawStatus.OK, np.int8)
    narrow = between & (s[np.maximum(last, 0)] - s[np.maximum(first, 0)] < min_width)
    status[narrow] = JawStatus.TOO_NARROW
    status[~between | (first == last)] = JawStatus.MISSED
    status[inside0 | inside1] = JawStatus.TOO_WIDE
    status[hits.count < 2] = JawStatus.MISSED
    return first, last, status


def contacts_from(hits: LineHits, first, last, status, base, axes, offset, widths):
    """``(points (k, 2, 3), normals (k, 2, 3))`` of closed jaws, with the fill values of
    :class:`JawContacts` where ``status`` is ``MISSED`` or ``TOO_WIDE``."""
    centre = base + offset[:, None] * axes
    half = 0.5 * widths[:, None] * axes
    points = np.stack([centre - half, centre + half], axis=1)
    normals = np.stack([-axes, axes], axis=1)
    found = (status != JawStatus.MISSED) & (status != JawStatus.TOO_WIDE)
    if found.any():
        points[found, 0], points[found, 1] = hits.points[first[found]], hits.points[last[found]]
        normals[found, 0], normals[found, 1] = hits.normals[first[found]], hits.normals[last[found]]
    return points, normals


def gripper_boxes(gripper: ParallelJaw, centers, axes, approaches, widths):
    """The collision body of each grasp: ``(extents (B, 3), transforms (k, B, 4, 4))`` of its
    ``B`` boxes (finger 0, finger 1[, palm]) in the frame of :class:`ParallelJaw`."""
    if gripper.finger_size is None:
        raise ValueError("the gripper has no collision body: give ParallelJaw a finger_size")
    t, _, length = gripper.finger_size
    extents = [gripper.finger_size, gripper.finger_size]
    binormal = np.cross(approaches, axes)
    rot = np.stack([axes, binormal, approaches], axis=-1)  # (k, 3, 3), columns: the frame
    reach = (0.5 * (widths + t))[:, None] * axes
    middle = centers + (gripper.tip_depth - 0.5 * length) * approaches  # the fingers' mid-plane
    origins = [middle - reach, middle + reach]
    if gripper.palm_size is not None:
        extents.append(gripper.palm_size)
        origins.append(centers + (gripper.tip_depth - length - 0.5 * gripper.palm_size[2]) * approaches)
    k = len(centers)
    transforms = np.zeros((k, len(extents), 4, 4))
    transforms[:, :, :3, :3] = rot[:, None]
    transforms[:, :, :3, 3] = np.stack(origins, axis=1)
    transforms[:, :, 3, 3] = 1.0
    return np.asarray(extents, float), transforms


def _manager(tm):
    try:
        import fcl  # noqa: F401
    except ImportError:
        raise ModuleNotFoundError(
            "the gripper collision check needs the package python-fcl (FCL for trimesh's collision "
            "manager): pip install python-fcl, or pip install 'grasp_jax[grippers]'", name="fcl") from None
    import trimesh

    manager = trimesh.collision.CollisionManager()
    manager.add_object("object", tm)
    return manager


def collision_check(tm, gripper: ParallelJaw, centers, axes, approaches, widths) -> np.ndarray:
    """``(k,) bool``: whether the gripper body at each pose intersects the mesh (touching counts),
    with ``trimesh.collision.CollisionManager`` (python-fcl)."""
    import trimesh

    manager = _manager(tm)
    extents, transforms = gripper_boxes(gripper, centers, axes, approaches, widths)
    boxes = [trimesh.creation.box(extents=e) for e in extents]
    hit = np.zeros(len(centers), bool)
    for i in range(len(centers)):
        for b, box in enumerate(boxes):
            if manager.in_collision_single(box, transform=transforms[i, b]):
                hit[i] = True
                break
    return hit


def require_collision_support() -> None:
    """Raise the error of :func:`collision_check` now if python-fcl is missing."""
    try:
        import fcl  # noqa: F401
    except ImportError:
        _manager(None)


def jaw_contacts(mesh, centers, axes, widths, *, approaches=None, gripper: ParallelJaw | None = None,
                 collision: bool = False) -> JawContacts:
    """The two contacts of each parallel-jaw grasp, by casting its closing line onto the mesh.

    Jaw 0 starts at ``centers - (widths / 2) axes`` and jaw 1 at ``centers + (widths / 2) axes``;
    each moves towards the other and its contact is the first surface hit it meets (all hits of
    the line from one vectorised trimesh ray query). See :class:`JawStatus` for the outcomes.

    Args:
        mesh: a :class:`grasp_jax.objects.Mesh` (outward normals) or a ``trimesh.Trimesh`` (whose
            face normals are taken as outward).
        centers: ``(k, 3)`` grasp centres.
        axes: ``(k, 3)`` closing directions (normalized here; non-zero).
        widths: ``(k,)`` openings > 0 (or one number for all), in the mesh's units.
        approaches: ``(k, 3)`` directions the hand moves in along, orthogonal to the axes (needed
            for the collision check only).
        gripper: a :class:`ParallelJaw`: widths must lie in its range; contacts closer than its
            ``min_width`` get ``TOO_NARROW``.
        collision: also test the gripper's body against the mesh (needs ``gripper`` with a
            ``finger_size``, ``approaches`` and python-fcl); grasps that would be ``OK`` and
            intersect get ``COLLISION``.

    Returns:
        :class:`JawContacts`: ``points (k, 2, 3)``, ``normals (k, 2, 3)``, ``status (k,) int8``.

    Raises:
        ValueError: wrong shapes, a zero direction, a width <= 0 or outside the gripper's range,
            an approach not orthogonal to its axis, or ``collision`` without what it needs.
        ModuleNotFoundError: ``collision=True`` without python-fcl.
    """
    tm = as_trimesh(mesh)
    centers, axes, widths, approaches = check_poses(centers, axes, widths, approaches, gripper)
    if collision:
        if gripper is None or not gripper.has_body:
            raise ValueError("collision=True needs a gripper with a collision body (ParallelJaw(..., finger_size=...))")
        if approaches is None:
            raise ValueError("collision=True needs the approaches of the grasps")
        require_collision_support()
    hits = line_hits(tm, centers, axes)
    offset = np.zeros(len(centers))
    min_width = 0.0 if gripper is None else gripper.min_width
    first, last, status = close_jaws(hits, offset, widths, min_width)
    points, normals = contacts_from(hits, first, last, status, centers, axes, offset, widths)
    if collision:
        ok = np.flatnonzero(status == JawStatus.OK)
        hit = collision_check(tm, gripper, centers[ok], axes[ok], approaches[ok], widths[ok])
        status[ok[hit]] = JawStatus.COLLISION
    return JawContacts(points, normals, status)
