"""The linear programs of one grasp: the quality LP of eq. (18-20) about ``c_1``, the min-weight
LP of a set of vectors, their certificates, and the rank test of a torque set."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ._cones import cone_edges, safe_normalize
from ._constants import tolerances
from ._contact import Columns, ContactModel, columns
from ._wrench import cross
from .lp import LP, LPSolution, Status

#: Hard contacts with the default cone.
HARD = ContactModel()


def arm_scale(points: jax.Array) -> jax.Array:
    """Largest distance from ``c_1`` to another contact (1 where all contacts coincide)."""
    sq = jnp.max(jnp.sum((points - points[0]) ** 2, axis=-1))
    # Double where: sqrt's derivative at 0 is inf, and a single where would turn it into NaN.
    spread = sq > tolerances(points.dtype).tiny ** 2
    return jnp.where(spread, jnp.sqrt(jnp.where(spread, sq, 1.0)), 1.0)


def torques_about_first(points: jax.Array, edges: jax.Array) -> jax.Array:
    """``(n, m, t)`` torques of the cone edges about ``c_1``, divided by the grasp's size."""
    arm = (points - points[0]) / arm_scale(points)
    tau = cross(arm[:, None, :], edges)
    return tau[..., None] if points.shape[-1] == 2 else tau


# ---------------------------------------------------------------------------------------------
# The LPs.


#: ``delta >= -SHIFT`` is added to the quality LP to make it standard form. Any ``SHIFT >= 1``
#: leaves the optimum unchanged (``delta* >= -1``); with 2 rather than 1 the bound is never active,
#: which spares the interior-point method a degenerate optimal face on grasps whose only
#: solution is the first contact alone (``delta* = -1``): 16 iterations fell to about 11 there.
SHIFT = 2.0


def about_first(points: jax.Array, normals: jax.Array, edges: jax.Array, model: ContactModel = HARD) -> Columns:
    """The wrench columns of a contact model (``_contact``) with torques about ``c_1`` divided by
    the grasp's size: the columns of the quality and torque LPs."""
    return columns(edges, torques_about_first(points, edges), normals, model.kind, model.torsion, arm_scale(points))


def quality_lp(cols: Columns, edges: jax.Array) -> LP:
    """The equilibrium LP of eq. (17)-(20) in the always-feasible normalized form.

    ``max delta  s.t.  sum a_k f_k + delta z_1 = 0,  sum a_k tau_k = 0,  sum a = 1,  a >= 0``
    over the columns ``(f_k, tau_k)`` of :func:`about_first` (hard contacts: the cone edges
    ``v_ij`` and their torques ``tau_ij``) with ``delta`` free (``a = 1/m`` on contact 1's edges,
    ``delta = -1`` is feasible for every contact model: soft columns come in pairs whose torsion
    cancels). Then ``delta* > 0`` iff eq. (17) has a solution, and ``delta* = Q`` of eq. (23)
    there (Charnes-Cooper). The standard form uses ``delta' = delta + SHIFT >= 0``: variables
    ``(a_1..a_K, delta')``, rows ``(force: d, torque: 1 or 3, sum: 1)``. ``edges``: ``(n, m, d)``,
    whose first cone gives ``z_1``.
    """
    z1 = jnp.mean(edges[0], axis=0)  # the mean of the first cone's edges is its axis
    z1 = safe_normalize(z1)
    K, t = cols.torque.shape
    force_rows = jnp.concatenate([cols.force.T, z1[:, None]], axis=1)
    torque_rows = jnp.concatenate([cols.torque.T, jnp.zeros((t, 1), edges.dtype)], axis=1)
    sum_row = jnp.concatenate([jnp.ones((1, K), edges.dtype), jnp.zeros((1, 1), edges.dtype)], axis=1)
    A = jnp.concatenate([force_rows, torque_rows, sum_row], axis=0)
    b = jnp.concatenate([SHIFT * z1, jnp.zeros(t, edges.dtype), jnp.ones(1, edges.dtype)])
    c = jnp.zeros(K + 1, edges.dtype).at[-1].set(-1.0)
    return LP(A, b, c)


