"""The batched public functions: validation, then the single-grasp code of ``_closure`` mapped over
the batch by ``_batch.map_grasps``."""

from __future__ import annotations

import dataclasses
import warnings
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from . import _closure, _friction
from ._batch import Retry, Staged, map_grasps
from ._constants import DEFAULT_NUM_EDGES, default_iterations, first_pass_iterations, tolerances
from ._contact import CONTACTS, ContactModel, columns_per_contact
from ._precision import scope_for
from ._result import GraspEvaluation
from ._validate import check_grasps, check_int, check_num_edges, check_scalar, is_traced
from .lp import Status

_TORQUE_TESTS = ("exact", "paper")


def _check_common(points, normals, mu, num_edges, tangents, torsion=0.0):
    """Validated inputs and the precision context the call runs in (see ``_precision``)."""
    points, normals, tangents, batch = check_grasps(points, normals, tangents)
    mu = check_scalar("mu", mu)
    num_edges = check_num_edges(num_edges)
    if is_traced(mu, torsion):
        points, normals, tangents = _as_traced(points, normals, tangents)
    scope = scope_for(points.dtype, is_traced(points, normals, tangents, mu, torsion))
    return points, normals, tangents, batch, mu, num_edges, scope


def check_contact(contact, torsion, d: int):
    """``(contact, torsion)`` validated: a known model, a torsion (a finite length >= 0) exactly
    where the model has one, hard contacts only in 2D. ``torsion`` comes back as a float (0 for
    hard contacts) or a tracer."""
    if contact not in CONTACTS:
        raise ValueError(f"contact must be one of {', '.join(map(repr, CONTACTS))}; got {contact!r}")
    if contact == "hard":
        if torsion is not None:
            raise ValueError("torsion is the torsional coefficient of soft contacts; pass contact='soft' "
                             "(or 'dexnet-soft') with it, or leave it out for hard contacts")
        return contact, 0.0
    if d == 2:
        raise ValueError(f"contact={contact!r} is 3D only: in the plane a contact's moment about its normal "
                         "is about an in-plane axis, outside the planar wrench space (f_x, f_y, tau_z)")
    if torsion is None:
        helper = "gj.patch_torsion(radius, mu)" if contact == "soft" else "gj.dexnet_torsion(finger_radius, mu)"
        raise ValueError(f"contact={contact!r} needs torsion=, the largest moment about the normal "
                         f"{'per unit normal force (a length)' if contact == 'soft' else 'of a contact'}; "
                         f"e.g. {helper}")
    return contact, check_scalar("torsion", torsion, positive=False, minimum=0.0)


def _as_traced(*arrays):
    """Concrete grasp arrays of a call whose other arguments are traced: as JAX arrays of the
    caller's precision (rule 1 of ``_precision``)."""
    return tuple(None if a is None else jnp.asarray(a) for a in arrays)


def _warn_unconverged(status, what: str):
    if is_traced(status):
        return
    bad = int(np.sum(np.asarray(status) == Status.NOT_CONVERGED))
    if bad:
        warnings.warn(
            f"{bad} of {np.size(status)} {what} did not converge in the iteration budget; their "
            "results are reported as not force-closure with quality 0 (see the status fields). "
            "Pass iterations= to give the solver more.",
            RuntimeWarning,
            stacklevel=3,
        )


#: float32: the retry pass runs an unfinished LP again from this many of the starting points of
#: ``tolerances(float32).restarts``; what it still leaves unfinished (about 1 grasp in 1,000), a
#: third pass runs from all of them (all of them in one pass would cost a third of the throughput).
RETRY_RESTARTS = 2

#: Grasps per block of :func:`min_weight`'s chunks (``_batch.map_grasps(block=)``): its LP runs
#: with the full budget in one pass, and in blocks of 512 the LPs stream through lanes
#: (``lp._stream``), each taking its own iterations, with the results of lock step (about 8% faster
#: than blocks of 256). One size for every batch: one compiled program per grasp shape.
MIN_WEIGHT_BLOCK = 512


