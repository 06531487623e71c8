"""Surfaces: contacts that stay on the object and move over it (grasp_jax.surfaces).

Every kind (analytic shapes, polygons with holes, triangle meshes) is checked against an
independent reference: the shape's implicit equation, a NumPy brute-force distance to the
polygon's edges, trimesh's closest points on a mesh. Float64 work runs inside
``float64_scope()`` (it does not rely on a global x64 switch); float32 runs too, looser.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from grasp_jax import objects, surfaces
from grasp_jax._precision import float64_scope
from grasp_jax.surfaces import Contact

# ------------------------------------------------------------------------------------ helpers


def ring_polygon():
    """A square with a square hole and a triangular hole (three rings)."""
    return objects.Polygon.from_vertices(
        [[0, 0], [4, 0], [4, 3], [0, 3]],
        holes=[[[0.5, 0.5], [1.5, 0.5], [1.5, 1.5], [0.5, 1.5]], [[2.5, 1], [3.5, 1], [3, 2.2]]],
        name="holes")


def circle_polygon(k=200):
    angle = 2 * np.pi * np.arange(k) / k
    return objects.Polygon.from_vertices(np.stack([np.cos(angle), np.sin(angle)], 1), name="circle")


def mesh_object(tm, name="mesh"):
    return objects.Mesh.from_trimesh(tm, name=name)


def icosphere():
    return mesh_object(trimesh.creation.icosphere(1), "icosphere")


def box_mesh():
    """A box of 2 x 1 x 0.5 with subdivided faces (coplanar triangles, sharp 90 degree edges)."""
    tm = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
    v, f = trimesh.remesh.subdivide(tm.vertices, tm.faces)
    return mesh_object(trimesh.Trimesh(v, f), "boxmesh")


OBJECTS = {
    "sphere": objects.Sphere,
    "ellipsoid": objects.Ellipsoid,
    "box": objects.Box,
    "cylinder": objects.Cylinder,
    "quad": objects.quad,
    "star": objects.star,
    "holes": ring_polygon,
    "icosphere": icosphere,
    "boxmesh": box_mesh,
}
ANALYTIC = ("sphere", "ellipsoid", "box", "cylinder")
POLYGONS = ("quad", "star", "holes")
MESHES = ("icosphere", "boxmesh")


@functools.cache
def build(name, normals="smooth"):
    obj = OBJECTS[name]()
    return obj, surfaces.for_object(obj, normals=normals)


def batched(method):
    """``jit(vmap(surface.method))`` with the surface passed as an argument (not a constant)."""
    return jax.jit(lambda surface, *args: jax.vmap(getattr(surface, method))(*args))


RETRACT, EMBED, CHART = batched("retract"), batched("embed"), batched("chart")

#: contacts per batch in every float64 test (one compiled program per surface and method)
N = 64


@functools.cache
def start(name):
    """``N`` contacts sampled on ``name`` in float64 (call inside ``float64_scope``)."""
    return build(name)[1].sample(jax.random.key(1), N)


def distance_from_surface(obj, points: np.ndarray) -> np.ndarray:
    """Independent reference distances of ``points`` from ``obj``'s exact surface."""
    if isinstance(obj, objects.Sphere):
        return np.abs(np.linalg.norm(points, axis=1) - obj.radius)
    if isinstance(obj, objects.Ellipsoid):
        return np.abs(np.linalg.norm(points / obj.axes, axis=1) - 1) * obj.axes.min()
    if isinstance(obj, objects.Box):
        excess = np.abs(points) - obj.extents / 2
        return np.maximum(np.abs(excess.max(1)), np.maximum(excess, 0).max(1))
    if isinstance(obj, objects.Cylinder):
        excess = np.stack([np.linalg.norm(points[:, :2], axis=1) - obj.section_radius,
                           np.abs(points[:, 2]) - obj.height / 2], 1)
        return np.maximum(np.abs(excess.max(1)), np.maximum(excess, 0).max(1))
    if isinstance(obj, objects.Polygon):
        a = np.concatenate(obj.rings)
        b = np.concatenate([np.roll(r, -1, 0) for r in obj.rings])
        e = b - a
        t = np.clip(np.einsum("pij,ij->pi", points[:, None] - a, e) / (e * e).sum(1), 0, 1)
        return np.linalg.norm(a + t[..., None] * e - points[:, None], axis=2).min(1)
    return mesh_distance(np.asarray(obj.mesh.triangles), points)


