"""A small dense linear-programming solver in pure JAX, written for one problem.

Standard form::

    minimize  c . x   subject to   A x = b,   x >= 0,          A: (rows, cols)

solved by a homogeneous self-dual interior-point method with Mehrotra's predictor-corrector
(Xu, Hung and Ye 1996; Andersen and Andersen 2000). The homogeneous model certifies infeasibility
as reliably as it finds optima, which matters here: a third of the grasps one samples give an
infeasible LP. Every problem of grasp_jax has at most 7 rows, so each iteration is a 7x7 Cholesky
factorization, unrolled into scalar operations: under ``jax.vmap`` every scalar becomes a vector
over the batch, the batch is the fast axis, and thousands of problems advance in lock step.

The iteration count is fixed (``jit`` friendly); a problem that has converged or been certified
infeasible is frozen with ``jnp.where`` so that further iterations cannot spoil it.

Differentiate an optimal value with :func:`optimal_value`, which applies the envelope theorem to
the primal-dual pair instead of unrolling the iterations.
"""

from __future__ import annotations

import enum
from typing import NamedTuple

import jax
import jax.numpy as jnp

from ._constants import default_iterations, tolerances


class Status(enum.IntEnum):
    """Outcome of one LP (stored per problem as ``int8``)."""

    OPTIMAL = 0
    INFEASIBLE = 1
    NOT_CONVERGED = 2
    #: Only with ``solve(..., best_effort=True)``: unfinished after the budget, and ``x, y`` are
    #: its best iterate (an approximate optimum, good for a gradient step, not for a verdict).
    APPROXIMATE = 3
    #: Set by the caller of :func:`solve`, never by it: unfinished after the full budget, but the
    #: dual of its best iterate bounds the optimum by weak duality, which settles the question the
    #: LP was solved for (grasp_jax: the quality LP's ``delta* < 0``, not in equilibrium, the
    #: reported value is that bound; the torque LP's ``l* <= 0``, no positive span, reported 0).
    BOUNDED = 4

    @property
    def message(self) -> str:
        return {
            Status.OPTIMAL: "optimal",
            Status.INFEASIBLE: "infeasible (certified by the homogeneous model)",
            Status.NOT_CONVERGED: "not converged in the iteration budget; values are not reliable",
            Status.APPROXIMATE: "not converged in the iteration budget; the best iterate is reported",
            Status.BOUNDED: "not converged in the iteration budget, but a dual bound settles the verdict",
        }[self]


class LP(NamedTuple):
    """One LP in standard form. ``A: (rows, cols)``, ``b: (rows,)``, ``c: (cols,)``."""

    A: jax.Array
    b: jax.Array
    c: jax.Array


class LPSolution(NamedTuple):
    """Result of :func:`solve` for one LP.

    Attributes:
        x: ``(cols,)`` primal solution (meaningful when ``status == OPTIMAL``; when
            ``NOT_CONVERGED``, the best iterate's).
        y: ``(rows,)`` dual solution; when ``status == INFEASIBLE`` a Farkas certificate scaled so
            that ``b . y = 1`` and ``A^T y <= 0`` (up to tolerance); when ``NOT_CONVERGED`` the
            dual part of the best iterate (for a weak-duality bound, not for a value).
        value: ``c . x`` (0 unless optimal).
        status: ``int8`` :class:`Status`.
        iterations: iterations actually taken before freezing.
        residual: largest relative primal/dual residual and gap at the end.
    """

    x: jax.Array
    y: jax.Array
    value: jax.Array
    status: jax.Array
    iterations: jax.Array
    residual: jax.Array


class _State(NamedTuple):
    x: jax.Array
    y: jax.Array
    s: jax.Array
    tau: jax.Array
    kappa: jax.Array
    done: jax.Array
    iterations: jax.Array
    # The iterate with the smallest residual so far, scaled by tau (see ``_finish``).
    best_x: jax.Array
    best_y: jax.Array
    best_residual: jax.Array
    # Restarts (float32, ``solve``): the starting points run so far, iterations from the current
    # one, and whether a step broke down (a non-finite direction froze the problem).
    attempt: jax.Array
    local: jax.Array
    broken: jax.Array
    # The residuals of the iterate (``_residuals``): each step judges the iterate it makes
    # (``_measured``) and the next step's direction starts from them.
    rp: jax.Array
    rd: jax.Array


