"""Crossover: from an interior-point solution to an optimal basis, with a certificate.

In float32 an interior-point method ends *near* the optimum (residuals near ``1e-6``, the
objective up to ``1e-4`` off along a badly conditioned face); a vertex solves one ``r x r`` system
``B x_B = b`` and carries its own proof of optimality. :func:`crossover` finds it from ``(x, y)``:

1. **Guess a basis**: columns ranked by reduced cost minus value, taken greedily among those at
   least ``INDEPENDENCE`` (relative) away from the span of those taken (Gram-Schmidt).
2. **Make it feasible**: the most negative basic column is replaced by one artificial column.
3. **Pivot**: Harris's two-pass ratio test, phase one then two, Dantzig's rule (Bland's after a
   degenerate pivot), dual pivots where needed; the basis inverse in product form.
4. **Certify** with a fresh inverse: primal and dual feasibility within ``tol``, no artificial
   weight, a nonsingular basis and a small backward error; an uncertified result is never used.

Dense arithmetic on ``r <= 7`` rows, rolled loops, no LAPACK; its accuracy: docs/guides/precision.md.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ._problem import Status

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
#: Reduced costs of a certified vertex: ``d_j >= -DUAL_FEASIBILITY`` times their rounding scale
#: (about 34 float32 roundoffs; the vertex is then optimal for an LP whose non-basic columns moved
#: by that much, and its value within ``DUAL_FEASIBILITY * |A| |y| * sum(x)`` of the optimum).
#: Looser than the pivots' :data:`FEASIBILITY`: ``y`` solves ``B^T y = c_B`` to about ``cond(B)``
#: roundoffs, and the same vertex of a basis of condition ~70 read ``d = -2.4e-7`` and
#: ``-1.02e-6`` of its scale in two compilations of one program (SSE4.2, a chunk of 256 grasps or
#: of 1,024): rejected in the second, its LP reported the interior-point value, 6e-4 off.
DUAL_FEASIBILITY = 4e-6
#: Smallest pivot element of the ratio test, relative to the largest entry of the column.
PIVOT = 1e-3
#: The ratio test's smallest pivot where no improving column has one of :data:`PIVOT` (an optimal
#: basis of condition 1e4 was out of reach of 16 random LPs in 100 otherwise).
SMALL_PIVOT = 1e-5
#: Entries of a pivot column (row) below this fraction of its largest are taken as zero.
TINY = 1e-9
#: Smallest pivot of the final basis inverse (columns of length about 1): below, the basis counts
#: as singular and the vertex is not certified. Above it, an ill-conditioned basis is certified when
#: the refined solves have a small backward error (:data:`BACKWARD`): then ``x_B`` and ``y`` are
#: the exact vertex of an LP whose data moved by a few roundoffs, and the value is within
#: ``|y| |dA| |x|`` of the optimum, whatever the basis's condition (a larger threshold on the
#: pivot alone would leave correct vertices of condition 1e4 uncertified).
CONDITION = 1e-6
#: Largest backward error of the refined solves ``B x_B = b`` and ``B^T y = c_B``, in units of the
#: roundoff times ``|B| |x_B| + |b|`` (resp. ``|B|^T |y| + |c_B|``).
BACKWARD = 64.0


#: Largest sensitivity of a certified value to its LP's rounding, :func:`sensitivity`, in units of
#: the unit roundoff: a vertex whose value moves by more than this many roundoffs when each entry of
#: ``A`` moves by one is the exact answer of a nearby LP but not a reliable one for this LP: random
#: grasps score 3-16, the ill-posed quality LPs of grasps whose torques lie in a half-space
#: (``tests/test_dtypes.py``) 730 and more, and their float32 vertex depends on the CPU's rounding.
#: 1e-5 / float32 eps.
SENSITIVE = 84.0


def sensitivity(A: jax.Array, x: jax.Array, y: jax.Array) -> jax.Array:
    """``|y|^T |A| |x|``: to first order, the change of the optimal value ``c.x`` when every entry of
    ``A`` moves by its own relative rounding (perturbation theory of the optimal basis: ``d(c.x) =
    -y^T dA x``), in units of that rounding. Large only where the optimal dual is large, i.e. the
    LP is ill-posed (close to one whose optimum jumps)."""
    return jnp.abs(y) @ (jnp.abs(A) @ jnp.abs(x))


def _inverse(B: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Inverse of a small square ``B`` by Gauss-Jordan elimination with partial pivoting.

    Row swaps are rank-one updates with one-hot vectors, so that under ``vmap`` the elimination is
    plain elementwise arithmetic; the loop over columns is rolled (``fori_loop``), which keeps the
    compiled program small (unrolled, the crossover doubled the compile time of ``evaluate``).
    Returns ``(inverse, smallest |pivot|)``.
    """
    r = B.shape[0]
    eye = jnp.eye(r, dtype=B.dtype)
    rows = jnp.arange(r)

    def eliminate(k, carry):
        M, smallest = carry
        e_k = (rows == k).astype(B.dtype)
        col = jnp.where(rows >= k, jnp.abs(M[:, :r] @ e_k), -1.0)
        e_p = jax.nn.one_hot(jnp.argmax(col), r, dtype=B.dtype)
        M = M + jnp.outer(e_k - e_p, e_p @ M - e_k @ M)  # swap rows k and p
        row_k = e_k @ M
        pivot = row_k[:r] @ e_k
        pivot_row = row_k / jnp.where(pivot == 0, 1.0, pivot)
        M = M - jnp.outer(M[:, :r] @ e_k - e_k, pivot_row)
        return M, jnp.minimum(smallest, jnp.abs(pivot))

    M, smallest = jax.lax.fori_loop(
        0, r, eliminate, (jnp.concatenate([B, eye], axis=1), jnp.full((), jnp.inf, B.dtype))
    )
    return M[:, r:], smallest


