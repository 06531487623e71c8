"""Analytic shapes centred at the origin: sphere, ellipsoid, box, capped cylinder.

A contact's ``coords`` is the point itself ``(3,)`` (``face`` is 0). Each shape has one
closed-form map ``*_map(x) -> (point, normal)`` from points near the surface onto it, written
once in ``jax.numpy`` for any leading shape; the objects' NumPy ``project`` methods call it
(:func:`project`). ``retract`` moves a contact by the tangent part of ``v`` and maps it back
(the box and the cylinder unfold the step over their edges and rims first, so that a contact
walks around them); ``chart(c, v)`` is the map of ``c.point + P v`` (``P`` the tangent
projection at ``c``), shifted so that ``chart(c, 0) == embed(c)`` exactly.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from .._precision import float64_scope
from ._base import Contact
from ._util import Fields, check_count, check_one, host_points, jit_method, norm, pytree, sign, tangent, unit

_X = np.array([1.0, 0.0])  # NumPy: importing must not start a JAX backend


# --------------------------------------------------------------------------------------------
# closed-form maps onto the surfaces: (..., 3) -> (point (..., 3), outward unit normal (..., 3))


def sphere_map(x: jax.Array, radius) -> tuple[jax.Array, jax.Array]:
    """Radial projection onto the sphere of ``radius``."""
    n = unit(x)
    return radius * n, n


def ellipsoid_map(x: jax.Array, axes) -> tuple[jax.Array, jax.Array]:
    """Radial projection onto the ellipsoid of semi-axes ``axes: (3,)``; normal ``∝ p / axes²``."""
    s = norm(x / axes)[..., None]
    ok = s > 0
    p = jnp.where(ok, x, axes * jnp.array([0.0, 0.0, 1.0])) / jnp.where(ok, s, 1.0)
    return p, unit(p / axes**2)


def box_map(x: jax.Array, half) -> tuple[jax.Array, jax.Array]:
    """Onto the box ``|x_i| <= half_i``: the face of the largest ``|x_i| / half_i``, the other
    coordinates clipped to it."""
    axis = jnp.argmax(jnp.abs(x) / half, axis=-1)
    on = axis[..., None] == jnp.arange(3)
    s = sign(x)
    normal = jnp.where(on, s, 0.0).astype(x.dtype)
    return jnp.where(on, s * half, jnp.clip(x, -half, half)), normal


def cylinder_map(x: jax.Array, radius, half) -> tuple[jax.Array, jax.Array]:
    """Onto the capped cylinder ``rho <= radius, |z| <= half``: a cap where ``|z| / half >=
    rho / radius`` (radius clipped to it), the side elsewhere (height clipped)."""
    xy, z = x[..., :2], x[..., 2:]
    rho = norm(xy)[..., None]
    cap = jnp.abs(z) / half >= rho / radius
    sz = sign(z)
    out = unit(xy, _X.astype(x.dtype))
    scale = jnp.minimum(1.0, radius / jnp.where(rho > 0, rho, 1.0))
    cap_point = jnp.concatenate([xy * scale, sz * half], -1)
    side_point = jnp.concatenate([radius * out, jnp.clip(z, -half, half)], -1)
    zero2, zero1 = jnp.zeros_like(xy), jnp.zeros_like(z)
    cap_normal = jnp.concatenate([zero2, sz], -1)
    side_normal = jnp.concatenate([out, zero1], -1)
    return jnp.where(cap, cap_point, side_point), jnp.where(cap, cap_normal, side_normal)


def project(shape_map, points, *params) -> tuple[np.ndarray, np.ndarray]:
    """Host helper for the objects' ``project``: ``shape_map`` applied to ``points: (n, 3)`` in
    float64, as NumPy arrays."""
    with float64_scope():
        x = jnp.asarray(np.asarray(points, dtype=float), dtype=jnp.float64)
        p, n = shape_map(x, *(jnp.asarray(a, dtype=jnp.float64) for a in params))
        return np.asarray(p), np.asarray(n)


# --------------------------------------------------------------------------------------------
# surfaces


class _Analytic(Fields):
    """Shared methods; subclasses define ``_map(x)``, ``_sample_points(key, count)`` and
    ``_closest(points)`` (host)."""

    def _map(self, x):
        raise NotImplementedError

    @jit_method()
    def embed(self, contact: Contact) -> tuple[jax.Array, jax.Array]:
        """``(point (3,), outward unit normal (3,))`` of one contact."""
        check_one("embed", contact, 3)
        p = jnp.asarray(contact.coords)
        return p, self._map(p)[1]

    @jit_method()
    def chart(self, contact: Contact, v: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The map of ``point + P v``, shifted by the map's rounding at ``point`` so that
        ``chart(c, 0) == embed(c)`` exactly; smooth in ``v`` away from edges and rims."""
        check_one("chart", contact, 3, v)
        p = jnp.asarray(contact.coords)
        p0, n0 = self._map(p)
        q, nq = self._map(p + tangent(jnp.asarray(v, p.dtype), n0))
        return p + (q - p0), nq

    @jit_method()
    def retract(self, contact: Contact, v: jax.Array) -> Contact:
        """One contact moved by the tangent part of ``v: (3,)`` and mapped onto the surface (a
        non-finite ``v`` leaves it in place)."""
        check_one("retract", contact, 3, v)
        p = jnp.asarray(contact.coords)
        v = jnp.asarray(v, p.dtype)
        v = jnp.where(jnp.isfinite(v).all(), v, 0.0)  # a non-finite step leaves the contact in place
        return Contact(jnp.asarray(contact.face), self._move(p, tangent(v, self._map(p)[1])))

    def _move(self, p, w):
        return self._map(p + w)[0]

    @jit_method(static=("count",))
    def sample(self, key: jax.Array, count: int) -> Contact:
        """``count`` contacts uniform by area: face ``(count,) int32`` (zeros), coords
        ``(count, 3)``."""
        count = check_count(count)
        points = self._sample_points(key, count)
        return Contact(jnp.zeros(count, jnp.int32), points)

    def locate(self, points) -> Contact:
        """Host side: the contacts at the surface points closest to ``points: (..., 3)``."""
        points = host_points(points, 3)
        flat = points.reshape(-1, 3)
        closest = self._closest(flat) if len(flat) else flat
        shape = points.shape[:-1]
        return Contact(np.zeros(shape, np.int32), closest.reshape(*shape, 3))


