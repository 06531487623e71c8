"""Crossover: from an interior-point solution to an optimal basis, with a certificate.

In float32 an interior-point method ends *near* the optimum: its primal and dual residuals stop
near ``1e-6`` relative, and along a badly conditioned optimal face the objective can still be
``1e-4`` off (``experiments/float32_accuracy.py``: 8 to 312 grasps in 100,000 had
``|Q32 - Q64| > 1e-4`` before this module). A vertex is another matter: its values solve one
``r x r`` system, ``B x_B = b``, whose rounding is ``cond(B)`` times the unit roundoff, and it
carries its own proof of optimality, ``x_B >= 0`` and reduced costs ``c - A^T y >= 0``.

:func:`crossover` finds that vertex from the interior-point solution ``(x, y)``:

1. **Guess a basis.** Columns are ranked by ``d_j - x_j`` (reduced cost minus value: basic
   columns have ``d = 0, x > 0``, the others ``d > 0, x = 0``) and taken greedily, lowest first,
   among those at least ``INDEPENDENCE`` (relative) away from the span of the columns already
   taken (Gram-Schmidt), so the basis is well conditioned.
2. **Make it feasible.** If ``x_B = B^{-1} b`` has negative entries, the most negative basic column
   is replaced by one artificial column ``b - B v`` (``v = max(x_B, 0)`` without that entry), which
   makes the basis feasible.
3. **Pivot.** Primal simplex pivots (Dantzig's rule, Harris's ratio test): phase one (minimize
   the artificial weight) while the artificial column carries weight, then phase two (the LP's
   costs) until every reduced cost is ``>= -tol``; a dual simplex pivot where the basis is then
   dual but not primal feasible. (A big-M cost was tried first: with ``M = 100`` it was too small on barely
   feasible grasps and already spoiled float32 reduced costs by ``M`` times the roundoff.)
4. **Certify** with a fresh inverse: ``x_B >= -tol``, reduced costs ``>= -tol``, no artificial
   weight, and the basis inverse well conditioned.

On the 59 grasps of 20,000 (sphere, 4 fingers, 25 edges) whose float32 Q missed float64's by more
than 1e-4, 57 were certified, all within 3.1e-7 of float64, and 10 pivots did what 40 did.

Everything is dense arithmetic on ``r <= 7`` rows, unrolled, with one-hot products instead of
gathers and scatters: under ``jax.vmap`` every problem of a batch pivots in lock step, and no
LAPACK call is made (see ``_batch``: LAPACK kernels and several CPU devices do not mix).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

#: A column enters the initial basis only if its component orthogonal to the columns already
#: chosen is at least this fraction of its length (0.1 rejected neighbouring cone edges, which the
#: optimum of a 25-edge cone often needs; 0.02 certified 57 of 59 hard grasps).
INDEPENDENCE = 0.02
#: Feasibility tolerance of a certified vertex: ``x_B >= -FEASIBILITY`` (the LPs of grasp_jax have
#: columns and right-hand sides of length about 1), and reduced costs ``d_j >= -FEASIBILITY`` times
#: the scale of their rounding, ``|c_j| + |A_j|.|y|`` (duals reach 10 in the quality LP: an
#: absolute 1e-6 rejected correct vertices whose ``d`` was ``-3e-6`` of rounding). About 8 float32
#: roundoffs; a vertex so certified has ``c.x`` within ``FEASIBILITY * sum(x) * max scale`` of
#: the optimum.
FEASIBILITY = 1e-6
#: Smallest pivot element of the ratio test, relative to the largest entry of the column.
PIVOT = 1e-3
#: Smallest pivot of the final basis inverse (columns of length about 1): below, the vertex's
#: rounding could exceed what the certificate promises, and it is not certified.
CONDITION = 1e-4


def _inverse(B: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Inverse of a small square ``B`` by Gauss-Jordan elimination with partial pivoting, unrolled.

    Row swaps are rank-one updates with one-hot vectors, so that under ``vmap`` the elimination is
    plain elementwise arithmetic. Returns ``(inverse, smallest |pivot|)``.
    """
    r = B.shape[0]
    eye = jnp.eye(r, dtype=B.dtype)
    M = jnp.concatenate([B, eye], axis=1)
    rows = jnp.arange(r)
    smallest = jnp.full((), jnp.inf, B.dtype)
    for k in range(r):
        col = jnp.where(rows >= k, jnp.abs(M[:, k]), -1.0)
        e_p = jax.nn.one_hot(jnp.argmax(col), r, dtype=B.dtype)
        row_p = e_p @ M
        M = M + jnp.outer(eye[k] - e_p, row_p - M[k])  # swap rows k and p
        pivot = M[k, k]
        smallest = jnp.minimum(smallest, jnp.abs(pivot))
        pivot_row = M[k] / jnp.where(pivot == 0, 1.0, pivot)
        M = M - jnp.outer(M[:, k] - eye[k], pivot_row)
    return M[:, r:], smallest