def _replace_column(Binv: jax.Array, column: jax.Array, row, apply) -> jax.Array:
    """The inverse of the basis whose column ``row`` is replaced by ``column`` (product form:
    row ``row`` of the new inverse is the old one over the pivot ``(Binv @ column)[row]``, the
    others lose their multiple of it). Unchanged where ``apply`` is false."""
    rows = jnp.arange(Binv.shape[0])
    pivot_col = Binv @ column
    pivot = jnp.sum(jnp.where(rows == row, pivot_col, 0.0))
    new_row = jnp.sum(jnp.where((rows == row)[:, None], Binv, 0.0), axis=0) / jnp.where(apply, pivot, 1.0)
    new = jnp.where((rows == row)[:, None], new_row, Binv - jnp.outer(pivot_col, new_row))
    return jnp.where(apply, new, Binv)


def _rounding(abs_A: jax.Array, c: jax.Array, y: jax.Array) -> jax.Array:
    """``(N,)`` scale of the rounding of the reduced costs ``c - A^T y``: ``|c| + |A|^T |y|``
    (``abs_A = |A|``, computed once)."""
    return jnp.abs(c) + abs_A.T @ jnp.abs(y)


def _select(idx: jax.Array, N: int, dtype) -> jax.Array:
    """``(N, r)`` one-hot matrix of the columns ``idx``: ``A @ P`` is ``A[:, idx]``, ``P @ v``
    scatters ``v`` to them (products, not gathers: under ``vmap`` gathers and scatters cost
    compile time as well as run time)."""
    return (jnp.arange(N)[:, None] == idx[None, :]).astype(dtype)


def _at(v: jax.Array, i) -> jax.Array:
    """``v[i]`` (along the first axis) by a one-hot product."""
    return jax.nn.one_hot(i, v.shape[0], dtype=v.dtype) @ v