def mesh_distance(triangles: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Distance from each of ``points: (n, 3)`` to the triangles ``(F, 3, 3)``, brute force: the
    plane distance where the projection falls inside a triangle, else the nearest of its edges.
    (trimesh's ``closest_point`` misreports some thin triangles of the part by ~1e-5.)"""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    out = np.empty(len(points))
    for i, x in enumerate(points):
        h = np.einsum("fj,fj->f", x - a, n)
        q = x - h[:, None] * n
        inside = np.ones(len(a), bool)
        best = np.full(len(a), np.inf)
        for u, v in ((a, b), (b, c), (c, a)):
            inside &= np.einsum("fj,fj->f", np.cross(v - u, q - u), n) >= 0
            e = v - u
            t = np.clip(np.einsum("fj,fj->f", x - u, e) / np.einsum("fj,fj->f", e, e), 0, 1)
            best = np.minimum(best, np.linalg.norm(u + t[:, None] * e - x, axis=1))
        out[i] = np.where(inside, np.abs(h), best).min()
    return out


def random_walk(surface, contacts, key, steps, size):
    """``steps`` random retracts of length ~``size``; returns the final contacts and the set of
    faces visited."""
    visited = [np.asarray(contacts.face)]
    for k in range(steps):
        v = size * jax.random.normal(jax.random.fold_in(key, k), contacts.coords.shape[:-1] + (surface.dim,))
        contacts = RETRACT(surface, contacts, v.astype(contacts.coords.dtype))
        visited.append(np.asarray(contacts.face))
    return contacts, np.concatenate(visited)


# ------------------------------------------------------------------------- protocol, pytree


@pytest.mark.parametrize("name", list(OBJECTS))
def test_protocol_and_pytree(name):
    obj, surface = build(name)
    assert isinstance(surface, surfaces.Surface)
    assert surface.dim == obj.dim and surface.scale == pytest.approx(obj.radius)
    assert np.allclose(surface.center, obj.center)
    assert surface.normal_kind == ("exact" if name in ANALYTIC else "smooth")
    leaves, tree = jax.tree_util.tree_flatten(surface)
    assert all(hasattr(leaf, "shape") for leaf in leaves)
    again = jax.tree_util.tree_unflatten(tree, leaves)
    assert type(again) is type(surface) and again.scale == surface.scale
    # the surface is an argument of the compiled function, not a constant baked in
    with float64_scope():
        c = start(name)
        traced = jax.jit(lambda s, c: jax.vmap(s.embed)(c)[0])
        assert np.allclose(traced(surface, c), jax.vmap(surface.embed)(c)[0])


def test_a_mesh_or_polygon_surface_is_built_once_per_object_and_options():
    mesh = objects.load("glass")
    first = surfaces.for_object(mesh)
    assert surfaces.for_object(mesh) is first
    assert surfaces.for_object(mesh, normals="flat") is not first
    assert surfaces.for_object(mesh, normals="flat").normal_kind == "flat"
    other = objects.load("glass")  # another object with the same mesh: its own surface
    assert surfaces.for_object(other) is not first
    np.testing.assert_array_equal(surfaces.for_object(other).vertices, first.vertices)


# ------------------------------------------------------------------------- staying on it


WALK = {"sphere": 0.3, "ellipsoid": 0.3, "box": 0.3, "cylinder": 0.3, "quad": 0.4, "star": 0.4,
        "holes": 0.4, "icosphere": 0.3, "boxmesh": 0.3}


@pytest.mark.parametrize("name", list(OBJECTS))
def test_random_walk_stays_on_surface_float64(name):
    obj, surface = build(name)
    with float64_scope():
        c = start(name)
        assert c.coords.dtype == jnp.float64
        c, visited = random_walk(surface, c, jax.random.key(2), 40, WALK[name] * obj.radius)
        points, normals = EMBED(surface, c)
    assert points.dtype == jnp.float64
    dist = distance_from_surface(obj, np.asarray(points))
    assert dist.max() <= 1e-9 * obj.radius, dist.max() / obj.radius
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0)
    if name not in ANALYTIC:
        b = np.asarray(c.coords)
        assert (b >= 0).all() and np.allclose(b.sum(1), 1.0, atol=1e-15)
        # many faces (every polygon edge, every ring) were visited
        assert len(np.unique(visited)) == len(surface.faces) or len(np.unique(visited)) > 60
    else:
        # the walk covers the whole surface (both signs of every axis)
        p = np.asarray(points)
        assert (p.max(0) > 0.5 * np.abs(p).max(0)).all() and (p.min(0) < -0.5 * np.abs(p).max(0)).all()


@pytest.mark.parametrize("name", ["cylinder", "star", "icosphere"])
def test_random_walk_float32(name):
    obj, surface = build(name)
    with jax.enable_x64(False):
        c = surface.sample(jax.random.key(3), N)
        assert c.coords.dtype == jnp.float32
        c, _ = random_walk(surface, c, jax.random.key(4), 20, WALK[name] * obj.radius)
        points, _ = EMBED(surface, c)
        assert points.dtype == jnp.float32
    dist = distance_from_surface(obj, np.asarray(points, float))
    assert dist.max() <= 2e-6 * obj.radius


# ---------------------------------------------------------------------- simplicial motion


def test_step_within_a_face_is_addition():
    for name in ("star", "icosphere", "boxmesh"):
        obj, surface = build(name)
        d = surface.dim
        with float64_scope():
            f = start(name).face
            c = Contact(f, jnp.full((N, d), 1.0 / d, dtype=jnp.float64))  # face centroids
            normal = jnp.asarray(surface.normals)[f]
            size = jnp.asarray(surface.areas)[f] ** (1 / (d - 1))
            v = 0.05 * size[:, None] * jax.random.normal(jax.random.key(5), (N, d))
            moved = RETRACT(surface, c, v)
            p0, _ = EMBED(surface, c)
            p1, _ = EMBED(surface, moved)
        tangent = v - jnp.sum(v * normal, 1, keepdims=True) * normal
        assert (moved.face == c.face).all()
        assert np.allclose(p1, p0 + tangent, rtol=0, atol=1e-14 * obj.radius)


def test_crossing_a_flat_region_is_a_straight_line():
    # two coplanar triangles: the unit square split along its diagonal
    square = surfaces.from_simplices(
        np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]), np.array([[0, 1, 2], [0, 2, 3]]),
        np.array([[0.0, 0, 1], [0, 0, 1]]), center=np.array([0.5, 0.5, 0.0]), scale=1.0)
    with float64_scope():
        c = square.locate(np.array([0.8, 0.1, 0.0]))
        assert int(c.face) == 0
        moved = square.retract(Contact(jnp.asarray(c.face), jnp.asarray(c.coords)), jnp.array([-0.6, 0.7, 0.3]))
        assert int(moved.face) == 1
        assert np.allclose(square.embed(moved)[0], [0.2, 0.8, 0.0], atol=1e-15)
        # an open mesh: a step past the boundary stops on the boundary edge
        out = square.retract(moved, jnp.array([-1.0, 0.0, 0.0]))
        assert np.allclose(square.embed(out)[0], [0.0, 0.8, 0.0], atol=1e-15)
    # across the many coplanar triangles of a box face and over its edges: along one face it is
    # straight, and over an edge the path unfolds (the length on the surface is kept)
    _, surface = build("boxmesh")
    with float64_scope():
        begin = surface.locate(np.array([-0.9, -0.45, 0.25]))
        begin = Contact(jnp.asarray(begin.face), jnp.asarray(begin.coords))
        p = surface.embed(surface.retract(begin, jnp.array([1.7, 0.8, 0.0])))[0]
        assert np.allclose(p, [0.8, 0.35, 0.25], atol=1e-14)
        p = surface.embed(surface.retract(begin, jnp.array([2.2, 0.0, 0.0])))[0]
        assert np.allclose(p, [1.0, -0.45, 0.25 - 0.3], atol=1e-14)  # 1.9 on top, 0.3 down the side


