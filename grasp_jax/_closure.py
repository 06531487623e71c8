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
from ._contact import ContactModel, wrench_columns
from ._polish import open_half_space, polish_exact
from ._programs import (
    SHIFT,
    about_first,
    arm_scale,
    full_rank,
    gram_rank3,
    grasp_quality_lp,
    min_weight_certificate,
    min_weight_lp,
    min_weight_margin_of,
    quality_bound,
)
from ._result import GraspEvaluation
from .lp import (
    LP,
    SENSITIVE,
    LPSolution,
    Status,
    has_value,
    optimal_value,
    polish,
    sensitivity,
    solve,
    warm_point,
)

# ---------------------------------------------------------------------------------------------
# Torque tests about c_1.


def paper_torque_test(tau: jax.Array) -> jax.Array:
    """Eq. (15) in 3D / eq. (21) in 2D on ``tau: (K, t)``: each torque component takes both signs.

    Necessary for Proposition 2(2) in 3D, not sufficient (``MATH.md``); exact in 2D.
    """
    tol = tolerances(tau.dtype)
    total_abs = jnp.sum(jnp.abs(tau), axis=0)
    return jnp.all(total_abs - jnp.abs(jnp.sum(tau, axis=0)) > tol.margin * total_abs + tol.tiny)


def exact_torque_2d(tau: jax.Array):
    """Scalar torques positively span R iff they take both signs. Returns (span, certificate)."""
    tol = tolerances(tau.dtype)
    t = tau[:, 0]
    hi, lo = jnp.max(t), jnp.min(t)
    span = (hi > tol.margin) & (lo < -tol.margin)
    # When not spanning, t_cert * tau >= 0 for every torque (within the margin).
    t_cert = jnp.where(lo >= -tol.margin, 1.0, -1.0).astype(tau.dtype)
    return span, jnp.minimum(hi, -lo), t_cert[None]


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
    (:func:`open_half_space`), the value is that, ``OPTIMAL``, whatever the solve found.
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
        # ``polish_exact`` reduces the LP.
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
    full, null = gram_rank3(tau)
    t_margin = min_weight_margin_of(tau, t_sol)
    # Unfinished after the full budget: the dual of the best iterate may still prove that the
    # torques do not span, by a direction u with u . tau >= 0 for every torque (then l* <= 0).
    t_dual = min_weight_certificate(tau, t_sol)
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
        points, t_q / arm_scale(points)
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
    LPs together, ``polish_exact``)."""
    return points.shape[-1] == 3 and torque_test == "exact" and not tolerances(points.dtype).crossover


def _torque_columns(points, normals, mu, model: ContactModel, tangents) -> jax.Array:
    """``(K, 3)`` the torques about ``c_1`` of the torque test (the columns of contacts 2..n)."""
    normals = safe_normalize(normals)
    cols = about_first(points, normals, cone_edges(normals, mu, model.num_edges, tangents), model)
    return cols.torque[cols.fixed:]


def torque_stage(points, normals, mu, model: ContactModel, tangents=None, iterations=None,
                 restarts=None) -> tuple[GraspEvaluation, Torques, jax.Array]:
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
    tau = _torque_columns(points, normals, mu, model, tangents)
    t_lp = min_weight_lp(tau)
    (t_sol,) = solve(jax.lax.stop_gradient(t_lp), iterations=iterations, restarts=restarts)
    margin = min_weight_margin_of(tau, t_sol)
    opposed = (model.kind == "hard") & (t_sol.status == Status.OPTIMAL) & (margin < -tol.margin)
    torques = _torque_test(tau, t_sol, _full_budget(t_lp, iterations), opposed)
    rows = 3 + 3 + 1
    out = _evaluation(points, 3, -jnp.ones((), points.dtype), jnp.asarray(Status.OPTIMAL, jnp.int8),
                      jnp.zeros(rows, points.dtype), jnp.zeros((), jnp.int32), *torques[:4])
    return out, torques, ~torques.opposed


def quality_stage(points, normals, mu, model: ContactModel, torques: Torques, tangents=None, iterations=None,
                  restarts=None) -> GraspEvaluation:
    """The second stage of :func:`evaluate_one` (where :func:`staged`): the quality LP, and the
    evaluation from it and the torque test of :func:`torque_stage`. Correct for every grasp: where
    the torques are opposed it reports what the first stage does (``delta = -1``)."""
    q_lp, cols = grasp_quality_lp(points, normals, mu, model, tangents)
    (q_sol,) = solve(jax.lax.stop_gradient(q_lp), iterations=iterations, consistent=True, restarts=restarts)
    delta, q_status, q_dual = _quality_value(q_lp, q_sol, iterations, forced=torques.opposed)
    iters = jnp.where(torques.opposed, 0, q_sol.iterations)
    return _evaluation(points, 3, delta, q_status, q_dual, iters, *torques[:4])


def evaluate_one(
    points: jax.Array,
    normals: jax.Array,
    mu,
    model: ContactModel,
    torque_test: str = "exact",
    tangents: jax.Array | None = None,
    iterations: int | None = None,
    restarts: int | None = None,
) -> GraspEvaluation:
    """Force-closure verdict, quality Q and certificate of one grasp.

    Args:
        points: ``(n, d)`` contact points; ``points[0]`` is the reference contact ``c_1``.
        normals: ``(n, d)`` outward unit normals.
        mu: friction coefficient.
        model: the :class:`~grasp_jax._contact.ContactModel` (kind, cone edges, torsion).
        torque_test: ``"exact"`` (default) or ``"paper"`` (eq. 15 / 21).
        tangents: optional ``(n, 3)`` first tangent of each 3D contact frame.
        iterations: interior-point iterations (default from the problem size).
        restarts: float32 starting points an unfinished LP runs from (``lp.solve``; default all).
    """
    tol = tolerances(points.dtype)
    d = points.shape[-1]
    if staged(points, torque_test):
        _, torques, _ = torque_stage(points, normals, mu, model, tangents, iterations, restarts)
        return quality_stage(points, normals, mu, model, torques, tangents, iterations, restarts)
    q_lp, cols = grasp_quality_lp(points, normals, mu, model, tangents)
    tau = cols.torque[cols.fixed:]
    if d == 3 and torque_test == "exact":
        # float32: both LPs, then one crossover for both (``polish_exact``).
        t_lp = min_weight_lp(tau)
        # Two loops, not one fused loop: the torque LP's block converges sooner, and its loop
        # stops then. The quality LP is feasible by construction.
        (q_sol,) = solve(jax.lax.stop_gradient(q_lp), iterations=iterations, consistent=True, restarts=restarts)
        (t_sol,) = solve(jax.lax.stop_gradient(t_lp), iterations=iterations, restarts=restarts)
        t_full = _full_budget(t_lp, iterations)
        q_full = _full_budget(q_lp, iterations)
        q_polished, t_polished = polish_exact(
            q_lp, t_lp, q_sol, t_sol, (_pivots(tol, q_full), _pivots(tol, t_full)), q_full
        )
        forced = open_half_space(t_polished)
        torque_span, t_margin, t_cert, t_status, _ = _torque_test(tau, t_polished[0], t_full, forced)
    else:
        (q_sol,) = solve(jax.lax.stop_gradient(q_lp), iterations=iterations, consistent=True, restarts=restarts)
        q_polished, forced = None, False
        if d == 2:
            torque_span, t_margin, t_cert = exact_torque_2d(tau)
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


def quality_dual_one(points, normals, mu, model: ContactModel, tangents=None):
    """``(rows,)`` the dual vector of one grasp's quality LP (zeros where the LP is not solved to
    optimality): for :func:`out_of_equilibrium` on grasps near this one (the perturbations of a
    robust label)."""
    lp, _ = grasp_quality_lp(points, normals, mu, model, tangents)
    (sol,) = solve(jax.lax.stop_gradient(lp), consistent=True)
    y = jnp.where(sol.status == Status.OPTIMAL, sol.y, 0.0)
    return jnp.where(jnp.all(jnp.isfinite(y)), y, 0.0)


def out_of_equilibrium(points, normals, mu, model: ContactModel, y, tangents=None):
    """Whether the dual vector ``y`` (any: from :func:`quality_dual_one` of a nearby grasp) proves
    that one grasp is not in equilibrium, with no LP solved: the weak-duality bound
    :func:`quality_bound` of its quality LP is below ``-SETTLED`` margins. Then
    :func:`evaluate_one` would report it not in equilibrium, Q 0, not force-closure. ``False``
    proves nothing."""
    tol = tolerances(points.dtype)
    lp, _ = grasp_quality_lp(points, normals, mu, model, tangents)
    bound, slack = quality_bound(lp, jnp.asarray(y, points.dtype))
    return bound + slack < -SETTLED * tol.margin


def quality_one(points, normals, mu, model: ContactModel, signed: bool = False, tangents=None, iterations=None,
                restarts=None):
    """``(Q, LP status)`` of one grasp: Q is ``delta*`` of the quality LP, clipped at 0 unless
    ``signed``, with envelope theorem derivatives in ``points`` and ``normals``. ``model``,
    ``restarts``: see :func:`evaluate_one`."""
    lp, cols = grasp_quality_lp(points, normals, mu, model, tangents)
    (sol,) = solve(jax.lax.stop_gradient(lp), iterations=iterations, consistent=True, restarts=restarts)
    tol = tolerances(points.dtype)
    polished, forced = None, False
    if tol.crossover and points.shape[-1] == 3:
        # float32: the half-space round of evaluate (``polish_exact``) needs the torque LP's
        # vertex; the crossover finds it from nothing (no interior-point loop for it here), with
        # the full budget only.
        t_lp = min_weight_lp(cols.torque[cols.fixed:])
        rows, cols = t_lp.A.shape
        zero = jnp.zeros((), points.dtype)
        nothing = LPSolution(jnp.zeros(cols, zero.dtype), jnp.zeros(rows, zero.dtype), zero,
                             jnp.asarray(Status.NOT_CONVERGED, jnp.int8), jnp.zeros((), jnp.int32), zero)
        full = _full_budget(lp, iterations)
        t_pivots = tol.crossover if full is True else jnp.where(full, tol.crossover, 0)
        polished, t_polished = polish_exact(lp, t_lp, sol, nothing, (_pivots(tol, full), t_pivots), full)
        forced = open_half_space(t_polished)
    delta, status, _ = _quality_value(lp, sol, iterations, polished, forced)
    ok = status == Status.OPTIMAL
    if signed:
        value = jnp.where(ok | (status == Status.BOUNDED), delta, 0.0)
    else:
        value = jnp.where(ok & (delta > tol.margin), delta, 0.0)
    return value, status


def min_weight_one(points, normals, mu, model: ContactModel, origin, torque_scale, tangents=None, iterations=None):
    """``(l*, status)`` of the classical min-weight LP on all primitive wrenches of one grasp (of
    the contact model, ``_contact``), differentiable in ``points`` and ``normals`` (see
    :func:`min_weight_value`)."""
    normals = safe_normalize(normals)
    edges = cone_edges(normals, mu, model.num_edges, tangents)
    return min_weight_value(wrench_columns(points, normals, edges, model.kind, model.torsion, origin, torque_scale).wrenches,
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
        full = gram_rank3(vectors_)[0] if vectors.shape[1] == 3 else full_rank(vectors_)
    K = vectors.shape[0]
    value = 1.0 / K - optimal_value(lp, sol)
    margin = jnp.where(has_value(sol), value, jnp.where(sol.status == Status.INFEASIBLE, -jnp.inf, 0.0))
    out = (jnp.where(full, margin, 0.0), sol.status)
    return out + (warm_point(lp, sol),) if solution else out
