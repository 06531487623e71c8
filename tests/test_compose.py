"""Every public function composes with ``jit``, ``vmap`` and ``grad`` (where its value is
differentiable) with any leading batch shape, or says why not in one clear error; result types
are pytrees that print a short summary.

One grasp shape per dimension (3 contacts in 2D, 4 contacts with 8 edges in 3D) and one jitted
function per check keep the number of compilations small.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _grasps import MU, QUAD, grasps, sample_polygon, sample_sphere

import grasp_jax as gj

from _jit import jit

FIELDS = ("force_closure", "quality", "equilibrium", "torque_span", "delta", "torque_margin",
          "certificate", "quality_status", "torque_status")


def _grasps(d: int, shape: tuple, seed: int = 0):
    rng = np.random.default_rng(seed)
    count = int(np.prod(shape))
    if d == 2:
        p, n = grasps(lambda c, r: sample_polygon(QUAD, c, r), count, 3, rng)
    else:
        p, n = grasps(sample_sphere, count, 4, rng)
    return p.reshape(shape + p.shape[1:]), n.reshape(shape + n.shape[1:])


def _close(a, b, atol=1e-9):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype
    if a.dtype.kind in "biu":
        np.testing.assert_array_equal(a, b)
    else:
        np.testing.assert_allclose(a, b, rtol=1e-7, atol=atol)


def test_evaluate_under_jit_vmap_with_a_leading_batch_shape():
    """3D (the quality and the torque LP): ``jit(vmap(evaluate))`` over a ``(2, 3)`` batch equals
    the concrete call."""
    p, n = _grasps(3, (2, 3))
    concrete = gj.evaluate(p, n, mu=MU)
    traced = jit(jax.vmap(lambda p, n: gj.evaluate(p, n, mu=MU)))(p, n)
    assert isinstance(traced, gj.GraspEvaluation) and traced.quality.shape == (2, 3)
    assert traced.certificate.shape == (2, 3, 6)
    for name in FIELDS:
        _close(getattr(traced, name), getattr(concrete, name))
    np.testing.assert_array_equal(np.asarray(traced.converged), concrete.converged)


@pytest.fixture(scope="module")
def traced_2d():
    """Everything that composes, for a ``(2, 2)`` batch of 2D grasps, in one jitted function."""
    p, n = _grasps(2, (2, 2))
    mus = jnp.array([0.2, MU, 0.8])
    summaries = []

    def everything(p, n):
        ev = gj.evaluate(p, n, mu=MU)
        summaries.append(repr(ev))
        q = lambda p, n, mu=MU: gj.quality(p, n, mu=mu, signed=True)
        mw = gj.min_weight(p, n, mu=MU)
        finite = jnp.isfinite(mw)
        return {
            "evaluate": ev,
            "converged": ev.converged,
            "force_closure": gj.force_closure(p, n, mu=MU),
            "quality": q(p, n),
            "min_weight": mw,
            "grad_quality": jax.grad(lambda p, n: q(p, n).sum(), argnums=(0, 1))(p, n),
            "grad_evaluate": jax.grad(lambda p: gj.evaluate(p, n, mu=MU).delta.sum())(p),
            "vmap_grad": jax.vmap(jax.vmap(jax.grad(q)))(p, n),
            "per_mu": jax.vmap(lambda m: q(p, n, m))(mus),
            "grad_mu": jax.grad(lambda m: q(p, n, m).sum())(MU),
            "grad_min_weight": jax.grad(lambda p: jnp.where(finite, gj.min_weight(p, n, mu=MU), 0.0).sum())(p),
        }

    out = jit(everything)(p, n)  # the suite's compiler options (_jit.py)
    return p, n, out, summaries


def test_evaluate_force_closure_quality_min_weight_under_jit(traced_2d):
    p, n, out, _ = traced_2d
    concrete = gj.evaluate(p, n, mu=MU)
    for name in FIELDS:
        _close(getattr(out["evaluate"], name), getattr(concrete, name))
    np.testing.assert_array_equal(np.asarray(out["converged"]), concrete.converged)
    np.testing.assert_array_equal(np.asarray(out["force_closure"]), np.asarray(concrete.force_closure))
    _close(out["quality"], concrete.delta)
    mw = np.asarray(out["min_weight"])
    assert mw.shape == (2, 2)
    # the classical margin and Proposition 2 agree away from the boundary
    clear = np.abs(mw) > 1e-6
    np.testing.assert_array_equal((mw > 0)[clear], np.asarray(concrete.force_closure)[clear])


def test_gradients_compose(traced_2d):
    p, n, out, _ = traced_2d
    gp, gn = out["grad_quality"]
    for g in (gp, gn, out["grad_evaluate"], out["vmap_grad"], out["grad_min_weight"]):
        assert g.shape == p.shape and np.all(np.isfinite(np.asarray(g)))
    _close(out["grad_evaluate"], gp, atol=1e-9)  # evaluate's delta is quality(signed=True)
    _close(out["vmap_grad"], gp, atol=1e-9)  # vmap(grad) per grasp = grad of the sum
    assert np.isfinite(float(out["grad_mu"]))
    assert np.any(np.asarray(gp) != 0)


def test_vmap_over_mu(traced_2d):
    p, n, out, _ = traced_2d
    per_mu = np.asarray(out["per_mu"])
    assert per_mu.shape == (3, 2, 2)
    _close(per_mu[1], out["quality"])
    # more friction, more quality (the cones grow)
    assert np.all(per_mu[2] >= per_mu[0] - 1e-9)


def test_central_axis_under_jit_vmap_grad():
    w = np.random.default_rng(3).normal(size=(2, 5, 6))
    concrete = gj.central_axis(w)
    mapped = jax.jit(jax.vmap(gj.central_axis))(w)
    for name in ("point", "direction", "pitch", "pure_torque"):
        _close(getattr(mapped, name), getattr(concrete, name))
    g = jax.jit(jax.grad(lambda w: gj.central_axis(w).point.sum() + gj.central_axis(w).pitch.sum()))(w)
    assert g.shape == w.shape and np.all(np.isfinite(g))


def test_ferrari_canny_refuses_tracers_with_one_clear_error():
    p, n = _grasps(3, (2,))
    calls = {
        "jit": lambda: jax.jit(lambda p: gj.ferrari_canny(p, n, mu=MU)[0])(p),
        "vmap": lambda: jax.vmap(lambda p, n: gj.ferrari_canny(p, n, mu=MU)[0])(p, n),
        "grad": lambda: jax.grad(lambda p: gj.ferrari_canny(p, n[0], mu=MU)[0].sum())(p[0]),
        "traced mu": lambda: jax.jit(lambda m: gj.ferrari_canny(p, n, mu=m)[0])(MU),
    }
    for name, call in calls.items():
        with pytest.raises(TypeError, match=r"ferrari_canny .*qhull.*grasp_jax.min_weight"):
            call()


def test_results_are_pytrees_with_a_short_summary(traced_2d):
    p, n = _grasps(3, (6,))
    ev = gj.evaluate(p, n, mu=MU)
    leaves, tree = jax.tree_util.tree_flatten(ev)
    assert len(leaves) == len(ev.__dataclass_fields__)
    assert isinstance(jax.tree_util.tree_unflatten(tree, leaves), gj.GraspEvaluation)
    text = repr(ev)
    assert text.startswith("GraspEvaluation(batch=(6,), force_closure ") and "dtype float64" in text
    assert len(text) < 120 and "\n" not in text
    assert "%" in text

    assert traced_2d[3] == ["GraspEvaluation(batch=(2, 2), traced, dtype float64)"]

    axis = gj.central_axis(np.array([[1.0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, 1.0]]))
    assert repr(axis) == "CentralAxis(batch=(2,), 3D, 1 pure torque, dtype float64)"
    assert len(jax.tree_util.tree_leaves(axis)) == 4