def _uniform_sphere(key, count, dtype):
    return unit(jax.random.normal(key, (count, 3), dtype))


@pytree(data=("radius",))
class SphereSurface(_Analytic):
    """Sphere of ``radius: ()`` about the origin."""

    radius: jax.Array

    def _map(self, x):
        return sphere_map(x, self.radius)

    def _sample_points(self, key, count):
        return self.radius * _uniform_sphere(key, count, jnp.result_type(float))

    def _closest(self, points):
        r = np.linalg.norm(points, axis=1, keepdims=True)
        up = np.array([0.0, 0.0, 1.0])
        return float(self.radius) * np.where(r > 0, points / np.where(r > 0, r, 1.0), up)


@pytree(data=("axes",), meta=("acceptance",))
class EllipsoidSurface(_Analytic):
    """Ellipsoid of semi-axes ``axes: (3,)`` about the origin. ``acceptance`` (static): the
    acceptance rate of the rejection sampler (area x min(axes) / (4 pi abc)), which sizes its
    fixed pool of candidates."""

    axes: jax.Array
    acceptance: float = 0.5

    def _map(self, x):
        return ellipsoid_map(x, self.axes)

    def _sample_points(self, key, count):
        # rejection from the sphere map: the ellipsoid's area per area of the unit sphere at u is
        # proportional to |u / axes|; a fixed pool, the first `count` accepted candidates kept
        # (a pool too small by chance, below 1e-12 here, fills up with rejected ones)
        pool = math.ceil(count / self.acceptance * 1.5) + 64
        k_dir, k_acc = jax.random.split(key)
        dtype = jnp.result_type(float)
        u = _uniform_sphere(k_dir, pool, dtype)
        axes = jnp.asarray(self.axes, dtype)
        keep = jax.random.uniform(k_acc, (pool,), dtype) < norm(u / axes) * jnp.min(axes)
        order = jnp.argsort(~keep, stable=True)[:count]
        return axes * u[order]

    def _closest(self, points):
        return _ellipsoid_closest(points, np.asarray(self.axes, float))


