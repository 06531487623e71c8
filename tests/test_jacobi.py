"""``_jacobi.eigh``: the LAPACK-free eigensolver of the 6-D rank test, against NumPy's LAPACK."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from grasp_jax import _jacobi
from grasp_jax._closure import _gram_rank


def _gram(rng, count, K, D, rank=None, dtype=np.float64):
    X = rng.normal(size=(count, K, D)) * rng.uniform(0.01, 10.0, size=(count, 1, D))
    if rank is not None:  # K vectors in a rank-dimensional subspace
        X = X[:, :, :rank] @ rng.normal(size=(count, rank, D))
    return np.einsum("bki,bkj->bij", X, X).astype(dtype)


@pytest.mark.parametrize("K, rank", [(3, None), (7, None), (32, None), (32, 5), (32, 3), (4, None)])
def test_eigenvalues_and_vectors_match_lapack(K, rank):
    G = _gram(np.random.default_rng(K), 500, K, 6, rank)
    w, V = jax.jit(jax.vmap(_jacobi.eigh))(G)
    w, V = np.asarray(w), np.asarray(V)
    ref = np.linalg.eigvalsh(G)
    scale = np.max(np.abs(ref), axis=1, keepdims=True)
    np.testing.assert_allclose(np.sort(w, axis=1) / scale, ref / scale, rtol=0, atol=1e-14)
    np.testing.assert_allclose(np.einsum("bki,bkj->bij", V, V), np.broadcast_to(np.eye(6), G.shape), atol=1e-13)
    np.testing.assert_allclose(G @ V / scale[..., None], V * w[:, None, :] / scale[..., None], atol=1e-13)


def test_float32_and_special_matrices():
    G = _gram(np.random.default_rng(1), 300, 12, 6, dtype=np.float32)
    w, _ = jax.vmap(_jacobi.eigh)(G)
    ref = np.linalg.eigvalsh(G.astype(np.float64))
    np.testing.assert_allclose(np.sort(np.asarray(w), axis=1) / ref[:, -1:], ref / ref[:, -1:], atol=2e-6)
    special = np.stack([np.zeros((6, 6)), np.eye(6), np.diag([3.0, 0, 1, 0, 2, 5]), np.full((6, 6), 2.0)])
    w, V = jax.vmap(_jacobi.eigh)(special)
    assert np.all(np.isfinite(w)) and np.all(np.isfinite(V))
    np.testing.assert_allclose(np.sort(np.asarray(w), axis=1), np.linalg.eigvalsh(special), atol=1e-14)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 6), st.integers(0, 2**31 - 1))
def test_rank_test_agrees_with_lapack(rank, seed):
    """The verdict of ``_gram_rank`` (full rank or not) is LAPACK's, and a rank-deficient set's null
    vector is orthogonal to every vector of the set."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(20, rank)) @ rng.normal(size=(rank, 6))
    full, null = _gram_rank(X)
    ev = np.linalg.eigvalsh(X.T @ X)
    assert bool(full) == (ev[0] > 1e-10 * ev[-1]) == (rank == 6)
    if rank < 6:
        assert np.max(np.abs(X @ np.asarray(null))) < 1e-10 * np.max(np.abs(X)) and abs(np.linalg.norm(null) - 1) < 1e-12
