"""``gj.optimize``: contacts on the surface, convergence on cases with a known answer,
reproducibility, the exact final scores, de-duplication and input errors."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
import trimesh

import grasp_jax as gj
from grasp_jax import _optimize, objects

MU, M = 0.364, 4


@pytest.fixture(scope="module")
def rectangle():
    return objects.Polygon.from_vertices(np.array([[-1.0, -0.5], [1.0, -0.5], [1.0, 0.5], [-1.0, 0.5]]),
                                         name="rectangle")


@pytest.fixture(scope="module")
def sphere_run():
    return gj.optimize(objects.Sphere(0.05), 3, fingers=3, mu=MU, num_edges=M, starts=48, steps=40)


def test_two_contacts_on_a_rectangle_converge_to_an_antipodal_grasp(rectangle):
    """Contacts on the short sides end facing each other (same height): the antipodal grasp,
    Q at its maximum, whatever the heights they start at."""
    init = np.array([[[-1.0, 0.3], [1.0, -0.35]], [[-1.0, -0.2], [1.0, 0.1]], [[-1.0, 0.0], [1.0, 0.4]]])
    res = gj.optimize(rectangle, init=init, fingers=2, mu=MU, steps=60, learning_rate=0.05)
    best = gj.evaluate(np.array([[-1.0, 0.0], [1.0, 0.0]]), np.array([[-1.0, 0.0], [1.0, 0.0]]), mu=MU)
    assert res.force_closure.all()
    np.testing.assert_allclose(res.points[:, 0, 1], res.points[:, 1, 1], atol=1e-3)
    np.testing.assert_allclose(np.abs(res.points[..., 0]), 1.0, atol=1e-12)  # on the short sides
    np.testing.assert_allclose(res.quality, float(best.quality), rtol=5e-3)
    assert set(np.asarray(res.reason)) == {gj.EndReason.FORCE_CLOSURE}


def test_an_optimal_start_stays_put(rectangle):
    init = np.array([[[-1.0, 0.1], [1.0, 0.1]]])
    res = gj.optimize(rectangle, init=init, fingers=2, mu=MU, steps=60, learning_rate=0.05)
    first = gj.evaluate(init, np.array([[[-1.0, 0.0], [1.0, 0.0]]]), mu=MU)
    np.testing.assert_allclose(res.points, init, atol=1e-9)
    np.testing.assert_allclose(res.quality, first.quality, rtol=1e-12)


def test_one_small_step_raises_the_objective(rectangle):
    rng = np.random.default_rng(0)
    heights = rng.uniform(-0.4, 0.4, size=(16, 2))
    init = np.stack([np.stack([-np.ones(16), heights[:, 0]], -1), np.stack([np.ones(16), heights[:, 1]], -1)], 1)
    res = gj.optimize(rectangle, init=init, fingers=2, mu=MU, steps=2, optimizer=optax.sgd(1e-3))
    gain = res.history[:, 1] - res.history[:, 0]
    moving = np.abs(heights[:, 0] - heights[:, 1]) > 1e-3
    assert (gain[moving] > 0).all()


def test_reported_scores_are_evaluate_of_the_reported_grasps(sphere_run):
    res = sphere_run
    ev = gj.evaluate(res.points, res.normals, mu=MU, num_edges=M)
    np.testing.assert_array_equal(np.asarray(ev.force_closure), res.force_closure)
    np.testing.assert_array_equal(np.asarray(ev.quality), res.quality)
    # On the sphere, exactly: |p| = r and n = p / r.
    np.testing.assert_allclose(np.linalg.norm(res.points, axis=-1), 0.05, rtol=1e-12)
    np.testing.assert_allclose(res.normals, res.points / 0.05, atol=1e-12)
    assert res.normal_kind == "exact"
    assert res.history.shape == (48, 40) and res.quality_history.shape == (48, 40)
    # The best iterate is kept: force-closure iterates by Q, so never worse than the start.
    assert np.all(res.quality >= res.quality_history[:, 0] - 1e-9)
    assert np.all(res.quality >= res.quality_history.max(axis=1) - 1e-9)
    assert res.force_closure.mean() > 0.9


def test_reproducible_for_a_key_different_across_keys(sphere_run):
    again = gj.optimize(objects.Sphere(0.05), 3, fingers=3, mu=MU, num_edges=M, starts=48, steps=40)
    np.testing.assert_array_equal(again.points, sphere_run.points)
    np.testing.assert_array_equal(again.history, sphere_run.history)
    other = gj.optimize(objects.Sphere(0.05), jax.random.key(4), fingers=3, mu=MU, num_edges=M, starts=48,
                        steps=40)
    assert not np.allclose(other.initial_points, sphere_run.initial_points)


def test_refining_given_starts_never_loses(sphere_run):
    rng = np.random.default_rng(5)
    p = rng.normal(size=(48, 3, 3))
    p = 0.05 * p / np.linalg.norm(p, axis=-1, keepdims=True)
    res = gj.optimize(objects.Sphere(0.05), init=(p, p / 0.05), fingers=3, mu=MU, num_edges=M, steps=40,
                      learning_rate=0.05)
    start = gj.evaluate(p, p / 0.05, mu=MU, num_edges=M)
    assert np.all(res.quality >= np.asarray(start.quality) - 1e-7)
    np.testing.assert_allclose(res.initial_points, p, atol=1e-12)


def test_contacts_stay_on_a_mesh_across_edges():
    mesh = objects.Mesh.from_trimesh(trimesh.creation.icosphere(1, radius=0.05), name="ico")
    res = gj.optimize(mesh, 1, fingers=3, mu=MU, num_edges=M, starts=16, steps=40, learning_rate=0.05)
    pts, tri = res.points.reshape(-1, 3), mesh.mesh.triangles
    pairs = np.repeat(pts, len(tri), axis=0), np.tile(tri, (len(pts), 1, 1))
    closest = trimesh.triangles.closest_point(pairs[1], pairs[0])
    dist = np.linalg.norm(closest - pairs[0], axis=1).reshape(len(pts), len(tri)).min(axis=1)
    assert dist.max() <= 1e-9 * mesh.radius
    moved = np.linalg.norm(res.points - res.initial_points, axis=-1)
    assert moved.max() > 0.2 * mesh.radius  # far enough to have crossed edges of 80 faces
    # the recorded path (start, then after each segment of steps) stays on the mesh too
    assert res.path.shape == (16, 5, 3, 3)  # 40 steps: 4 segments of 10
    np.testing.assert_array_equal(res.path[:, 0], res.initial_points)
    on = trimesh.proximity.closest_point(mesh.mesh, res.path.reshape(-1, 3))[1]
    assert on.max() <= 1e-9 * mesh.radius
    assert res.normal_kind == "smooth"
    ev = gj.evaluate(res.points, res.normals, mu=MU, num_edges=M)
    np.testing.assert_array_equal(np.asarray(ev.quality), res.quality)


def test_distinct_ignores_the_order_of_contacts_2_to_n():
    rng = np.random.default_rng(2)
    p = rng.normal(size=(5, 4, 3))
    swapped = p[:, [0, 3, 1, 2]]
    points = np.concatenate([p, swapped, p + 1e-6])
    q = np.arange(15, dtype=float)
    keep = _optimize.distinct_grasps(points, q, cell=1e-2)
    assert len(keep) <= 10 and len(keep) >= 5
    moved_first = p[:, [1, 0, 2, 3]]
    assert len(_optimize.distinct_grasps(np.concatenate([p, moved_first]), np.zeros(10), 1e-2)) == 10


@pytest.mark.parametrize(
    "kwargs, error, words",
    [
        ({"obj": None}, ValueError, "obj must be"),
        ({"fingers": 1}, ValueError, "fingers must be an integer >= 2"),
        ({"steps": 0}, ValueError, "steps must be a positive integer"),
        ({"starts": 0}, ValueError, "starts must be a positive integer"),
        ({"mu": -1.0}, ValueError, "mu must be"),
        ({"objective": "epsilon"}, ValueError, "objective must be one of"),
        ({"optimizer": lambda g: g}, TypeError, "optax.GradientTransformation"),
        ({"init": np.zeros((4, 2, 3))}, ValueError, "init must have shape (starts, 3, 3)"),
        ({"normals": "bumpy"}, ValueError, "normals must be"),
        ({"dtype": "int8"}, ValueError, "dtype must be"),
        ({"key": "seed"}, ValueError, "key must be"),
        ({"iterations": 0}, ValueError, "iterations must be a positive integer"),
        ({"optimizer": optax.lbfgs()}, TypeError, "a line search such as optax.lbfgs()'s cannot run here"),
    ],
)
def test_bad_input_is_one_clear_error(kwargs, error, words):
    args = {"obj": objects.Sphere(), "key": 0, "fingers": 3, "mu": MU, "steps": 5, "starts": 4}
    args.update(kwargs)
    obj, key = args.pop("obj"), args.pop("key")
    with pytest.raises(error) as info:
        gj.optimize(obj, key, **args)
    assert words in str(info.value)
    assert "\n" not in str(info.value)


def test_the_optimizer_sees_the_sum_of_its_updates_as_params(rectangle):
    """An optimizer whose update is ``target - params`` moves each contact by ``target`` once and
    then stays: its params are the displacement so far (with params always 0 it would move again at
    every step)."""
    target = jnp.array([[0.0, 0.1], [0.0, -0.05]])
    go_to = optax.GradientTransformation(lambda p: optax.EmptyState(), lambda u, s, p: (target - p, s))
    init = np.array([[[-1.0, -0.2], [1.0, 0.1]]])
    res = gj.optimize(rectangle, init=init, fingers=2, mu=MU, steps=5, optimizer=go_to)
    np.testing.assert_allclose(res.history[:, 1:], np.broadcast_to(res.history[:, 1:2], (1, 4)), rtol=1e-12)
    moved = init + np.asarray(target) * res.scale
    assert np.allclose(res.points, init, atol=1e-9) or np.allclose(res.points, moved, atol=1e-9)
    assert not np.allclose(res.history[:, 0], res.history[:, 1])


def test_warm_restart_runs_the_second_optimizer_from_its_initial_state():
    """The default optimizer's restart: ``first`` for ``boundary`` updates, then ``second`` exactly
    as a fresh ``second`` would run on the same gradients."""
    first, second = optax.adam(0.3), optax.adam(0.05)
    both = _optimize.warm_restart(first, second, 3)
    grads = [jnp.full((2, 3), g) for g in (1.0, -2.0, 0.5, 3.0, -1.0, 0.25)]
    state, fresh_a, fresh_b = both.init(grads[0]), first.init(grads[0]), second.init(grads[0])
    for k, g in enumerate(grads):
        u, state = both.update(g, state)
        if k < 3:
            ref, fresh_a = first.update(g, fresh_a)
        else:
            ref, fresh_b = second.update(g, fresh_b)
        np.testing.assert_allclose(u, ref, rtol=1e-12)
