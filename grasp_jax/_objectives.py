"""Objectives a contact optimizer maximizes, for **one** grasp, beside the metrics of ``_closure``.

Each is continuous, finite and differentiable almost everywhere (envelope theorem on each LP's
solution), unlike Q, which is flat at 0 off equilibrium. Each takes ``points, normals: (n, d)``
and returns a scalar and a small dict of monitors.

* ``"closure"`` (default): ``min(delta*, W T, delta* + W T)``, ``delta*`` the signed quality LP
  optimum, ``T`` the torque margin about ``c_1``, ``W = TORQUE_WEIGHT``; positive exactly at
  force-closure, equal to ``Q`` wherever ``W T >= Q``. ``"closure_any"``: its minimum over the
  choice of ``c_1``.
* ``"min_weight"``: ``K l*`` of the min-weight LP on all primitive wrenches (FRoGGeR's margin).
* ``"signed_q"``: ``delta*`` alone (equilibrium only).
* ``"friction"``: ``-mu*`` (``_friction``), ``-cap + K l*(cap)`` above :data:`FRICTION_CAP`.
* ``"dfc"``, ``"dfc_eig"``: the negated energies of DexGraspNet / DFC (Liu et al. 2021), baselines
  that are not signed at force-closure.
"""

from __future__ import annotations


import jax
import jax.numpy as jnp

from ._api import _bind, _check_common, contact_model
from ._batch import map_grasps
from ._closure import exact_torque_2d, min_weight_value
from ._cones import cone_edges, safe_normalize
from ._constants import DEFAULT_NUM_EDGES, tolerances
from ._contact import ContactModel, wrench_columns
from ._friction import FrictionStatus, critical_friction_one
from ._programs import SHIFT, about_first, quality_lp
from ._validate import check_scalar
from ._wrench import cross
from .lp import Status, has_value, optimal_value, solve

#: Objectives :func:`objective_one` knows, in the order of the module docstring.
OBJECTIVES: tuple[str, ...] = ("closure", "closure_any", "min_weight", "signed_q", "friction", "dfc", "dfc_eig")

#: Largest friction coefficient the ``"friction"`` objective searches (``_friction.DEFAULT_CAP``).
FRICTION_CAP = 4.0

#: Weight of the torque margin in ``"closure"``. ``T`` lies in ``(-inf, 1]`` (3D) and Q in
#: ``[0, sqrt(1 + mu^2)]``; with 4 the torque term binds on few optimized grasps (it is reported
#: per grasp as ``torque_bound``).
TORQUE_WEIGHT = 4.0

#: Value given to an LP that has no optimum (a rank-deficient, infeasible min-weight LP): finite,
#: below every value a feasible grasp reaches.
FLOOR = -10.0

#: DFC's eigenvalue threshold (``epsilon`` of ``relu(-eig(G G^T - epsilon I))``).
DFC_EPSILON = 0.01


def signed_quality(cols, edges, iterations=None, best_effort: bool = False) -> jax.Array:
    """``delta*`` of the always-feasible quality LP (``Q`` where positive), envelope derivatives.

    Args:
        cols: the grasp's wrench columns about ``c_1`` (``_programs.about_first``); edges:
            ``(n, m, d)`` cone edges (:func:`cone_edges`).
        iterations, best_effort: as :func:`grasp_jax.lp.solve`."""
    lp = quality_lp(cols, edges)
    (sol,) = solve(jax.lax.stop_gradient(lp), iterations=iterations, consistent=True, best_effort=best_effort)
    return jnp.where(has_value(sol), -optimal_value(lp, sol) - SHIFT, 0.0)


def torque_margin(cols, iterations=None, best_effort: bool = False) -> jax.Array:
    """``T`` of the module docstring: > 0 iff the torques about ``c_1`` of the columns of the
    torque test (hard contacts: of contacts 2..n) positively span R^3 (R in 2D). Arguments as
    :func:`signed_quality`."""
    tau = cols.torque[cols.fixed:]
    if tau.shape[-1] == 1:
        return exact_torque_2d(tau)[1]
    margin, status = min_weight_value(tau, iterations, best_effort)
    return jnp.where(status == Status.INFEASIBLE, FLOOR, tau.shape[0] * margin)


