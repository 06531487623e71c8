"""Eigenvalues of small symmetric matrices by cyclic Jacobi rotations, in plain ``jax.numpy``.

``jnp.linalg.eigh`` calls LAPACK on a CPU, and a program that calls LAPACK runs on one XLA
device only (``_batch``: jaxlib's LAPACK kernels wait on the thread pool that several CPU devices
share). The rank test of the 6-D wrench set (``_closure._gram_rank``) needs the extreme
eigenvalues of a 6x6 Gram matrix per grasp; with this module ``gj.min_weight``,
``gj.critical_friction`` and the robust margin columns make no LAPACK call, and their programs are
sharded over every CPU device like ``gj.evaluate``'s.

Cyclic Jacobi (Golub and Van Loan, *Matrix Computations*, 4th ed., algorithm 8.5.3): each
rotation zeroes one off-diagonal pair; a sweep rotates every pair once, and the off-diagonal norm
falls quadratically once it is small. The eigenvalues it returns are those of a matrix within a few
roundoffs of ``G`` (rotations are orthogonal), as LAPACK's are. Under ``vmap`` every matrix of a
batch rotates in lock step; the sweep is a rolled loop (one copy of its rotations in the program).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

#: Sweeps of :func:`eigh`. The off-diagonal norm of a 6x6 Gram matrix falls below a roundoff of
#: its norm in 4 to 6 sweeps (quadratic convergence after the first two); 8 leave a margin.
SWEEPS = 8


def _rotate(A: jax.Array, V: jax.Array, p: int, q: int) -> tuple[jax.Array, jax.Array]:
    """``A <- J^T A J``, ``V <- V J`` with the rotation ``J`` in the plane ``(p, q)`` that zeroes
    ``A[p, q]`` (the smaller of the two angles that do)."""
    app, aqq, apq = A[p, p], A[q, q], A[p, q]
    active = apq != 0.0
    tau = (aqq - app) / (2.0 * jnp.where(active, apq, 1.0))
    # t = tan(angle), |t| <= 1; for |tau| beyond 1e154, tau^2 is inf and t = 0, as it should be.
    t = jnp.where(tau >= 0, 1.0, -1.0) / (jnp.abs(tau) + jnp.sqrt(1.0 + tau * tau))
    c = jnp.where(active, 1.0 / jnp.sqrt(1.0 + t * t), 1.0)
    s = jnp.where(active, t * c, 0.0)
    rp, rq = A[p], A[q]
    A = A.at[p].set(c * rp - s * rq).at[q].set(s * rp + c * rq)
    cp, cq = A[:, p], A[:, q]
    A = A.at[:, p].set(c * cp - s * cq).at[:, q].set(s * cp + c * cq)
    vp, vq = V[:, p], V[:, q]
    V = V.at[:, p].set(c * vp - s * vq).at[:, q].set(s * vp + c * vq)
    return A, V


def eigh(G: jax.Array, sweeps: int = SWEEPS) -> tuple[jax.Array, jax.Array]:
    """Eigenvalues and eigenvectors of one symmetric ``(D, D)`` matrix (batch with ``vmap``).

    Returns ``(w, V)``: ``w: (D,)`` eigenvalues in no particular order, ``V: (D, D)`` orthonormal
    eigenvectors as columns (``G V ~ V diag(w)``). Not differentiable in any useful way: for
    verdicts and certificates (wrap the input in ``stop_gradient``).
    """
    D = G.shape[0]
    pairs = [(p, q) for p in range(D - 1) for q in range(p + 1, D)]

    def sweep(_, carry):
        A, V = carry
        for p, q in pairs:
            A, V = _rotate(A, V, p, q)
        return A, V

    A, V = jax.lax.fori_loop(0, sweeps, sweep, (G, jnp.eye(D, dtype=G.dtype)))
    return jnp.diagonal(A), V
