"""Antipodal parallel-jaw grasps, sampled in the manner of Dex-Net's ``AntipodalGraspSampler``.

For each grasp: a point ``p`` uniform by area on the surface, a closing direction ``v`` uniform
inside the inward friction cone of ``p`` (half-angle ``atan(mu)``), and the first hit ``q`` of the
line ``p + s v`` beyond ``p`` (one trimesh ray query for all grasps). The jaw centre is the
midpoint, the axis ``v``, the opening ``clip(|q - p| + 2 clearance, min_width, max_width)``, and
the jaws close on that line (:func:`jaw_contacts`), so the contacts are where the jaws stop. The
approach is uniform on the circle about the axis; with the collision check, up to
``approach_tries`` approaches are tried and the first clear one kept.

Nothing is rejected: every candidate comes with its :class:`JawStatus`, and the friction test is
the scorer's (:func:`score_grasps`). Grasps are drawn in blocks of :data:`BLOCK`, block ``b`` from
``np.random.SeedSequence(seed, spawn_key=(b,))``, so they do not depend on how
:func:`iter_antipodal_grasps` chunks them.
"""

from __future__ import annotations

import math
from typing import Iterator, NamedTuple

import numpy as np

from ..objects import Mesh
from ._contacts import (
    as_trimesh,
    close_jaws,
    collision_check,
    contacts_from,
    line_hits,
    require_collision_support,
)
from ._gripper import JawStatus, ParallelJaw

#: Grasps drawn from one random stream.
BLOCK = 1 << 12
#: Default clearance between each open jaw and its contact, as a fraction of ``max_width``.
CLEARANCE = 0.05
#: Hits within this fraction of the mesh's bounding-box diagonal of the sampled point are that
#: point (the ray query meets the point's own triangle there).
SELF_HIT = 1e-7

#: The per-grasp fields of :class:`AntipodalGrasps` (and of result files), besides the contacts.
POSE_FIELDS = ("center", "axis", "approach", "width", "jaw_status")


class AntipodalGrasps(NamedTuple):
    """``k`` parallel-jaw grasps and their contacts (:func:`antipodal_grasps`).

    Attributes:
        centers: ``(k, 3) float64`` jaw centres.
        axes: ``(k, 3) float64`` unit closing axes (jaw 0 on the ``-axis`` side).
        approaches: ``(k, 3) float64`` unit approach directions, orthogonal to the axes.
        widths: ``(k,) float64`` openings.
        points: ``(k, 2, 3) float64`` contacts (fill values as :class:`JawContacts` says).
        normals: ``(k, 2, 3) float64`` outward unit normals at the contacts.
        status: ``(k,) int8`` :class:`JawStatus`.
    """

    centers: np.ndarray
    axes: np.ndarray
    approaches: np.ndarray
    widths: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    status: np.ndarray

    def columns(self) -> dict[str, np.ndarray]:
        """The grasps as result-file columns: ``points``, ``normals`` and :data:`POSE_FIELDS`."""
        return {"points": self.points, "normals": self.normals, "center": self.centers, "axis": self.axes,
                "approach": self.approaches, "width": self.widths, "jaw_status": self.status}

    def __len__(self) -> int:  # noqa: D105 - the number of grasps, not of fields
        return len(self.widths)