@pytest.mark.parametrize("name", ["quad", "star", "holes", "circle"])
def test_walking_once_around_a_ring_returns_to_the_start(name):
    obj = circle_polygon() if name == "circle" else OBJECTS[name]()
    surface = surfaces.for_object(obj, max_crossings=max(len(r) for r in obj.rings) + 2)
    offsets = np.cumsum([0] + [len(r) for r in obj.rings])
    with float64_scope():
        for ring, first in zip(obj.rings, offsets[:-1]):
            length = np.linalg.norm(np.roll(ring, -1, 0) - ring, axis=1).sum()
            c = Contact(jnp.int32(first + 1), jnp.array([0.3, 0.7]))
            p0 = surface.embed(c)[0]
            normal = jnp.asarray(surface.normals)[first + 1]
            direction = jnp.array([-normal[1], normal[0]])  # along the edge, material on the left
            for sign in (1.0, -1.0):
                moved = surface.retract(c, sign * length * direction)
                assert np.allclose(surface.embed(moved)[0], p0, atol=1e-12 * obj.radius)
            half = surface.retract(c, 0.5 * length * direction)
            assert distance_from_surface(obj, np.asarray(surface.embed(half)[0])[None])[0] < 1e-12


# ------------------------------------------------------------------------------ charts


@pytest.mark.parametrize("name", list(OBJECTS))
def test_chart_at_zero_is_embed(name):
    _, surface = build(name)
    scopes = (float64_scope(), jax.enable_x64(False)) if name in ("cylinder", "star", "icosphere") else \
        (float64_scope(),)  # float32: the kinds the float32 walk compiles anyway
    for scope in scopes:
        with scope:
            c = surface.sample(jax.random.key(1), N)
            p, n = EMBED(surface, c)
            q, m = CHART(surface, c, jnp.zeros_like(p))
            assert (np.asarray(p) == np.asarray(q)).all() and (np.asarray(n) == np.asarray(m)).all()