def grasp_quality_lp(points, normals, mu, model: ContactModel, tangents=None) -> tuple[LP, Columns]:
    """The quality LP of one grasp from its contacts (normals normalized, cone edges, columns
    about ``c_1``), and those columns."""
    normals = safe_normalize(normals)
    edges = cone_edges(normals, mu, model.num_edges, tangents)
    cols = about_first(points, normals, edges, model)
    return quality_lp(cols, edges), cols


def quality_bound(lp: LP, y: jax.Array) -> tuple[jax.Array, jax.Array]:
    """An upper bound on ``delta*`` of :func:`quality_lp` from any dual vector ``y``, by weak duality.

    With ``u = y[:-1]`` (force and torque rows) scaled so that ``z_1 . u_f = -1``, every feasible
    ``(a, delta)`` has ``delta = sum_ij a_ij (w_ij . u) <= max_ij w_ij . u`` (``sum a = 1``), where
    ``w_ij`` are the LP's columns (cone edge and torque about ``c_1``). Returns ``(bound, slack)``:
    ``slack`` bounds the rounding of the computed bound (``inf`` where ``u`` is no such direction).
    """
    A = lp.A
    dt = A.dtype
    scale = -(A[:-1, -1] @ y[:-1])
    ok = scale > jnp.finfo(dt).eps
    u = y[:-1] / jnp.where(ok, scale, 1.0)
    bound = jnp.max(A[:-1, :-1].T @ u)
    slack = 16.0 * jnp.finfo(dt).eps * (1.0 + jnp.max(jnp.abs(A[:-1, :-1]).T @ jnp.abs(u)))
    return jnp.where(ok, bound, jnp.inf), jnp.where(ok, slack, jnp.inf)


def min_weight_lp(vectors: jax.Array) -> LP:
    """The min-weight LP ``max l s.t. sum alpha_k w_k = 0, sum alpha = 1, alpha_k >= l``.

    Args:
        vectors: ``(K, D)`` vectors ``w_k``.

    ``l <= 1/K`` always, so with ``alpha = beta + 1/K - s`` the standard form has variables
    ``(beta_1..beta_K, s) >= 0``, rows ``W beta - s W1 = -W1/K`` and ``1.beta - K s = 0``, and
    minimizes ``s``; ``l* = 1/K - s*``. Infeasible iff no affine combination of the ``w_k`` is 0.
    """
    K, D = vectors.shape
    W = vectors.T
    w1 = jnp.sum(W, axis=1)
    A = jnp.concatenate(
        [
            jnp.concatenate([W, -w1[:, None]], axis=1),
            jnp.concatenate([jnp.ones((1, K), W.dtype), jnp.full((1, 1), -float(K), W.dtype)], axis=1),
        ],
        axis=0,
    )
    b = jnp.concatenate([-w1 / K, jnp.zeros(1, W.dtype)])
    c = jnp.zeros(K + 1, W.dtype).at[-1].set(1.0)
    return LP(A, b, c)


def min_weight_margin_of(vectors: jax.Array, sol: LPSolution) -> jax.Array:
    """``l*`` from a solved :func:`min_weight_lp` (``-inf`` when infeasible, 0 if not converged)."""
    K = vectors.shape[0]
    return jnp.where(
        sol.status == Status.OPTIMAL,
        1.0 / K - sol.x[-1],
        jnp.where(sol.status == Status.INFEASIBLE, -jnp.inf, 0.0),
    )


def min_weight_certificate(vectors: jax.Array, sol: LPSolution) -> jax.Array:
    """A direction ``u`` with ``u . w_k >= -l*`` for all k, from the dual of the min-weight LP."""
    return -sol.y[: vectors.shape[1]]


#: Squarings of the normalized Gram matrix that give the direction of its largest eigenvalue
#: (:func:`full_rank`): after ``k``, a component along an eigenvalue ``lambda`` is scaled by
#: ``(lambda / lambda_max)^(2^k)``, and the Rayleigh quotient of the result is within
#: ``(D - 1) / (2^(k+1) e)`` relative of ``lambda_max`` in the worst case (a second eigenvalue just
#: below the largest): 1e-3 for ``k = 10`` and ``D = 6``, i.e. the rank threshold moves by at most
#: 0.1% of itself. No LAPACK call, so the programs run on every CPU device (``_batch``).
SQUARINGS = 10


