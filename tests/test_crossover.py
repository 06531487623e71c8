"""The crossover to a certified vertex (``grasp_jax._crossover``) against SciPy's HiGHS and NumPy."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog

from grasp_jax._programs import SHIFT, about_first, quality_lp
from grasp_jax._cones import cone_edges
from grasp_jax.lp._crossover import FEASIBILITY, _inverse, crossover, polish
from grasp_jax.lp import LP, LPSolution, Status, solve

from _grasps import MU, grasps, sample_sphere
from _jit import jit

ROWS, COLS, BATCH = 5, 14, 32
PIVOTS = 16


def _feasible(rng):
    """A random LP with a strictly feasible primal and dual (a finite optimum)."""
    A = rng.normal(size=(ROWS, COLS))
    x0 = rng.uniform(0.1, 2.0, size=COLS)
    y0 = rng.normal(size=ROWS)
    s0 = rng.uniform(0.1, 2.0, size=COLS)
    return A, A @ x0, A.T @ y0 + s0


@jit
def _ipm_then_crossover(A, b, c):
    def one(A, b, c):
        (sol,) = solve(LP(A, b, c))
        return crossover(A, b, c, sol.x, sol.y, PIVOTS) + (sol.value,)

    return jax.vmap(one)(A, b, c)


@pytest.fixture(scope="module")
def random_lps():
    rng = np.random.default_rng(11)
    A, b, c = (np.stack(v) for v in zip(*(_feasible(rng) for _ in range(BATCH))))
    return A, b, c


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_certified_vertex_is_highs_optimum(random_lps, dtype):
    """A certified vertex is feasible, its reduced costs are >= 0, and its value is HiGHS's."""
    A, b, c = random_lps
    x, y, cert, _ = map(np.asarray, _ipm_then_crossover(*(jnp.asarray(v, dtype) for v in (A, b, c))))
    assert cert.mean() >= 0.9
    for k in np.nonzero(cert)[0]:
        ref = linprog(c[k], A_eq=A[k], b_eq=b[k], bounds=(0, None), method="highs")
        assert ref.status == 0
        scale = 1.0 + abs(ref.fun)
        assert c[k] @ x[k] == pytest.approx(ref.fun, abs=(2e-5 if dtype == np.float32 else 1e-9) * scale)
        assert np.all(x[k] >= 0)
        assert np.abs(A[k] @ x[k] - b[k]).max() <= 1e-4 * (1 + np.abs(b[k]).max())
        # A vertex: at most ROWS non-zero entries.
        assert np.count_nonzero(x[k]) <= ROWS


def test_float32_vertex_beats_the_interior_point_value(random_lps):
    """In float32 the certified vertex is closer to HiGHS than the interior-point optimum it came from
    (in the worst case over the batch)."""
    A, b, c = random_lps
    x, _, cert, ipm = map(np.asarray, _ipm_then_crossover(*(jnp.asarray(v, np.float32) for v in (A, b, c))))
    ref = np.array([linprog(c[k], A_eq=A[k], b_eq=b[k], bounds=(0, None), method="highs").fun for k in range(BATCH)])
    vertex_err = np.abs(np.einsum("kj,kj->k", c, x.astype(np.float64)) - ref)[cert]
    ipm_err = np.abs(ipm.astype(np.float64) - ref)[cert]
    assert vertex_err.max() <= ipm_err.max()


def _ill_conditioned(rng, condition):
    """A random LP whose unique optimum is the vertex of the first ``ROWS`` columns, a basis of the
    given condition number (``x_B > 0``, the other columns' reduced costs > 0)."""
    U, _ = np.linalg.qr(rng.normal(size=(ROWS, ROWS)))
    V, _ = np.linalg.qr(rng.normal(size=(ROWS, ROWS)))
    B = U @ np.diag(np.geomspace(1.0, 1.0 / condition, ROWS)) @ V.T
    N = rng.normal(size=(ROWS, COLS - ROWS))
    y = rng.normal(size=ROWS)
    c = np.concatenate([B.T @ y, N.T @ y + rng.uniform(0.5, 2.0, COLS - ROWS)])
    return np.concatenate([B, N], axis=1), B @ rng.uniform(0.5, 2.0, ROWS), c


def test_float32_ill_conditioned_vertex_is_certified():
    """A basis of condition 1e4 is certified in float32 when its refined solves have a small backward
    error, and its value is the optimum of the float32 LP (HiGHS on the same numbers): the basis
    inverse's smallest pivot is near 1e-4 there, and a threshold on it alone rejected such vertices."""
    rng = np.random.default_rng(5)
    A, b, c = (np.stack(v).astype(np.float32) for v in zip(*(_ill_conditioned(rng, 1e4) for _ in range(BATCH))))
    x, _, cert, _ = map(np.asarray, _ipm_then_crossover(A, b, c))
    assert cert.mean() >= 0.9
    for k in np.nonzero(cert)[0]:
        ref = linprog(c[k], A_eq=A[k], b_eq=b[k], bounds=(0, None), method="highs")
        assert c[k].astype(np.float64) @ x[k] == pytest.approx(ref.fun, abs=1e-5 * (1 + abs(ref.fun)))