def objective(point, normal):
    """A smooth test function of a contact's point and normal."""
    return jnp.sin(3.0 * point).sum() + jnp.dot(normal, jnp.arange(1.0, 1.0 + point.shape[0])) + point @ point


@pytest.mark.parametrize("name", list(OBJECTS))
def test_chart_gradient_matches_finite_differences_of_retract(name):
    obj, surface = build(name)
    with float64_scope():
        c = start(name)
        if name not in ANALYTIC:  # away from edges, where the finite difference stays on the face
            c = Contact(c.face, 0.8 * c.coords + 0.2 / surface.dim)
        grad = jax.jit(jax.vmap(lambda s, c: jax.grad(lambda v: objective(*s.chart(c, v)))(
            jnp.zeros(s.dim)), in_axes=(None, 0)))(surface, c)
        _, n = EMBED(surface, c)
        if name not in ANALYTIC:  # the chart moves in the face's plane
            n = jnp.asarray(surface.normals)[c.face]
        u = jax.random.normal(jax.random.key(8), n.shape)
        u = u - jnp.sum(u * n, 1, keepdims=True) * n
        u = u / jnp.linalg.norm(u, axis=1, keepdims=True)
        h = 1e-5 * obj.radius
        f = jax.vmap(lambda c: objective(*surface.embed(c)))
        fd = (f(RETRACT(surface, c, h * u)) - f(RETRACT(surface, c, -h * u))) / (2 * h)
        # the gradient is tangent (no normal part) and its directional derivative matches
        assert np.all(np.isfinite(grad))
        assert np.allclose(jnp.sum(grad * n, 1), 0.0, atol=1e-10)
        assert np.allclose(jnp.sum(grad * u, 1), fd, rtol=1e-5, atol=1e-6)


