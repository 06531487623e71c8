"""One homogeneous self-dual interior-point step for one LP, its state, start and finish.

The Mehrotra predictor-corrector step of Xu, Hung and Ye (1996) and Andersen and Andersen (2000)
on a problem of at most 7 rows: the normal matrix is factored by an unrolled Cholesky, so that
under ``jax.vmap`` every scalar becomes a vector over the batch. A problem that has converged or
been certified infeasible is frozen with ``jnp.where``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from .._constants import tolerances
from ._problem import LP, LPSolution, Status


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
    """One Mehrotra predictor-corrector step of the homogeneous self-dual model.

    One function for one step: moving the same arithmetic between functions changes how XLA:CPU
    fuses the loop body, and with it the step's speed.
    """
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
#: below ``WARM[1]``, ``WARM[3]``; else ``WARM[4]`` (:func:`warm_weight`). On the critical friction
#: search's min-weight LPs a move of 1e-3 takes about 3.5 iterations instead of 9 cold.
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