@pytree(data=("half",))
class BoxSurface(_Analytic):
    """Box ``|x_i| <= half_i`` (``half: (3,)``). ``retract`` unfolds a step over the edges onto
    the neighbouring faces (up to 6 crossings), as on the box's net."""

    half: jax.Array

    def _map(self, x):
        return box_map(x, self.half)

    def _move(self, p, w):
        half = jnp.asarray(self.half, p.dtype)
        n0 = self._map(p)[1]
        axes = jnp.arange(3)
        axis = jnp.argmax(jnp.abs(n0))
        s = n0[axis]

        def cross(_, state):
            p, axis, s, w = state
            on_a = axes == axis
            room = jnp.where(w > 0, half - p, -half - p)
            moving = (w != 0) & ~on_a
            t = jnp.where(moving, jnp.maximum(room / jnp.where(moving, w, 1.0), 0.0), jnp.inf)
            b = jnp.argmin(t)
            crossed = t[b] < 1
            step = jnp.where(crossed, t[b], 1.0)
            on_b = axes == b
            sb = sign(w[b])
            p = jnp.where(crossed & on_b, sb * half, p + step * w)
            rest = (1 - step) * w
            # over the edge: the outward part of the rest turns down the new face (-s e_a)
            turned = jnp.where(on_b, 0.0, rest) + jnp.where(on_a, -s * jnp.abs(rest[b]), 0.0)
            w = jnp.where(crossed, turned, jnp.zeros_like(w))
            return p, jnp.where(crossed, b, axis), jnp.where(crossed, sb, s), w

        p, axis, s, _ = jax.lax.fori_loop(0, 6, cross, (p, axis, s, w))
        return jnp.where(axes == axis, s * half, jnp.clip(p, -half, half))

    def _sample_points(self, key, count):
        dtype = jnp.result_type(float)
        half = jnp.asarray(self.half, dtype)
        k_face, k_pos = jax.random.split(key)
        area = jnp.repeat(jnp.prod(half) / half, 2)
        face = jax.random.choice(k_face, 6, (count,), p=area / area.sum())
        axis, s = face // 2, jnp.where(face % 2 == 0, 1.0, -1.0).astype(dtype)
        x = jax.random.uniform(k_pos, (count, 3), dtype, -1.0, 1.0) * half
        on = axis[:, None] == jnp.arange(3)
        return jnp.where(on, s[:, None] * half, x)

    def _closest(self, points):
        half = np.asarray(self.half, float)
        best, dist = None, None
        for axis in range(3):
            for s in (1.0, -1.0):
                cand = np.clip(points, -half, half)
                cand[:, axis] = s * half[axis]
                d = np.linalg.norm(points - cand, axis=1)
                if best is None:
                    best, dist = cand, d
                else:
                    closer = d < dist
                    best[closer], dist[closer] = cand[closer], d[closer]
        return best


