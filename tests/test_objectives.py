"""The optimizer's objectives (``_objectives``) and the differentiable min-weight margin:
signs against the exact verdicts and HiGHS, values against Q, gradients against finite
differences, vmap against a loop, finiteness everywhere.

Compiling is most of this module's time, so the programs are few and shared (and compiled with the
suite's options, ``_jit.py``): one batched objective per closure kind and dimension
(:func:`_objective`), run on the whole 300-grasp sphere set (:func:`sphere_values`) by every 3D test
that compares its values, and one batched value-and-gradient per kind (:func:`_value_and_grad`) of
the 49-grasp batches of the finite differences (:data:`GRAD_ROWS`), which the degenerate grasps of
4 contacts are padded to and which gives the batched values of the vmap-against-a-loop test.
Gradients of the public functions are taken under ``jit`` (op by op, they compile a program per
operation)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _jit import jit

import grasp_jax as gj
from grasp_jax import _objectives, reference
from grasp_jax._contact import ContactModel

MU, M = 0.364, 4
CENTER3 = np.zeros(3)

#: The objectives checked here. ``"friction"`` is a root finder's value (good to ~1e-7 relative,
#: below what these finite differences resolve): tests/test_friction.py checks it.
KINDS = tuple(kind for kind in _objectives.OBJECTIVES if kind != "friction")


def _sphere_grasps(rng, count, n):
    p = rng.normal(size=(count, n, 3))
    p /= np.linalg.norm(p, axis=-1, keepdims=True)
    return p, p.copy()


def _square_grasps(rng, count, n):
    """Contacts on the boundary of the square [-1, 1]^2, normals outward."""
    side = rng.integers(4, size=(count, n))
    t = rng.uniform(-1, 1, size=(count, n))
    normals = np.array([[1.0, 0], [0, 1.0], [-1.0, 0], [0, -1.0]])[side]
    points = normals + t[..., None] * normals[..., ::-1] * np.array([-1.0, 1.0])
    return points, normals


@functools.cache
def _objective(kind, d):
    """The batched objective ``kind`` in ``d`` dimensions, jitted once per kind and dimension."""
    center = np.zeros(d)
    model = ContactModel(num_edges=M)
    return jit(jax.vmap(lambda p, nr: _objectives.objective_one(p, nr, MU, model, kind, center, 1.0)[0]))


@pytest.fixture(scope="module")
def sphere_set():
    rng = np.random.default_rng(7)
    p, nr = _sphere_grasps(rng, 300, 4)
    ev = gj.evaluate(p, nr, mu=MU, num_edges=M)
    return p, nr, ev


@pytest.fixture(scope="module")
def sphere_values(sphere_set):
    """``kind -> _objective(kind, 3)`` of the whole sphere set, as NumPy (computed once per kind)."""
    p, nr, _ = sphere_set
    cache = {}

    def get(kind):
        if kind not in cache:
            cache[kind] = np.asarray(_objective(kind, 3)(p, nr))
        return cache[kind]

    return get


@pytest.mark.parametrize("kind", ["closure", "closure_any", "min_weight"])
def test_positive_exactly_when_force_closure_3d(sphere_set, sphere_values, kind):
    _, _, ev = sphere_set
    value = sphere_values(kind)
    fc = np.asarray(ev.force_closure)
    assert 0.2 < fc.mean() < 0.9
    assert np.isfinite(value).all()
    # Marginal grasps (either margin within 1e-6) may go either way.
    clear = (np.abs(np.asarray(ev.delta)) > 1e-6) & (np.abs(np.asarray(ev.torque_margin)) > 1e-6)
    np.testing.assert_array_equal((value > 1e-7)[clear], fc[clear])


def test_positive_exactly_when_force_closure_2d():
    rng = np.random.default_rng(3)
    p, nr = _square_grasps(rng, 300, 3)
    ev = gj.evaluate(p, nr, mu=MU)
    fc = np.asarray(ev.force_closure)
    assert 0.05 < fc.mean() < 0.9
    for kind in ("closure", "closure_any", "min_weight"):
        value = np.asarray(_objective(kind, 2)(p, nr))
        clear = (np.abs(np.asarray(ev.delta)) > 1e-6) & (np.abs(np.asarray(ev.torque_margin)) > 1e-6)
        np.testing.assert_array_equal((value > 1e-7)[clear], fc[clear], err_msg=kind)


def test_min_weight_sign_agrees_with_highs(sphere_set, sphere_values):
    p, nr, _ = sphere_set
    value = sphere_values("min_weight")[:60]
    for i in range(60):
        ref = reference.min_weight_highs(p[i], nr[i], MU, num_edges=M)
        if abs(ref) > 1e-6:
            assert (value[i] > 0) == (ref > 0), i


def test_closure_is_q_where_the_torque_term_does_not_bind(sphere_set, sphere_values):
    _, _, ev = sphere_set
    value = sphere_values("closure")
    fc, q = np.asarray(ev.force_closure), np.asarray(ev.quality)
    equal = np.abs(value - q) < 1e-7
    assert equal[fc].mean() > 0.95
    # Where it is not Q, it is smaller (the torque term binds), never larger.
    assert np.all(value[fc] <= q[fc] + 1e-7)


def test_closure_any_does_not_depend_on_the_order(sphere_set, sphere_values):
    p, nr, _ = sphere_set
    perm = np.array([2, 0, 3, 1])
    permuted = np.asarray(_objective("closure_any", 3)(p[:, perm], nr[:, perm]))  # the set's program
    np.testing.assert_allclose(sphere_values("closure_any")[:40], permuted[:40], atol=1e-7)


def test_vmap_equals_a_loop(sphere_set, sphere_values):
    """The first grasps of a vmapped batch against the objective of each grasp alone; the batch is
    the first :data:`GRAD_ROWS` sphere grasps through :func:`_value_and_grad` (the closure kinds
    also through :func:`_objective`, on the whole set)."""
    p, nr, _ = sphere_set
    for kind in KINDS:
        batched = np.asarray(_value_and_grad(kind, 3)(p[:GRAD_ROWS], nr[:GRAD_ROWS])[0])[:5]
        model = ContactModel(num_edges=M)
        one = jit(lambda a, b, kind=kind: _objectives.objective_one(a, b, MU, model, kind, CENTER3, 1.0)[0])
        loop = [one(p[i], nr[i]) for i in range(5)]
        np.testing.assert_allclose(batched, loop, rtol=1e-9, atol=1e-12, err_msg=kind)
        if kind in ("closure", "closure_any", "min_weight"):
            np.testing.assert_allclose(sphere_values(kind)[:5], loop, rtol=1e-9, atol=1e-12, err_msg=kind)


def _finite_difference(f, x, h=1e-6):
    g = np.zeros_like(x)
    for idx in np.ndindex(x.shape):
        e = np.zeros_like(x)
        e[idx] = h
        g[idx] = (f(x + e) - f(x - e)) / (2 * h)
    return g


#: Rows of every batch given to :func:`_value_and_grad` (one compiled shape per kind): the
#: :func:`_perturbed` copies of a 4-contact 3D grasp, and the grasp itself.
GRAD_ROWS = 2 * 2 * 4 * 3 + 1


@functools.cache
def _value_and_grad(kind, d):
    """Batched value and gradient in points and normals, compiled once per objective."""
    one = lambda p, nr: _objectives.objective_one(p, nr, MU, ContactModel(num_edges=M), kind, np.zeros(d), 1.0)[0]
    return jit(jax.vmap(jax.value_and_grad(one, argnums=(0, 1))))


def _perturbed(p, nr, h):
    """``(2 * 2 * p.size + 1)`` copies of the grasp, each coordinate of points and normals moved
    by +h and -h, then the grasp itself."""
    P, N = [], []
    for which in (0, 1):
        for idx in np.ndindex(p.shape):
            for sign in (1.0, -1.0):
                a, b = p.copy(), nr.copy()
                (a if which == 0 else b)[idx] += sign * h
                P.append(a)
                N.append(b)
    return np.array(P + [p]), np.array(N + [nr])


@pytest.mark.parametrize("kind", KINDS)
def test_gradients_match_finite_differences(kind):
    """Away from kinks (the one-sided differences agree), d objective / d points and
    d normals match central differences, on perturbed FC-ish sphere grasps."""
    rng = np.random.default_rng(11)
    h = 1e-6
    f = _value_and_grad(kind, 3)
    checked = 0
    for _ in range(8):
        p, nr = _sphere_grasps(rng, 1, 4)
        p, nr = p[0] + 0.05 * rng.normal(size=(4, 3)), nr[0]
        P, N = _perturbed(p, nr, h)
        assert len(P) == GRAD_ROWS
        values, (gp, gn) = (np.asarray(v) if not isinstance(v, tuple) else tuple(map(np.asarray, v))
                            for v in f(P, N))
        assert np.isfinite(gp).all() and np.isfinite(gn).all()
        up, down, mid = values[:-1:2], values[1:-1:2], values[-1]
        if np.any(np.abs((up - mid) - (mid - down)) > 1e-3 * h + 1e-10):
            continue  # a kink along some coordinate
        fd = ((up - down) / (2 * h)).reshape(2, *p.shape)
        scale = max(1.0, np.abs(fd).max())
        np.testing.assert_allclose(gp[-1], fd[0], atol=2e-5 * scale)
        np.testing.assert_allclose(gn[-1], fd[1], atol=2e-5 * scale)
        checked += 1
        if checked == 3:
            break
    assert checked >= 2, f"too few smooth cases for {kind}"


def test_min_weight_is_differentiable(sphere_set):
    """``jax.grad`` of ``gj.min_weight`` works (it used to fail on the while loop), is finite on
    every grasp, and matches finite differences."""
    p, nr, _ = sphere_set
    g = jit(jax.grad(lambda x: gj.min_weight(x, nr[:20], mu=MU, num_edges=M).sum()))(jnp.asarray(p[:20]))
    assert np.isfinite(np.asarray(g)).all()
    fc = np.flatnonzero(np.asarray(gj.min_weight(p[:20], nr[:20], mu=MU, num_edges=M)) > 1e-4)
    i = int(fc[0])
    f = lambda x: float(gj.min_weight(x, nr[i], mu=MU, num_edges=M))
    fd = _finite_difference(f, p[i])
    np.testing.assert_allclose(np.asarray(g[i]), fd, atol=1e-5 * max(1.0, np.abs(fd).max()))


def test_objectives_are_finite_on_degenerate_grasps():
    """All contacts at one point with one normal, and two contacts in 3D: finite values and
    gradients; a 2-finger 3D grasp is never force-closure, so the closure objectives are <= 0.
    The two 4-contact grasps are repeated to :data:`GRAD_ROWS` rows: the finite differences'
    compiled programs."""
    same = np.tile([1.0, 0.0, 0.0], (4, 1))
    two = np.array([[1.0, 0, 0], [-1.0, 0, 0]])
    for kind in KINDS:
        for p in (same, two):
            P = np.stack([p, p + 1e-3 * np.eye(len(p), 3)])
            if len(p) == 4:
                P = P[np.arange(GRAD_ROWS) % 2]
            v, (gp, gn) = _value_and_grad(kind, 3)(P, P)
            assert np.isfinite(np.asarray(v)).all(), kind
            assert np.isfinite(np.asarray(gp)).all() and np.isfinite(np.asarray(gn)).all(), kind
            if kind in ("closure", "closure_any", "min_weight") and len(p) == 2:
                assert np.all(np.asarray(v) <= 1e-7), kind


def test_public_objective_batches_and_differentiates(sphere_set, sphere_values):
    p, nr, _ = sphere_set
    value = np.asarray(gj.objective(p[:40].reshape(4, 10, 4, 3), nr[:40].reshape(4, 10, 4, 3), mu=MU,
                                    num_edges=M)).reshape(40)
    np.testing.assert_allclose(value, sphere_values("closure")[:40], atol=1e-12)
    g = jit(jax.grad(lambda x: gj.objective(x, nr[:8], mu=MU, num_edges=M, kind="min_weight").sum()))(
        jnp.asarray(p[:8]))
    assert g.shape == (8, 4, 3) and np.isfinite(np.asarray(g)).all()
    with pytest.raises(ValueError, match="kind must be one of"):
        gj.objective(p, nr, mu=MU, kind="epsilon")


def test_closure_has_no_plateau_on_the_quality_floor(sphere_set, sphere_values):
    """``delta* = -1`` (the first contact alone, a constant) on many grasps that are not in
    equilibrium. There ``"closure"`` is ``delta* + 4 T`` wherever ``T < 0``, so it varies with
    the torque margin even where ``-1 < 4 T < 0`` (the plain minimum was the constant -1 there),
    with a gradient that finite differences confirm."""
    p, nr, _ = sphere_set
    model = ContactModel(num_edges=M)
    monitors = jit(jax.vmap(lambda a, b: _objectives.objective_one(a, b, MU, model, "closure", CENTER3, 1.0)))
    value, mon = monitors(p[:120], nr[:120])
    value, delta, torque = map(np.asarray, (value, mon["delta"], mon["torque"]))
    np.testing.assert_allclose(value, sphere_values("closure")[:120], atol=1e-12)
    floor = np.abs(delta + 1) < 1e-9
    assert floor.mean() > 0.1
    both = (delta < 0) & (torque < 0)
    np.testing.assert_allclose(value[both], (delta + torque)[both], atol=1e-12)
    pulled = np.flatnonzero(floor & (torque > -0.9) & (torque < -1e-3))
    assert len(pulled) >= 3
    assert np.all(value[pulled] < -1 - 1e-3)
    h = 1e-6
    P, N = _perturbed(p[pulled[0]], nr[pulled[0]], h)
    values, (gp, gn) = _value_and_grad("closure", 3)(P, N)
    values, gp, gn = map(np.asarray, (values, gp, gn))
    fd = (values[:-1:2] - values[1:-1:2]) / (2 * h)
    grad = np.concatenate([gp[-1].ravel(), gn[-1].ravel()])
    assert np.abs(fd).max() > 1e-3
    np.testing.assert_allclose(grad, fd, atol=2e-5 * max(1.0, np.abs(fd).max()))