def _initial_basis(A: jax.Array, score: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``r`` column indices, lowest ``score`` first among columns independent enough of those
    already chosen (Gram-Schmidt residual >= ``INDEPENDENCE`` of the column's length).

    Returns ``(indices, ok)``; ``ok`` is false when fewer than ``r`` such columns exist.
    """
    r, N = A.shape
    norms = jnp.sqrt(jnp.sum(A * A, axis=0))

    def choose(k, carry):
        R, chosen, idx, ok = carry
        rn = jnp.sqrt(jnp.sum(R * R, axis=0))
        eligible = (rn > INDEPENDENCE * norms) & ~chosen
        j = jnp.argmin(jnp.where(eligible, score, jnp.inf))
        ok = ok & jnp.any(eligible & (jnp.arange(N) == j))
        e_j = jax.nn.one_hot(j, N, dtype=A.dtype)
        q = (R @ e_j) / jnp.where(ok, rn @ e_j, 1.0)
        R = R - jnp.outer(q, q @ R)
        return R, chosen | (e_j > 0), jnp.where(jnp.arange(r) == k, j.astype(jnp.int32), idx), ok

    init = (A, jnp.zeros(N, bool), jnp.zeros(r, jnp.int32), jnp.ones((), bool))
    _, _, idx, ok = jax.lax.fori_loop(0, r, choose, init)
    return idx.astype(jnp.int32), ok


def crossover(A: jax.Array, b: jax.Array, c: jax.Array, x: jax.Array, y: jax.Array, pivots: int):
    """An optimal vertex of ``min c.x s.t. A x = b, x >= 0`` near the approximate solution ``(x, y)``.

    Args:
        A, b, c: one LP in standard form, ``A: (r, N)`` of full row rank, ``r`` small.
        x: ``(N,)`` approximate primal solution (zeros if unknown: then ``y`` alone guides).
        y: ``(r,)`` approximate dual solution.
        pivots: most simplex pivots (a Python or a traced integer).

    Returns:
        ``(x, y, certified)``: the vertex ``(N,)`` (negative rounding clipped to 0), its dual
        ``(r,)``, and whether it is certified optimal (then ``x`` and ``y`` are exact up to the
        rounding of one ``r x r`` solve). Where not certified, ``x`` and ``y`` are not meaningful.

    One function of the module docstring's four steps: they share the basis, its inverse and the
    pivot loop's state, which a split would pass through six-tuple returns.
    """
    r, N = A.shape
    dt = A.dtype
    # Rows scaled to unit length (the vertex is the same; the dual scales back at the end): the
    # min-weight LP's row of ones has length sqrt(K) + K, its torque rows 0.01 on a contact near
    # the first, and the initial basis found no 4 columns independent enough in the raw ones.
    rescale = 1.0 / jnp.maximum(jnp.sqrt(jnp.sum(A * A, axis=1)), jnp.finfo(dt).tiny)
    A, b, y = A * rescale[:, None], b * rescale, y / rescale
    idx, ok = _initial_basis(A, (c - A.T @ y) - x)

    # Step 2: an artificial column makes the basis primal feasible.
    B = A @ _select(idx, N, dt)
    Binv, _ = _inverse(B)
    xB = Binv @ b
    worst = jnp.argmin(xB)
    infeasible = _at(xB, worst) < -FEASIBILITY
    v = jnp.where(jnp.arange(r) == worst, 0.0, jnp.maximum(xB, 0.0))
    art = b - B @ v
    art = art / jnp.maximum(jnp.sqrt(art @ art), jnp.finfo(dt).tiny)
    A = jnp.concatenate([A, art[:, None]], axis=1)
    c = jnp.concatenate([c, jnp.zeros((1,), dt)])
    phase_one_costs = jnp.zeros(N + 1, dt).at[N].set(1.0)
    idx = jnp.where(infeasible & (jnp.arange(r) == worst), N, idx).astype(jnp.int32)
    rows = jnp.arange(r)
    abs_A = jnp.abs(A)
    Binv = _replace_column(Binv, art, worst, infeasible)

    # Step 3: pivots.
    def cond(state):
        k, _, _, done, _, _ = state
        return (k < pivots) & ~done

    def body(state):
        # The basis inverse is updated in product form (a fresh one each pivot cost a third of
        # the throughput): with Harris's ratio test no pivot is small, and step 4 certifies with
        # a fresh inverse.
        k, idx, Binv, _, bland, small = state
        # One step of iterative refinement on each solve undoes most of the update's drift.
        P = _select(idx, N + 1, dt)
        B = A @ P
        xB = Binv @ b
        xB = x_raw = xB + Binv @ (b - B @ xB)
        is_art = idx == N
        art_basic = jnp.any(is_art)
        x_art = jnp.sum(jnp.where(is_art, xB, 0.0))
        # Phase one while the artificial column carries weight: minimize that weight.
        phase_one = art_basic & (x_art > FEASIBILITY)
        costs = jnp.where(phase_one, phase_one_costs, c)
        cB = costs @ P
        y = Binv.T @ cB
        y = y + Binv.T @ (cB - B.T @ y)
        d = costs - A.T @ y
        # Basic columns have d = 0 up to rounding, and the artificial column never enters.
        basic = jnp.any(jnp.arange(N + 1)[None, :] == idx[:, None], axis=0)
        d = jnp.where(basic | (jnp.arange(N + 1) == N), 0.0, d)
        scale = _rounding(abs_A, costs, y)
        improving = d < -0.25 * FEASIBILITY * scale  # stricter than step 4: it is refined
        # The whole tableau (r x (N + 1), cheap at r <= 7): the ratio test of every column.
        T = Binv @ A
        # Harris's two-pass ratio test, per column: the largest step that leaves every
        # x_B >= -FEASIBILITY / 2, then among the rows that block within it the one of largest
        # entry, the pivot (a pivot of 1e-6 made a basis of condition 1e7, whose float32 solves are
        # noise; entries below PIVOT of the column's largest are taken as zero).
        xB = jnp.maximum(xB, 0.0)
        big = jnp.max(jnp.abs(T), axis=0)

        def blocking_rows(pivot):
            positive = T > pivot * big
            safe = jnp.where(positive, T, 1.0)
            step = jnp.min(jnp.where(positive, (xB[:, None] + 0.5 * FEASIBILITY) / safe, jnp.inf), axis=0)
            return positive & (xB[:, None] / safe <= step)

        # Only columns with a blocking row enter: a column without one is a ray along which the
        # rounding of x_B, not the LP, decreases the cost (phase one stopped there with the
        # artificial column at weight 3e-3 on two quadrilateral grasps). Where no improving column
        # has one, the next pass of the loop tries smaller pivots (``small``, SMALL_PIVOT): an
        # ill-conditioned optimal basis is reached only through them, and the certificate (step 4)
        # judges the result.
        blocking = blocking_rows(jnp.where(small, SMALL_PIVOT, PIVOT))
        eligible = improving & jnp.any(blocking, axis=0)
        # Dantzig's rule (in units of each reduced cost's rounding); after a degenerate pivot,
        # Bland's (the first eligible column, and below the first basic column), which cannot
        # cycle: the vertices of delta* = -1 are degenerate, and Dantzig's rule cycled there.
        q = jnp.where(bland, jnp.argmax(eligible), jnp.argmin(jnp.where(eligible, d / scale, jnp.inf)))
        optimal = ~jnp.any(improving)
        e_q = jax.nn.one_hot(q, N + 1, dtype=dt)
        delta, block_q = T @ e_q, blocking @ e_q > 0
        i = jnp.where(bland, jnp.argmin(jnp.where(block_q, idx, N + 1)), jnp.argmax(jnp.where(block_q, delta, -jnp.inf)))
        degenerate = _at(xB, i) <= FEASIBILITY * _at(delta, i)
        primal = jnp.any(eligible)
        # Dual feasible but not primal feasible (the rounding of a long path, or an artificial
        # column forced out at a small weight): a dual simplex pivot on the most negative row.
        i_d = jnp.argmin(x_raw)
        i_a = jnp.argmax(is_art)
        alpha, alpha_a = _at(T, i_d), _at(T, i_a)
        # Harris's test again, on the reduced costs: the largest step that leaves every
        # d_j >= -FEASIBILITY / 2 (in units of its rounding), then the largest |alpha_j| within it.
        entering = (alpha < -TINY * jnp.max(jnp.abs(alpha))) & ~basic & (jnp.arange(N + 1) < N)
        safe_a = jnp.where(entering, -alpha, 1.0)
        d_plus = jnp.maximum(d, 0.0)
        step_d = jnp.min(jnp.where(entering, (d_plus + 0.5 * FEASIBILITY * scale) / safe_a, jnp.inf))
        q_d = jnp.argmax(jnp.where(entering & (d_plus / safe_a <= step_d), -alpha, -jnp.inf))
        dual = optimal & ~phase_one & (_at(x_raw, i_d) < -FEASIBILITY) & jnp.any(entering)
        # An artificial column left at weight ~0 after phase one is driven out first, by the
        # nonbasic column of largest entry in its row (a degenerate pivot: nothing moves). Left in,
        # the next pivot could lift its weight again and phase one undo it (seen: a cycle of two).
        alpha_a = jnp.abs(alpha_a)
        candidates = ~basic & (jnp.arange(N + 1) < N)
        q_a = jnp.argmax(jnp.where(candidates, alpha_a, -1.0))
        drive_out = art_basic & ~phase_one & (_at(alpha_a, q_a) > PIVOT * jnp.max(alpha_a))
        row = jnp.where(drive_out, i_a, jnp.where(primal, i, i_d))
        column = jnp.where(drive_out, q_a, jnp.where(primal, q, q_d))
        new_idx = jnp.where(rows == row, column.astype(idx.dtype), idx)
        stop = ~(primal | dual | drive_out)
        again = stop & ~small & jnp.any(improving)  # with smaller pivots, before stopping
        # Row ``row`` of the new inverse is the old one over the pivot; the others lose their
        # multiple of it.
        new_Binv = _replace_column(Binv, A @ jax.nn.one_hot(column, N + 1, dtype=dt), row, ~stop)
        return (k + 1, jnp.where(stop, idx, new_idx), new_Binv, stop & ~again,
                jnp.where(again, bland, (primal & degenerate) | drive_out), again)

    state = (jnp.zeros((), jnp.int32), idx, Binv, ~ok, jnp.zeros((), bool), jnp.zeros((), bool))
    _, idx, _, _, _, _ = jax.lax.while_loop(cond, body, state)

    # Step 4: certify with a fresh inverse, one step of iterative refinement on each solve.
    P = _select(idx, N + 1, dt)
    B = A @ P
    Binv, smallest = _inverse(B)
    xB = Binv @ b
    xB = xB + Binv @ (b - B @ xB)
    cB = c @ P
    y = Binv.T @ cB
    y = y + Binv.T @ (cB - B.T @ y)
    d = c - A.T @ y
    eps = jnp.finfo(dt).eps
    abs_B = jnp.abs(B)
    primal_ok = jnp.all(jnp.abs(b - B @ xB) <= BACKWARD * eps * (abs_B @ jnp.abs(xB) + jnp.abs(b)))
    dual_ok = jnp.all(jnp.abs(cB - B.T @ y) <= BACKWARD * eps * (abs_B.T @ jnp.abs(y) + jnp.abs(cB)))
    certified = (
        ok
        & (smallest > CONDITION)
        & primal_ok
        & dual_ok
        & jnp.all(xB >= -FEASIBILITY)
        & jnp.all((d >= -DUAL_FEASIBILITY * _rounding(abs_A, c, y))[:N])
        & (jnp.sum(jnp.where(idx == N, xB, 0.0)) <= FEASIBILITY)  # an artificial basic at 0 is harmless
        & jnp.all(jnp.isfinite(xB))
        & jnp.all(jnp.isfinite(y))
    )
    x = (P @ jnp.maximum(xB, 0.0))[:N]
    return x, y * rescale, certified


def polish(lp, sol, pivots: int):
    """:func:`crossover` applied to an :class:`~grasp_jax._lp.LPSolution` of ``lp``.

    Where the vertex is certified, the solution becomes that vertex with status ``OPTIMAL`` (also
    an unfinished or an "infeasible" one: the certificate does not care how the basis was found);
    elsewhere it is left as it was. ``pivots = 0`` returns ``sol`` unchanged.

    Returns:
        ``(solution, certified, y)``: ``y`` is the crossover's last dual vector, certified or not
        (for a weak-duality bound such as ``_closure.quality_bound``, valid for any ``y``).
    """
    if isinstance(pivots, int) and not pivots:
        return sol, jnp.zeros((), bool), sol.y
    lp = jax.lax.stop_gradient(lp)
    return as_solution(lp, sol, *crossover(lp.A, lp.b, lp.c, sol.x, sol.y, pivots))


def _padded(lp, x, y, r: int, N: int):
    """``lp`` and its ``(x, y)`` embedded in an LP of ``r`` rows and ``N`` columns with the same
    vertices: each added row fixes an added unit column at 1, the other added columns are zero
    (never eligible for a basis, never improving)."""
    A, b, c = lp
    r0, N0 = A.shape
    extra = r - r0
    dt = A.dtype
    A = jnp.block([[A, jnp.zeros((r0, N - N0), dt)],
                   [jnp.zeros((extra, N0), dt), jnp.eye(extra, N - N0, dtype=dt)]])
    one = jnp.ones(extra, dt)
    return (A, jnp.concatenate([b, one]), jnp.concatenate([c, jnp.zeros(N - N0, dt)]),
            jnp.concatenate([x, one, jnp.zeros(N - N0 - extra, dt)]), jnp.concatenate([y, jnp.zeros(extra, dt)]))


def stacked(lps: tuple, xs: tuple, ys: tuple, pivots) -> list:
    """:func:`crossover` of several LPs in one vmapped call: the smaller ones are padded to the
    largest and all pivot together (one copy of the crossover in the program instead of one per
    LP: it is a fifth of the compile time of a float32 chunk program). ``pivots``: a Python
    integer per LP, or an ``(len(lps),)`` integer array. Returns ``(x, y, certified)`` per LP."""
    r = max(lp.A.shape[0] for lp in lps)
    N = max(lp.A.shape[1] + r - lp.A.shape[0] for lp in lps)
    padded = [_padded(lp, x, y, r, N) for lp, x, y in zip(lps, xs, ys)]
    budget = pivots if isinstance(pivots, jax.Array) else jnp.stack([jnp.asarray(k, jnp.int32) for k in pivots])
    X, Y, C = jax.vmap(crossover)(*(jnp.stack(parts) for parts in zip(*padded)), budget)
    return [(X[k, : lp.A.shape[1]], Y[k, : lp.A.shape[0]], C[k]) for k, lp in enumerate(lps)]


def as_solution(lp, sol, x, y, certified):
    """``sol`` replaced by the vertex ``(x, y)`` where it is certified (status ``OPTIMAL``, also for
    an unfinished or an "infeasible" one: the certificate does not care how the basis was found).
    Returns :func:`polish`'s triple."""
    # float32's Farkas test erred on a torque LP of margin 2.4e-3 (box, 3 fingers).
    new = sol._replace(
        x=jnp.where(certified, x, sol.x),
        y=jnp.where(certified, y, sol.y),
        value=jnp.where(certified, lp.c @ x, sol.value),
        status=jnp.where(certified, Status.OPTIMAL, sol.status).astype(sol.status.dtype),
    )
    return new, certified, y