def _cholesky(M: jax.Array, pivot_tol: float, huge: float) -> list[list[jax.Array]]:
    """Unrolled lower Cholesky factor of a small SPD matrix as nested lists of scalars.

    A pivot below ``pivot_tol`` times its diagonal entry marks a degenerate direction (rank
    deficient ``A`` or a variable at its bound); it is replaced by ``huge`` so that the solve
    returns ~0 along it instead of failing.
    """
    k = M.shape[0]
    L: list[list[jax.Array]] = [[None] * k for _ in range(k)]  # type: ignore[list-item]
    for j in range(k):
        d = M[j, j] - sum((L[j][p] * L[j][p] for p in range(j)), start=jnp.zeros((), M.dtype))
        bad = d <= pivot_tol * jnp.abs(M[j, j]) + jnp.finfo(M.dtype).tiny
        ljj = jnp.sqrt(jnp.where(bad, huge, d))
        L[j][j] = ljj
        inv = 1.0 / ljj
        for i in range(j + 1, k):
            off = M[i, j] - sum((L[i][p] * L[j][p] for p in range(j)), start=jnp.zeros((), M.dtype))
            L[i][j] = off * inv
    return L


def _huge(dtype) -> float:
    """The value that replaces a degenerate Cholesky pivot."""
    return 1e64 if dtype == jnp.float64 else 1e30


def _cho_solve(L: list[list[jax.Array]], r: jax.Array) -> jax.Array:
    k = len(L)
    z: list[jax.Array] = []
    for i in range(k):
        acc = r[i] - sum((L[i][p] * z[p] for p in range(i)), start=jnp.zeros((), r.dtype))
        z.append(acc / L[i][i])
    out: list[jax.Array] = [None] * k  # type: ignore[list-item]
    for i in reversed(range(k)):
        acc = z[i] - sum((L[p][i] * out[p] for p in range(i + 1, k)), start=jnp.zeros((), r.dtype))
        out[i] = acc / L[i][i]
    return jnp.stack(out)


def _max_step(v: jax.Array, dv: jax.Array) -> jax.Array:
    """Largest ``alpha`` with ``v + alpha dv >= 0`` (``inf`` when ``dv >= 0``)."""
    ratio = jnp.where(dv < 0, -v / jnp.where(dv < 0, dv, -1.0), jnp.inf)
    return jnp.min(ratio)


def _init(lp: LP, scale=1.0) -> _State:
    """The starting point ``x = s = scale``, ``tau = 1``, ``kappa = scale^2``."""
    rows, cols = lp.A.shape
    dt = lp.A.dtype
    return _State(
        x=jnp.full(cols, scale, dt),
        y=jnp.zeros(rows, dt),
        s=jnp.full(cols, scale, dt),
        tau=jnp.ones((), dt),
        kappa=jnp.full((), scale * scale, dt),
        done=jnp.zeros((), bool),
        iterations=jnp.zeros((), jnp.int32),
        best_x=jnp.zeros(cols, dt),
        best_y=jnp.zeros(rows, dt),
        best_residual=jnp.full((), jnp.inf, dt),
        attempt=jnp.zeros((), jnp.int32),
        local=jnp.zeros((), jnp.int32),
        broken=jnp.zeros((), bool),
        rp=jnp.zeros(rows, dt),
        rd=jnp.zeros(cols, dt),
    )


def _inconsistency(lp: LP) -> tuple[jax.Array, jax.Array]:
    """A Farkas certificate in the left null space of ``A``: ``A^T y = 0``, ``b . y = 1``.

    It exists iff ``b`` is not in the range of ``A`` (rank-deficient ``A``, inconsistent ``b``;
    for example all contacts of a grasp on one flat face). The interior-point iterations cannot
    find it: the normal matrix is singular along exactly that direction, and :func:`_cholesky`
    replaces its pivot. So it is read off up front from the least-squares residual of ``A x = b``,
    ``r = b - A A^T (G + e I)^{-1} b = e (G + e I)^{-1} b`` with ``G = A A^T`` and ``e`` the rank
    tolerance times the mean eigenvalue of ``G``: ``r`` is ``b``'s component in the null space of
    ``A^T`` up to ``O(e / lambda)`` on the rest. It certifies when ``|A^T r| <= sqrt(rank) |A| |r|``,
    i.e. when ``r`` lies along eigenvalues below the rank tolerance. The rows are scaled to unit
    length first (neither the rank nor the range changes): the min-weight LP's row of ones, with
    its ``-K``, otherwise sets the tolerance, and float32 certified the torques of a 3-finger box
    grasp inconsistent whose min-weight margin is 8e-3. Returns ``(certified, y)``.
    """
    A, b, _ = lp
    tol = tolerances(A.dtype)
    rescale = 1.0 / jnp.maximum(jnp.sqrt(jnp.sum(A * A, axis=1)), tol.tiny)
    A, b = A * rescale[:, None], b * rescale
    G = A @ A.T
    rows = G.shape[0]
    eps = tol.rank * jnp.maximum(jnp.trace(G) / rows, tol.tiny)
    L = _cholesky(G + eps * jnp.eye(rows, dtype=G.dtype), tol.pivot, _huge(A.dtype))
    r = eps * _cho_solve(L, b)
    br = b @ r
    atr = A.T @ r
    certified = (br > tol.rank * (b @ b)) & (
        jnp.sum(atr * atr) <= tol.rank * jnp.trace(G) * jnp.sum(r * r)
    )
    return certified, rescale * r / jnp.where(certified, br, 1.0)