def _restart_points(dtype) -> tuple[np.int32, np.int32]:
    """``(points of the retry pass, all points)`` an unfinished LP restarts from (float32: 2, 6;
    float64, which needs none: 0, 0). A last pass from all of them is needed where they differ."""
    every = len(tolerances(dtype).restarts)
    return np.int32(min(RETRY_RESTARTS, every)), np.int32(every)


def contact_model(contact, torsion, num_edges: int, d: int) -> ContactModel:
    """The :class:`ContactModel` of validated arguments (:func:`check_contact`)."""
    contact, torsion = check_contact(contact, torsion, d)
    return ContactModel(contact, num_edges, torsion)


def _evaluate_single(points, normals, tangents, shared, *, torque_test):
    (mu, model), iterations, restarts = shared  # traced: every budget runs one compiled program
    return _closure.evaluate_one(points, normals, mu, model, torque_test, tangents, iterations, restarts)


def _torque_stage(points, normals, tangents, shared):
    (mu, model), iterations, restarts = shared
    return _closure.torque_stage(points, normals, mu, model, tangents, iterations, restarts)


def _quality_stage(points, normals, tangents, torques, shared):
    (mu, model), iterations, restarts = shared
    return _closure.quality_stage(points, normals, mu, model, torques, tangents, iterations, restarts)


def evaluation_function(points, torque_test: str):
    """The single-grasp function of an evaluation, ``(points, normals, tangents, shared) ->``
    :class:`GraspEvaluation` with ``shared = ((mu, model), iterations, restarts)``: in two
    stages (``_batch.Staged``: the quality LP only where the torque LP leaves it needed) where
    ``_closure.staged``, else in one."""
    if _closure.staged(points, torque_test):
        return Staged(_torque_stage, _quality_stage)
    return _bind(_evaluate_single, torque_test=torque_test)


def evaluate(
    points,
    normals,
    *,
    mu,
    num_edges: int = DEFAULT_NUM_EDGES,
    torque_test: str = "exact",
    tangents=None,
    iterations: int | None = None,
    progress: bool = False,
    contact: str = "hard",
    torsion=None,
) -> GraspEvaluation:
    """Decide force-closure and compute the quality Q of a batch of grasps.

    Args:
        points: ``(..., n, d)`` contact points, ``d`` in {2, 3}, ``n >= 2``; the reference contact
            ``c_1`` is index 0. NumPy or JAX, any leading batch shape.
        normals: ``(..., n, d)`` **outward** surface normals (normalized here).
        mu: friction coefficient ``tan(alpha)`` > 0.
        num_edges: edges of each linearized 3D friction cone (the paper uses 25; 2D cones have 2).
        torque_test: ``"exact"`` (positive-spanning LP, the default) or ``"paper"`` (eq. 15 / 21,
            only necessary in 3D; see ``MATH.md``).
        tangents: optional ``(..., n, 3)`` first tangent direction of each contact frame.
        iterations: interior-point iterations. Default: a first pass of 10 to 16 (by LP size,
            ``_constants.first_pass_iterations``), then the grasps it leaves unfinished again
            with 30 (40 above 64 LP columns; in float32 restarted from other points, the few
            that stall in a pass of their own, :data:`RETRY_RESTARTS`); an explicit number is
            one pass with that budget.
        progress: show a progress bar (concrete inputs only).
        contact: the contact model: ``"hard"`` (point contact with friction, the paper's),
            ``"soft"`` (soft finger: a moment about the normal up to ``torsion`` times the normal
            force) or ``"dexnet-soft"`` (Dex-Net's soft-finger columns); 3D only, see
            ``grasp_jax._contact``.
        torsion: the soft contact's torsional coefficient, a length >= 0 (``"soft"``:
            :func:`grasp_jax.patch_torsion` of a patch radius; ``"dexnet-soft"``:
            :func:`grasp_jax.dexnet_torsion`). Required for soft contacts, refused for hard ones.

    Returns:
        :class:`GraspEvaluation` whose fields have the leading batch shape.
    """
    if torque_test not in _TORQUE_TESTS:
        raise ValueError(f"torque_test must be one of {_TORQUE_TESTS}; got {torque_test!r}")
    points, normals, tangents, batch, mu, num_edges, scope = _check_common(points, normals, mu, num_edges, tangents,
                                                                           torsion)
    model = contact_model(contact, torsion, num_edges, points.shape[-1])
    fn = evaluation_function(points, torque_test)
    budget, retry = _passes(points, model, iterations)
    with scope:
        friction = (jnp.asarray(mu, points.dtype), model.astype(points.dtype))
        shared = (friction, *budget)
        retry = tuple(Retry((friction, *pass_), _unfinished) for pass_ in retry)
        result = map_grasps(fn, (points, normals, tangents), shared, batch, progress=progress, retry=retry)
    _warn_unconverged(result.quality_status, "quality LPs")
    _warn_unconverged(result.torque_status, "torque LPs")
    return result


