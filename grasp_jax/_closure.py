"""The central-axis force-closure test and quality of the paper, for **one** grasp.

Proposition 2 (corrected as in ``MATH.md``): a grasp is force-closure iff, about the first contact
``c_1``, (1) some positive combination of cone edges produces ``-delta z_1`` with zero torque about
``c_1``, ``delta > 0`` (eq. 17 / 22), and (2) the torques ``tau_ij = (c_i - c_1) x v_ij`` of the
other contacts positively span R^3 (R in 2D). (1) is the quality LP; its optimum is the paper's
``Q`` (eq. 23). (2) is exact here: a min-weight LP in R^3 plus a rank check (:func:`full_rank`);
the paper's per-axis eq. (15) is kept as ``torque_test="paper"``. In 2D, (2) is eq. (21).

Where the torques of (2) lie strictly inside an open half-space (torque LP margin ``l* < 0``),
the quality LP's optimum is ``delta* = -1`` without solving it: in float64, 3D, exact mode the
evaluation runs as two stages, :func:`torque_stage` and :func:`quality_stage`, so that the batched
evaluation (``_batch.Staged``) solves the quality LP only where it is needed.

All functions here take one grasp; batching lives in ``_batch.py``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from ._cones import cone_edges, safe_normalize
from ._constants import default_iterations, tolerances
from ._contact import Columns, columns, wrench_columns
from ._result import GraspEvaluation
from ._wrench import cross
from .lp import (
    LP,
    SENSITIVE,
    LPSolution,
    Status,
    as_solution,
    has_value,
    optimal_value,
    polish,
    sensitivity,
    solve,
    stacked,
    warm_point,
)


def _arm_scale(points: jax.Array) -> jax.Array:
    """Largest distance from ``c_1`` to another contact (1 where all contacts coincide)."""
    sq = jnp.max(jnp.sum((points - points[0]) ** 2, axis=-1))
    # Double where: sqrt's derivative at 0 is inf, and a single where would turn it into NaN.
    spread = sq > tolerances(points.dtype).tiny ** 2
    return jnp.where(spread, jnp.sqrt(jnp.where(spread, sq, 1.0)), 1.0)


def _torques_about_first(points: jax.Array, edges: jax.Array) -> jax.Array:
    """``(n, m, t)`` torques of the cone edges about ``c_1``, divided by the grasp's size."""
    arm = (points - points[0]) / _arm_scale(points)
    tau = cross(arm[:, None, :], edges)
    return tau[..., None] if points.shape[-1] == 2 else tau


# ---------------------------------------------------------------------------------------------
# The LPs.


#: ``delta >= -SHIFT`` is added to the quality LP to make it standard form. Any ``SHIFT >= 1``
#: leaves the optimum unchanged (``delta* >= -1``); with 2 rather than 1 the bound is never active,
#: which spares the interior-point method a degenerate optimal face on grasps whose only
#: solution is the first contact alone (``delta* = -1``): 16 iterations fell to about 11 there.
SHIFT = 2.0


def about_first(points: jax.Array, normals: jax.Array, edges: jax.Array, contact: str = "hard", torsion=0.0) -> Columns:
    """The wrench columns of a contact model (``_contact``) with torques about ``c_1`` divided by
    the grasp's size: the columns of the quality and torque LPs."""
    return columns(edges, _torques_about_first(points, edges), normals, contact, torsion, _arm_scale(points))


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


def grasp_quality_lp(points, normals, mu, num_edges: int, tangents=None, contact: str = "hard", torsion=0.0
                     ) -> tuple[LP, Columns]:
    """The quality LP of one grasp from its contacts (normals normalized, cone edges, columns
    about ``c_1``), and those columns."""
    normals = safe_normalize(normals)
    edges = cone_edges(normals, mu, num_edges, tangents)
    cols = about_first(points, normals, edges, contact, torsion)
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


def _min_weight_margin(vectors: jax.Array, sol: LPSolution) -> jax.Array:
    """``l*`` from a solved :func:`min_weight_lp` (``-inf`` when infeasible, 0 if not converged)."""
    K = vectors.shape[0]
    return jnp.where(
        sol.status == Status.OPTIMAL,
        1.0 / K - sol.x[-1],
        jnp.where(sol.status == Status.INFEASIBLE, -jnp.inf, 0.0),
    )


def _min_weight_certificate(vectors: jax.Array, sol: LPSolution) -> jax.Array:
    """A direction ``u`` with ``u . w_k >= -l*`` for all k, from the dual of the min-weight LP."""
    return -sol.y[: vectors.shape[1]]


