"""Derivatives of the quality Q (envelope theorem on the LP's primal-dual solution) against
central finite differences of gj.quality itself and of the SciPy-HiGHS reference."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import linprog

import grasp_jax as gj
from grasp_jax import reference

from _jit import jit
from _grasps import MU, QUAD, STAR, grasps, sample_box, sample_cylinder, sample_polygon, sample_sphere

N = {2: 3, 3: 4}  # fingers per dimension: one shape, one compilation per transformation
B = 6  # grasps per batch
SAMPLERS = {
    2: {"quad": lambda c, r: sample_polygon(QUAD, c, r), "star": lambda c, r: sample_polygon(STAR, c, r)},
    3: {"sphere": sample_sphere, "cylinder": lambda c, r: _rotated(sample_cylinder(c, r)),
        "box": lambda c, r: _rotated(sample_box(c, r))},
}


def _rotated(sample):
    """A fixed generic rotation, so that face normals are not horizontal (see ``_select``)."""
    q, _ = np.linalg.qr(np.random.default_rng(7).normal(size=(3, 3)))
    return sample[0] @ q.T, sample[1] @ q.T


def _select(d: int, want: str, count: int, seed: int):
    """``count`` grasps with n = N[d] fingers: ``"fc"`` generic force-closure grasps (HiGHS margin
    clearly positive, Q clear of 0 and of its upper bound), or ``"open"``: clearly not in equilibrium."""
    rng = np.random.default_rng(seed)
    names = list(SAMPLERS[d])
    out_p, out_n = [], []
    while len(out_p) < count:
        name = names[len(out_p) % len(names)]
        (p,), (nr,) = grasps(SAMPLERS[d][name], 1, N[d], rng)
        if d == 3 and np.abs(nr[:, 2]).min() < 0.05:
            # The default contact frame (Duff et al.) flips where normal_z changes sign: the pyramid
            # rotates by a jump there and Q is only one-sided differentiable. Stay clear of it.
            continue
        q, eq = reference.quality_highs(p, nr, MU)
        if want == "fc":
            ok = eq and 0.05 < q < np.sqrt(1 + MU**2) - 0.05 and reference.min_weight_highs(p, nr, MU) > 1e-3
        else:
            # Not in equilibrium, and delta* clear of -1 (where it is flat: only cone 1 helps).
            ok = not eq and _signed_delta_highs(p, nr) < -0.01 and _signed_delta_highs(p, nr) > -0.95
        if ok:
            out_p.append(p)
            out_n.append(nr)
    return np.stack(out_p), np.stack(out_n)


def _signed_delta_highs(points, normals) -> float:
    """``delta*`` of ``max delta s.t. sum a_ij (v_ij, (c_i - c_1) x v_ij) + delta (z_1, 0) = 0,
    sum a = 1, a >= 0`` with delta free: HiGHS's version of ``quality(..., signed=True)``."""
    edges = reference.cone_edges(normals, MU, 8)
    n, m, d = edges.shape
    cols = []
    for i in range(n):
        for v in edges[i]:
            arm = points[i] - points[0]
            torque = arm[0] * v[1] - arm[1] * v[0] if d == 2 else np.cross(arm, v)
            cols.append(np.concatenate([v, np.atleast_1d(torque)]))
    A = np.array(cols).T
    z1 = -normals[0] / np.linalg.norm(normals[0])
    A = np.hstack([A, np.concatenate([z1, np.zeros(A.shape[0] - d)])[:, None]])
    A = np.vstack([A, np.r_[np.ones(n * m), 0.0]])
    b = np.r_[np.zeros(A.shape[0] - 1), 1.0]
    c = np.r_[np.zeros(n * m), -1.0]
    res = linprog(c, A_eq=A, b_eq=b, bounds=[(0, None)] * (n * m) + [(None, None)], method="highs")
    assert res.status == 0
    return -res.fun


@functools.lru_cache(maxsize=None)
def _grads(d: int):
    """Gradients of Q and of signed delta wrt points and normals, and jacrev of Q wrt points, in
    one compiled function of a (B, n, d) batch (the suite's compiler options, ``_jit.py``)."""

    def run(P, Nrm):
        q = lambda P, Nrm: gj.quality(P, Nrm, mu=MU)  # noqa: E731
        s = lambda P, Nrm: gj.quality(P, Nrm, mu=MU, signed=True)  # noqa: E731
        gq = jax.grad(lambda P, Nrm: q(P, Nrm).sum(), argnums=(0, 1))(P, Nrm)
        gs = jax.grad(lambda P, Nrm: s(P, Nrm).sum(), argnums=(0, 1))(P, Nrm)
        jac = jax.jacrev(q, argnums=1)(P, Nrm)
        return q(P, Nrm), s(P, Nrm), gq, gs, jac

    return jit(run)


@functools.lru_cache(maxsize=None)
def _values():
    return jit(lambda P, Nrm: (gj.quality(P, Nrm, mu=MU), gj.quality(P, Nrm, mu=MU, signed=True)))


