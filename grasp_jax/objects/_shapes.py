"""Analytic 3D shapes centred at the origin, with exact normals: sphere, box, cylinder, ellipsoid.

Sizes default to hand-sized objects in metres. ``facets()`` are the triangles of a fine
deterministic tessellation (``.mesh``), with their centroids moved onto the exact surface and
the exact normals there.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import trimesh

from ..surfaces import _analytic
from ._base import ObjectError, Picker, check_count, unit


def revolve(profile: np.ndarray, sections: int) -> trimesh.Trimesh:
    """Closed surface of revolution about the z axis.

    Args:
        profile: ``(P, 2) float`` (r, z) points; the first and last have r = 0 (on the axis), the
            others r > 0.
        sections: segments around the axis.

    Returns:
        A watertight mesh of ``2 * sections * (P - 2)`` triangles, normals outward.
    """
    r, z = np.asarray(profile, dtype=float).T
    inner = len(r) - 2
    angle = 2 * np.pi * np.arange(sections) / sections
    rings = np.stack([np.outer(r[1:-1], np.cos(angle)), np.outer(r[1:-1], np.sin(angle)),
                      np.repeat(z[1:-1, None], sections, 1)], -1).reshape(-1, 3)
    vertices = np.concatenate([rings, [[0.0, 0.0, z[0]], [0.0, 0.0, z[-1]]]])
    ring = np.arange(inner * sections).reshape(inner, sections)
    nxt = np.roll(ring, -1, axis=1)
    first, last = inner * sections, inner * sections + 1
    faces = np.concatenate([
        np.stack([np.full(sections, first), ring[0], nxt[0]], 1),
        np.stack([ring[:-1], ring[1:], nxt[1:]], -1).reshape(-1, 3),
        np.stack([ring[:-1], nxt[1:], nxt[:-1]], -1).reshape(-1, 3),
        np.stack([np.full(sections, last), nxt[-1], ring[-1]], 1),
    ])
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def _positive(where: str, **values) -> None:
    for key, value in values.items():
        v = np.asarray(value, dtype=float)
        if not (np.isfinite(v).all() and (v > 0).all()):
            raise ObjectError(f"{where}: {key} must be finite and > 0; got {value!r}.")


class _Analytic:
    """Shared behaviour: centre at the origin, facets from the tessellation projected onto the
    exact surface."""

    dim = 3
    warnings: tuple[str, ...] = ()
    name: str
    radius: float

    @property
    def center(self) -> np.ndarray:
        """``(3,) float`` centre of mass: the origin."""
        return np.zeros(3)

    @functools.cached_property
    def mesh(self) -> trimesh.Trimesh:
        """A fine deterministic tessellation (for facets and drawing)."""
        return self._tessellate()

    def facets(self) -> tuple[np.ndarray, np.ndarray]:
        """Tessellation triangle centroids moved onto the surface ``(F, 3) float`` and the exact
        outward unit normals there ``(F, 3) float``."""
        return self.project(np.asarray(self.mesh.triangles_center, float))

    def project(self, points) -> tuple[np.ndarray, np.ndarray]:
        """Points ``(n, 3) float`` near the surface moved onto it, and the outward unit normals
        there, ``(n, 3) float`` each."""
        raise NotImplementedError

    def _tessellate(self) -> trimesh.Trimesh:
        raise NotImplementedError

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in vars(self).items() if k != "mesh")
        return f"{type(self).__name__}({args})"


class Sphere(_Analytic):
    """Sphere of radius ``radius`` (its ``radius`` is also the protocol's radius)."""

    def __init__(self, radius: float = 0.04, *, name: str = "sphere"):
        _positive(f"Sphere {name!r}", radius=radius)
        self.radius, self.name = float(radius), name

    def project(self, points):
        return _analytic.project(_analytic.sphere_map, points, self.radius)

    def exact_surface(self):
        """The :class:`~grasp_jax.surfaces.Surface` of the exact shape (exact normals)."""
        return _analytic.for_sphere(self)

    def sample_surface(self, count: int, rng: np.random.Generator):
        """``count`` points uniform by area and outward unit normals, ``(count, 3) float`` each."""
        normals = unit(rng.normal(size=(check_count(count), 3)))
        return self.radius * normals, normals

    def _tessellate(self):
        return trimesh.creation.icosphere(subdivisions=3, radius=self.radius)


class Ellipsoid(_Analytic):
    """Ellipsoid with semi-axes ``axes`` (a, b, c) along x, y, z; ``radius`` is max(axes)."""

    def __init__(self, axes=(0.05, 0.035, 0.025), *, name: str = "ellipsoid"):
        _positive(f"Ellipsoid {name!r}", axes=axes)
        self.axes = np.array(axes, dtype=float).reshape(3)
        self.radius, self.name = float(self.axes.max()), name

    def project(self, points):
        return _analytic.project(_analytic.ellipsoid_map, points, self.axes)

    def exact_surface(self):
        """The :class:`~grasp_jax.surfaces.Surface` of the exact shape (exact normals)."""
        return _analytic.for_ellipsoid(self)

    def sample_surface(self, count: int, rng: np.random.Generator):
        """``count`` points uniform by area (rejection from the sphere map) and outward unit
        normals, ``(count, 3) float`` each."""
        count, found = check_count(count), []
        # acceptance rate: E|u / axes| min(axes) = area min(axes) / (4 pi abc), area from the mesh
        rate = self.mesh.area * self.axes.min() / (4 * np.pi * np.prod(self.axes))
        while sum(len(f) for f in found) < count:
            u = unit(rng.normal(size=(int(1.1 * count / rate) + 64, 3)))
            # area of the ellipsoid per area of the unit sphere at u is prop. to |u / axes|
            keep = rng.random(len(u)) < np.linalg.norm(u / self.axes, axis=1) * self.axes.min()
            found.append(u[keep])
        points = self.axes * np.concatenate(found)[:count]
        return points, unit(points / self.axes**2)

    def _tessellate(self):
        sphere = trimesh.creation.icosphere(subdivisions=3)
        return trimesh.Trimesh(sphere.vertices * self.axes, sphere.faces, process=False)


class Box(_Analytic):
    """Box with side lengths ``extents`` along x, y, z; ``radius`` is half its diagonal."""

    def __init__(self, extents=(0.08, 0.05, 0.03), *, name: str = "box"):
        _positive(f"Box {name!r}", extents=extents)
        self.extents = np.array(extents, dtype=float).reshape(3)
        self.radius, self.name = float(np.linalg.norm(self.extents) / 2), name

    def project(self, points):
        return _analytic.project(_analytic.box_map, points, self.extents / 2)

    def exact_surface(self):
        """The :class:`~grasp_jax.surfaces.Surface` of the exact shape (exact normals)."""
        return _analytic.for_box(self)

    def sample_surface(self, count: int, rng: np.random.Generator):
        """``count`` points uniform by area and outward unit normals, ``(count, 3) float`` each."""
        count = check_count(count)
        half = self.extents / 2
        face = Picker(np.repeat(np.prod(self.extents) / self.extents, 2))(count, rng)
        axis, sign = face // 2, np.where(face % 2 == 0, 1.0, -1.0)
        points = (rng.random((count, 3)) * 2 - 1) * half
        rows = np.arange(count)
        points[rows, axis] = sign * half[axis]
        normals = np.zeros((count, 3))
        normals[rows, axis] = sign
        return points, normals

    def _tessellate(self):
        mesh = trimesh.creation.box(extents=self.extents)
        vertices, faces = mesh.vertices, mesh.faces
        for _ in range(3):
            vertices, faces = trimesh.remesh.subdivide(vertices, faces)
        return trimesh.Trimesh(vertices, faces, process=False)


class Cylinder(_Analytic):
    """Capped cylinder along z of section radius ``radius`` and height ``height``, stored as
    ``section_radius`` and ``height``; the protocol's ``radius`` is the distance from the centre to
    a rim, ``hypot(radius, height / 2)``."""

    def __init__(self, radius: float = 0.03, height: float = 0.1, *, name: str = "cylinder"):
        _positive(f"Cylinder {name!r}", radius=radius, height=height)
        self.section_radius, self.height, self.name = float(radius), float(height), name
        self.radius = math.hypot(self.section_radius, self.height / 2)

    def project(self, points):
        return _analytic.project(_analytic.cylinder_map, points, self.section_radius, self.height / 2)

    def exact_surface(self):
        """The :class:`~grasp_jax.surfaces.Surface` of the exact shape (exact normals)."""
        return _analytic.for_cylinder(self)

    def sample_surface(self, count: int, rng: np.random.Generator):
        """``count`` points uniform by area and outward unit normals, ``(count, 3) float`` each."""
        count = check_count(count)
        r, h = self.section_radius, self.height
        part = Picker([2 * np.pi * r * h, np.pi * r * r, np.pi * r * r])(count, rng)
        theta = 2 * np.pi * rng.random(count)
        rho = np.where(part == 0, r, r * np.sqrt(rng.random(count)))
        z = np.where(part == 0, (rng.random(count) - 0.5) * h, np.where(part == 1, h / 2, -h / 2))
        points = np.stack([rho * np.cos(theta), rho * np.sin(theta), z], 1)
        normals = np.zeros((count, 3))
        side = part == 0
        normals[side, :2] = points[side, :2] / r
        normals[~side, 2] = np.sign(z[~side])
        return points, normals

    def _tessellate(self):
        r, half = self.section_radius, self.height / 2
        profile = np.concatenate([
            np.stack([np.linspace(0, r, 9), np.full(9, -half)], 1),
            np.stack([np.full(15, r), np.linspace(-half, half, 17)[1:-1]], 1),
            np.stack([np.linspace(r, 0, 9), np.full(9, half)], 1),
        ])
        return revolve(profile, 64)