def test_chart_normal_turns_with_v():
    # smooth normals vary along the chart (the gradient sees how moving turns the normal)
    _, surface = build("icosphere")
    with float64_scope():
        c = start("icosphere")
        jac = jax.vmap(lambda c: jax.jacfwd(lambda v: surface.chart(c, v)[1])(jnp.zeros(3)))(c)
    assert (np.abs(jac).max(axis=(1, 2)) > 0.1).all()
    _, flat = build("icosphere", "flat")
    with float64_scope():
        jac = jax.vmap(lambda c: jax.jacfwd(lambda v: flat.chart(c, v)[1])(jnp.zeros(3)))(c)
    assert (jac == 0).all()


# ------------------------------------------------------------------------------ normals


def test_smooth_normals_are_continuous_across_smooth_edges():
    obj = mesh_object(trimesh.creation.icosphere(2))
    surface = surfaces.for_object(obj)
    faces = np.asarray(surface.faces)
    corners = np.asarray(surface.corners)
    nbr = np.asarray(surface.neighbors)
    # the two faces at every edge agree on both end vertices' normals
    for i in range(3):
        g = nbr[:, i]
        for j in ((i + 1) % 3, (i + 2) % 3):
            k = np.argmax(faces[g] == faces[:, j:j + 1], axis=1)
            assert np.allclose(corners[np.arange(len(faces)), j], corners[g, k], atol=1e-14)
    # and they are the sphere's normals, nearly
    assert np.abs(np.einsum("fij,fij->fi", corners, obj.mesh.vertices[faces]) - 1).max() < 0.02
    # a finely sampled circle: smooth at its corners too
    circle = surfaces.for_object(circle_polygon())
    assert not np.allclose(circle.corners, circle.normals[:, None])


def test_flat_faces_stay_flat_and_sharp_edges_sharp():
    for obj in (box_mesh(), objects.part(), objects.quad(), objects.star()):
        surface = surfaces.for_object(obj)
        corners, normals = np.asarray(surface.corners), np.asarray(surface.normals)
        axis = np.abs(normals).max(1) > 1 - 1e-12  # faces of the box, plates and floors of the part
        if obj.dim == 2:
            axis[:] = True  # every polygon corner of the quad and star is a crease
        assert axis.sum() > 0
        assert np.allclose(corners[axis], normals[axis][:, None], atol=1e-12)
    part = surfaces.for_object(objects.part())
    walls = np.abs(np.asarray(part.normals)[:, 2]) < 1e-9
    curved = walls & ~(np.abs(np.asarray(part.normals)).max(1) > 1 - 1e-12)
    assert not np.allclose(np.asarray(part.corners)[curved], np.asarray(part.normals)[curved][:, None])
    glass = surfaces.for_object(objects.glass())
    spread = np.linalg.norm(np.asarray(glass.corners) - np.asarray(glass.normals)[:, None], axis=2)
    assert np.median(spread) > 1e-3  # the glass gets smooth normals
    with pytest.raises(ValueError, match="normals"):
        surfaces.for_object(objects.quad(), normals="bumpy")


# ------------------------------------------------------------------------------ sampling