def test_crossover_from_the_dual_alone():
    """An unfinished solve has no trusted primal: from ``x = 0`` and a rough ``y`` the pivots still
    reach a certified optimum on small problems."""
    rng = np.random.default_rng(3)
    A, b, c = _feasible(rng)
    ref = linprog(c, A_eq=A, b_eq=b, bounds=(0, None), method="highs")
    (sol,) = jit(lambda A, b, c: solve(LP(A, b, c), iterations=4))(A, b, c)
    x, y, cert = jit(lambda A, b, c, x, y: crossover(A, b, c, x, y, 40))(A, b, c, jnp.zeros(COLS), sol.y)
    assert bool(cert)
    assert float(c @ x) == pytest.approx(ref.fun, abs=1e-9 * (1 + abs(ref.fun)))
    np.testing.assert_allclose(np.asarray(y), ref.eqlin.marginals, atol=1e-8)


def test_vmap_equals_a_loop(random_lps):
    A, b, c = (jnp.asarray(v, np.float32) for v in random_lps)
    xs, ys, cs, _ = _ipm_then_crossover(A, b, c)
    for k in range(4):
        x, y, cert, _ = _ipm_then_crossover(A[k : k + 1], b[k : k + 1], c[k : k + 1])
        np.testing.assert_array_equal(np.asarray(cert[0]), np.asarray(cs[k]))
        if bool(cs[k]):
            np.testing.assert_allclose(np.asarray(x[0]), np.asarray(xs[k]), atol=1e-6)


_inverse_jitted = jit(_inverse)  # one program per size, kept across the examples


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 7))
def test_inverse_matches_numpy(seed, r):
    """The unrolled Gauss-Jordan inverse with partial pivoting, also with a zero leading entry."""
    B = np.random.default_rng(seed).normal(size=(r, r))
    B[0, 0] = 0.0
    inv, smallest = _inverse_jitted(B)
    if np.linalg.cond(B) < 1e8:
        np.testing.assert_allclose(np.asarray(inv) @ B, np.eye(r), atol=1e-8 * np.linalg.cond(B))
        assert float(smallest) > 0


@jit
def _polished(A, b, c):
    (sol,) = solve(LP(A, b, c))
    return sol, polish(LP(A, b, c), sol, PIVOTS)


def test_polish_without_pivots_is_the_identity():
    z = jnp.zeros(2)
    sol = LPSolution(z, z, z[0], jnp.int8(0), jnp.int32(0), z[0])
    new, certified, _ = polish(LP(jnp.eye(2), jnp.ones(2), jnp.ones(2)), sol, 0)
    assert new is sol and not bool(certified)


def test_infeasible_lp_is_left_alone():
    """A Farkas-certified LP keeps its status and certificate."""
    A = jnp.array([[1.0, 1.0], [1.0, 1.0]])
    b = jnp.array([1.0, -1.0])  # x1 + x2 cannot be 1 and -1
    sol, (new, certified, _) = _polished(A, b, jnp.array([1.0, 2.0]))
    assert sol.status == Status.INFEASIBLE
    assert new.status == Status.INFEASIBLE and not bool(certified)
    np.testing.assert_array_equal(np.asarray(new.y), np.asarray(sol.y))


def test_float32_quality_lp_vertex_matches_float64():
    """On random sphere grasps (4 fingers, 25 edges, where float32 interior-point values missed by up
    to 4e-4), every certified float32 vertex is within 1e-5 of the float64 optimum."""
    p, n = grasps(sample_sphere, 256, 4, np.random.default_rng(21))

    @jit
    def deltas(p, n):
        def one(p, n):
            edges = cone_edges(n, jnp.asarray(MU, p.dtype), 25, None)
            lp = quality_lp(about_first(p, n, edges), edges)
            (sol,) = solve(lp, consistent=True)
            x, _, cert = crossover(*lp, sol.x, sol.y, PIVOTS)
            return x[-1] - SHIFT, cert, sol.x[-1] - SHIFT

        return jax.vmap(one)(p, n)

    d32, cert, _ = map(np.asarray, deltas(p.astype(np.float32), n.astype(np.float32)))
    _, _, d64 = map(np.asarray, deltas(p, n))
    assert cert.mean() >= 0.9
    assert np.abs(d32[cert].astype(np.float64) - d64[cert]).max() <= 1e-5
    assert FEASIBILITY <= 1e-5