def positive_definite(M: jax.Array) -> jax.Array:
    """Whether a small symmetric ``M`` is positive definite: every pivot of its unrolled
    ``L D L^T`` factorization is positive (exact in exact arithmetic; backward stable, so a
    computed verdict is that of a matrix within a few roundoffs of ``|M|``). No LAPACK, no loop."""
    k = M.shape[0]
    L = [[None] * k for _ in range(k)]
    pivots = []
    ok = jnp.ones((), bool)
    for j in range(k):
        d = M[j, j] - sum((L[j][p] * L[j][p] * pivots[p] for p in range(j)), start=jnp.zeros((), M.dtype))
        ok = ok & (d > 0)
        d = jnp.where(d > 0, d, 1.0)  # a failed pivot: the verdict is known, keep the rest finite
        pivots.append(d)
        for i in range(j + 1, k):
            off = M[i, j] - sum((L[i][p] * L[j][p] * pivots[p] for p in range(j)), start=jnp.zeros((), M.dtype))
            L[i][j] = off / d
    return ok


def full_rank(vectors: jax.Array) -> jax.Array:
    """Whether ``(K, D)`` vectors span R^D: the least eigenvalue of their Gram matrix ``G`` exceeds
    ``tolerances(dtype).rank`` times the largest.

    Without an eigensolver (LAPACK calls keep a program on one CPU device, ``_batch``), and without
    a loop: the largest eigenvalue is the Rayleigh quotient of a column of ``G^(2^k)`` (``k =``
    :data:`SQUARINGS` squarings, each normalized by its trace), then ``G - rank * lambda_max * I``
    is positive definite iff the least eigenvalue is above the threshold (:func:`positive_definite`).
    For ``D = 3`` use the closed form :func:`gram_rank3`, which also gives a null vector.
    """
    tol = tolerances(vectors.dtype)
    G = vectors.T @ vectors
    D = G.shape[0]
    tr = jnp.trace(G)
    H = G / jnp.where(tr > tol.tiny, tr, 1.0)
    for _ in range(SQUARINGS):
        H = H @ H
        H = H / jnp.maximum(jnp.trace(H), tol.tiny)
    v = H @ jax.nn.one_hot(jnp.argmax(jnp.diagonal(H)), D, dtype=G.dtype)  # its largest column
    top = (v @ G @ v) / jnp.maximum(v @ v, tol.tiny)
    top = jnp.maximum(top, tr / D)  # never below the mean eigenvalue (a degenerate v)
    return (tr > tol.tiny) & positive_definite(G - tol.rank * top * jnp.eye(D, dtype=G.dtype))


def gram_rank3(vectors: jax.Array) -> tuple[jax.Array, jax.Array]:
    """:func:`_gram_rank` for ``D = 3`` in closed form (no eigensolver in the hot path).

    Rank 3 iff ``det G / (tr G / 3)^3`` exceeds ``rank`` (this ratio lies between
    ``(l_min/l_max)^2`` and ``27 l_min/l_max``; rounding leaves ~1e-16 on rank-2 sets). The null vector of a rank-2 Gram matrix is any
    non-zero column of its adjugate; of a rank-1 matrix, a vector orthogonal to its largest row.
    """
    tol = tolerances(vectors.dtype)
    G = vectors.T @ vectors
    tr = jnp.trace(G)
    g = G / jnp.where(tr > tol.tiny, tr, 1.0)
    adj = jnp.stack([jnp.cross(g[1], g[2]), jnp.cross(g[2], g[0]), jnp.cross(g[0], g[1])])
    det = jnp.dot(g[0], adj[0])
    full = (tr > tol.tiny) & (det * 27.0 > tol.rank)
    col = adj[jnp.argmax(jnp.sum(adj * adj, axis=1))]
    row = g[jnp.argmax(jnp.sum(g * g, axis=1))]
    perp = jnp.cross(row, jnp.eye(3, dtype=g.dtype)[jnp.argmin(jnp.abs(row))])
    null = jnp.where(jnp.sum(col * col) > tol.rank**2, col, perp)
    null = jnp.where(jnp.sum(null * null) > tol.tiny, null, jnp.eye(3, dtype=g.dtype)[2])
    return full, safe_normalize(null)
