"""Invariances of the verdict and of Q (MATH.md, "Invariances, exactly as they hold")."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from hypothesis import given
from hypothesis import strategies as st

import grasp_jax as gj
from grasp_jax._cones import cone_edges

from _grasps import MU, QUAD, STAR, grasps, sample_box, sample_cylinder, sample_polygon, sample_sphere

K = 8  # grasps per example
N = {2: 3, 3: 4}
SAMPLERS = {
    2: (lambda c, r: sample_polygon(QUAD, c, r), lambda c, r: sample_polygon(STAR, c, r)),
    3: (sample_box, sample_cylinder, sample_sphere),
}
seeds = st.integers(0, 2**32 - 1)
coords = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)


def _grasps(d, seed):
    """K random grasps (no grasp with all contacts on one face), normals of random length."""
    rng = np.random.default_rng(seed)
    ps, ns = [], []
    while len(ps) < K:
        sampler = SAMPLERS[d][len(ps) % len(SAMPLERS[d])]
        (p,), (n,) = grasps(sampler, 1, N[d], rng)
        if np.all(np.abs(n - n[0]) < 1e-12):
            continue
        ps.append(p)
        ns.append(n * rng.uniform(0.5, 2.0, size=(N[d], 1)))  # normals are normalized by the engine
    return np.stack(ps), np.stack(ns)


def _evaluate_pair(p, n, p2, n2, **kw):
    """Evaluate the originals and the transformed grasps in one call."""
    ev = gj.evaluate(np.stack([p, p2]), np.stack([n, n2]), mu=MU, **kw)
    return ev[0], ev[1]


def _assert_invariant(a: gj.GraspEvaluation, b: gj.GraspEvaluation, q_tol=1e-9):
    np.testing.assert_allclose(np.asarray(b.quality), np.asarray(a.quality), atol=q_tol)
    np.testing.assert_allclose(np.asarray(b.delta), np.asarray(a.delta), atol=q_tol)
    # Verdicts agree wherever the grasp is not within the tolerance of the boundary.
    clear = (np.abs(np.asarray(a.delta)) > 1e-6) & (np.abs(np.asarray(a.torque_margin)) > 1e-6)
    np.testing.assert_array_equal(np.asarray(b.force_closure)[clear], np.asarray(a.force_closure)[clear])
    np.testing.assert_array_equal(np.asarray(b.equilibrium)[clear], np.asarray(a.equilibrium)[clear])


def _rotation_3d(a, b, c):
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    rz = np.array([[ca, -sa, 0], [sa, ca, 0], [0, 0, 1]])
    ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    rx = np.array([[1, 0, 0], [0, cc, -sc], [0, sc, cc]])
    return rz @ ry @ rx


@given(d=st.sampled_from([2, 3]), seed=seeds, shift=st.tuples(coords, coords, coords))
def test_translation(d, seed, shift):
    p, n = _grasps(d, seed)
    a, b = _evaluate_pair(p, n, p + np.asarray(shift[:d]), n)
    _assert_invariant(a, b)


@given(d=st.sampled_from([2, 3]), seed=seeds, scale=st.floats(1e-3, 1e3))
def test_scaling(d, seed, scale):
    p, n = _grasps(d, seed)
    a, b = _evaluate_pair(p, n, scale * p, n)
    _assert_invariant(a, b)


@given(seed=seeds, angle=st.floats(-np.pi, np.pi), shift=st.tuples(coords, coords))
def test_rotation_2d(seed, angle, shift):
    p, n = _grasps(2, seed)
    r = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    a, b = _evaluate_pair(p, n, p @ r.T + np.asarray(shift), n @ r.T)
    _assert_invariant(a, b)


@given(seed=seeds, angles=st.tuples(*[st.floats(-np.pi, np.pi)] * 3))
def test_rotation_3d_with_tangents(seed, angles):
    """Rotating the grasp together with its contact frames (explicit tangents) changes nothing."""
    p, n = _grasps(3, seed)
    t = np.random.default_rng(seed).normal(size=p.shape)
    r = _rotation_3d(*angles)
    ev = gj.evaluate(np.stack([p, p @ r.T]), np.stack([n, n @ r.T]), mu=MU, tangents=np.stack([t, t @ r.T]))
    _assert_invariant(ev[0], ev[1])


@given(d=st.sampled_from([2, 3]), seed=seeds, data=st.data())
def test_permuting_other_contacts(d, seed, data):
    """Q is defined about c_1: any order of contacts 2..n gives the same Q and verdict."""
    p, n = _grasps(d, seed)
    perm = [0] + data.draw(st.permutations(range(1, N[d])))
    a, b = _evaluate_pair(p, n, p[:, perm], n[:, perm])
    _assert_invariant(a, b)


@given(d=st.sampled_from([2, 3]), seed=seeds, data=st.data())
def test_force_closure_does_not_depend_on_reference_contact(d, seed, data):
    """Q depends on which contact is c_1; whether the grasp is force-closure does not."""
    p, n = _grasps(d, seed)
    perm = data.draw(st.permutations(range(N[d])))
    a, b = _evaluate_pair(p, n, p[:, perm], n[:, perm])
    clear = (np.abs(np.asarray(a.delta)) > 1e-6) & (np.abs(np.asarray(a.torque_margin)) > 1e-6)
    clear &= (np.abs(np.asarray(b.delta)) > 1e-6) & (np.abs(np.asarray(b.torque_margin)) > 1e-6)
    np.testing.assert_array_equal(np.asarray(b.force_closure)[clear], np.asarray(a.force_closure)[clear])


@given(
    normal=st.tuples(*[st.floats(-1, 1)] * 3).filter(lambda v: np.linalg.norm(v) > 1e-3),
    tangent=st.one_of(st.none(), st.tuples(*[st.floats(-1, 1)] * 3)),
    mu=st.floats(0.01, 3.0),
    m=st.sampled_from([3, 8, 25]),
)
def test_cone_edges_lie_on_the_cone(normal, tangent, mu, m):
    nrm = np.asarray(normal) / np.linalg.norm(normal)
    axis = -nrm
    tangents = None
    if tangent is not None:
        t = np.asarray(tangent)
        if np.linalg.norm(t - (t @ axis) * axis) < 1e-3:  # no direction in the tangent plane
            t = np.cross(axis, np.eye(3)[np.argmin(np.abs(axis))])
        tangents = jnp.asarray(t[None])
    edges = np.asarray(cone_edges(jnp.asarray(nrm[None]), mu, m, tangents))[0]
    assert edges.shape == (m, 3)
    lengths = np.linalg.norm(edges, axis=1)
    np.testing.assert_allclose(lengths, np.sqrt(1 + mu**2), rtol=1e-12)
    np.testing.assert_allclose(edges @ axis / lengths, 1 / np.sqrt(1 + mu**2), rtol=1e-12)  # angle atan(mu)
    np.testing.assert_allclose(edges.mean(axis=0), axis, atol=1e-12)
    # Equally spaced around the axis: consecutive edges subtend the same angle.
    radial = edges - axis
    cosines = np.sum(radial * np.roll(radial, -1, axis=0), axis=1) / mu**2
    np.testing.assert_allclose(cosines, np.cos(2 * np.pi / m), atol=1e-9)