def _closure(points, normals, mu, model: ContactModel, iterations, best_effort):
    normals = safe_normalize(normals)
    edges = cone_edges(normals, mu, model.num_edges)
    cols = about_first(points, normals, edges, model)
    delta = signed_quality(cols, edges, iterations, best_effort)
    torque = TORQUE_WEIGHT * torque_margin(cols, iterations, best_effort)
    # Where both are negative their sum, so that the torque term still pulls where delta* sits on
    # its floor -1 (the first contact alone: a constant, though the LP's dual gives it a gradient).
    return jnp.minimum(jnp.minimum(delta, torque), delta + torque), delta, torque


def min_weight_margin(points, normals, mu, model: ContactModel, center, scale, iterations=None,
                      best_effort: bool = False, full=None) -> jax.Array:
    """``K l*`` of the min-weight LP on all ``K`` primitive wrenches, torques about ``center`` over
    ``scale``: > 0 iff force-closure; envelope derivatives; :data:`FLOOR` where infeasible.
    ``full``: as :func:`grasp_jax._closure.min_weight_value` (``True`` skips the rank test)."""
    normals = safe_normalize(normals)
    edges = cone_edges(normals, mu, model.num_edges)
    # Points in units of scale: torsion moments (a length times a force) are divided by it too.
    w = wrench_columns((points - center) / scale, normals, edges, model.kind, model.torsion / scale).wrenches
    margin, status = min_weight_value(w, iterations, best_effort, full=full)
    return jnp.where(status == Status.INFEASIBLE, FLOOR, w.shape[0] * margin)


def dfc_energy(points, normals, center, scale, eig: bool) -> jax.Array:
    """DexGraspNet's ``||sum_i [n_i; p_i x n_i]||^2``, plus DFC's eigenvalue term if ``eig``."""
    n, d = points.shape
    arm = (points - center) / scale
    unit = safe_normalize(normals)
    torque = cross(arm, unit)
    torque = torque[:, None] if d == 2 else torque
    energy = jnp.sum(jnp.sum(jnp.concatenate([unit, torque], axis=-1), axis=0) ** 2)
    if not eig:
        return energy
    # G: (d + t, n d), the columns of contact i are [I; [p_i]_x] (force directions e_k).
    basis = jnp.eye(d, dtype=points.dtype)
    cols = jax.vmap(lambda p: jax.vmap(lambda e: jnp.concatenate([e, jnp.atleast_1d(cross(p, e))]))(basis))(arm)
    G = cols.reshape(n * d, -1).T
    evals = jnp.linalg.eigvalsh(G @ G.T)
    return energy + jnp.sum(jax.nn.relu(DFC_EPSILON - evals) ** 2)


def objective_one(points, normals, mu, model: ContactModel, kind: str, center, scale, iterations=None,
                  best_effort: bool = False):
    """``(value, monitors)`` of objective ``kind`` for one grasp (larger is better).

    Args:
        points, normals: ``(n, d)``; normals outward.
        mu: friction coefficient.
        model: the :class:`~grasp_jax._contact.ContactModel` (the DFC energies ignore it).
        kind: one of :data:`OBJECTIVES`.
        center: ``(d,)`` the object's centre; scale: its radius (``"min_weight"`` and the DFC
            energies take torques about ``center`` in units of ``scale``).
        iterations: interior-point iterations (default from the LP size).
        best_effort: LPs unfinished after ``iterations`` give their best iterate's value (see
            :func:`grasp_jax.lp.solve`): what ``gj.optimize`` uses, with a short budget.

    Returns:
        ``value: ()`` and ``monitors``: ``{"delta": delta*, "torque": weighted T}`` for the closure
        objectives (about the reported ``c_1``), empty otherwise.
    """
    if kind == "closure":
        value, delta, torque = _closure(points, normals, mu, model, iterations, best_effort)
        return value, {"delta": delta, "torque": torque}
    if kind == "closure_any":
        points, normals = jnp.asarray(points), jnp.asarray(normals)
        n = points.shape[0]
        rolled = jnp.stack([jnp.roll(jnp.arange(n), -k) for k in range(n)])
        values, deltas, torques = jax.vmap(
            lambda idx: _closure(points[idx], normals[idx], mu, model, iterations, best_effort)
        )(rolled)
        k = jnp.argmin(values)
        return values[k], {"delta": deltas[0], "torque": torques[0]}
    if kind == "min_weight":
        return min_weight_margin(points, normals, mu, model, center, scale, iterations, best_effort), {}
    if kind == "signed_q":
        normals = safe_normalize(normals)
        edges = cone_edges(normals, mu, model.num_edges)
        return signed_quality(about_first(points, normals, edges, model), edges, iterations, best_effort), {}
    if kind == "friction":
        return friction_objective(points, normals, model, center, scale, iterations, best_effort), {}
    if kind in ("dfc", "dfc_eig"):
        return -dfc_energy(points, normals, center, scale, eig=kind == "dfc_eig"), {}
    raise ValueError(f"objective must be one of {OBJECTIVES}; got {kind!r}")