def _rounding(A: jax.Array, c: jax.Array, y: jax.Array) -> jax.Array:
    """``(N,)`` scale of the rounding of the reduced costs ``c - A^T y``: ``|c| + |A|^T |y|``."""
    return jnp.abs(c) + jnp.abs(A).T @ jnp.abs(y)


def _initial_basis(A: jax.Array, score: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``r`` column indices, lowest ``score`` first among columns independent enough of those
    already chosen (Gram-Schmidt residual >= ``INDEPENDENCE`` of the column's length).

    Returns ``(indices, ok)``; ``ok`` is false when fewer than ``r`` such columns exist.
    """
    r, N = A.shape
    norms = jnp.sqrt(jnp.sum(A * A, axis=0))
    R = A
    chosen = jnp.zeros(N, bool)
    idx = []
    ok = jnp.ones((), bool)
    for _ in range(r):
        rn = jnp.sqrt(jnp.sum(R * R, axis=0))
        eligible = (rn > INDEPENDENCE * norms) & ~chosen
        j = jnp.argmin(jnp.where(eligible, score, jnp.inf))
        ok = ok & eligible[j]
        e_j = jax.nn.one_hot(j, N, dtype=A.dtype)
        q = (R @ e_j) / jnp.where(ok, rn[j], 1.0)
        R = R - jnp.outer(q, q @ R)
        chosen = chosen | (e_j > 0)
        idx.append(j)
    return jnp.stack(idx).astype(jnp.int32), ok


def crossover(A: jax.Array, b: jax.Array, c: jax.Array, x: jax.Array, y: jax.Array, pivots: int):
    """An optimal vertex of ``min c.x s.t. A x = b, x >= 0`` near the approximate solution ``(x, y)``.

    Args:
        A, b, c: one LP in standard form, ``A: (r, N)`` of full row rank, ``r`` small.
        x: ``(N,)`` approximate primal solution (zeros if unknown: then ``y`` alone guides).
        y: ``(r,)`` approximate dual solution.
        pivots: most primal simplex pivots.

    Returns:
        ``(x, y, certified)``: the vertex ``(N,)`` (negative rounding clipped to 0), its dual
        ``(r,)``, and whether it is certified optimal (then ``x`` and ``y`` are exact up to the
        rounding of one ``r x r`` solve). Where not certified, ``x`` and ``y`` are not meaningful.
    """
    r, N = A.shape
    dt = A.dtype
    idx, ok = _initial_basis(A, (c - A.T @ y) - x)

    # Step 2: an artificial column makes the basis primal feasible.
    B = jnp.take(A, idx, axis=1)
    Binv, _ = _inverse(B)
    xB = Binv @ b
    worst = jnp.argmin(xB)
    infeasible = xB[worst] < -FEASIBILITY
    v = jnp.where(jnp.arange(r) == worst, 0.0, jnp.maximum(xB, 0.0))
    art = b - B @ v
    art = art / jnp.maximum(jnp.sqrt(art @ art), jnp.finfo(dt).tiny)
    A = jnp.concatenate([A, art[:, None]], axis=1)
    c = jnp.concatenate([c, jnp.zeros((1,), dt)])
    phase_one_costs = jnp.zeros(N + 1, dt).at[N].set(1.0)
    idx = jnp.where(infeasible & (jnp.arange(r) == worst), N, idx).astype(jnp.int32)
    rows = jnp.arange(r)

    # Step 3: pivots.
    def cond(state):
        k, _, done = state
        return (k < pivots) & ~done

    def body(state):
        # A fresh inverse each pivot: product-form updates drift by 1e-5 in float32 after a few
        # small pivots, which is the accuracy this module is for.
        k, idx, _ = state
        Binv, _ = _inverse(jnp.take(A, idx, axis=1))
        xB = x_raw = Binv @ b
        is_art = idx == N
        art_basic = jnp.any(is_art)
        x_art = jnp.sum(jnp.where(is_art, xB, 0.0))
        # Phase one while the artificial column carries weight: minimize that weight.
        phase_one = art_basic & (x_art > FEASIBILITY)
        costs = jnp.where(phase_one, phase_one_costs, c)
        y = Binv.T @ jnp.take(costs, idx)
        d = costs - A.T @ y
        # Basic columns have d = 0 up to rounding, and the artificial column never enters.
        basic = jnp.any(jnp.arange(N + 1)[None, :] == idx[:, None], axis=0)
        d = jnp.where(basic | (jnp.arange(N + 1) == N), 0.0, d)
        scale = _rounding(A, costs, y)
        q = jnp.argmin(d / scale)  # Dantzig's rule, in units of each reduced cost's rounding
        optimal = d[q] >= -0.25 * FEASIBILITY * scale[q]  # stricter than step 4: it is refined
        delta = Binv @ A[:, q]
        # Harris's two-pass ratio test: the largest step that leaves every x_B >= -FEASIBILITY / 2,
        # then among the rows that block within it the one of largest pivot (a pivot of 1e-6 made
        # a basis of condition 1e7, whose float32 solves are noise).
        positive = delta > PIVOT * jnp.max(jnp.abs(delta))
        safe = jnp.where(positive, delta, 1.0)
        xB = jnp.maximum(xB, 0.0)
        step = jnp.min(jnp.where(positive, (xB + 0.5 * FEASIBILITY) / safe, jnp.inf))
        blocking = positive & (xB / safe <= step)
        # An artificial column left at weight 0 leaves on the first pivot that would move it.
        art_leaves = is_art & ~phase_one & (jnp.abs(delta) > PIVOT * jnp.max(jnp.abs(delta)))
        i = jnp.where(jnp.any(art_leaves), jnp.argmax(art_leaves), jnp.argmax(jnp.where(blocking, delta, -jnp.inf)))
        primal = ~optimal & (jnp.any(blocking) | jnp.any(art_leaves))
        # Dual feasible but not primal feasible (the rounding of a long path, or an artificial
        # column forced out at a small weight): a dual simplex pivot on the most negative row.
        i_d = jnp.argmin(x_raw)
        alpha = Binv[i_d] @ A
        entering = (alpha < -FEASIBILITY) & ~basic & (jnp.arange(N + 1) < N)
        q_d = jnp.argmin(jnp.where(entering, jnp.maximum(d, 0.0) / -jnp.where(entering, alpha, -1.0), jnp.inf))
        dual = optimal & ~phase_one & (x_raw[i_d] < -FEASIBILITY) & jnp.any(entering)
        new_idx = jnp.where(rows == jnp.where(primal, i, i_d), jnp.where(primal, q, q_d).astype(idx.dtype), idx)
        stop = ~(primal | dual)
        return k + 1, jnp.where(stop, idx, new_idx), stop

    _, idx, _ = jax.lax.while_loop(cond, body, (jnp.zeros((), jnp.int32), idx, ~ok))

    # Step 4: certify with a fresh inverse, one step of iterative refinement on each solve.
    B = jnp.take(A, idx, axis=1)
    Binv, smallest = _inverse(B)
    xB = Binv @ b
    xB = xB + Binv @ (b - B @ xB)
    cB = jnp.take(c, idx)
    y = Binv.T @ cB
    y = y + Binv.T @ (cB - B.T @ y)
    d = c - A.T @ y
    certified = (
        ok
        & (smallest > CONDITION)
        & jnp.all(xB >= -FEASIBILITY)
        & jnp.all((d >= -FEASIBILITY * _rounding(A, c, y))[:N])
        & (jnp.sum(jnp.where(idx == N, xB, 0.0)) <= FEASIBILITY)  # an artificial basic at 0 is harmless
        & jnp.all(jnp.isfinite(xB))
        & jnp.all(jnp.isfinite(y))
    )
    x = jnp.zeros(N + 1, dt).at[idx].set(jnp.maximum(xB, 0.0))[:N]
    return x, y, certified


def polish(lp, sol, pivots: int):
    """:func:`crossover` applied to an :class:`~grasp_jax._lp.LPSolution` of ``lp``.

    Where the vertex is certified, the solution becomes that vertex with status ``OPTIMAL`` (also
    an unfinished one: the certificate does not care how the basis was found); elsewhere it is
    left as it was. An infeasible LP is left alone. ``pivots = 0`` returns ``sol`` unchanged.

    Returns:
        ``(solution, certified, y)``: ``y`` is the crossover's last dual vector, certified or not
        (for a weak-duality bound such as ``_closure.quality_bound``, valid for any ``y``).
    """
    from ._lp import Status

    if not pivots:
        return sol, jnp.zeros((), bool), sol.y
    lp = jax.lax.stop_gradient(lp)
    x, y, certified = crossover(lp.A, lp.b, lp.c, sol.x, sol.y, pivots)
    certified = certified & (sol.status != Status.INFEASIBLE)
    new = sol._replace(
        x=jnp.where(certified, x, sol.x),
        y=jnp.where(certified, y, sol.y),
        value=jnp.where(certified, lp.c @ x, sol.value),
        status=jnp.where(certified, Status.OPTIMAL, sol.status).astype(sol.status.dtype),
    )
    return new, certified, y