def _passes(points, model: ContactModel, iterations) -> tuple[tuple, tuple]:
    """``(iterations, restarts)`` of the first pass and of each retry pass (:class:`Retry`) of
    :func:`evaluate` and :func:`quality`.

    Default: a fast pass with a short budget (``first_pass_iterations``), then the full budget for
    the few grasps it leaves unfinished (float32: restarted from :data:`RETRY_RESTARTS` points,
    then the few still unfinished from all of them). An explicit ``iterations``: one pass with that
    budget, all restarts. The budget is an input of the program: one program serves every pass.
    """
    few, every = _restart_points(points.dtype)
    if iterations is not None:
        iterations = _check_iterations(iterations)
        return (iterations if is_traced(iterations) else np.int32(iterations), every), ()
    columns = _lp_columns(points.shape[-2], points.shape[-1], model.num_edges, model.kind)
    full = np.int32(default_iterations(columns))
    retry = ((full, few),) + (((full, every),) if every > few else ())
    return (np.int32(first_pass_iterations(columns)), every), retry


def _check_iterations(iterations):
    if is_traced(iterations):
        return iterations
    return check_int("iterations", iterations)


def _lp_columns(n: int, d: int, num_edges: int, contact: str = "hard") -> int:
    """Columns of the largest LP of a grasp: the quality LP's ``K + 1`` (hard: ``K = n m``)."""
    return n * (2 if d == 2 else columns_per_contact(contact, num_edges)) + 1


def _unfinished(result: GraspEvaluation) -> jax.Array:
    return (result.quality_status == Status.NOT_CONVERGED) | (result.torque_status == Status.NOT_CONVERGED)


def force_closure(points, normals, *, mu, num_edges: int = DEFAULT_NUM_EDGES, torque_test: str = "exact", tangents=None,
                  contact: str = "hard", torsion=None):
    """``(...)`` bool: whether each grasp is force-closure (Proposition 2). Arguments as
    :func:`evaluate`; ``torque_test="paper"`` reproduces eq. (15) / (21)."""
    return evaluate(points, normals, mu=mu, num_edges=num_edges, torque_test=torque_test, tangents=tangents,
                    contact=contact, torsion=torsion).force_closure


def _quality_single(points, normals, tangents, shared, *, signed):
    (mu, model), iterations, restarts = shared  # traced, as in evaluate
    return _closure.quality_one(points, normals, mu, model, signed, tangents, iterations, restarts)


def _quality_unfinished(out) -> np.ndarray:
    return np.asarray(out[1]) == Status.NOT_CONVERGED