#: Squarings of the normalized Gram matrix that give the direction of its largest eigenvalue
#: (:func:`full_rank`): after ``k``, a component along an eigenvalue ``lambda`` is scaled by
#: ``(lambda / lambda_max)^(2^k)``, and the Rayleigh quotient of the result is within
#: ``(D - 1) / (2^(k+1) e)`` relative of ``lambda_max`` in the worst case (a second eigenvalue just
#: below the largest): 1e-3 for ``k = 10`` and ``D = 6``, i.e. the rank threshold moves by at most
#: 0.1% of itself. No LAPACK call, so the programs run on every CPU device (``_batch``).
SQUARINGS = 10


def _positive_definite(M: jax.Array) -> jax.Array:
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
    is positive definite iff the least eigenvalue is above the threshold (:func:`_positive_definite`).
    For ``D = 3`` use the closed form :func:`_gram_rank3`, which also gives a null vector.
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
    return (tr > tol.tiny) & _positive_definite(G - tol.rank * top * jnp.eye(D, dtype=G.dtype))


def _gram_rank3(vectors: jax.Array) -> tuple[jax.Array, jax.Array]:
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


# ---------------------------------------------------------------------------------------------
# Torque tests about c_1.


def paper_torque_test(tau: jax.Array) -> jax.Array:
    """Eq. (15) in 3D / eq. (21) in 2D on ``tau: (K, t)``: each torque component takes both signs.

    Necessary for Proposition 2(2) in 3D, not sufficient (``MATH.md``); exact in 2D.
    """
    tol = tolerances(tau.dtype)
    total_abs = jnp.sum(jnp.abs(tau), axis=0)
    return jnp.all(total_abs - jnp.abs(jnp.sum(tau, axis=0)) > tol.margin * total_abs + tol.tiny)


def _exact_torque_2d(tau: jax.Array):
    """Scalar torques positively span R iff they take both signs. Returns (span, certificate)."""
    tol = tolerances(tau.dtype)
    t = tau[:, 0]
    hi, lo = jnp.max(t), jnp.min(t)
    span = (hi > tol.margin) & (lo < -tol.margin)
    # When not spanning, t_cert * tau >= 0 for every torque (within the margin).
    t_cert = jnp.where(lo >= -tol.margin, 1.0, -1.0).astype(tau.dtype)
    return span, jnp.minimum(hi, -lo), t_cert[None]


# ---------------------------------------------------------------------------------------------
# float32: the quality LP of a grasp whose torques about c_1 lie in a half-space.

#: A certified torque LP margin ``|l*|`` at most this (float32 rounding leaves ~1e-8 on exact zeros)
#: means the torques lie in the closed half-space ``u . tau >= 0`` of its dual direction ``u`` and
#: some on its boundary plane. (``l* < -HALF_SPACE``: all of them strictly inside an open
#: half-space, which forces ``delta* = -1`` exactly, :func:`_open_half_space`.)
HALF_SPACE = 1e-7
#: Columns with ``u . tau_j`` above this fraction of ``max |tau_j|`` are off the plane ``u . tau = 0``
#: (exactly: the torques of a box grasp's contacts on one face; the others are ~1e-8).
OFF_PLANE = 1e-5
#: Simplex pivots of the reduced quality LP, which starts from nothing (``x = y = 0``).
REDUCED_PIVOTS = 64


def _plane_basis(u: jax.Array) -> jax.Array:
    """``(3, 3)`` orthonormal rows, the first ``u`` (unit)."""
    a = jnp.eye(3, dtype=u.dtype)[jnp.argmin(jnp.abs(u))]
    v1 = safe_normalize(a - (a @ u) * u)
    return jnp.stack([u, v1, jnp.cross(u, v1)])


def _half_space_quality_lp(q_lp: LP, u: jax.Array) -> tuple[LP, jax.Array]:
    """The 3D quality LP (one zero column appended) when every torque satisfies ``u . tau >= 0``.

    Then ``sum a_ij tau_ij = 0`` forces ``a_ij = 0`` on every column off the plane ``u . tau = 0``,
    and the LP is degenerate: its optimal bases have condition ~1e5 in float32 and are not
    certified (``lp._crossover.CONDITION``). Here those columns are removed (zeroed), the torque rows
    are rotated to ``(u, v1, v2)`` and the ``u`` row, now empty up to rounding, fixes the appended
    column at 1. Returns ``(lp, rotation)``.
    """
    A, b, c = q_lp
    R = _plane_basis(u)
    tau = A[3:6]
    off = (u @ tau) > OFF_PLANE * jnp.max(jnp.abs(tau), axis=0)
    rows = jnp.concatenate([A[:3], (R @ tau)[1:], A[6:]])
    rows = jnp.where(off[None, :], 0.0, rows)
    r, N = A.shape
    A = jnp.concatenate([rows[:3], jnp.zeros((1, N), A.dtype), rows[3:]])
    A = jnp.concatenate([A, jnp.eye(r, 1, -3, dtype=A.dtype)], axis=1)  # the unit column of row 3
    b = b.at[3:6].set(R @ b[3:6]).at[3].set(1.0)
    c = jnp.concatenate([jnp.where(off, 0.0, c), jnp.zeros(1, c.dtype)])
    return LP(A, b, c), R