def _measures(lp: LP, st: _State, rp, rd, aty):
    """Convergence tests of the current iterate from its residuals.

    ``rp = b tau - A x`` and ``rd = c tau - A^T y - s`` are the residuals of the homogeneous model;
    divided by ``tau`` they are those of the scaled iterate ``(x, y, s) / tau``. Returns
    ``(optimal, infeasible, residual)``.
    """
    A, b, c = lp
    tol = tolerances(A.dtype)
    tau = st.tau
    pres = jnp.linalg.norm(rp) / (tau * (1.0 + jnp.linalg.norm(b)))
    dres = jnp.linalg.norm(rd) / (tau * (1.0 + jnp.linalg.norm(c)))
    pobj, dobj = c @ st.x, b @ st.y
    gap = jnp.abs(pobj - dobj) / (tau + jnp.abs(pobj))
    residual = jnp.maximum(jnp.maximum(pres, dres), gap)
    # A problem without a strictly feasible point (a grasp whose every equilibrium uses the first
    # contact alone, say) drives tau and kappa to 0 together; dividing by tau then leaves the
    # residuals of an optimal iterate stalled near 1e-8. Accept 100x the tolerance there.
    ill_posed = (tau <= 1e-6) & (st.kappa <= 1e-6)
    optimal = residual <= jnp.where(ill_posed, tol.near * tol.lp, tol.lp)
    # Farkas: A^T y <= 0 and b . y > 0 proves A x = b, x >= 0 infeasible.
    scale = jnp.max(jnp.abs(aty)) + jnp.abs(dobj)
    infeasible = (jnp.max(aty) <= 1e3 * tol.lp * scale) & (dobj > 1e3 * tol.lp * scale)
    infeasible = infeasible & (tau <= 1e-3 * st.kappa) & ~optimal
    return optimal, infeasible, residual


def _residuals(lp: LP, st: _State):
    A, b, c = lp
    aty = A.T @ st.y
    rp = b * st.tau - A @ st.x
    rd = c * st.tau - aty - st.s
    return rp, rd, aty


def _step(lp: LP, st: _State) -> _State:
    """One Mehrotra predictor-corrector step of the homogeneous self-dual model."""
    A, b, c = lp
    tol = tolerances(A.dtype)
    huge = _huge(A.dtype)
    x, y, s, tau, kappa = st.x, st.y, st.s, st.tau, st.kappa
    n = x.shape[0]

    rp, rd = st.rp, st.rd
    rg = kappa + c @ x - b @ y
    mu = (x @ s + tau * kappa) / (n + 1)

    d = x / s
    Ad = A * d
    M = Ad @ A.T
    L = _cholesky(M, tol.pivot, huge)
    # The solve for p and the predictor's solve share one pass through the factor.
    rhs = jnp.stack([b, rp], axis=1) + Ad @ jnp.stack([c, rd + s], axis=1)
    p, q_affine = _cho_solve(L, rhs).T
    u = d * (A.T @ p - c)
    for _ in range(tol.refine):  # A u = b, refined as the directions below
        dp = _cho_solve(L, b - A @ u)
        p = p + dp
        u = u + d * (A.T @ dp)
    denom = -(c @ u) + b @ p + kappa / tau

    def direction(eta, rxs, rtk, q=None):
        if q is None:
            q = _cho_solve(L, eta * rp + Ad @ (eta * rd - rxs / x))
        v = d * (A.T @ q + rxs / x - eta * rd)
        dtau = (eta * rg + c @ v - b @ q + rtk / tau) / denom
        dx = u * dtau + v
        dy = p * dtau + q
        ds = (rxs - s * dx) / x
        for _ in range(tol.refine):
            # Iterative refinement of the primal equation A dx - b dtau = eta rp: forming dx as
            # d * (A^T q - ...) multiplies the rounding of A^T q by x / s, which near the optimum
            # spans 1e+-8; in float32 the primal residual then stops falling. The correction
            # keeps the dual and complementarity equations (ds absorbs -A^T dq).
            dq = _cho_solve(L, eta * rp - (A @ dx - b * dtau))
            atdq = A.T @ dq
            dx = dx + d * atdq
            dy = dy + dq
            ds = ds - atdq
        dkappa = (rtk - kappa * dtau) / tau
        return dx, dy, ds, dtau, dkappa

    everything = jnp.concatenate([x, s, tau[None], kappa[None]])

    def step_length(dx, ds, dtau, dkappa):
        return _max_step(everything, jnp.concatenate([dx, ds, dtau[None], dkappa[None]]))

    # Predictor (affine scaling).
    dx_a, _, ds_a, dtau_a, dkappa_a = direction(1.0, -x * s, -tau * kappa, q_affine)
    a_aff = jnp.minimum(1.0, step_length(dx_a, ds_a, dtau_a, dkappa_a))
    mu_aff = (
        (x + a_aff * dx_a) @ (s + a_aff * ds_a) + (tau + a_aff * dtau_a) * (kappa + a_aff * dkappa_a)
    ) / (n + 1)
    sigma = jnp.clip((mu_aff / mu) ** 3, 0.0, 1.0)

    # Corrector with Mehrotra's second-order term.
    rxs = -x * s - dx_a * ds_a + sigma * mu
    rtk = -tau * kappa - dtau_a * dkappa_a + sigma * mu
    dx, dy, ds, dtau, dkappa = direction(1.0 - sigma, rxs, rtk)
    alpha = jnp.minimum(1.0, tol.step * step_length(dx, ds, dtau, dkappa))

    new = _State(
        x=x + alpha * dx,
        y=y + alpha * dy,
        s=s + alpha * ds,
        tau=tau + alpha * dtau,
        kappa=kappa + alpha * dkappa,
        done=st.done,
        iterations=st.iterations + 1,
        best_x=st.best_x,
        best_y=st.best_y,
        best_residual=st.best_residual,
        attempt=st.attempt,
        local=st.local + 1,
        broken=st.broken,
        rp=rp,
        rd=rd,
    )
    # Keep every quantity finite and positive even on a wild step; a frozen problem stays put.
    # The fraction-to-boundary rule keeps the iterate positive; only a non-finite direction
    # (a breakdown of the factorization) can spoil it.
    ok = jnp.isfinite(alpha * (jnp.sum(dx) + jnp.sum(dy) + jnp.sum(ds) + dtau + dkappa))
    keep = st.done | ~ok
    # The new iterate judged at once (not at the start of the next step, which a finished problem
    # would spend for nothing); a frozen problem keeps its state and its judgement.
    new = jax.tree_util.tree_map(lambda o, nw: jnp.where(keep, o, nw), st, _measured(lp, new))
    return new._replace(done=new.done | ~ok, broken=st.broken | (~st.done & ~ok),
                        iterations=jnp.where(st.done, st.iterations, st.iterations + 1))