def quality(
    points,
    normals,
    *,
    mu,
    num_edges: int = DEFAULT_NUM_EDGES,
    signed: bool = False,
    tangents=None,
    iterations: int | None = None,
    contact: str = "hard",
    torsion=None,
):
    """The paper's quality Q (eq. 23) of each grasp, differentiable in ``points``, ``normals``,
    ``mu`` and ``torsion``.

    Q is the optimum ``delta*`` of the normalized equilibrium LP; derivatives come from the
    envelope theorem on the LP's primal-dual solution (no iteration is differentiated), so
    ``jax.grad`` and ``jax.jacrev`` work and are finite everywhere.

    Args:
        points, normals, mu, num_edges, tangents, iterations, contact, torsion: as :func:`evaluate`.
        signed: return ``delta*`` itself, negative where the grasp is not in equilibrium, instead
            of clipping it to 0. Its gradient pulls a grasp towards equilibrium from anywhere,
            which is what a contact optimizer wants.

    Returns:
        ``(...)`` float: Q, ``0`` where the grasp is not in equilibrium (unless ``signed``).
    """
    points, normals, tangents, batch, mu, num_edges, scope = _check_common(points, normals, mu, num_edges, tangents,
                                                                           torsion)
    model = contact_model(contact, torsion, num_edges, points.shape[-1])
    fn = _bind(_quality_single, signed=signed)
    budget, retry = _passes(points, model, iterations)
    with scope:
        friction = (jnp.asarray(mu, points.dtype), model.astype(points.dtype))
        shared = (friction, *budget)
        retry = tuple(Retry((friction, *pass_), _quality_unfinished) for pass_ in retry)
        value, _ = map_grasps(fn, (points, normals, tangents), shared, batch, retry=retry)
        return value


def _min_weight_single(points, normals, tangents, shared, *, iterations):
    mu, model, origin, torque_scale = shared
    return _closure.min_weight_one(points, normals, mu, model, origin, torque_scale, tangents, iterations)


def min_weight(
    points,
    normals,
    *,
    mu,
    num_edges: int = DEFAULT_NUM_EDGES,
    origin=None,
    torque_scale: float = 1.0,
    tangents=None,
    iterations: int | None = None,
    contact: str = "hard",
    torsion=None,
):
    """The classical force-closure margin: ``l*`` of the min-weight LP on the primitive wrenches,

    ``max l  s.t.  sum_k alpha_k w_k = 0,  sum alpha = 1,  alpha_k >= l``.

    ``l* > 0`` iff the grasp is force-closure (then every primitive wrench takes part with weight
    at least ``l*``). Independent of Proposition 2, this is the reference definition.

    Args:
        points, normals, mu, num_edges, tangents, iterations, contact, torsion: as :func:`evaluate`
            (soft contacts: the wrenches of ``grasp_jax._contact``; torsion moments are divided
            by ``torque_scale`` like the torques).
        origin: ``(d,)`` point torques are taken about (default: the frame origin). ``l*`` does
            not depend on it; its sign never does.
        torque_scale: torques are divided by this length (> 0).

    Returns:
        ``(...)`` float ``l*``: 0 where the wrenches do not span the wrench space, ``-inf`` where
        no affine combination of them vanishes (LP infeasible).
    """
    points, normals, tangents, batch, mu, num_edges, scope = _check_common(points, normals, mu, num_edges, tangents,
                                                                           torsion)
    d = points.shape[-1]
    model = contact_model(contact, torsion, num_edges, d)
    if origin is not None and not is_traced(origin):
        origin = np.asarray(origin, points.dtype)
    if origin is not None and origin.shape != (d,):
        raise ValueError(f"origin must have shape ({d},); got {origin.shape}")
    torque_scale = check_scalar("torque_scale", torque_scale)
    if is_traced(origin, torque_scale) and not is_traced(points):
        points, normals, tangents = _as_traced(points, normals, tangents)
        scope = scope_for(points.dtype, traced=True)
    fn = _bind(_min_weight_single, iterations=iterations)
    with scope:
        origin = jnp.zeros(d, points.dtype) if origin is None else jnp.asarray(origin, points.dtype)
        shared = (jnp.asarray(mu, points.dtype), model.astype(points.dtype), origin,
                  jnp.asarray(torque_scale, points.dtype))
        margin, status = map_grasps(fn, (points, normals, tangents), shared, batch, block=MIN_WEIGHT_BLOCK)
    _warn_unconverged(status, "min-weight LPs")
    return margin