def _original_dual(y: jax.Array, R: jax.Array) -> jax.Array:
    """The dual vector of a :func:`_half_space_quality_lp` in the rows of the quality LP: torque
    rows rotated back, 0 on the ``u`` row. Its reduced costs are those of the reduced LP on the
    columns it kept; the removed ones are zero at every feasible point. (A ``u`` entry that also
    prices them reaches 1e4 where ``u . tau_j`` is small, and the envelope value ``c.x -
    y.(A x - b)`` then carried 1e-4 of the kept columns' rounding.)"""
    return jnp.concatenate([y[:3], R.T @ y[3:6].at[0].set(0.0), y[6:]])


def _open_half_space(t_polished) -> jax.Array:
    """float32: whether the torque LP's certified vertex proves ``l* < -HALF_SPACE``, i.e. every
    torque about ``c_1`` strictly inside an open half-space ``u . tau > 0``. Then no combination
    of the other contacts' columns has zero torque, only contact 1's edges balance, and
    ``delta* = -1`` exactly, whatever the quality LP's float32 solve says: on such a grasp a few
    roundoffs in the data make the torques span (the torque margin -2.3e-7 of one cylinder-side
    grasp, where float32's certified quality vertex read ``delta = 0.158``; in float64 moving the
    inputs by 1e-8 flips its ``Q`` between 0 and 0.135). ``t_polished``: :func:`polish`'s triple."""
    sol, certified, _ = t_polished
    K = sol.x.shape[0] - 1
    return certified & (1.0 / K - sol.x[-1] < -HALF_SPACE)


def _polish_exact(q_lp: LP, t_lp: LP, q_sol: LPSolution, t_sol: LPSolution, pivots: tuple, full):
    """:func:`polish` of the quality and torque LPs of a 3D exact evaluation (one :func:`stacked`
    crossover), then a second round through the same compiled crossover (a loop of two rounds, the
    second only where needed) for a grasp whose torque LP certifies ``|l*| <=`` :data:`HALF_SPACE`:
    the quality LP again, in the reduced form of :func:`_half_space_quality_lp`, from nothing. On
    such a grasp round one's vertex is never taken, even certified: the full quality LP is
    ill-posed there (its optimal dual is ~1e4-1e5, against ~2-5 elsewhere, so a few roundoffs in
    its data move ``delta*`` by up to 4e-3 and the vertex the crossover reaches depends on the
    CPU's rounding order). Without a certified reduced vertex the quality LP stays uncertified.
    ``t_sol``: the torque LP's interior-point solution, or zeros (``quality_one``: the crossover
    then starts from nothing). ``full``: whether the quality LP had the full budget (may be
    traced); then a full quality LP that round one does not certify runs again in round two, from
    the interior point's dual alone. Returns :func:`polish`'s triples.

    Such grasps are most of float32's rare ``|Q32 - Q64| > 1e-4`` (``experiments/float32_accuracy.py``);
    the reduced LP's vertex is certified on them and within 1e-6 of float64's Q.
    """
    if all(isinstance(k, int) and not k for k in pivots):  # float64: no crossover
        return [polish(q_lp, q_sol, 0), polish(t_lp, t_sol, 0)]
    q_lp, t_lp = jax.lax.stop_gradient(q_lp), jax.lax.stop_gradient(t_lp)
    r, N = q_lp.A.shape
    K = t_lp.A.shape[1] - 1
    dt = q_lp.A.dtype
    wide = LP(jnp.pad(q_lp.A, ((0, 0), (0, 1))), q_lp.b, jnp.pad(q_lp.c, (0, 1)))
    start = (wide, jnp.pad(q_sol.x, (0, 1)), q_sol.y)
    budget = jnp.stack([jnp.asarray(k, jnp.int32) for k in pivots])

    def body(carry):
        k, (lp, x, y), budget, best, half, need = carry
        (xq, yq, cq), (xt, yt, ct) = stacked((lp, t_lp), (x, t_sol.x), (y, t_sol.y), budget)
        first = k == 0
        # Round two keeps round one's torque vertex: that LP had no second pivot budget.
        xt, yt, ct = (jnp.where(first, new, old) for new, old in zip((xt, yt, ct), best[3:]))
        reduced, R = _half_space_quality_lp(q_lp, safe_normalize(-yt[:3]))
        # On such a grasp round one's vertex, certified or not, is never the answer: the LP is
        # ill-posed (a few roundoffs in its data move delta* by 1e-3) and the vertex found
        # depends on the CPU's rounding order. Only the reduced LP's vertex is taken; without it
        # the value stays uncertified.
        half = jnp.where(first, ct & (jnp.abs(1.0 / K - xt[-1]) <= HALF_SPACE), half)  # l* ~ 0
        # After the full budget, a full quality LP whose vertex round one did not certify runs
        # again from the interior point's dual alone (x = 0): its primal iterate can lead the
        # initial basis astray.
        retry = first & ~cq & ~half & full
        cq = jnp.where(first, cq & ~half, cq)
        take = first | cq
        xq = jnp.where(take, xq, best[0])
        back = jnp.where(half, _original_dual(yq, R), yq)
        yq = jnp.where(first, yq, jnp.where(cq, back, best[1]))
        cq = jnp.where(take, cq, best[2])
        need = first & (half | retry)
        lp = jax.tree_util.tree_map(lambda a, b: jnp.where(half, a, b), reduced, wide)
        start_y = jnp.where(half, 0.0, q_sol.y)
        again = jnp.asarray([REDUCED_PIVOTS, 0], jnp.int32)
        return k + 1, (lp, jnp.zeros(N + 1, dt), start_y), again, (xq, yq, cq, xt, yt, ct), half, need

    best = (start[1], start[2], jnp.zeros((), bool), t_sol.x, t_sol.y, jnp.zeros((), bool))
    carry = (jnp.zeros((), jnp.int32), start, budget, best, jnp.zeros((), bool), jnp.ones((), bool))
    _, _, _, (xq, yq, cq, xt, yt, ct), _, _ = jax.lax.while_loop(lambda c: c[-1], body, carry)
    return [as_solution(q_lp, q_sol, xq[:N], yq, cq), as_solution(t_lp, t_sol, xt, yt, ct)]


