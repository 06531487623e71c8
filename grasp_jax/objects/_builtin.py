"""Demo objects generated in code (no data files): the paper's glass and mechanical part in 3D
(metres), its quadrilateral and star in 2D (unit size)."""

from __future__ import annotations

import numpy as np
import trimesh

from ._mesh import Mesh
from ._polygon import Polygon
from ._shapes import revolve


def _arc(center, radius: float, start: float, stop: float, segments: int) -> np.ndarray:
    """``segments`` points on a circular arc in the (r, z) plane, the start point excluded."""
    angle = np.linspace(start, stop, segments + 1)[1:]
    return np.asarray(center) + radius * np.stack([np.cos(angle), np.sin(angle)], 1)


def _line(a, b, segments: int) -> np.ndarray:
    """``segments`` points from ``a`` (excluded) to ``b`` (included)."""
    t = np.linspace(0.0, 1.0, segments + 1)[1:, None]
    return np.asarray(a) + t * (np.asarray(b) - np.asarray(a))


def glass() -> Mesh:
    """A drinking glass, 10 cm tall: tapered wall 3 mm thick with a rounded rim, 8 mm bottom with
    filleted edges; a watertight surface of revolution of 9,486 triangles (as the paper's)."""
    base, top, height, wall, bottom = 0.028, 0.036, 0.10, 0.003, 0.008
    fillet, inner_fillet = 0.004, 0.005
    alpha = np.arctan((top - base) / height)  # taper; the outer wall is r = base + z tan(alpha)
    s, c = np.sin(alpha), np.cos(alpha)
    normal = np.array([c, -s])  # outward normal of the outer wall in (r, z)
    outer_center = np.array([base - fillet * (1 - s) / c, fillet])
    inner_center = np.array([base + ((bottom + inner_fillet) * s - wall - inner_fillet) / c,
                             bottom + inner_fillet])
    rim_z = height - wall / 2
    rim_outer = np.array([base + rim_z * np.tan(alpha), rim_z])
    profile = np.concatenate([
        [[0.0, 0.0]],
        _line([0.0, 0.0], [outer_center[0], 0.0], 4),
        _arc(outer_center, fillet, -np.pi / 2, -alpha, 4),
        _line(outer_center + fillet * normal, rim_outer, 14),
        _arc(rim_outer - wall / 2 * normal, wall / 2, -alpha, np.pi - alpha, 6),
        _line(rim_outer - wall * normal, inner_center + inner_fillet * normal, 14),
        _arc(inner_center, inner_fillet, -alpha, -np.pi / 2, 4),
        _line([inner_center[0], bottom], [0.0, bottom], 6),
    ])
    return Mesh.from_trimesh(revolve(profile, 93), name="glass")


def part() -> Mesh:
    """A mechanical part: an 8 x 6 x 1 cm plate on a 4 x 3 grid of 2 cm cells with four through
    holes and four blind pockets; watertight, 2,752 triangles."""
    layout = ("O.PO", ".PO.", "OP.P")  # O: through hole, P: pocket, .: solid
    cell, thick, n = 0.02, 0.01, 8  # cell size, plate thickness, segments per cell side
    hole, pocket, depth, layers = 0.006, 0.007, 0.005, 2
    steps = np.arange(n) / n
    square = np.concatenate([np.stack([steps, 0 * steps], 1), np.stack([1 + 0 * steps, steps], 1),
                             np.stack([1 - steps, 1 + 0 * steps], 1), np.stack([0 * steps, 1 - steps], 1)])
    tris, outward = [], []

    def add(ring_a, ring_b, za, zb, direction):
        """Quads between two closed (k, 2) loops at heights za, zb (broadcastable per point)."""
        a = np.column_stack([ring_a, np.broadcast_to(za, len(ring_a))])
        b = np.column_stack([ring_b, np.broadcast_to(zb, len(ring_b))])
        a1, b1 = np.roll(a, -1, 0), np.roll(b, -1, 0)
        tris.extend([np.stack([a, a1, b1], 1), np.stack([a, b1, b], 1)])
        outward.extend([direction(a, a1, b1), direction(a, b1, b)])

    def fan(center, ring, z, up):
        a = np.column_stack([ring, np.full(len(ring), z)])
        c = np.broadcast_to(np.append(center, z), a.shape)
        tris.append(np.stack([c, a, np.roll(a, -1, 0)], 1))
        outward.append(np.broadcast_to([0.0, 0.0, up], a.shape))

    def vertical(z):
        return lambda *corners: np.broadcast_to([0.0, 0.0, z], corners[0].shape)

    def towards(center):
        return lambda a, *rest: np.column_stack([center - a[:, :2], np.zeros(len(a))])

    levels = np.linspace(0.0, thick, layers + 1)
    for row, line in enumerate(layout[::-1]):
        for col, kind in enumerate(line):
            boundary = (square + [col, row]) * cell
            center = (np.array([col, row]) + 0.5) * cell
            if kind == ".":
                fan(center, boundary, thick, 1.0)
                fan(center, boundary, 0.0, -1.0)
                continue
            radius = hole if kind == "O" else pocket
            offset = boundary - center
            circle = center + radius * offset / np.linalg.norm(offset, axis=1, keepdims=True)
            add(boundary, circle, thick, thick, vertical(1.0))
            if kind == "O":
                add(boundary, circle, 0.0, 0.0, vertical(-1.0))
                walls = levels
            else:
                fan(center, boundary, 0.0, -1.0)
                fan(center, circle, thick - depth, 1.0)
                walls = np.linspace(thick - depth, thick, layers + 1)
            for z0, z1 in zip(walls[:-1], walls[1:]):
                add(circle, circle, z0, z1, towards(center))
    cols, rows = len(layout[0]), len(layout)
    ring = np.concatenate([
        np.stack([np.arange(cols * n), np.zeros(cols * n)], 1),
        np.stack([np.full(rows * n, cols * n), np.arange(rows * n)], 1),
        np.stack([cols * n - np.arange(cols * n), np.full(cols * n, rows * n)], 1),
        np.stack([np.zeros(rows * n), rows * n - np.arange(rows * n)], 1),
    ]) * (cell / n)
    middle = np.array([cols, rows]) * cell / 2
    for z0, z1 in zip(levels[:-1], levels[1:]):
        add(ring, ring, z0, z1, lambda a, *rest: np.column_stack([a[:, :2] - middle, np.zeros(len(a))]))
    tris, outward = np.concatenate(tris), np.concatenate(outward)
    normal = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    flip = np.einsum("ij,ij->i", normal, outward) < 0
    tris[flip] = tris[flip][:, ::-1]
    mesh = trimesh.Trimesh(tris.reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3), process=True)
    return Mesh.from_trimesh(mesh, name="part")


def quad() -> Polygon:
    """An irregular convex quadrilateral of unit size, like the paper's Fig. 6 (a-c)."""
    return Polygon.from_vertices([[0.0, 0.0], [1.0, 0.15], [0.85, 0.9], [0.1, 0.7]], name="quad")


def star() -> Polygon:
    """A five-pointed star (non-convex): outer radius 1, inner radius 0.4, a point up."""
    angle = np.pi / 2 + np.arange(10) * np.pi / 5
    radius = np.where(np.arange(10) % 2 == 0, 1.0, 0.4)
    return Polygon.from_vertices(np.stack([radius * np.cos(angle), radius * np.sin(angle)], 1), name="star")