def _perturbations(P, Nrm, h):
    """All central-difference perturbations of every coordinate of points and normals:
    ``(B, 2 [points, normals], n, d, 2 [+h, -h])`` grasps, flattened."""
    b, n, d = P.shape
    ps, ns = [], []
    for k in range(b):
        for which in range(2):
            for i in range(n):
                for j in range(d):
                    for sign in (1.0, -1.0):
                        p, nr = P[k].copy(), Nrm[k].copy()
                        (p if which == 0 else nr)[i, j] += sign * h
                        ps.append(p)
                        ns.append(nr)
    return np.stack(ps), np.stack(ns)


def _fd_from(values, P, h):
    b, n, d = P.shape
    v = np.asarray(values).reshape(b, 2, n, d, 2)
    fd = (v[..., 0] - v[..., 1]) / (2 * h)
    return fd[:, 0], fd[:, 1]


def _assert_grad_close(ad, fd, rel):
    for k in range(len(ad)):
        err = np.linalg.norm(ad[k] - fd[k])
        assert err <= rel * np.linalg.norm(fd[k]) + 1e-7, (k, err, np.linalg.norm(fd[k]), ad[k], fd[k])


@pytest.fixture(scope="module", params=[2, 3], ids=["2d", "3d"])
def fc_case(request):
    d = request.param
    P, Nrm = _select(d, "fc", B, seed=100 + d)
    q, s, (gq_p, gq_n), (gs_p, gs_n), jac = jax.tree_util.tree_map(np.asarray, _grads(d)(P, Nrm))
    return d, P, Nrm, q, s, gq_p, gq_n, gs_p, gs_n, jac


def test_quality_values_and_signed_agree_on_fc(fc_case):
    d, P, Nrm, q, s, *_ = fc_case
    ref = np.array([reference.quality_highs(p, nr, MU)[0] for p, nr in zip(P, Nrm)])
    np.testing.assert_allclose(q, ref, atol=1e-9)
    np.testing.assert_allclose(s, q, atol=1e-12)


def test_grad_vs_finite_differences_of_quality(fc_case):
    d, P, Nrm, q, s, gq_p, gq_n, gs_p, gs_n, jac = fc_case
    h = 1e-5
    fp, fn = _perturbations(P, Nrm, h)
    vq, vs = _values()(fp, fn)
    fd_p, fd_n = _fd_from(vq, P, h)
    _assert_grad_close(gq_p, fd_p, 1e-5)
    _assert_grad_close(gq_n, fd_n, 1e-5)
    sd_p, sd_n = _fd_from(vs, P, h)
    _assert_grad_close(gs_p, sd_p, 1e-5)
    _assert_grad_close(gs_n, sd_n, 1e-5)
    assert np.all(np.linalg.norm(gq_p.reshape(B, -1), axis=1) > 0)  # Q does depend on the points


def test_grad_vs_finite_differences_of_highs(fc_case):
    d, P, Nrm, q, s, gq_p, gq_n, *_ = fc_case
    h = 1e-6
    fp, fn = _perturbations(P, Nrm, h)
    values = [reference.quality_highs(p, nr, MU)[0] for p, nr in zip(fp, fn)]
    fd_p, fd_n = _fd_from(values, P, h)
    _assert_grad_close(gq_p, fd_p, 1e-5)
    _assert_grad_close(gq_n, fd_n, 1e-5)


def test_jacrev_is_block_diagonal_grad(fc_case):
    d, P, Nrm, q, s, gq_p, gq_n, gs_p, gs_n, jac = fc_case
    assert jac.shape == (B, B, N[d], d)
    for k in range(B):
        np.testing.assert_allclose(jac[k, k], gq_n[k], rtol=1e-12, atol=1e-14)
        np.testing.assert_array_equal(np.delete(jac[k], k, axis=0), 0.0)


def test_translation_gradient_sums_to_zero(fc_case):
    """Q is translation invariant, so its gradient wrt the points sums to zero over contacts."""
    d, P, Nrm, q, s, gq_p, *_ = fc_case
    np.testing.assert_allclose(gq_p.sum(axis=1), 0.0, atol=1e-9 * np.abs(gq_p).max())
    # ... and scale invariant: sum_i p_i . dQ/dp_i = 0 (Euler's theorem for degree-0 functions).
    euler = np.einsum("bnd,bnd->b", P, gq_p)
    np.testing.assert_allclose(euler, 0.0, atol=1e-9 * np.abs(gq_p).max() * np.abs(P).max())