@dataclasses.dataclass(frozen=True)
class _Bound:
    """``func`` with static keyword arguments; equal (and hashed) by value, so that the compiled
    chunk functions of ``_batch`` are reused across calls with the same settings."""

    func: Callable
    kwargs: tuple

    def __call__(self, *args):
        return self.func(*args, **dict(self.kwargs))


def _bind(func: Callable, **kwargs) -> _Bound:
    return _Bound(func, tuple(sorted(kwargs.items())))


def _critical_single(points, normals, tangents, start, shared):
    model, cap, steps, iterations = shared  # traced: both passes run one compiled program
    return _friction.critical_friction_one(points, normals, cap, model, tangents, iterations, steps, start)


def _critical_first(points, normals, tangents, start, shared):
    """The first stage of a search pass (``_batch.Staged``): ``steps`` steps, then the searches
    still open go on, gathered, for ``more`` steps (:func:`_critical_more`)."""
    model, cap, steps, more, iterations = shared
    # the full state (with the last LP's solution) to the second stage, the short one to the batch
    full = _friction.full_state(start, points.shape, model.kind, model.num_edges)
    mu, status, state = _friction.critical_friction_one(points, normals, cap, model, tangents, iterations, steps, full)
    open_ = (status == _friction.FrictionStatus.NOT_CONVERGED) & (more > 0)
    return (mu, status, state[:_friction.RESUME]), state, open_


def _critical_more(points, normals, tangents, start, carry, shared):
    """The second stage: resumed from the first's state (a search it closed ends where it was)."""
    model, cap, steps, more, iterations = shared
    mu, status, state = _friction.critical_friction_one(points, normals, cap, model, tangents, iterations, more, carry)
    return mu, status, state[:_friction.RESUME]


def _resume_search(out, batched):
    """The second pass of :func:`critical_friction` goes on from the first pass's brackets."""
    return (*batched[:-1], out[2])


def _search_open(out) -> jax.Array:
    return out[1] == _friction.FrictionStatus.NOT_CONVERGED