def _measured(lp: LP, st: _State) -> _State:
    """``st`` with the residuals of its iterate, done where that iterate is optimal or certified
    infeasible (:func:`_measures`), and its best iterate updated."""
    rp, rd, aty = _residuals(lp, st)
    optimal, infeasible, residual = _measures(lp, st, rp, rd, aty)
    better = ~st.done & (residual < st.best_residual)
    return st._replace(
        rp=rp, rd=rd, done=st.done | optimal | infeasible,
        best_x=jnp.where(better, st.x / st.tau, st.best_x),
        best_y=jnp.where(better, st.y / st.tau, st.best_y),
        best_residual=jnp.where(better, residual, st.best_residual),
    )


def _with_residuals(lp: LP, st: _State) -> _State:
    """``st`` with the residuals of its iterate, for the first step's direction (a starting point
    is not judged: the first step's iterate is)."""
    rp, rd, _ = _residuals(lp, st)
    return st._replace(rp=rp, rd=rd)


def _restart(lp: LP, st: _State, iterations, factors: jax.Array, count, accept_near) -> _State:
    """After a step: a problem that has spent its budget (or broken down) without converging starts
    again from ``x = s = factors[attempt]`` while starting points are left (``count``); otherwise,
    or when its best iterate is within ``near`` of the tolerance (``_finish`` accepts it), it is
    frozen."""
    tol = tolerances(lp.A.dtype)
    # ``local > iterations``: an attempt takes ``iterations + 1`` steps (the loop's limit counts them).
    exhausted = st.broken | (~st.done & (st.local > iterations))
    near = st.best_residual <= tol.near * tol.lp
    again = exhausted & ~near & (st.attempt < count) & accept_near
    factor = jax.nn.one_hot(st.attempt, factors.shape[0], dtype=factors.dtype) @ factors
    fresh = _with_residuals(lp, _init(lp, factor)._replace(iterations=st.iterations, attempt=st.attempt + 1))
    st = jax.tree_util.tree_map(lambda old, new: jnp.where(again, new, old), st, fresh)
    return st._replace(done=st.done | (exhausted & ~again))