def _frame(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents completing unit rows ``z: (k, 3)`` (Duff et al. 2017, as
    ``grasp_jax._cones.tangent_frame``)."""
    sign = np.where(z[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + z[:, 2])
    b = z[:, 0] * z[:, 1] * a
    x = np.stack([1.0 + sign * z[:, 0] ** 2 * a, sign * b, -sign * z[:, 0]], axis=1)
    y = np.stack([b, sign + z[:, 1] ** 2 * a, -z[:, 1]], axis=1)
    return x, y


def _surface(mesh):
    """An object whose ``sample_surface`` draws points on the triangles of ``mesh``'s trimesh (an
    analytic shape's own sampler draws on the exact surface, off the triangles the rays meet)."""
    if isinstance(mesh, Mesh):
        return mesh

    tm = as_trimesh(mesh)
    centre = np.asarray(tm.centroid, float)
    return Mesh(name="mesh", mesh=tm, center=centre, radius=float(np.linalg.norm(tm.vertices - centre, axis=1).max()))


def _check(num, mu, gripper, seed, clearance, collision, approach_tries=1):
    if isinstance(approach_tries, bool) or not isinstance(approach_tries, (int, np.integer)) or approach_tries < 1:
        raise ValueError(f"approach_tries must be a positive integer; got {approach_tries!r}")
    if isinstance(num, bool) or not isinstance(num, (int, np.integer)) or num < 1:
        raise ValueError(f"num must be a positive integer; got {num!r}")
    if isinstance(mu, bool) or not isinstance(mu, (int, float, np.floating)) or not (math.isfinite(mu) and mu > 0):
        raise ValueError(f"mu must be a finite number > 0; got {mu!r}")
    if not isinstance(gripper, ParallelJaw):
        raise ValueError(f"gripper must be a ParallelJaw; got {type(gripper).__name__}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer; got {seed!r}")
    if clearance is None:
        clearance = CLEARANCE * gripper.max_width
    if isinstance(clearance, bool) or not isinstance(clearance, (int, float, np.floating)) \
            or not (math.isfinite(clearance) and clearance >= 0):
        raise ValueError(f"clearance must be a finite length >= 0; got {clearance!r}")
    if collision:
        if not gripper.has_body:
            raise ValueError("collision=True needs a gripper with a collision body (ParallelJaw(..., finger_size=...) "
                             "or ParallelJaw.scaled(max_width))")
        require_collision_support()
    return int(num), float(mu), int(seed), float(clearance)


def _block(surface, tm, count, rng, mu, gripper: ParallelJaw, clearance, collision, tries) -> AntipodalGrasps:
    p, n = (np.asarray(a, np.float64) for a in surface.sample_surface(count, rng))
    radius_u, angle_u = rng.random((2, count))
    approach_u = rng.random((tries, count))
    z = -n
    x, y = _frame(z)
    r = mu * np.sqrt(radius_u)
    t = 2.0 * np.pi * angle_u
    v = z + (r * np.cos(t))[:, None] * x + (r * np.sin(t))[:, None] * y
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    hits = line_hits(tm, p, v)
    diagonal = float(np.linalg.norm(np.ptp(np.asarray(tm.bounds, float), axis=0))) or 1.0
    behind = np.bincount(hits.line, weights=hits.s <= SELF_HIT * diagonal, minlength=count).astype(np.int64)
    found = behind < hits.count
    s_all = np.concatenate([hits.s, [0.0]])
    gap = np.where(found, s_all[np.where(found, hits.start + behind, len(hits.s))], 0.0)
    offset = 0.5 * gap
    widths = np.where(found, np.clip(gap + 2.0 * clearance, gripper.min_width, gripper.max_width), gripper.max_width)
    first, last, status = close_jaws(hits, offset, widths, gripper.min_width)
    status[~found] = JawStatus.MISSED
    points, normals = contacts_from(hits, first, last, status, p, v, offset, widths)
    centers = p + offset[:, None] * v
    ax, ay = _frame(v)
    phi = 2.0 * np.pi * approach_u  # (tries, count)
    approaches = np.cos(phi[0])[:, None] * ax + np.sin(phi[0])[:, None] * ay
    if collision:
        todo = np.flatnonzero(status == JawStatus.OK)
        for attempt in range(tries):
            if attempt:
                a = phi[attempt, todo]
                approaches[todo] = np.cos(a)[:, None] * ax[todo] + np.sin(a)[:, None] * ay[todo]
            hit = collision_check(tm, gripper, centers[todo], v[todo], approaches[todo], widths[todo])
            todo = todo[hit]
            if not len(todo):
                break
        status[todo] = JawStatus.COLLISION
    return AntipodalGrasps(centers, v, approaches, widths, points, normals, status)


def _blocks(mesh, num, mu, gripper, seed, clearance, collision, tries) -> Iterator[AntipodalGrasps]:
    surface = _surface(mesh)
    tm = as_trimesh(surface)
    for b, start in enumerate(range(0, num, BLOCK)):
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(b,)))
        yield _block(surface, tm, min(BLOCK, num - start), rng, mu, gripper, clearance, collision, tries)


