"""Random grasps on simple shapes with exact outward normals, and on real meshes (test helper)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

MU = 0.364  # tan(20 deg), the paper's friction


def unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# ---------------------------------------------------------------------------------------------
# 2D polygons (counter-clockwise vertices; the outward normal of edge (dx, dy) is (dy, -dx)).

QUAD = np.array([[0.0, 0.0], [2.0, 0.0], [2.5, 1.5], [0.3, 1.2]])


def star(points: int = 5, outer: float = 1.0, inner: float = 0.4) -> np.ndarray:
    angles = np.pi / 2 + np.arange(2 * points) * np.pi / points
    radii = np.where(np.arange(2 * points) % 2 == 0, outer, inner)
    return np.stack([radii * np.cos(angles), radii * np.sin(angles)], axis=1)


STAR = star()


def _signed_area(vertices):
    x, y = vertices[:, 0], vertices[:, 1]
    return 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)


def sample_polygon(vertices: np.ndarray, count: int, rng: np.random.Generator):
    """``count`` boundary points (away from the corners) with their outward unit normals."""
    assert _signed_area(vertices) > 0, "vertices must be counter-clockwise"
    start = vertices
    edge = np.roll(vertices, -1, axis=0) - vertices
    length = np.linalg.norm(edge, axis=1)
    k = rng.choice(len(vertices), size=count, p=length / length.sum())
    t = rng.uniform(0.03, 0.97, size=count)
    points = start[k] + t[:, None] * edge[k]
    normals = unit(np.stack([edge[k, 1], -edge[k, 0]], axis=1))
    return points, normals


# ---------------------------------------------------------------------------------------------
# 3D solids with exact outward normals.


def sample_box(count, rng, extents=(2.0, 1.2, 0.8)):
    e = np.asarray(extents) / 2
    areas = np.array([e[1] * e[2], e[0] * e[2], e[0] * e[1]])
    axis = rng.choice(3, size=count, p=areas / areas.sum())
    sign = rng.choice([-1.0, 1.0], size=count)
    points = rng.uniform(-0.97, 0.97, size=(count, 3)) * e
    points[np.arange(count), axis] = sign * e[axis]
    normals = np.zeros((count, 3))
    normals[np.arange(count), axis] = sign
    return points, normals


def sample_cylinder(count, rng, radius=0.5, height=1.5):
    side, cap = 2 * np.pi * radius * height, np.pi * radius**2
    kind = rng.choice(3, size=count, p=np.array([side, cap, cap]) / (side + 2 * cap))
    theta = rng.uniform(0, 2 * np.pi, size=count)
    z = rng.uniform(-0.97, 0.97, size=count) * height / 2
    r = radius * np.sqrt(rng.uniform(0, 0.95, size=count))
    points = np.stack([radius * np.cos(theta), radius * np.sin(theta), z], axis=1)
    normals = np.stack([np.cos(theta), np.sin(theta), np.zeros(count)], axis=1)
    for k, sign in ((1, 1.0), (2, -1.0)):
        sel = kind == k
        points[sel] = np.stack([r[sel] * np.cos(theta[sel]), r[sel] * np.sin(theta[sel]),
                                np.full(sel.sum(), sign * height / 2)], axis=1)
        normals[sel] = [0.0, 0.0, sign]
    return points, normals


def sample_cylinder_side(count, rng, radius=0.5, height=1.5):
    """Points on the side of the cylinder only (no caps). A grasp of them has horizontal normals,
    so the torques of its cone edges about ``c_1`` lie in a half-space: the degenerate quality LP
    of ``_polish.half_space_quality_lp``."""
    theta = rng.uniform(0, 2 * np.pi, size=count)
    z = rng.uniform(-0.97, 0.97, size=count) * height / 2
    normals = np.stack([np.cos(theta), np.sin(theta), np.zeros(count)], axis=1)
    return np.concatenate([radius * normals[:, :2], z[:, None]], axis=1), normals


def sample_sphere(count, rng, radius=1.0):
    normals = unit(rng.normal(size=(count, 3)))
    return radius * normals, normals


def load_mesh(path: Path):
    import trimesh

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # missing material files of the YCB scans
        mesh = trimesh.load(path, force="mesh", process=True, merge_tex=True, merge_norm=True)
    # Centre and normalize (Q is scale free; this keeps tolerances comparable across meshes).
    mesh.apply_translation(-mesh.bounds.mean(axis=0))
    mesh.apply_scale(1.0 / mesh.scale)
    return mesh


def mesh_sampler(mesh):
    import trimesh

    def sample(count, rng):
        points, faces = trimesh.sample.sample_surface(mesh, count, seed=rng)
        return np.asarray(points, float), unit(mesh.face_normals[faces])

    return sample


def grasps(sampler, batch: int, n: int, rng):
    """``(batch, n, d)`` points and normals of random grasps: ``n`` independent surface samples."""
    points, normals = sampler(batch * n, rng)
    d = points.shape[-1]
    return points.reshape(batch, n, d), normals.reshape(batch, n, d)