def _finish(lp: LP, st: _State, inconsistent: jax.Array, y_null: jax.Array, accept_near,
            best_effort: bool = False) -> LPSolution:
    A, b, c = lp
    rp, rd, aty = _residuals(lp, st)
    optimal, infeasible, residual = _measures(lp, st, rp, rd, aty)
    optimal = optimal & ~inconsistent
    infeasible = infeasible | inconsistent
    x_opt, y_opt = st.x / st.tau, st.y / st.tau
    if best_effort:
        # Unfinished: the iterate of smallest residual, the last one or an earlier one.
        approximate = ~optimal & ~infeasible
        earlier = st.best_residual < residual
        x_opt = jnp.where(approximate & earlier, st.best_x, x_opt)
        y_opt = jnp.where(approximate & earlier, st.best_y, y_opt)
        residual = jnp.where(approximate, jnp.minimum(residual, st.best_residual), residual)
        status = jnp.where(optimal, Status.OPTIMAL, jnp.where(infeasible, Status.INFEASIBLE, Status.APPROXIMATE))
        by = b @ st.y
        y = jnp.where(infeasible, jnp.where(inconsistent, y_null, st.y / jnp.where(by > 0, by, 1.0)), y_opt)
        x = jnp.where(infeasible, 0.0, x_opt)
        value = jnp.where(infeasible, 0.0, c @ x)
        residual = jnp.where(inconsistent, 0.0, residual)
        return LPSolution(x, y, value, status.astype(jnp.int8), st.iterations, residual)
    if accept_near is not False:
        # Near the optimum of an ill-conditioned problem the iterates can wander instead of
        # meeting the tolerance (seen: a residual of 2e-9 at iteration 14, 5e-2 at 40). After the
        # full budget, the best iterate counts as optimal when within 100x the tolerance.
        tol = tolerances(A.dtype)
        near = accept_near & ~optimal & ~infeasible & (st.best_residual <= tol.near * tol.lp)
        x_opt = jnp.where(near, st.best_x, x_opt)
        y_opt = jnp.where(near, st.best_y, y_opt)
        residual = jnp.where(near, st.best_residual, residual)
        optimal = optimal | near
    status = jnp.where(
        optimal, Status.OPTIMAL, jnp.where(infeasible, Status.INFEASIBLE, Status.NOT_CONVERGED)
    ).astype(jnp.int8)
    # Unfinished: the best iterate, a starting guess for the crossover (``_crossover``).
    x = jnp.where(optimal, x_opt, jnp.where(infeasible, 0.0, st.best_x))
    by = b @ st.y
    y_inf = st.y / jnp.where(by > 0, by, 1.0)
    y = jnp.where(optimal, y_opt, jnp.where(inconsistent, y_null, jnp.where(infeasible, y_inf, st.best_y)))
    value = jnp.where(optimal, c @ x, 0.0)
    residual = jnp.where(inconsistent, 0.0, residual)
    return LPSolution(x, y, value, status, st.iterations, residual)


def _warm(st: _State, start, weight) -> _State:
    """The warm start of Skajaa, Andersen and Ye (2013) for the homogeneous model: ``weight`` times
    a nearby problem's solution ``(x, y, s)`` (:func:`warm_point`) plus ``1 - weight`` times the
    standard start, with ``tau = 1`` and ``kappa = 1 - weight`` (``weight = 0``: the standard start
    itself). Any positive point is a valid start of the homogeneous model; this one is close to the
    nearby optimum and still far enough inside the orthant for the central path to be followed."""
    x, y, s = start
    w = jnp.asarray(weight, st.x.dtype)
    return st._replace(x=w * x + (1 - w) * st.x, y=w * y, s=w * s + (1 - w) * st.s, kappa=(1 - w) * st.kappa)


#: Warm starts' weights by how far the problem moved (relative): below ``WARM[0]``, ``WARM[2]``;
#: below ``WARM[1]``, ``WARM[3]``; else ``WARM[4]`` (:func:`warm_weight`). Measured on the min-weight
#: LPs of the critical friction search (``_friction``): iterations per LP 9.1 -> 3.3-3.5 for moves
#: of 1e-3..1e-4, 8.8 -> 6.1 for 3e-2, 8.6 -> 7.2 for 2x.
WARM = (0.03, 0.3, 0.999, 0.99, 0.9)


def warm_weight(move):
    """The warm start's weight (:func:`solve`'s ``weight``) for a relative move ``move`` of the
    problem's data since the solution it starts from (:data:`WARM`)."""
    a, b, w1, w2, w3 = WARM
    return jnp.where(move < a, w1, jnp.where(move < b, w2, w3))