def friction_objective(points, normals, model: ContactModel, center, scale, iterations=None,
                       best_effort=False) -> jax.Array:
    """``-mu*`` where the grasp is force-closure at :data:`FRICTION_CAP`, else ``-cap + K l*(cap)``
    (see the module docstring). The search itself always has the full interior-point budget."""
    points = jnp.asarray(points)
    cap = jnp.asarray(FRICTION_CAP, points.dtype)
    mu_star, status = critical_friction_one(points, normals, cap, model)
    # No rank test here (full=True): the search has made its own, and a second eigendecomposition
    # in the program could deadlock XLA's CPU thread pool (``_friction._spans``); only l* <= 0 is
    # used, and a rank-deficient set is not force-closure either way.
    margin = min_weight_margin(points, normals, cap, model, center, scale, iterations, best_effort, full=True)
    found = status != FrictionStatus.ABOVE_CAP
    return jnp.where(found, -jnp.where(found, mu_star, 0.0), -cap + jnp.minimum(margin, 0.0))


def is_positive(value, dtype) -> jax.Array:
    """Whether an objective value counts as force-closure (above the margin tolerance)."""
    return value > tolerances(dtype).margin


# ---------------------------------------------------------------------------------------------
# The batched public function.


def _objective_single(points, normals, shared, *, kind, iterations):
    mu, model, center, scale = shared
    return objective_one(points, normals, mu, model, kind, center, scale, iterations)[0]


def objective(
    points,
    normals,
    *,
    mu,
    kind: str = "closure",
    num_edges: int = DEFAULT_NUM_EDGES,
    center=None,
    scale: float = 1.0,
    iterations: int | None = None,
    contact: str = "hard",
    torsion=None,
):
    """An optimizer's objective (larger is better) for a batch of grasps, differentiable in
    ``points`` and ``normals`` (``jax.grad``, ``jit``, ``vmap``); see the module docstring.

    Args:
        points, normals: ``(..., n, d)``, normals outward; ``c_1`` is contact 0.
        mu, num_edges, iterations, contact, torsion: as :func:`grasp_jax.evaluate`.
        kind: one of :data:`OBJECTIVES`.
        center: ``(d,)`` the object's centre (default the origin) and ``scale`` its radius: torques
            of ``"min_weight"`` and the DFC energies are taken about ``center`` in units of ``scale``.

    Returns:
        ``(...)`` float. For ``"closure"``, ``"closure_any"`` and ``"min_weight"``: > 0 exactly
        when the grasp is force-closure.
    """
    if kind not in OBJECTIVES:
        raise ValueError(f"kind must be one of {', '.join(map(repr, OBJECTIVES))}; got {kind!r}")
    points, normals, _, batch, mu, num_edges, scope = _check_common(points, normals, mu, num_edges, None, torsion)
    scale = check_scalar("scale", scale)
    d = points.shape[-1]
    model = contact_model(contact, torsion, num_edges, d)
    with scope:
        center = jnp.zeros(d, points.dtype) if center is None else jnp.asarray(center, points.dtype)
        if center.shape != (d,):
            raise ValueError(f"center must have shape ({d},); got {center.shape}")
        fn = _bind(_objective_single, kind=kind, iterations=iterations)
        model = model.astype(points.dtype)
        shared = (jnp.asarray(mu, points.dtype), model, center,
                  jnp.asarray(scale, points.dtype))
        return map_grasps(fn, (points, normals), shared, batch)