def _concat(parts) -> AntipodalGrasps:
    if len(parts) == 1:
        return parts[0]
    return AntipodalGrasps(*(np.concatenate(a) for a in zip(*parts)))


def antipodal_grasps(mesh, num: int, *, mu: float, gripper: ParallelJaw, seed: int = 0,
                     clearance: float | None = None, collision: bool = False,
                     approach_tries: int = 8) -> AntipodalGrasps:
    """``num`` antipodal parallel-jaw grasp candidates of a mesh (see the module docstring).

    Args:
        mesh: a :class:`grasp_jax.objects.Mesh` or a ``trimesh.Trimesh`` (face normals outward).
        num: candidates, >= 1.
        mu: friction coefficient of the cone the closing directions are drawn from (> 0).
        gripper: the :class:`ParallelJaw`; its widths bound the opening.
        seed: non-negative integer; the same arguments give the same grasps.
        clearance: gap between each open jaw and its contact (default ``0.05 max_width``).
        collision: test the gripper body against the mesh (:func:`jaw_contacts`).
        approach_tries: with ``collision``, approaches tried per grasp before it is marked
            ``COLLISION`` (the first is the one drawn without the check).

    Returns:
        :class:`AntipodalGrasps` of ``num`` rows, each with its :class:`JawStatus`.

    Raises:
        ValueError: a bad argument (one sentence).
        ModuleNotFoundError: ``collision=True`` without python-fcl.
    """
    num, mu, seed, clearance = _check(num, mu, gripper, seed, clearance, collision, approach_tries)
    return _concat(list(_blocks(mesh, num, mu, gripper, seed, clearance, collision, int(approach_tries))))


def iter_antipodal_grasps(mesh, num: int, *, mu: float, gripper: ParallelJaw, seed: int = 0,
                          clearance: float | None = None, collision: bool = False,
                          approach_tries: int = 8, chunk: int = 65536) -> Iterator[AntipodalGrasps]:
    """The grasps of :func:`antipodal_grasps` in chunks of ``chunk`` rows (the last may be
    smaller), with flat memory; their concatenation equals :func:`antipodal_grasps`."""
    num, mu, seed, clearance = _check(num, mu, gripper, seed, clearance, collision, approach_tries)
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ValueError(f"chunk must be a positive integer; got {chunk!r}")
    return _rechunk(_blocks(mesh, num, mu, gripper, seed, clearance, collision, int(approach_tries)), int(chunk))


def _rechunk(blocks, chunk: int) -> Iterator[AntipodalGrasps]:
    held, size = [], 0
    for block in blocks:
        held.append(block)
        size += len(block)
        while size >= chunk:
            whole = _concat(held)
            yield AntipodalGrasps(*(a[:chunk] for a in whole))
            held, size = [AntipodalGrasps(*(a[chunk:] for a in whole))], size - chunk
    if size:
        yield _concat(held)


def column_chunks(mesh, num: int, start: int, stop: int, chunk: int, **kwargs) -> Iterator[dict]:
    """Rows ``[start, stop)`` of :func:`iter_antipodal_grasps` as result-file column chunks
    (:meth:`AntipodalGrasps.columns`) of at most ``chunk`` rows (the streaming pipeline's input)."""
    pos = 0
    for part in iter_antipodal_grasps(mesh, num, chunk=chunk, **kwargs):
        end = pos + len(part)
        lo, hi = max(start, pos), min(stop, end)
        if lo < hi:
            yield {name: a[lo - pos:hi - pos] for name, a in part.columns().items()}
        pos = end
        if pos >= stop:
            break