@pytest.mark.parametrize("name", ["quad", "holes", "icosphere", "boxmesh"])
def test_sample_is_uniform_by_area_and_reproducible(name):
    _, surface = build(name)
    if name == "icosphere":  # unequal areas: stretch the sphere
        obj = mesh_object(trimesh.Trimesh(trimesh.creation.icosphere(1).vertices * [3.0, 1.0, 0.5],
                                          trimesh.creation.icosphere(1).faces))
        surface = surfaces.for_object(obj)
    with float64_scope():
        c = surface.sample(jax.random.key(10), 40_000)
        again = surface.sample(jax.random.key(10), 40_000)
        other = surface.sample(jax.random.key(11), 40_000)
        b = np.asarray(c.coords)
    assert (np.asarray(c.face) == np.asarray(again.face)).all() and (b == np.asarray(again.coords)).all()
    assert not (b == np.asarray(other.coords)).all()
    assert (b >= 0).all() and np.allclose(b.sum(1), 1)
    areas = np.asarray(surface.areas)
    expected = len(b) * areas / areas.sum()
    counts = np.bincount(np.asarray(c.face), minlength=len(areas))
    chi2 = ((counts - expected) ** 2 / expected).sum()
    dof = len(areas) - 1
    assert chi2 < dof + 5 * np.sqrt(2 * dof)
    # uniform within a face: each barycentric has mean 1/d, and the (1-b) spacing is uniform
    assert np.allclose(b.mean(0), 1 / surface.dim, atol=0.01)


@pytest.mark.parametrize("name", ANALYTIC)
def test_analytic_sample_matches_the_objects_sampler(name):
    obj, surface = build(name)
    with float64_scope():
        c = surface.sample(jax.random.key(12), 40_000)
        assert (np.asarray(c.coords) == np.asarray(surface.sample(jax.random.key(12), 40_000).coords)).all()
        p = np.asarray(c.coords)
    assert distance_from_surface(obj, p).max() < 1e-12 * obj.radius
    q, _ = obj.sample_surface(40_000, np.random.default_rng(0))
    # fractions of area in slabs along each axis agree with the NumPy sampler (exact by area)
    for axis in range(3):
        for cut in (-0.5, 0.0, 0.6):
            lim = cut * np.abs(q[:, axis]).max()
            a, b = (p[:, axis] > lim).mean(), (q[:, axis] > lim).mean()
            assert abs(a - b) < 5 * np.sqrt(0.25 / 20_000), (axis, cut, a, b)


# ------------------------------------------------------------------------------- locate


