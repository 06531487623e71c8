"""2D objects: polygons with holes, from vertices or CSV files of x,y rows."""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from ._base import ObjectError, Picker, check_count

_CHUNK = 1 << 22  # pair tests per block in the edge-crossing and point-in-polygon checks


@dataclass(frozen=True, eq=False)
class Polygon:
    """A polygon, possibly non-convex and with holes. Build it with :meth:`from_vertices` or
    :meth:`from_csv`.

    Attributes:
        name: short name.
        rings: list of ``(k, 2) float`` vertex loops without a repeated closing vertex; the
            exterior first, counter-clockwise, then the holes, clockwise. The material is on the
            left of every edge, so each edge's outward normal (right of the edge) points out of
            the material: away from the polygon on the exterior, into the hole on a hole.
        center: ``(2,) float`` area centroid.
        radius: largest distance from ``center`` to a vertex.
    """

    name: str
    rings: list[np.ndarray]
    center: np.ndarray
    radius: float
    warnings: tuple[str, ...] = ()
    dim: ClassVar[int] = 2

    @classmethod
    def from_vertices(cls, exterior, holes=(), *, name: str = "polygon") -> Polygon:
        """A polygon from its exterior ``(k, 2) float`` and holes (each ``(k_i, 2) float``), in
        either orientation, with or without a closing vertex equal to the first."""
        return cls._build([exterior, *holes], name, where=f"polygon {name!r}")

    @classmethod
    def from_csv(cls, path, holes=(), *, name: str | None = None) -> Polygon:
        """A polygon from a CSV file of x,y rows (an optional header line; ``#`` starts a
        comment), and optionally one CSV file per hole."""
        paths = [Path(path), *map(Path, holes)]
        rings = [_read_csv(p) for p in paths]
        where = " + ".join(map(str, paths))
        return cls._build(rings, name or paths[0].stem, where=where)

    @classmethod
    def _build(cls, rings, name: str, where: str) -> Polygon:
        rings = [_clean_ring(r, where, i) for i, r in enumerate(rings)]
        areas = np.array([_signed_area(r) for r in rings])
        rings = [r if (a > 0) == (i == 0) else r[::-1] for i, (r, a) in enumerate(zip(rings, areas))]
        _check_layout(rings, where)
        signed = np.abs(areas) * np.where(np.arange(len(rings)) == 0, 1.0, -1.0)
        if signed.sum() <= 0:
            raise ObjectError(f"{where}: the holes cover the whole exterior; give holes smaller than "
                              "the shape.")
        centroids = np.array([_ring_centroid(r) for r in rings])
        center = (signed[:, None] * centroids).sum(0) / signed.sum()
        radius = float(max(np.linalg.norm(r - center, axis=1).max() for r in rings))
        return cls(name=name, rings=rings, center=center, radius=radius)

    @property
    def area(self) -> float:
        """Area of the material (exterior minus holes)."""
        return float(sum(_signed_area(r) for r in self.rings))

    @functools.cached_property
    def _sampler(self) -> tuple[Picker, np.ndarray, np.ndarray, np.ndarray]:
        """Edge picker, edge starts, edge vectors and outward normals, ``(E, 2)``."""
        a, b = _ring_edges(self.rings)
        return Picker(np.linalg.norm(b - a, axis=1)), a, b - a, _edge_normals(a, b)

    def facets(self) -> tuple[np.ndarray, np.ndarray]:
        """Edge midpoints ``(E, 2) float`` and outward unit normals ``(E, 2) float``."""
        _, start, edge, normals = self._sampler
        return start + 0.5 * edge, normals

    def sample_surface(self, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """``count`` points uniform by length on the boundary and their outward unit normals,
        ``(count, 2) float`` each."""
        pick, start, edge, normals = self._sampler
        index = pick(check_count(count), rng)
        return start[index] + rng.random((count, 1)) * edge[index], normals[index]

    def contains(self, points) -> np.ndarray:
        """Whether each of ``points: (n, 2) float`` lies inside the material (``(n,) bool``);
        points on the boundary may go either way."""
        return _contains(self.rings, points)


def _ring_edges(rings: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Edge start and end points, ``(E, 2) float`` each, following the rings."""
    return np.concatenate(rings), np.concatenate([np.roll(r, -1, axis=0) for r in rings])


def _contains(rings: list[np.ndarray], points) -> np.ndarray:
    """Even-odd point-in-polygon test of ``points: (n, 2) float`` (``(n,) bool``)."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    a, b = _ring_edges(rings)
    inside = np.zeros(len(points), dtype=bool)
    step = max(1, _CHUNK // len(a))
    for lo in range(0, len(points), step):
        x, y = points[lo:lo + step, :1], points[lo:lo + step, 1:]
        straddle = (a[:, 1] > y) != (b[:, 1] > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            cross_x = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
        inside[lo:lo + step] = (straddle & (x < cross_x)).sum(1) % 2 == 1
    return inside


def _edge_normals(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Unit normals to the right of the edges ``a -> b``, ``(E, 2) float``."""
    e = b - a
    return np.stack([e[:, 1], -e[:, 0]], axis=1) / np.linalg.norm(e, axis=1, keepdims=True)


def _signed_area(ring: np.ndarray) -> float:
    x, y = ring.T
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _ring_centroid(ring: np.ndarray) -> np.ndarray:
    x, y = ring.T
    x1, y1 = np.roll(x, -1), np.roll(y, -1)
    cross = x * y1 - x1 * y
    return np.array([((x + x1) * cross).sum(), ((y + y1) * cross).sum()]) / (3.0 * cross.sum())


def _clean_ring(ring, where: str, i: int) -> np.ndarray:
    """Float ``(k, 2)`` vertices without consecutive duplicates or a closing vertex."""
    what = "the exterior" if i == 0 else f"hole {i}"
    try:
        ring = np.asarray(ring, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ObjectError(f"{where}: {what} is not an array of numbers ({exc}); give (k, 2) x,y "
                          "vertices.") from None
    if ring.ndim != 2 or ring.shape[1] != 2:
        raise ObjectError(f"{where}: {what} has shape {ring.shape}; give (k, 2) x,y vertices.")
    if not np.isfinite(ring).all():
        raise ObjectError(f"{where}: {what} has non-finite coordinates; give finite x,y vertices.")
    ring = ring[np.any(ring != np.roll(ring, -1, axis=0), axis=1)]
    if len(ring) < 3:
        raise ObjectError(f"{where}: {what} has {len(ring)} distinct vertices; a polygon needs at least 3.")
    scale = np.ptp(ring, axis=0).max()
    if abs(_signed_area(ring)) <= 1e-12 * scale**2:
        if _crossing_edges([ring]) is not None:
            raise ObjectError(f"{where}: {what} crosses itself and encloses zero net area; list the "
                              "vertices in order along the boundary.")
        raise ObjectError(f"{where}: {what} has zero area (its vertices are collinear); give a "
                          "proper polygon.")
    return ring


def _check_layout(rings: list[np.ndarray], where: str) -> None:
    """Holes inside the exterior and outside each other; no two edges cross."""
    for i, hole in enumerate(rings[1:], 1):
        if not _contains(rings[:1], hole).all():
            raise ObjectError(f"{where}: hole {i} is not inside the exterior; check the order of the rings.")
    for i, hole in enumerate(rings[1:], 1):
        for j, other in enumerate(rings[1:], 1):
            if i != j and _contains([other], hole[:1]).any():
                raise ObjectError(f"{where}: hole {i} lies inside hole {j}; give disjoint holes.")
    crossing = _crossing_edges(rings)
    if crossing is not None:
        raise ObjectError(
            f"{where}: edges {crossing[0]} and {crossing[1]} cross (the boundary intersects itself); "
            "list the vertices in order along the boundary."
        )


def _crossing_edges(rings: list[np.ndarray]) -> tuple[int, int] | None:
    """A pair of edges (indices in the concatenated rings) that properly cross, if any.

    Sweep along x: with the edges sorted by their smallest x, edge ``i`` can only meet the edges
    after it that start before it ends; only those pairs are tested, a block at a time."""
    a, b = _ring_edges(rings)
    order = np.argsort(np.minimum(a[:, 0], b[:, 0]), kind="stable")
    a, b = a[order], b[order]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    count = np.searchsorted(lo[:, 0], hi[:, 0], side="right") - np.arange(len(a)) - 1
    count = np.maximum(count, 0)
    total = np.concatenate([[0], np.cumsum(count)])

    def orient(p, q, r):
        return np.sign((q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0]))

    first = 0
    while first < len(a):
        last = max(first + 1, int(np.searchsorted(total, total[first] + _CHUNK, side="right")) - 1)
        ii = np.repeat(np.arange(first, last), count[first:last])
        jj = ii + 1 + np.arange(len(ii)) - np.repeat(total[first:last] - total[first], count[first:last])
        near = (lo[jj, 1] <= hi[ii, 1]) & (lo[ii, 1] <= hi[jj, 1])
        ii, jj = ii[near], jj[near]
        cross = (orient(a[ii], b[ii], a[jj]) * orient(a[ii], b[ii], b[jj]) < 0) & (
            orient(a[jj], b[jj], a[ii]) * orient(a[jj], b[jj], b[ii]) < 0)
        if cross.any():
            k = np.argmax(cross)
            return tuple(sorted((int(order[ii[k]]), int(order[jj[k]]))))
        first = last
    return None


def _read_csv(path: Path) -> np.ndarray:
    """``(k, 2) float`` rows of a CSV file; an optional non-numeric first line is a header."""
    if not path.is_file():
        raise ObjectError(f"{path}: file not found; check the path.")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise ObjectError(f"{path}: cannot be read as text ({exc}); give a CSV file of x,y rows.") from None
    rows, header = [], False
    for number, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        cells = [c for c in re.split(r"[,;\s]+", line) if c]
        try:
            values = [float(c) for c in cells]
        except ValueError:
            if rows or header:
                raise ObjectError(f"{path}: line {number} ({line!r}) is not two numbers; every row "
                                  "after an optional header must be x,y.") from None
            header = True
            continue
        if len(values) != 2:
            raise ObjectError(f"{path}: line {number} has {len(values)} values; every row must be x,y.")
        rows.append(values)
    if not rows:
        raise ObjectError(f"{path}: holds no x,y rows; give one vertex per line.")
    return np.array(rows)