# ---------------------------------------------------------------------------------------------
# Evaluation of one grasp.


def _certificate_from_torque(points, t):
    """Wrench direction ``(c_1 x t, t)`` whose product with ``w_ij`` is ``t . tau_ij`` (about c_1)."""
    c1 = points[0]
    if points.shape[-1] == 2:
        force = t[0] * jnp.stack([c1[1], -c1[0]])
    else:
        force = jnp.cross(c1, t)
    return jnp.concatenate([force, t])


def _full_budget(lp: LP, iterations) -> jax.Array | bool:
    """Whether ``iterations`` (``None``: the default) is at least the full budget of ``lp``."""
    return True if iterations is None else iterations >= default_iterations(lp.A.shape[1])


def _pivots(tol, full) -> jax.Array | int:
    """Crossover pivots after the full or a short budget (``full`` may be traced)."""
    if full is True or tol.crossover == tol.crossover_short:
        return tol.crossover
    return jnp.where(full, tol.crossover, tol.crossover_short)


def _quality_value(q_lp: LP, q_sol: LPSolution, iterations, polished=None, forced=False
                   ) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(delta, status, dual)`` from a solve of :func:`quality_lp`: the value with envelope
    derivatives, its status, and the dual vector behind it (for the certificate).

    float32: the solution is first moved to a certified optimal vertex (``_crossover``). A solve
    that ends without a value (unfinished after the full budget) or with a value no vertex
    confirms (float32) still settles the verdict when the dual of the interior-point iterate or of
    the crossover's last basis bounds ``delta* < 0`` by weak duality (:func:`quality_bound`): status
    ``BOUNDED``, ``delta`` is that bound, ``Q = 0`` exactly. (Seen in float32: an ill-posed LP
    accepted at ``delta = 4e-4`` whose ``delta*`` is -1.) ``polished``: :func:`polish`'s result
    where the caller already has it. ``forced``: where ``delta* = -1`` is known
    (:func:`_open_half_space`), the value is that, ``OPTIMAL``, whatever the solve found.
    """
    tol = tolerances(q_lp.A.dtype)
    full = _full_budget(q_lp, iterations)
    if polished is None:
        polished = polish(q_lp, q_sol, _pivots(tol, full))
    q_sol, certified, y_vertex = polished
    q_ok = q_sol.status == Status.OPTIMAL
    delta = jnp.where(q_ok, -optimal_value(q_lp, q_sol) - SHIFT, 0.0)
    y_ipm = jax.lax.stop_gradient(q_sol.y)
    bound, slack = quality_bound(q_lp, y_ipm)
    y_bound = y_ipm
    if tol.crossover:
        bound_v, slack_v = quality_bound(q_lp, jax.lax.stop_gradient(y_vertex))
        tighter = bound_v + slack_v < bound + slack
        bound, slack = jnp.where(tighter, bound_v, bound), jnp.where(tighter, slack_v, slack)
        y_bound = jnp.where(tighter, y_vertex, y_ipm)
    unfinished = full & (q_sol.status == Status.NOT_CONVERGED)
    if tol.crossover:
        # A certified vertex of an ill-posed LP (a grasp whose torques lie in a half-space, whose
        # torque LP the short pass did not solve: ``quality``) waits for the full budget, where
        # ``_polish_exact`` reduces the LP.
        ill_posed = sensitivity(q_lp.A, jax.lax.stop_gradient(q_sol.x), jax.lax.stop_gradient(q_sol.y)) > SENSITIVE
        suspect = q_ok & (~certified | (ill_posed & ~full)) & (delta > -tol.margin)
    else:
        suspect = False
    bounded = (unfinished | suspect) & (bound + slack < -tol.margin)
    delta = jnp.where(bounded, jax.lax.stop_gradient(bound), delta)
    status = jnp.where(bounded, Status.BOUNDED, q_sol.status)
    # After a short budget, a value that no vertex certifies waits for the full budget.
    status = jnp.where(suspect & ~bounded & ~full, Status.NOT_CONVERGED, status).astype(jnp.int8)
    delta = jnp.where(status == Status.NOT_CONVERGED, 0.0, delta)
    delta = jnp.where(forced, -1.0, delta)
    status = jnp.where(forced, Status.OPTIMAL, status).astype(jnp.int8)
    return delta, status, jnp.where(bounded, y_bound, q_sol.y)


class Torques(NamedTuple):
    """The torque test of one 3D grasp (exact): what :func:`quality_stage` needs from
    :func:`torque_stage`.

    Attributes:
        span: whether the torques of contacts 2..n about ``c_1`` positively span R^3.
        margin: ``l*`` of the torque LP (0 where the torques are rank deficient, or the LP
            unfinished but bounded).
        direction: ``(3,)`` a torque direction ``t`` with ``t . tau >= -l*`` for every torque (the
            certificate of a grasp that does not span), or a null vector where rank deficient.
        status: ``int8`` :class:`Status` of the torque LP.
        opposed: whether the torques lie strictly inside an open half-space (``l* < 0``, proved):
            then only contact 1's own edges can balance, and ``delta* = -1`` exactly (hard
            contacts), with no quality LP.
    """

    span: jax.Array
    margin: jax.Array
    direction: jax.Array
    status: jax.Array
    opposed: jax.Array


def _torque_test(tau: jax.Array, t_sol: LPSolution, t_full, opposed) -> Torques:
    """:class:`Torques` from a (polished) solve of the torque LP ``min_weight_lp(tau)``.
    ``t_full``: whether it had the full budget; ``opposed``: what proves ``l* < 0`` (the caller
    knows how precise its ``l*`` is)."""
    tol = tolerances(tau.dtype)
    full, null = _gram_rank3(tau)
    t_margin = _min_weight_margin(tau, t_sol)
    # Unfinished after the full budget: the dual of the best iterate may still prove that the
    # torques do not span, by a direction u with u . tau >= 0 for every torque (then l* <= 0).
    t_dual = _min_weight_certificate(tau, t_sol)
    u = safe_normalize(t_dual)
    u_slack = 16.0 * jnp.finfo(tau.dtype).eps * jnp.max(jnp.abs(tau))
    t_bounded = t_full & (t_sol.status == Status.NOT_CONVERGED) & (jnp.min(tau @ u) >= -u_slack)
    t_margin = jnp.where(t_bounded, 0.0, t_margin)
    span = full & (t_sol.status == Status.OPTIMAL) & (t_margin > tol.margin)
    t_cert = jnp.where(full & ((t_sol.status != Status.NOT_CONVERGED) | t_bounded), t_dual, null)
    t_status = jnp.where(full, jnp.where(t_bounded, Status.BOUNDED, t_sol.status), Status.OPTIMAL).astype(jnp.int8)
    return Torques(span, jnp.where(full, t_margin, 0.0), t_cert, t_status, full & opposed)


def _evaluation(points, tau_dim: int, delta, q_status, q_dual, iterations, torque_span, t_margin, t_cert, t_status
                ) -> GraspEvaluation:
    """The :class:`GraspEvaluation` of one grasp from the outcomes of its two tests."""
    tol = tolerances(points.dtype)
    d = points.shape[-1]
    q_ok = q_status == Status.OPTIMAL
    bounded = q_status == Status.BOUNDED
    equilibrium = q_ok & (delta > tol.margin)
    quality = jnp.where(equilibrium, delta, 0.0)
    force_closure = equilibrium & torque_span & (t_status != Status.NOT_CONVERGED)

    # Certificate: a wrench direction u (about the origin) with u . w_ij >= 0 for all edges, from
    # the quality LP's dual where it has one (optimal, or a bounding best iterate).
    has_dual = q_ok | bounded
    t_q = q_dual[d : d + tau_dim]
    eq_cert = -jnp.concatenate([q_dual[:d], jnp.zeros(tau_dim, points.dtype)]) - _certificate_from_torque(
        points, t_q / _arm_scale(points)
    )
    cert = jnp.where(~torque_span, _certificate_from_torque(points, t_cert), eq_cert)
    cert = jnp.where(force_closure | ~has_dual, 0.0, safe_normalize(cert))

    return GraspEvaluation(
        force_closure=force_closure,
        quality=quality,
        equilibrium=equilibrium,
        torque_span=torque_span,
        delta=delta,
        torque_margin=t_margin.astype(points.dtype),
        certificate=cert,
        quality_status=q_status,
        torque_status=t_status,
        iterations=iterations,
    )


def staged(points: jax.Array, torque_test: str = "exact") -> bool:
    """Whether :func:`evaluate_one` of grasps like ``points`` runs as :func:`torque_stage` then
    :func:`quality_stage`: 3D, the exact torque test, float64 (float32's crossover polishes both
    LPs together, ``_polish_exact``)."""
    return points.shape[-1] == 3 and torque_test == "exact" and not tolerances(points.dtype).crossover


def _torque_columns(points, normals, mu, num_edges, tangents, contact, torsion) -> jax.Array:
    """``(K, 3)`` the torques about ``c_1`` of the torque test (the columns of contacts 2..n)."""
    normals = safe_normalize(normals)
    cols = about_first(points, normals, cone_edges(normals, mu, num_edges, tangents), contact, torsion)
    return cols.torque[cols.fixed:]


def torque_stage(points, normals, mu, num_edges: int, tangents=None, iterations=None, restarts=None,
                 contact: str = "hard", torsion=0.0) -> tuple[GraspEvaluation, Torques, jax.Array]:
    """The first stage of :func:`evaluate_one` (where :func:`staged`): the torque LP alone.

    About half of random grasps have all torques of contacts 2..n about ``c_1`` strictly inside an
    open half-space (``l* < -margin``, ``Torques.opposed``). Then no combination of those contacts'
    edges has zero torque, only contact 1's own edges balance, the quality LP's optimum is
    ``delta* = -1`` exactly (hard contacts, whose edges are ``z_1 + mu t``), and the certificate
    comes from the torque LP: the evaluation is complete without the quality LP. (Soft contacts
    never get there: contact 1's paired columns have opposite torsions.)

    Returns:
        ``(evaluation, torques, need)``: the evaluation where ``need`` is false, the torque test
        for :func:`quality_stage`, and whether the quality LP is needed.
    """
    tol = tolerances(points.dtype)
    tau = _torque_columns(points, normals, mu, num_edges, tangents, contact, torsion)
    t_lp = min_weight_lp(tau)
    (t_sol,) = solve(jax.lax.stop_gradient(t_lp), iterations=iterations, restarts=restarts)
    margin = _min_weight_margin(tau, t_sol)
    opposed = (contact == "hard") & (t_sol.status == Status.OPTIMAL) & (margin < -tol.margin)
    torques = _torque_test(tau, t_sol, _full_budget(t_lp, iterations), opposed)
    rows = 3 + 3 + 1
    out = _evaluation(points, 3, -jnp.ones((), points.dtype), jnp.asarray(Status.OPTIMAL, jnp.int8),
                      jnp.zeros(rows, points.dtype), jnp.zeros((), jnp.int32), *torques[:4])
    return out, torques, ~torques.opposed


def quality_stage(points, normals, mu, num_edges: int, torques: Torques, tangents=None, iterations=None,
                  restarts=None, contact: str = "hard", torsion=0.0) -> GraspEvaluation:
    """The second stage of :func:`evaluate_one` (where :func:`staged`): the quality LP, and the
    evaluation from it and the torque test of :func:`torque_stage`. Correct for every grasp: where
    the torques are opposed it reports what the first stage does (``delta = -1``)."""
    q_lp, cols = grasp_quality_lp(points, normals, mu, num_edges, tangents, contact, torsion)
    (q_sol,) = solve(jax.lax.stop_gradient(q_lp), iterations=iterations, consistent=True, restarts=restarts)
    delta, q_status, q_dual = _quality_value(q_lp, q_sol, iterations, forced=torques.opposed)
    iters = jnp.where(torques.opposed, 0, q_sol.iterations)
    return _evaluation(points, 3, delta, q_status, q_dual, iters, *torques[:4])


def evaluate_one(
    points: jax.Array,
    normals: jax.Array,
    mu,
    num_edges: int,
    torque_test: str = "exact",
    tangents: jax.Array | None = None,
    iterations: int | None = None,
    restarts: int | None = None,
    contact: str = "hard",
    torsion=0.0,
) -> GraspEvaluation:
    """Force-closure verdict, quality Q and certificate of one grasp.

    Args:
        points: ``(n, d)`` contact points; ``points[0]`` is the reference contact ``c_1``.
        normals: ``(n, d)`` outward unit normals.
        mu: friction coefficient.
        num_edges: edges per 3D friction cone.
        torque_test: ``"exact"`` (default) or ``"paper"`` (eq. 15 / 21).
        tangents: optional ``(n, 3)`` first tangent of each 3D contact frame.
        iterations: interior-point iterations (default from the problem size).
        restarts: float32 starting points an unfinished LP runs from (``lp.solve``; default all).
        contact, torsion: the contact model (``_contact``) and its torsional coefficient.
    """
    tol = tolerances(points.dtype)
    d = points.shape[-1]
    if staged(points, torque_test):
        _, torques, _ = torque_stage(points, normals, mu, num_edges, tangents, iterations, restarts, contact, torsion)
        return quality_stage(points, normals, mu, num_edges, torques, tangents, iterations, restarts, contact, torsion)
    q_lp, cols = grasp_quality_lp(points, normals, mu, num_edges, tangents, contact, torsion)
    tau = cols.torque[cols.fixed:]
    if d == 3 and torque_test == "exact":
        # float32: both LPs, then one crossover for both (``_polish_exact``).
        t_lp = min_weight_lp(tau)
        # Two loops, not one fused loop: the torque LP's block converges sooner, and its loop
        # stops then. The quality LP is feasible by construction.
        (q_sol,) = solve(jax.lax.stop_gradient(q_lp), iterations=iterations, consistent=True, restarts=restarts)
        (t_sol,) = solve(jax.lax.stop_gradient(t_lp), iterations=iterations, restarts=restarts)
        t_full = _full_budget(t_lp, iterations)
        q_full = _full_budget(q_lp, iterations)
        q_polished, t_polished = _polish_exact(
            q_lp, t_lp, q_sol, t_sol, (_pivots(tol, q_full), _pivots(tol, t_full)), q_full
        )
        forced = _open_half_space(t_polished)
        torque_span, t_margin, t_cert, t_status, _ = _torque_test(tau, t_polished[0], t_full, forced)
    else:
        (q_sol,) = solve(jax.lax.stop_gradient(q_lp), iterations=iterations, consistent=True, restarts=restarts)
        q_polished, forced = None, False
        if d == 2:
            torque_span, t_margin, t_cert = _exact_torque_2d(tau)
            if torque_test == "paper":
                torque_span = paper_torque_test(tau)
        else:
            torque_span = paper_torque_test(tau)
            # No exact LP was solved: report the eq. (15) slack of the weakest axis as the margin.
            total_abs = jnp.sum(jnp.abs(tau), axis=0)
            slack = (total_abs - jnp.abs(jnp.sum(tau, axis=0))) / jnp.maximum(total_abs, tol.tiny)
            t_margin = jnp.min(slack)
            axis = jnp.argmin(slack)
            t_cert = jnp.sign(jnp.sum(tau, axis=0)[axis]) * jax.nn.one_hot(axis, 3, dtype=tau.dtype)
        t_status = jnp.asarray(Status.OPTIMAL, jnp.int8)

    # Unfinished after the full budget (in float32 about 1 quality LP in 1,000 random grasps): the
    # dual of its best iterate may still prove delta* < 0, i.e. no equilibrium, Q = 0 exactly.
    delta, q_status, q_dual = _quality_value(q_lp, q_sol, iterations, q_polished, forced)
    return _evaluation(points, tau.shape[-1], delta, q_status, q_dual, q_sol.iterations, torque_span, t_margin,
                       t_cert, t_status)


#: A grasp counts as settled out of equilibrium (:func:`out_of_equilibrium`) when weak duality
#: puts ``delta*`` below ``-SETTLED`` times the margin tolerance: far enough below the verdict's
#: threshold (``delta* > margin``) that :func:`evaluate_one`, whose ``delta`` is accurate to well
#: within 10 margins (float32: |dQ| < 7e-5 against a margin of 2e-5), reports the same.
SETTLED = 10.0


def quality_dual_one(points, normals, mu, num_edges: int, tangents=None, contact: str = "hard", torsion=0.0):
    """``(rows,)`` the dual vector of one grasp's quality LP (zeros where the LP is not solved to
    optimality): for :func:`out_of_equilibrium` on grasps near this one (the perturbations of a
    robust label)."""
    lp, _ = grasp_quality_lp(points, normals, mu, num_edges, tangents, contact, torsion)
    (sol,) = solve(jax.lax.stop_gradient(lp), consistent=True)
    y = jnp.where(sol.status == Status.OPTIMAL, sol.y, 0.0)
    return jnp.where(jnp.all(jnp.isfinite(y)), y, 0.0)


def out_of_equilibrium(points, normals, mu, num_edges: int, y, tangents=None, contact: str = "hard", torsion=0.0):
    """Whether the dual vector ``y`` (any: from :func:`quality_dual_one` of a nearby grasp) proves
    that one grasp is not in equilibrium, with no LP solved: the weak-duality bound
    :func:`quality_bound` of its quality LP is below ``-SETTLED`` margins. Then
    :func:`evaluate_one` would report it not in equilibrium, Q 0, not force-closure. ``False``
    proves nothing."""
    tol = tolerances(points.dtype)
    lp, _ = grasp_quality_lp(points, normals, mu, num_edges, tangents, contact, torsion)
    bound, slack = quality_bound(lp, jnp.asarray(y, points.dtype))
    return bound + slack < -SETTLED * tol.margin


def quality_one(points, normals, mu, num_edges: int, signed: bool = False, tangents=None, iterations=None,
                restarts=None, contact: str = "hard", torsion=0.0):
    """``(Q, LP status)`` of one grasp: Q is ``delta*`` of the quality LP, clipped at 0 unless
    ``signed``, with envelope theorem derivatives in ``points`` and ``normals``. ``restarts``,
    ``contact``, ``torsion``: see :func:`evaluate_one`."""
    lp, cols = grasp_quality_lp(points, normals, mu, num_edges, tangents, contact, torsion)
    (sol,) = solve(jax.lax.stop_gradient(lp), iterations=iterations, consistent=True, restarts=restarts)
    tol = tolerances(points.dtype)
    polished, forced = None, False
    if tol.crossover and points.shape[-1] == 3:
        # float32: the half-space round of evaluate (``_polish_exact``) needs the torque LP's
        # vertex; the crossover finds it from nothing (no interior-point loop for it here), with
        # the full budget only.
        t_lp = min_weight_lp(cols.torque[cols.fixed:])
        rows, cols = t_lp.A.shape
        zero = jnp.zeros((), points.dtype)
        nothing = LPSolution(jnp.zeros(cols, zero.dtype), jnp.zeros(rows, zero.dtype), zero,
                             jnp.asarray(Status.NOT_CONVERGED, jnp.int8), jnp.zeros((), jnp.int32), zero)
        full = _full_budget(lp, iterations)
        t_pivots = tol.crossover if full is True else jnp.where(full, tol.crossover, 0)
        polished, t_polished = _polish_exact(lp, t_lp, sol, nothing, (_pivots(tol, full), t_pivots), full)
        forced = _open_half_space(t_polished)
    delta, status, _ = _quality_value(lp, sol, iterations, polished, forced)
    ok = status == Status.OPTIMAL
    if signed:
        value = jnp.where(ok | (status == Status.BOUNDED), delta, 0.0)
    else:
        value = jnp.where(ok & (delta > tol.margin), delta, 0.0)
    return value, status


def min_weight_one(points, normals, mu, num_edges: int, origin, torque_scale, tangents=None, iterations=None,
                   contact: str = "hard", torsion=0.0):
    """``(l*, status)`` of the classical min-weight LP on all primitive wrenches of one grasp (of
    the contact model, ``_contact``), differentiable in ``points`` and ``normals`` (see
    :func:`min_weight_value`)."""
    normals = safe_normalize(normals)
    edges = cone_edges(normals, mu, num_edges, tangents)
    return min_weight_value(wrench_columns(points, normals, edges, contact, torsion, origin, torque_scale).wrenches,
                            iterations)


def min_weight_value(vectors: jax.Array, iterations=None, best_effort: bool = False, full=None, pivots=None,
                     warm=None, weight=0.0, solution: bool = False, skip=None) -> tuple[jax.Array, ...]:
    """``(l*, status)`` of :func:`min_weight_lp` on ``vectors: (K, D)``.

    ``l*`` is 0 when the vectors are rank deficient and ``-inf`` when the LP is infeasible. Its
    derivatives come from the envelope theorem on the LP's primal-dual pair (no iteration is
    differentiated), finite everywhere, zero where the value is a constant (0 or ``-inf``).
    ``best_effort``: see :func:`grasp_jax.lp.solve` (an unfinished LP gives its best iterate's value).
    ``full``: whether the vectors span R^D, where the caller knows it (no rank test here).
    ``pivots``: crossover pivots to a certified vertex (default ``tolerances(dtype).crossover``:
    none in float64, where the interior-point value is accurate to about 1e-8).
    ``warm, weight``: a warm start (:func:`grasp_jax.lp.solve`); ``solution``: also return the
    solution's :func:`grasp_jax.lp.warm_point`, to warm-start a nearby LP from. ``skip``: as
    :func:`grasp_jax.lp.solve` (the result is then meaningless).
    """
    lp = min_weight_lp(vectors)
    (sol,) = solve(jax.lax.stop_gradient(lp), iterations=iterations, best_effort=best_effort,
                   warm=None if warm is None else (warm,), weight=weight, skip=skip)
    if not best_effort:
        if pivots is None:
            pivots = _pivots(tolerances(vectors.dtype), _full_budget(lp, iterations))
        sol, _, _ = polish(lp, sol, pivots)
    if full is None:
        vectors_ = jax.lax.stop_gradient(vectors)
        full = _gram_rank3(vectors_)[0] if vectors.shape[1] == 3 else full_rank(vectors_)
    K = vectors.shape[0]
    value = 1.0 / K - optimal_value(lp, sol)
    margin = jnp.where(has_value(sol), value, jnp.where(sol.status == Status.INFEASIBLE, -jnp.inf, 0.0))
    out = (jnp.where(full, margin, 0.0), sol.status)
    return out + (warm_point(lp, sol),) if solution else out