@pytest.mark.parametrize("d", [2, 3])
def test_signed_gradient_on_open_grasps(d):
    """Off equilibrium, Q = 0 with zero gradient while signed delta < 0 has a finite, non-zero
    gradient that matches finite differences."""
    P, Nrm = _select(d, "open", B, seed=200 + d)
    q, s, (gq_p, gq_n), (gs_p, gs_n), jac = jax.tree_util.tree_map(np.asarray, _grads(d)(P, Nrm))
    np.testing.assert_array_equal(q, 0.0)
    np.testing.assert_array_equal(gq_p, 0.0)
    np.testing.assert_array_equal(gq_n, 0.0)
    assert np.all(s < 0)
    np.testing.assert_allclose(s, [_signed_delta_highs(p, nr) for p, nr in zip(P, Nrm)], atol=1e-9)
    assert np.all(np.isfinite(gs_p)) and np.all(np.isfinite(gs_n))
    assert np.all(np.linalg.norm(gs_n.reshape(B, -1), axis=1) > 0)
    h = 1e-5
    fp, fn = _perturbations(P, Nrm, h)
    vq, vs = _values()(fp, fn)
    np.testing.assert_array_equal(np.asarray(vq), 0.0)
    sd_p, sd_n = _fd_from(vs, P, h)
    _assert_grad_close(gs_p, sd_p, 1e-5)
    _assert_grad_close(gs_n, sd_n, 1e-5)
    hd = 1e-6
    fp, fn = _perturbations(P, Nrm, hd)
    hd_p, hd_n = _fd_from([_signed_delta_highs(p, nr) for p, nr in zip(fp, fn)], P, hd)
    _assert_grad_close(gs_p, hd_p, 1e-5)
    _assert_grad_close(gs_n, hd_n, 1e-5)


def _finite_grads(d, P, Nrm):
    out = jax.tree_util.tree_map(np.asarray, _grads(d)(P, Nrm))
    for name, leaf in zip(("quality", "signed", "grad quality", "grad signed", "jacrev"), out):
        for k, x in enumerate(jax.tree_util.tree_leaves(leaf)):
            assert np.all(np.isfinite(x)), (name, k, x)


@pytest.mark.parametrize("d", [2, 3])
def test_gradients_finite_on_degenerate_grasps(d):
    """Coincident contacts, exactly antipodal grasps, coplanar contacts, horizontal normals (where
    the default 3D frame flips): every value and gradient is finite."""
    n = N[d]
    rng = np.random.default_rng(300 + d)
    P = rng.normal(size=(B, n, d))
    Nrm = rng.normal(size=(B, n, d))
    P[0, 1] = P[0, 0]
    Nrm[0, 1] = Nrm[0, 0]  # two coincident contacts with one normal
    P[1, 1] = P[1, 0]  # two coincident contacts with different normals
    P[2, :2] = [np.eye(d)[0], -np.eye(d)[0]]
    Nrm[2, :2] = [np.eye(d)[0], -np.eye(d)[0]]  # exactly antipodal pair
    P[3, :-1] = 0.0
    Nrm[3, :-1] = Nrm[3, 0]  # all but the last contact at one point
    Nrm[4] = np.eye(d)[:1].repeat(n, axis=0)
    P[4] = rng.normal(size=(n, d)) * np.r_[0.0, np.ones(d - 1)]  # coplanar on a face, same normal
    Nrm[5, :, -1] = 0.0  # normals with a zero last coordinate
    _finite_grads(d, P, Nrm)


@pytest.mark.parametrize("d", [2, 3])
def test_gradients_finite_when_all_contacts_coincide(d):
    n = N[d]
    rng = np.random.default_rng(400 + d)
    P = np.repeat(rng.normal(size=(B, 1, d)), n, axis=1)  # every contact of a grasp at one point
    Nrm = rng.normal(size=(B, n, d))
    Nrm[:3] = Nrm[:3, :1]  # ... with one normal, or with several
    P[5] = 0.0
    _finite_grads(d, P, Nrm)


def test_quality_under_jit_and_vmap():
    """The concrete path, jax.jit and jax.vmap (inside jit) agree."""
    P, Nrm = _select(2, "fc", B, seed=102)
    q_jit = np.asarray(_grads(2)(P, Nrm)[0])
    direct = np.asarray(gj.quality(P, Nrm, mu=MU))
    vmapped = jit(jax.vmap(lambda p, nr: gj.quality(p, nr, mu=MU)))(jnp.asarray(P), jnp.asarray(Nrm))
    assert vmapped.shape == direct.shape == q_jit.shape == (B,)
    np.testing.assert_allclose(q_jit, direct, atol=1e-13)
    np.testing.assert_allclose(np.asarray(vmapped), direct, atol=1e-13)


def test_gradient_wrt_mu():
    """mu may be traced as well: dQ/dmu from the envelope theorem matches HiGHS differences."""
    P, Nrm = _select(2, "fc", B, seed=102)
    g = np.asarray(jit(jax.grad(lambda mu: gj.quality(P, Nrm, mu=mu).sum()))(MU))
    h = 1e-6
    fd = sum((reference.quality_highs(p, nr, MU + h)[0] - reference.quality_highs(p, nr, MU - h)[0]) / (2 * h)
             for p, nr in zip(P, Nrm))
    assert g == pytest.approx(fd, rel=1e-5)