@pytree(data=("radius", "half"))
class CylinderSurface(_Analytic):
    """Capped cylinder along z: section ``radius: ()``, half height ``half: ()``. ``retract``
    walks the side exactly (unrolled), and carries a step over a rim once (side to cap or cap to
    side) before mapping back."""

    radius: jax.Array
    half: jax.Array

    def _map(self, x):
        return cylinder_map(x, self.radius, self.half)

    def _move(self, p, w):
        r = jnp.asarray(self.radius, p.dtype)
        h = jnp.asarray(self.half, p.dtype)
        n0 = self._map(p)[1]
        on_cap = jnp.abs(n0[2]) > 0.5
        return jnp.where(on_cap, self._from_cap(p, w, r, h, n0[2]), self._from_side(p, w, r, h, n0))

    def _from_side(self, p, w, r, h, n0):
        """Unrolled side: rotate by arc / r, climb by w_z; past a rim, the rest goes in over the
        cap."""
        out = n0[:2]
        along = jnp.array([-out[1], out[0]])
        arc, climb = jnp.dot(w[:2], along), w[2]
        top = sign(climb)
        room = top * h - p[2]
        t = jnp.where(climb != 0, room / jnp.where(climb != 0, climb, 1.0), jnp.inf)
        t = jnp.clip(t, 0.0, 1.0)
        angle = arc * t / r
        c, s = jnp.cos(angle), jnp.sin(angle)
        out_t = jnp.array([c * out[0] - s * out[1], s * out[0] + c * out[1]])
        z = p[2] + t * climb
        rim = jnp.concatenate([r * out_t, z[None]])
        # on the cap from the rim point: in by the rest of the climb, along the rim's tangent
        rest = 1 - t
        along_t = jnp.array([-out_t[1], out_t[0]])
        cap_xy = rim[:2] - out_t * (rest * jnp.abs(climb)) + along_t * (rest * arc)
        cap = jnp.concatenate([cap_xy, (top * h)[None]])
        return self._map(jnp.where(rest > 0, cap, rim))[0]

    def _from_cap(self, p, w, r, h, nz):
        """Straight on the cap; past the rim, the rest goes down the side (unrolled)."""
        xy, d = p[:2], w[:2]
        # |xy + t d| = r: the exit along the step
        a, b, c = jnp.dot(d, d), jnp.dot(xy, d), jnp.dot(xy, xy) - r * r
        disc = jnp.maximum(b * b - a * c, 0.0)
        t = jnp.where(a > 0, (-b + jnp.sqrt(disc)) / jnp.where(a > 0, a, 1.0), jnp.inf)
        t = jnp.clip(t, 0.0, 1.0)
        exit_xy = xy + t * d
        out = unit(exit_xy, _X.astype(p.dtype))
        rest = (1 - t) * d
        down = jnp.dot(rest, out)
        angle = jnp.dot(rest, jnp.array([-out[1], out[0]])) / r
        c, s = jnp.cos(angle), jnp.sin(angle)
        out_t = jnp.array([c * out[0] - s * out[1], s * out[0] + c * out[1]])
        side = jnp.concatenate([r * out_t, (nz * (h - down))[None]])
        moved = jnp.concatenate([xy + d, p[2:]])
        return self._map(jnp.where(t < 1, side, moved))[0]

    def _sample_points(self, key, count):
        dtype = jnp.result_type(float)
        r, h = jnp.asarray(self.radius, dtype), jnp.asarray(self.half, dtype)
        k_part, k_theta, k_rho, k_z = jax.random.split(key, 4)
        area = jnp.stack([4 * jnp.pi * r * h, jnp.pi * r * r, jnp.pi * r * r])
        part = jax.random.choice(k_part, 3, (count,), p=area / area.sum())
        theta = jax.random.uniform(k_theta, (count,), dtype, 0.0, 2 * jnp.pi)
        rho = jnp.where(part == 0, r, r * jnp.sqrt(jax.random.uniform(k_rho, (count,), dtype)))
        z = jnp.where(part == 0, jax.random.uniform(k_z, (count,), dtype, -1.0, 1.0) * h,
                      jnp.where(part == 1, h, -h))
        return jnp.stack([rho * jnp.cos(theta), rho * jnp.sin(theta), z], 1)

    def _closest(self, points):
        r, h = float(self.radius), float(self.half)
        rho = np.linalg.norm(points[:, :2], axis=1, keepdims=True)
        out = np.where(rho > 0, points[:, :2] / np.where(rho > 0, rho, 1.0), [1.0, 0.0])
        side = np.column_stack([r * out, np.clip(points[:, 2], -h, h)])
        cands = [side] + [np.column_stack([points[:, :2] * np.minimum(1.0, r / np.maximum(rho, 1e-300)),
                                           np.full(len(points), z)]) for z in (h, -h)]
        dist = np.stack([np.linalg.norm(points - c, axis=1) for c in cands])
        return np.stack(cands)[np.argmin(dist, axis=0), np.arange(len(points))]


def _ellipsoid_closest(points: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """Closest points on the ellipsoid ``axes`` (host, float64): the root ``t`` of
    ``sum (a_i x_i / (t + a_i^2))^2 = 1`` by bisection, ``y_i = a_i^2 x_i / (t + a_i^2)``, then
    mapped radially to remove the rounding (points with no root in range, inside on the
    shortest axis' plane, fall back to the radial map)."""
    a2 = axes**2
    lo = np.full(len(points), -a2.min())
    hi = np.full(len(points), np.linalg.norm(points * axes, axis=1) + 0.0)
    hi = np.maximum(hi, a2.max())
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        g = ((axes * points / (mid[:, None] + a2)) ** 2).sum(1) - 1.0
        lo, hi = np.where(g > 0, mid, lo), np.where(g > 0, hi, mid)
    t = 0.5 * (lo + hi)
    y = a2 * points / (t[:, None] + a2)
    fine = np.isfinite(y).all(1) & (t > -a2.min() * (1 - 1e-9))
    y = np.where(fine[:, None], y, points)
    return project(ellipsoid_map, y, axes)[0]


def for_sphere(obj) -> SphereSurface:
    return SphereSurface(center=np.zeros(3), radius=np.asarray(float(obj.radius)),
                         scale=float(obj.radius))


def for_ellipsoid(obj) -> EllipsoidSurface:
    axes = np.asarray(obj.axes, float)
    rate = float(obj.mesh.area) * axes.min() / (4 * np.pi * np.prod(axes))
    return EllipsoidSurface(center=np.zeros(3), axes=axes, scale=float(obj.radius),
                            acceptance=float(min(1.0, rate)))


def for_box(obj) -> BoxSurface:
    return BoxSurface(center=np.zeros(3), half=np.asarray(obj.extents, float) / 2,
                      scale=float(obj.radius))


def for_cylinder(obj) -> CylinderSurface:
    return CylinderSurface(center=np.zeros(3), radius=np.asarray(float(obj.section_radius)),
                           half=np.asarray(obj.height / 2), scale=float(obj.radius))