def warm_point(lp: LP, solution: LPSolution) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(x, y, s)`` of ``solution`` to warm-start a nearby problem from (:func:`solve`'s ``warm``):
    the primal point and the dual slacks ``c - A^T y`` clipped at 0, no gradient."""
    A, _, c = jax.lax.stop_gradient(lp)
    y = jax.lax.stop_gradient(solution.y)
    return jnp.maximum(jax.lax.stop_gradient(solution.x), 0.0), y, jnp.maximum(c - A.T @ y, 0.0)


def solve(*lps: LP, iterations: int | jax.Array | None = None, consistent: bool = False,
          best_effort: bool = False, restarts: int | jax.Array | None = None, warm=None,
          weight=0.0, skip=None) -> tuple[LPSolution, ...]:
    """Solve one or more independent LPs in a single fused iteration loop.

    Each iteration advances every LP by one step; the loop ends when all are done (under
    ``vmap``: all problems of the batch) or after ``iterations``. (Padding the LPs to one shape
    and stacking them was measured 1.7x slower on the CPU.)

    Args:
        *lps: problems in standard form; each may have its own shape. Each is *one* problem:
            batch with ``jax.vmap``.
        iterations: interior-point iterations; default from the largest problem's column count.
            With at least the default, a problem that ends unfinished but whose best iterate is
            within 100x the tolerance is reported optimal at that iterate. May be a traced integer
            scalar, so that one compiled program serves every budget (``_batch.Retry``).
        consistent: the caller knows that ``A x = b`` has a solution (for example a feasible
            point by construction); skips the up-front test for a rank-deficient, inconsistent
            system (:func:`_inconsistency`), which costs about one iteration.
        best_effort: a problem unfinished after ``iterations`` reports its best iterate with
            status ``APPROXIMATE`` instead of ``NOT_CONVERGED`` and zeros (no restarts, no
            acceptance within 100x): for a gradient step that cannot wait for stragglers, as in
            ``gj.optimize``. Never for a verdict.
        restarts: with at least the default budget, how many of the starting points of
            ``tolerances(dtype).restarts`` (float32 only) a problem still unfinished runs from in
            turn (default: all); may be traced, as ``iterations``.
        warm: one ``(x, y, s)`` (:func:`warm_point` of a nearby problem's solution) or ``None``
            per LP: the LP starts from ``weight`` times it plus ``1 - weight`` times the standard
            start (:func:`_warm`); restarts still run from the standard starting points.
        weight: the warm start's weight in ``[0, 1)`` (may be traced; 0: the standard start).
        skip: a boolean (may be traced): the LPs are not solved (their solution is meaningless),
            for a caller under ``vmap`` whose result for this problem is discarded (a search that
            is already done): a streamed solve (:func:`_stream`) gives it no lane.

    Returns:
        One :class:`LPSolution` per LP, in order.
    """
    for lp in lps:
        if lp.A.ndim != 2 or lp.b.ndim != 1 or lp.c.ndim != 1:
            raise ValueError(
                f"solve() takes one LP with A: (rows, cols), b: (rows,), c: (cols,); got shapes "
                f"{lp.A.shape}, {lp.b.shape}, {lp.c.shape}. Batch with jax.vmap."
            )
    if isinstance(iterations, jax.Array):
        iterations = iterations.astype(jnp.int32)
    elif iterations is not None:
        iterations = int(iterations)
    skip = jnp.zeros((), bool) if skip is None else jnp.asarray(skip, bool)
    if len(lps) > 1:
        return _loop(lps, iterations, consistent, best_effort, restarts, warm, weight, skip)
    return (_single(lps[0], None if warm is None else warm[0], weight, skip, iterations, restarts, consistent,
                    best_effort),)


class _Plan(NamedTuple):
    """What :func:`_loop` and :func:`_stream` share: the budget, whether a best iterate within
    ``near`` counts (``accept_near``), the restarts' starting points and their count, and the
    iteration limit of one problem (restarts included)."""

    iterations: int | jax.Array
    accept_near: bool | jax.Array
    factors: tuple
    starts: jax.Array
    count: int | jax.Array
    limit: int | jax.Array


def _plan(columns: int, dtype, iterations, best_effort: bool, restarts) -> _Plan:
    full = default_iterations(columns)
    if iterations is None:
        iterations = full
    accept_near = iterations >= full  # a Python bool, or a traced one
    # float32, full budget: a trajectory can stall off the optimum (rounding, not the problem); a
    # start elsewhere mostly does not (2/3 of the stalled sphere grasps then converged). A problem
    # unfinished after its budget starts again from each starting point in turn, inside the same
    # loop (one copy of the step in the program: a second loop for the restarts cost a third of
    # the compile time of a float32 ``evaluate``); the others stay frozen.
    factors = tolerances(dtype).restarts if accept_near is not False and not best_effort else ()
    if restarts is not None and not isinstance(restarts, jax.Array):
        factors = factors[: max(0, int(restarts))]
    count = len(factors) if not isinstance(restarts, jax.Array) else jnp.clip(restarts, 0, len(factors))
    # With restarts, each round has an extra step (``_restart``).
    limit = (1 + len(factors)) * (iterations + 1) if factors else iterations
    return _Plan(iterations, accept_near, factors, jnp.asarray(factors or (1.0,), dtype), count, limit)


def _start(lp: LP, consistent: bool, warm, weight, skip) -> tuple[_State, tuple[jax.Array, jax.Array]]:
    """The starting state of one LP and its up-front inconsistency test ``(certified, y)``."""
    check = (jnp.zeros((), bool), jnp.zeros_like(lp.b)) if consistent else _inconsistency(lp)
    # An inconsistent problem is certified before the first step and frozen (a skipped one too).
    st = _init(lp)._replace(done=check[0] | skip)
    return _with_residuals(lp, st if warm is None else _warm(st, warm, weight)), check


def _advance(lp: LP, st: _State, plan: _Plan) -> _State:
    """One iteration of one LP: a step, and a restart where its budget is spent (float32)."""
    st = _step(lp, st)
    if plan.factors:
        st = _restart(lp, st, plan.iterations, plan.starts, plan.count, plan.accept_near)
    return st


def _finished(st: _State, plan: _Plan) -> jax.Array:
    """Whether an LP needs no more iterations: done, or (without restarts, which mark a spent
    budget done themselves) its budget spent."""
    return st.done if plan.factors else st.done | (st.iterations >= plan.iterations)


def _result(lp: LP, st: _State, check, plan: _Plan, best_effort: bool) -> LPSolution:
    # A short budget (the first pass of ``_batch.Retry``) reports unfinished problems as such.
    if best_effort:
        return _finish(lp, st, *check, False, True)
    return _finish(lp, st, *check, plan.accept_near)


def _loop(lps, iterations, consistent, best_effort, restarts, warm, weight, skip) -> tuple[LPSolution, ...]:
    """:func:`solve` for one problem of each of ``lps``, in one fused loop (under ``vmap``, in lock
    step: the loop runs until the slowest problem of the batch is done)."""
    plan = _plan(max(lp.A.shape[1] for lp in lps), lps[0].A.dtype, iterations, best_effort, restarts)
    starts = [_start(lp, consistent, None if warm is None else warm[k], weight, skip) for k, lp in enumerate(lps)]
    states = tuple(st for st, _ in starts)

    def body(carry):
        k, sts = carry
        return k + 1, tuple(_advance(lp, st, plan) for lp, st in zip(lps, sts))

    def cond(carry):
        k, sts = carry
        return (k < plan.limit) & ~jnp.all(jnp.stack([st.done for st in sts]))

    _, states = jax.lax.while_loop(cond, body, (jnp.zeros((), jnp.int32), states))
    return tuple(_result(lp, st, check, plan, best_effort) for lp, st, (_, check) in zip(lps, states, starts))


#: A vmapped :func:`solve` of at least this many problems streams them through :data:`LANES`
#: lanes (:func:`_stream`) instead of running them in lock step. Callers choose it by the size of
#: their vmapped blocks (``_batch.map_grasps(block=)``).
STREAM_MIN = 512
#: Lanes of a streamed solve. Measured (8,192 quality or torque LPs of 4-finger grasps, one CPU
#: device): 64 to 128 lanes in batches of 512 to 8,192 1.2x to 1.5x faster than lock-step blocks of
#: 256 with the full budget, and 1.5x to 1.9x with warm starts (mean 4-5 iterations); 256 lanes
#: slower (the per-lane work of the refill grows with the lanes).
LANES = 128


def _single(lp: LP, warm, weight, skip, iterations, restarts, consistent: bool, best_effort: bool) -> LPSolution:
    """One LP through :func:`_loop`, with a batching rule: ``vmap`` over :data:`STREAM_MIN` or more
    problems streams them (:func:`_stream`), with the same results."""
    traced = tuple(v for v in (iterations, restarts) if isinstance(v, jax.Array))

    def options(dynamic):
        it, rs = iterations, restarts
        dynamic = list(dynamic)
        if isinstance(iterations, jax.Array):
            it = dynamic.pop(0)
        if isinstance(restarts, jax.Array):
            rs = dynamic.pop(0)
        return it, rs

    def one(lp, warm, weight, skip, dynamic):
        it, rs = options(dynamic)
        return _loop((lp,), it, consistent, best_effort, rs, None if warm is None else (warm,), weight, skip)[0]

    fn = jax.custom_batching.custom_vmap(one)

    @fn.def_vmap
    def rule(size, batched, lp, warm, weight, skip, dynamic):
        lp_b, warm_b, weight_b, skip_b, dynamic_b = batched
        flags = jax.tree_util.tree_leaves(batched)
        if size < STREAM_MIN or any(jax.tree_util.tree_leaves(dynamic_b)) or not any(flags):
            axes = jax.tree_util.tree_map(lambda b: 0 if b else None, batched)
            out = jax.vmap(one, in_axes=tuple(axes))(lp, warm, weight, skip, dynamic)
        else:
            wide = lambda a, b: a if b else jnp.broadcast_to(a, (size,) + jnp.shape(a))  # noqa: E731
            lp, warm, weight, skip = jax.tree_util.tree_map(wide, (lp, warm, weight, skip),
                                                            (lp_b, warm_b, weight_b, skip_b))
            it, rs = options(dynamic)
            out = _stream(lp, warm, weight, skip, it, rs, consistent, best_effort)
        return out, jax.tree_util.tree_map(lambda _: True, out)

    return fn(lp, warm, jnp.asarray(weight, lp.A.dtype), skip, traced)


def _stream(lps: LP, warm, weight, skip, iterations, restarts, consistent: bool, best_effort: bool) -> LPSolution:
    """``vmap`` of :func:`solve` over a batch of single LPs (leading axis ``N`` on every leaf),
    streamed: :data:`LANES` problems iterate at a time, and a lane whose problem is finished takes
    the next one of the batch at once, instead of every problem waiting for the slowest of its
    block. Each problem takes exactly the iterations it takes alone, so the results are
    :func:`_loop`'s (up to the rounding of differently vectorized arithmetic). Problems done
    before the first step (certified inconsistent, or ``skip``) never take a lane."""
    N = lps.b.shape[0]
    lanes = min(LANES, N)
    plan = _plan(lps.A.shape[-1], lps.A.dtype, iterations, best_effort, restarts)
    states, checks = jax.vmap(lambda lp, w, wt, sk: _start(lp, consistent, w, wt, sk))(lps, warm, weight, skip)
    # The queue: positions of the problems to iterate, the others (already done) after them.
    order = jnp.argsort(states.done, stable=True).astype(jnp.int32)
    live = N - jnp.sum(states.done, dtype=jnp.int32)

    def load(pos):
        """``(problem, lp, state)`` of queue positions ``pos: (lanes,)``; past the queue's end an
        empty lane (problem ``N``, done)."""
        empty = pos >= live
        index = order[jnp.clip(pos, 0, N - 1)]
        take = lambda a: a[index]  # noqa: E731
        st = jax.tree_util.tree_map(take, states)
        return jnp.where(empty, N, index), jax.tree_util.tree_map(take, lps), st._replace(done=st.done | empty)

    def refill(carry, finished):
        ahead, index, lp, st, out = carry
        target = jnp.where(finished, index, N)
        out = jax.tree_util.tree_map(lambda o, s: o.at[target].set(s, mode="drop"), out, st)
        pos = ahead + jnp.cumsum(finished, dtype=jnp.int32) - 1
        new_index, new_lp, new_st = load(pos)
        pick = lambda new, old: jnp.where(finished.reshape((-1,) + (1,) * (new.ndim - 1)), new, old)  # noqa: E731
        lp, st = jax.tree_util.tree_map(pick, (new_lp, new_st), (lp, st))
        return ahead + jnp.sum(finished, dtype=jnp.int32), jnp.where(finished, new_index, index), lp, st, out

    def body(carry):
        ahead, index, lp, st, out = carry
        st = jax.vmap(lambda p, s: _advance(p, s, plan))(lp, st)
        carry = (ahead, index, lp, st, out)
        finished = _finished(st, plan) & (index < N)
        # Every finished lane takes its next problem at once (refilling only once 16 or 32 lanes
        # had finished, the others waiting frozen, measured within the noise).
        return jax.lax.cond(jnp.any(finished), refill, lambda c, f: c, carry, finished)

    first = jnp.arange(lanes, dtype=jnp.int32)
    index, lp, st = load(first)
    carry = (jnp.asarray(lanes, jnp.int32), index, lp, st, states)
    *_, out = jax.lax.while_loop(lambda c: jnp.any(c[1] < N), body, carry)
    return jax.vmap(lambda lp, st, check: _result(lp, st, check, plan, best_effort))(lps, out, checks)


def optimal_value(lp: LP, solution: LPSolution) -> jax.Array:
    """``c . x*`` with derivatives from the envelope theorem.

    With ``x*, y*`` held fixed, ``c.x* - y*.(A x* - b)`` equals the optimal value and its
    derivative in ``(A, b, c)`` is ``dc.x* - y*.(dA x* - db)``, the derivative of the optimal
    value wherever the optimum is unique. No iteration is differentiated. Zero where the LP is not
    optimal (or ``APPROXIMATE``: then the same expression at the best iterate).
    """
    x = jax.lax.stop_gradient(solution.x)
    y = jax.lax.stop_gradient(solution.y)
    value = lp.c @ x - y @ (lp.A @ x - lp.b)
    return jnp.where(has_value(solution), value, 0.0)


def has_value(solution: LPSolution) -> jax.Array:
    """Whether ``solution`` carries an optimum: ``OPTIMAL``, or ``APPROXIMATE`` (best effort)."""
    return (solution.status == Status.OPTIMAL) | (solution.status == Status.APPROXIMATE)