@pytest.mark.parametrize("name", list(OBJECTS))
def test_locate_finds_the_closest_point(name):
    obj, surface = build(name)
    rng = np.random.default_rng(13)
    points = (obj.center + obj.radius * rng.uniform(-1.3, 1.3, size=(N, obj.dim))).reshape(2, N // 2, obj.dim)
    c = surface.locate(points)
    assert c.face.shape == (2, N // 2) and c.coords.shape[:2] == (2, N // 2)
    with float64_scope():
        found, _ = EMBED(surface, Contact(jnp.asarray(c.face.ravel()), jnp.asarray(c.coords.reshape(N, -1))))
    found = np.asarray(found)
    flat = points.reshape(N, obj.dim)
    assert distance_from_surface(obj, found).max() < 1e-12 * obj.radius
    got = np.linalg.norm(found - flat, axis=1)
    if obj.dim == 2 or name in MESHES:
        best = distance_from_surface(obj, flat)  # exact closest distances
        assert np.allclose(got, best, atol=1e-12 * obj.radius)
    else:  # no closer point among many on the surface
        dense, _ = obj.sample_surface(20_000, rng)
        best = np.array([np.linalg.norm(dense - x, axis=1).min() for x in flat])
        assert (got <= best + 1e-12).all()
        assert np.median(best - got) < 0.02 * obj.radius


# ------------------------------------------------------------------------------ batching


@pytest.mark.parametrize("name", ["sphere", "ellipsoid", "box", "cylinder", "holes", "icosphere"])
def test_vmap_equals_a_python_loop(name):
    obj, surface = build(name)
    with float64_scope():
        c = start(name)
        v = 0.5 * obj.radius * jax.random.normal(jax.random.key(15), (N, surface.dim))
        moved = RETRACT(surface, c, v)
        charts = CHART(surface, c, 0.01 * v)
        for i in range(3):
            one = Contact(c.face[i], c.coords[i])
            m = surface.retract(one, v[i])
            assert int(m.face) == int(moved.face[i])
            assert np.allclose(m.coords, moved.coords[i], rtol=0, atol=1e-13 * obj.radius)
            p, n = surface.chart(one, 0.01 * v[i])
            assert np.allclose(p, charts[0][i], atol=1e-15) and np.allclose(n, charts[1][i], atol=1e-14)


@pytest.mark.parametrize("name", ["box", "cylinder", "holes", "icosphere"])
def test_non_finite_step_leaves_the_contact_in_place(name):
    _, surface = build(name)
    with float64_scope():
        c = start(name)
        v = jnp.full((N, surface.dim), jnp.nan).at[:, 0].set(0.01)
        moved = RETRACT(surface, c, v)
        assert (moved.face == c.face).all()
        assert np.allclose(EMBED(surface, moved)[0], EMBED(surface, c)[0], rtol=0, atol=1e-15)


def test_walk_reports_crossings_and_what_was_left():
    obj = objects.star()
    with float64_scope():
        c = Contact(jnp.int32(0), jnp.array([0.5, 0.5]))
        normal = jnp.asarray(build("star")[1].normals)[0]
        along = 3.0 * jnp.array([-normal[1], normal[0]])
        edge = np.linalg.norm(obj.rings[0][1] - obj.rings[0][0])
        crossings = int(np.ceil((3.0 - edge / 2) / edge))  # vertices passed from the edge's middle
        for cap, left in ((32, False), (3, True)):
            surface = surfaces.for_object(obj, max_crossings=cap)
            moved, passes, rest = surface.walk(c, along)
            assert int(passes) == (crossings + 1 if not left else 3) and (float(rest) > 0) == left
            assert distance_from_surface(obj, np.asarray(surface.embed(moved)[0])[None])[0] < 1e-12


def test_one_contact_per_call():
    _, surface = build("quad")
    with float64_scope():
        c = surface.sample(jax.random.key(0), 3)
        with pytest.raises(ValueError, match="one contact"):
            surface.embed(c)
        with pytest.raises(ValueError, match="one displacement"):
            surface.retract(Contact(c.face[0], c.coords[0]), jnp.zeros((3, 2)))
    with pytest.raises(TypeError, match="no surface"):
        surfaces.for_object("glass")


def test_part_walk_and_locate():
    """The mechanical part: sharp 90 degree edges, through holes and pockets, thin triangles."""
    obj = objects.part()
    surface = surfaces.for_object(obj)
    with float64_scope():
        c = surface.sample(jax.random.key(18), N)
        c, visited = random_walk(surface, c, jax.random.key(19), 30, 0.1 * obj.radius)
        points, _ = EMBED(surface, c)
    tri = np.asarray(obj.mesh.triangles)
    assert mesh_distance(tri, np.asarray(points)).max() <= 1e-9 * obj.radius
    assert len(np.unique(visited)) > 300
    x = obj.center + obj.radius * np.random.default_rng(20).uniform(-0.8, 0.8, size=(40, 3)) * [1, 1, 0.3]
    found = surface.locate(x)
    with float64_scope():
        q, _ = jax.vmap(surface.embed)(Contact(jnp.asarray(found.face), jnp.asarray(found.coords)))
    assert np.allclose(np.linalg.norm(np.asarray(q) - x, axis=1), mesh_distance(tri, x), atol=1e-12 * obj.radius)


# ---------------------------------------------------------------------------- a real mesh


def test_real_mesh_walk(mesh_dir):
    path = mesh_dir / "pybullet_mug.obj"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    obj = objects.Mesh.from_file(path)
    surface = surfaces.for_object(obj)
    with float64_scope():
        c = surface.sample(jax.random.key(16), 128)
        c, visited = random_walk(surface, c, jax.random.key(17), 30, 0.2 * obj.radius)
        points, normals = EMBED(surface, c)
    dist = mesh_distance(np.asarray(obj.mesh.triangles), np.asarray(points))
    assert dist.max() <= 1e-9 * obj.radius
    assert len(np.unique(visited)) > 300
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0)