def critical_friction(
    points,
    normals,
    *,
    num_edges: int = DEFAULT_NUM_EDGES,
    contact: str = "hard",
    torsion=None,
    cap: float = _friction.DEFAULT_CAP,
    tangents=None,
    progress: bool = False,
):
    """The smallest friction coefficient at which each grasp is force-closure.

    Force-closure is monotone in ``mu`` (each pyramid contains the pyramids of smaller ``mu``), so
    ``mu*`` is well defined: the grasp holds for every ``mu > mu*`` and for none below. Found to a
    relative accuracy of 1e-6 (float32: 3e-5) by bracketed Newton / false-position steps on the
    min-weight margin, and differentiable in ``points``, ``normals`` and ``torsion`` (implicit
    function theorem; ``grasp_jax._friction``). GraspNet-1Billion's label is
    :func:`friction_label` of it.

    Args:
        points, normals, num_edges, contact, tangents: as :func:`evaluate`.
        torsion: soft contacts' torsional coefficient, held fixed while ``mu`` moves.
        cap: largest ``mu`` searched (> 0): a grasp not force-closure at ``cap`` gets ``inf``.
        progress: a progress bar over the chunks of a large batch.

    Returns:
        ``(mu, status)``: ``(...)`` float ``mu*`` (``inf`` where not force-closure at ``cap``, 0
        for a grasp that holds without friction), and ``(...)`` int8 :class:`FrictionStatus`
        (``FOUND``, ``ABOVE_CAP``, ``FRICTIONLESS``, ``NOT_CONVERGED``).
    """
    points, normals, tangents, batch, _, num_edges, scope = _check_common(points, normals, 1.0, num_edges, tangents,
                                                                          torsion)
    contact, torsion = check_contact(contact, torsion, points.shape[-1])
    cap = check_scalar("cap", cap)
    if is_traced(cap) and not is_traced(points):
        points, normals, tangents = _as_traced(points, normals, tangents)
        scope = scope_for(points.dtype, traced=True)
    traced = is_traced(points)
    if traced:
        fn = _critical_single
    else:
        fn = Staged(_critical_first, _critical_more)
    with scope:
        model = ContactModel(contact, num_edges, jnp.asarray(torsion, points.dtype))
        cap = jnp.asarray(cap, points.dtype)
        # A first pass of few steps, each with a short interior-point budget; the searches it
        # leaves open again with every step and the full budget (``_friction.FIRST_STEPS``,
        # ``FIRST_EXTRA_ITERATIONS``). (No crossover: ``_friction.CROSSOVER``.)
        columns = _friction.min_weight_columns(points.shape[-2], points.shape[-1], contact, num_edges)
        iterations = np.int32(default_iterations(columns))
        short = min(int(iterations), first_pass_iterations(columns) + _friction.FIRST_EXTRA_ITERATIONS)
        # The first pass in two stages: FIRST_STAGE_STEPS steps for every grasp, then the rest of
        # FIRST_STEPS for the searches still open, gathered into full blocks (a block no longer
        # waits for its slowest search for all FIRST_STEPS steps). The second pass resumes each
        # search still open from its last proven bracket (``_friction._search``), with every step
        # and the full budget, in one stage.
        more = _friction.FIRST_STEPS - _friction.FIRST_STAGE_STEPS
        first = (np.int32(_friction.MAX_STEPS), iterations) if traced else \
            (np.int32(_friction.FIRST_STAGE_STEPS), np.int32(more), np.int32(short))
        retry = Retry((model, cap, np.int32(_friction.MAX_STEPS), np.int32(0), iterations), _search_open,
                      _resume_search)
        # (traced: a jnp array, a NumPy constant of this dtype is not canonical inside jit)
        start = jnp.zeros(batch + (_friction.RESUME,), points.dtype) if traced else \
            np.zeros(batch + (_friction.RESUME,), points.dtype)
        mu, status, _ = map_grasps(fn, (points, normals, tangents, start), (model, cap, *first), batch,
                                   progress=progress, retry=None if traced else retry, block=_friction.BLOCK)
    if not is_traced(status):
        stuck = int(np.sum(np.asarray(status) == _friction.FrictionStatus.NOT_CONVERGED))
        if stuck:
            warnings.warn(f"{stuck} of {np.size(status)} critical friction searches did not converge; their mu is "
                          "an upper bound at which the grasp is force-closure (status NOT_CONVERGED)",
                          RuntimeWarning, stacklevel=2)
    return mu, status


#: GraspNet-1Billion's friction coefficients, in the order its labels try them.
GRASPNET_FRICTIONS = (0.2, 0.4, 0.6, 0.8, 1.0, 1.2)


def friction_label(mu, levels=GRASPNET_FRICTIONS):
    """GraspNet-1Billion's discrete label from :func:`critical_friction`: the smallest of
    ``levels`` at which the grasp is force-closure (``mu* < level``), ``-1`` where none is.

    Args:
        mu: ``(...)`` critical friction coefficients.
        levels: increasing friction coefficients (default GraspNet's 0.2, 0.4, ..., 1.2).

    Returns:
        ``(...)`` float array of labels (a level, or -1).
    """
    levels = np.asarray(levels, float)
    if levels.ndim != 1 or levels.size == 0 or np.any(np.diff(levels) <= 0) or np.any(levels <= 0):
        raise ValueError(f"levels must be increasing positive friction coefficients; got {levels.tolist()}")
    mu = np.asarray(mu)
    index = np.searchsorted(levels, mu, side="right")  # first level > mu*
    return np.where(index < levels.size, levels[np.minimum(index, levels.size - 1)], -1.0)
