"""Contact frames, linearized friction cones, primitive wrenches and central axes."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grasp_jax as gj
from grasp_jax import reference
from grasp_jax._cones import cone_edges, safe_normalize, tangent_frame
from grasp_jax._wrench import cross, grasp_wrench, primitive_wrenches

MU = 0.364  # tan(20 deg), as in the paper


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _special_normals_3d():
    eps = 1e-9
    return _unit(
        np.array(
            [
                [0.0, 0.0, 1.0],
                [0.0, 0.0, -1.0],
                [eps, -eps, 1.0],
                [eps, eps, -1.0],
                [-eps, 0.0, -1.0],
                [1e-4, 2e-4, -1.0],
                [1e-4, -2e-4, 1.0],
                [1.0, 0.0, 0.0],
                [0.0, -1.0, 0.0],
                [1.0, 1.0, 0.0],
                [1.0, 1.0, 1e-300],
                [1.0, 1.0, -1e-300],
            ]
        )
    )


@pytest.fixture(scope="module")
def normals_3d():
    rng = np.random.default_rng(0)
    return np.concatenate([_special_normals_3d(), _unit(rng.normal(size=(40, 3)))])


# ---------------------------------------------------------------------------------------------
# Tangent frames.


def test_tangent_frame_orthonormal_right_handed(normals_3d):
    axes = -normals_3d
    x, y = (np.asarray(a) for a in jax.vmap(tangent_frame)(jnp.asarray(axes)))
    assert np.all(np.isfinite(x)) and np.all(np.isfinite(y))
    for a, xi, yi in zip(axes, x, y):
        np.testing.assert_allclose([xi @ xi, yi @ yi], 1.0, atol=1e-12)
        np.testing.assert_allclose([xi @ yi, xi @ a, yi @ a], 0.0, atol=1e-12)
        np.testing.assert_allclose(np.cross(xi, yi), a, atol=1e-12)  # right-handed: x cross y = z
        rx, ry = reference.frame(a)
        np.testing.assert_allclose(xi, rx, atol=1e-14)
        np.testing.assert_allclose(yi, ry, atol=1e-14)


def test_tangent_frame_exact_poles():
    for axis, sign in (([0.0, 0.0, 1.0], 1.0), ([0.0, 0.0, -1.0], -1.0)):
        x, y = tangent_frame(jnp.asarray(axis))
        np.testing.assert_allclose(np.asarray(x), [1.0, 0.0, 0.0], atol=0)
        np.testing.assert_allclose(np.asarray(y), [0.0, sign, 0.0], atol=0)


def test_tangent_frame_with_tangent(normals_3d):
    rng = np.random.default_rng(1)
    axes = -normals_3d
    tangents = rng.normal(size=axes.shape)
    x, y = (np.asarray(a) for a in jax.vmap(tangent_frame)(jnp.asarray(axes), jnp.asarray(tangents)))
    for a, t, xi, yi in zip(axes, tangents, x, y):
        proj = t - (t @ a) * a
        np.testing.assert_allclose(xi, proj / np.linalg.norm(proj), atol=1e-12)
        np.testing.assert_allclose(np.cross(xi, yi), a, atol=1e-12)
        np.testing.assert_allclose([xi @ yi, yi @ a, yi @ yi], [0.0, 0.0, 1.0], atol=1e-12)


def test_safe_normalize_zero_vector_finite_gradient():
    v = jnp.zeros(3)
    np.testing.assert_array_equal(np.asarray(safe_normalize(v)), 0.0)
    g = jax.jacrev(safe_normalize)(v)
    assert np.all(np.isfinite(np.asarray(g)))
    np.testing.assert_allclose(np.asarray(safe_normalize(jnp.array([3.0, 0.0, 4.0]))), [0.6, 0, 0.8])


# ---------------------------------------------------------------------------------------------
# Cone edges.


@pytest.mark.parametrize("m", [3, 8, 25])
@pytest.mark.parametrize("mu", [0.1, MU, 1.5])
def test_cone_edges_3d(normals_3d, m, mu):
    edges = np.asarray(cone_edges(jnp.asarray(normals_3d), mu, m))
    assert edges.shape == (len(normals_3d), m, 3)
    axes = -normals_3d
    np.testing.assert_allclose(np.linalg.norm(edges, axis=-1), np.sqrt(1 + mu**2), rtol=1e-13)
    cos_angle = np.einsum("imk,ik->im", edges, axes) / np.linalg.norm(edges, axis=-1)
    np.testing.assert_allclose(np.arccos(np.clip(cos_angle, -1, 1)), np.arctan(mu), atol=1e-7)
    np.testing.assert_allclose(cos_angle, 1 / np.sqrt(1 + mu**2), atol=1e-13)
    np.testing.assert_allclose(edges.mean(axis=1), axes, atol=1e-13)
    # Consecutive edges are 2 pi / m apart around the axis, counter-clockwise about z.
    radial = edges - axes[:, None, :]
    np.testing.assert_allclose(np.linalg.norm(radial, axis=-1), mu, rtol=1e-12)
    turn = np.einsum("imk,ik->im", np.cross(radial, np.roll(radial, -1, axis=1)), axes) / mu**2
    np.testing.assert_allclose(turn, np.sin(2 * np.pi / m), atol=1e-12)
    np.testing.assert_allclose(edges, reference.cone_edges(normals_3d, mu, m), atol=1e-13)


def test_cone_edges_3d_with_tangents(normals_3d):
    rng = np.random.default_rng(2)
    m = 8
    tangents = rng.normal(size=normals_3d.shape)
    edges = np.asarray(cone_edges(jnp.asarray(normals_3d), MU, m, jnp.asarray(tangents)))
    axes = -normals_3d
    proj = tangents - np.einsum("ik,ik->i", tangents, axes)[:, None] * axes
    # The last edge (angle 2 pi) points along the projected tangent.
    np.testing.assert_allclose(edges[:, -1], axes + MU * _unit(proj), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(edges, axis=-1), np.sqrt(1 + MU**2), rtol=1e-13)
    np.testing.assert_allclose(edges.mean(axis=1), axes, atol=1e-13)
    np.testing.assert_allclose(edges, reference.cone_edges(normals_3d, MU, m, tangents), atol=1e-12)


@pytest.mark.parametrize("mu", [0.1, MU, 1.5])
def test_cone_edges_2d(mu):
    rng = np.random.default_rng(3)
    normals = np.concatenate([_unit(rng.normal(size=(30, 2))), np.eye(2), -np.eye(2)])
    edges = np.asarray(cone_edges(jnp.asarray(normals), mu, 8))  # num_edges is ignored in 2D
    assert edges.shape == (len(normals), 2, 2)
    axes = -normals
    np.testing.assert_allclose(np.linalg.norm(edges, axis=-1), np.sqrt(1 + mu**2), rtol=1e-13)
    cos_angle = np.einsum("imk,ik->im", edges, axes) / np.linalg.norm(edges, axis=-1)
    np.testing.assert_allclose(cos_angle, 1 / np.sqrt(1 + mu**2), atol=1e-13)
    np.testing.assert_allclose(edges.mean(axis=1), axes, atol=1e-13)
    # One edge on each side of the axis: z x v takes both signs, +/- mu.
    side = axes[:, None, 0] * edges[..., 1] - axes[:, None, 1] * edges[..., 0]
    np.testing.assert_allclose(side, np.broadcast_to([-mu, mu], side.shape), atol=1e-13)
    np.testing.assert_allclose(edges, reference.cone_edges(normals, mu, 8), atol=1e-13)


def test_exported_cone_edges_alias():
    assert gj._cone_edges is cone_edges


# ---------------------------------------------------------------------------------------------
# Primitive wrenches (eq. 6).


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("with_origin", [False, True])
def test_primitive_wrenches_vs_reference(d, with_origin):
    rng = np.random.default_rng(4 + d)
    m = 8
    for n in (2, 5):
        points = rng.normal(size=(n, d))
        normals = _unit(rng.normal(size=(n, d)))
        origin = rng.normal(size=d) if with_origin else None
        edges = cone_edges(jnp.asarray(normals), MU, m)
        o = None if origin is None else jnp.asarray(origin)
        w = np.asarray(primitive_wrenches(jnp.asarray(points), edges, o))
        k = 2 if d == 2 else m
        assert w.shape == (n, k, 3 if d == 2 else 6)
        ref = reference.wrenches(points, normals, MU, m, origin)
        np.testing.assert_allclose(w.reshape(n * k, -1), ref, atol=1e-13)
        # Net wrench (eq. 7) is the coefficient-weighted sum about the frame origin.
        if origin is None:
            a = rng.uniform(size=(n, k))
            np.testing.assert_allclose(np.asarray(grasp_wrench(jnp.asarray(points), edges, jnp.asarray(a))),
                                       a.reshape(-1) @ ref, atol=1e-12)


def test_primitive_wrenches_with_tangents_vs_reference():
    rng = np.random.default_rng(7)
    points, normals, tangents = rng.normal(size=(3, 4, 3))
    normals = _unit(normals)
    edges = cone_edges(jnp.asarray(normals), MU, 8, jnp.asarray(tangents))
    w = np.asarray(primitive_wrenches(jnp.asarray(points), edges)).reshape(32, 6)
    np.testing.assert_allclose(w, reference.wrenches(points, normals, MU, 8, tangents=tangents), atol=1e-13)


def test_planar_cross():
    a, b = np.array([2.0, 3.0]), np.array([-1.0, 5.0])
    assert float(cross(jnp.asarray(a), jnp.asarray(b))) == 2 * 5 - 3 * -1
    a3, b3 = np.array([1.0, 2.0, 3.0]), np.array([-4.0, 0.5, 2.0])
    np.testing.assert_allclose(np.asarray(cross(jnp.asarray(a3), jnp.asarray(b3))), np.cross(a3, b3))


# ---------------------------------------------------------------------------------------------
# Central axis (eq. 10-11).


def _torque_about(point, force, torque):
    """Torque of a wrench (force, torque about the origin) about ``point``."""
    if len(force) == 2:
        return torque[0] - (point[0] * force[1] - point[1] * force[0])
    return torque - np.cross(point, force)


def test_central_axis_3d_hand_computed():
    # F along x, torque along z: the axis passes through I = F x tau / |F|^2 = (0, -2, 0), pitch 0.
    ax = gj.central_axis(np.array([1.0, 0.0, 0.0, 0.0, 0.0, 2.0]))
    assert isinstance(ax, gj.CentralAxis)
    np.testing.assert_allclose(np.asarray(ax.point), [0.0, -2.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(np.asarray(ax.direction), [1.0, 0.0, 0.0], atol=1e-15)
    assert float(ax.pitch) == 0.0 and not bool(ax.pure_torque)
    # A screw: F = (0, 0, 2), tau = (1, 0, 3): I = (0, 0.5, 0), pitch 6/4 and tau_I = 1.5 F (eq. 11).
    ax = gj.central_axis(np.array([0.0, 0.0, 2.0, 1.0, 0.0, 3.0]))
    np.testing.assert_allclose(np.asarray(ax.point), [0.0, 0.5, 0.0], atol=1e-15)
    np.testing.assert_allclose(np.asarray(ax.direction), [0.0, 0.0, 1.0], atol=1e-15)
    assert float(ax.pitch) == pytest.approx(1.5, rel=1e-15)
    np.testing.assert_allclose(_torque_about(np.asarray(ax.point), [0, 0, 2.0], np.array([1.0, 0, 3])),
                               [0.0, 0.0, 3.0], atol=1e-15)


def test_central_axis_3d_pure_torque():
    ax = gj.central_axis(np.array([0.0, 0.0, 0.0, 0.0, 3.0, 4.0]))
    assert bool(ax.pure_torque)
    np.testing.assert_allclose(np.asarray(ax.point), 0.0)
    np.testing.assert_allclose(np.asarray(ax.direction), [0.0, 0.6, 0.8], atol=1e-15)
    assert float(ax.pitch) == np.inf


def test_central_axis_2d_hand_computed():
    ax = gj.central_axis(np.array([1.0, 0.0, 2.0]))
    np.testing.assert_allclose(np.asarray(ax.point), [0.0, -2.0], atol=1e-15)
    np.testing.assert_allclose(np.asarray(ax.direction), [1.0, 0.0], atol=1e-15)
    assert float(ax.pitch) == 0.0 and not bool(ax.pure_torque)
    ax = gj.central_axis(np.array([0.0, 2.0, -4.0]))  # I = (f_y t, -f_x t) / |F|^2 = (-2, 0)
    np.testing.assert_allclose(np.asarray(ax.point), [-2.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(np.asarray(ax.direction), [0.0, 1.0], atol=1e-15)
    for t, pitch in ((-3.0, -np.inf), (3.0, np.inf)):
        ax = gj.central_axis(np.array([0.0, 0.0, t]))
        assert bool(ax.pure_torque)
        np.testing.assert_array_equal(np.asarray(ax.point), 0.0)
        np.testing.assert_array_equal(np.asarray(ax.direction), 0.0)  # normal to the plane
        assert float(ax.pitch) == pitch


@pytest.mark.parametrize("d", [2, 3])
def test_central_axis_poinsot_random(d):
    """About every point of the axis the torque is parallel to the force (Poinsot); the reported
    point is the axis point closest to the origin; batched leading shapes are kept."""
    rng = np.random.default_rng(10 + d)
    D = 3 if d == 2 else 6
    w = rng.normal(size=(4, 5, D))
    ax = gj.central_axis(w)
    assert ax.point.shape == (4, 5, d) and ax.direction.shape == (4, 5, d)
    assert ax.pitch.shape == (4, 5) and ax.pure_torque.shape == (4, 5)
    assert not np.any(np.asarray(ax.pure_torque))
    for k in np.ndindex(4, 5):
        f, tau = w[k][:d], w[k][d:]
        point, direction, pitch = (np.asarray(a[k]) for a in (ax.point, ax.direction, ax.pitch))
        np.testing.assert_allclose(direction, f / np.linalg.norm(f), atol=1e-14)
        assert point @ f == pytest.approx(0.0, abs=1e-12)
        for lam in (-2.0, 0.0, 3.5):
            t_p = np.atleast_1d(_torque_about(point + lam * f, f, tau))
            if d == 2:
                np.testing.assert_allclose(t_p, 0.0, atol=1e-12)  # planar: the torque vanishes
                assert pitch == 0.0
            else:
                np.testing.assert_allclose(np.cross(t_p, f), 0.0, atol=1e-12)
                np.testing.assert_allclose(t_p, pitch * f, atol=1e-12)
        if d == 3:
            assert pitch == pytest.approx(f @ tau / (f @ f), rel=1e-13)
            np.testing.assert_allclose(point, np.cross(f, tau) / (f @ f), atol=1e-13)


@pytest.mark.parametrize("d", [2, 3])
def test_central_axis_finite_gradients_at_zero_force(d):
    """Point and direction have finite values and derivatives at F = 0 (pure torque and the zero
    wrench); the pitch has a finite derivative away from it."""
    t = 1 if d == 2 else 3

    def finite_part(w):
        ax = gj.central_axis(w)
        return jnp.concatenate([ax.point, ax.direction])

    for w in (np.zeros(d + t), np.r_[np.zeros(d), np.ones(t)], np.r_[1e-200, np.zeros(d - 1), np.ones(t)]):
        jac = np.asarray(jax.jacrev(finite_part)(jnp.asarray(w)))
        assert np.all(np.isfinite(jac)), (w, jac)
        assert np.all(np.isfinite(np.asarray(finite_part(jnp.asarray(w)))))
    pitch_grad = jax.grad(lambda w: gj.central_axis(w).pitch)(jnp.ones(d + t))
    assert np.all(np.isfinite(np.asarray(pitch_grad)))


def test_central_axis_integer_and_jit():
    ax = gj.central_axis(np.array([1, 0, 0, 0, 0, 2]))
    assert jnp.issubdtype(ax.point.dtype, jnp.floating)
    np.testing.assert_allclose(np.asarray(ax.point), [0.0, -2.0, 0.0])
    jitted = jax.jit(gj.central_axis)(jnp.array([0.0, 0.0, 2.0, 1.0, 0.0, 3.0]))
    assert float(jitted.pitch) == pytest.approx(1.5)
