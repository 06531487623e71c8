"""Multi-start gradient optimization of contacts on an object's surface: the optimizer loop.

``surfaces`` says how a contact sits on and moves over each object kind, ``_objectives`` what is
maximized; this module advances one *start* ``length`` steps by ``lax.scan`` (:func:`_segment`),
batched over all starts by ``_batch.map_grasps``, segment after segment for a progress bar.

A step, for every start at once: the objective's gradient with respect to an ambient displacement
``v: (n, d)`` of the contacts at ``v = 0`` (through ``surface.chart``: a Riemannian gradient), one
optax update of ``-gradient``, and ``surface.retract`` by the update times the object's radius.
Each start keeps its best iterate (the highest Q among those the closure objective calls
force-closure, else the highest objective), scored at the end by :func:`grasp_jax.evaluate`: the
reported ``quality`` is exactly what ``evaluate`` returns for the reported contacts.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
import time

import jax
import jax.numpy as jnp
import numpy as np
import optax

from . import _noise
from . import surfaces as _surfaces
from ._api import _bind, _lp_columns, contact_model, evaluate
from ._batch import map_grasps
from ._constants import DEFAULT_NUM_EDGES, first_pass_iterations, tolerances
from ._contact import ContactModel
from ._objectives import OBJECTIVES, objective_one
from ._precision import float64_scope
from ._result import GraspEvaluation
from ._status import StatusEnum
from ._validate import check_int, check_key, check_num_edges, check_scalar

#: Default peak learning rates of Adam, in object radii per step: from random starts (the smallest
#: of 0.02..0.8 with >= 99.5% of 256 random 4-finger starts on the glass force-closure after 100
#: steps was 0.4; 0.2 gave 99.2% with the highest median Q: ``experiments/bench_optimize.py``), and
#: for refining given starts (``init``), which are near a good grasp already.
DEFAULT_LEARNING_RATE = 0.3
REFINE_LEARNING_RATE = 0.02
#: From random starts the default optimizer restarts Adam (moments reset) after this fraction of
#: the steps, at this fraction of the peak learning rate (:func:`default_optimizer`).
RESTART_AT = 1 / 3
RESTART_RATE = 1 / 6
#: Steps over which the restarted Adam's rate rises linearly from where the first decay ended (1% of
#: the peak) to its own peak: a fresh Adam's first updates are full-size, and without the ramp
#: the median Q of the iterates fell to 0 for about 12 steps after the restart.
RESTART_WARMUP = 5
#: Segments of the step loop (one compiled call each; the progress bar advances per segment):
#: at most :data:`SEGMENTS`, of about :data:`MIN_SEGMENT` steps or more (a call costs about 10 ms
#: on the host whatever its length).
SEGMENTS = 20
MIN_SEGMENT = 10
#: A start has converged when its best objective rose by less than this over the last
#: :data:`CONVERGED_WINDOW` of the steps.
CONVERGED_TOL = 1e-3
CONVERGED_WINDOW = 0.25
#: Distinct grasps: contacts closer than this fraction of the object's radius are the same.
DISTINCT_TOL = 0.01

_CLOSURE_KINDS = ("closure", "closure_any")
#: ``objective=ROBUST`` (with ``noise=``): the mean ``"closure"`` objective over fixed
#: perturbations (:func:`grasp_jax._noise.robust_value`).
ROBUST = "robust"


class EndReason(StatusEnum):
    """Why a start ended where it did (stored per start as ``int8``)."""

    FORCE_CLOSURE = 0, "force-closure reached"
    CONVERGED = 1, "converged below force-closure"
    NOT_CONVERGED = 2, "not converged in the step budget"


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class OptimizeResult:
    """What :func:`optimize` found, one entry per start (``S`` starts, ``n`` contacts, ``d``).

    Attributes:
        points: ``(S, n, d)`` the best iterate of each start, exactly on the surface: the highest Q
            among the iterates that are force-closure (by the closure objective's sign), else the
            highest objective (by objective alone when ``quality_history`` is ``None``).
        normals: ``(S, n, d)`` outward unit normals there, of kind ``normal_kind``; the grasps were
            scored with these.
        evaluation: :class:`GraspEvaluation` of ``points, normals`` by :func:`grasp_jax.evaluate`.
        objective: ``(S,)`` the objective at ``points``.
        history: ``(S, steps)`` the objective at each step's iterate.
        quality_history: ``(S, steps)`` Q of each step's iterate where its closure objective is
            positive (force-closure), else 0; ``None`` when not monitored. From the step's LPs
            (``iterations``); one left unfinished gives its best iterate's Q.
        reason: ``(S,) int8`` :class:`EndReason`.
        initial_points: ``(S, n, d)`` the starts, on the surface.
        path: ``(S, F, n, d)`` the contacts' positions (on the surface) at the start and after each
            compiled segment of steps (``F - 1`` of them, :data:`SEGMENTS` at most; the last is the
            final iterate, which need not be the best): for drawing where the contacts went.
        objective_name, normal_kind: static strings.
        steps, seconds: the budget and the wall time.
        scale: the object's radius.
        learning_rate: the default optimizer's peak rate (``None`` with a user's optimizer).
    """

    points: jax.Array
    normals: jax.Array
    evaluation: GraspEvaluation
    objective: jax.Array
    history: jax.Array
    quality_history: jax.Array | None
    reason: jax.Array
    initial_points: jax.Array
    path: jax.Array | None = None
    objective_name: str = dataclasses.field(metadata={"static": True}, default="closure")
    normal_kind: str = dataclasses.field(metadata={"static": True}, default="smooth")
    steps: int = dataclasses.field(metadata={"static": True}, default=0)
    seconds: float = dataclasses.field(metadata={"static": True}, default=0.0)
    scale: float = dataclasses.field(metadata={"static": True}, default=1.0)
    learning_rate: float | None = dataclasses.field(metadata={"static": True}, default=None)

    @property
    def force_closure(self) -> np.ndarray:
        """``(S,) bool`` exact verdicts of the reported grasps."""
        return np.asarray(self.evaluation.force_closure)

    @property
    def quality(self) -> np.ndarray:
        """``(S,) float`` Q of the reported grasps (exactly ``evaluate``'s)."""
        return np.asarray(self.evaluation.quality)

    def distinct(self, tol: float = DISTINCT_TOL, *, force_closure_only: bool = True) -> np.ndarray:
        """Indices of distinct grasps, best Q first.

        Two grasps are the same when their first contacts and their other contacts (in any order:
        ``c_2..c_n`` are interchangeable, ``c_1`` is the reference) fall in the same cells of a
        grid of ``tol`` times the object's radius.
        """
        return distinct_grasps(np.asarray(self.points), self.quality, tol * self.scale,
                               mask=self.force_closure if force_closure_only else None)

    @property
    def num_distinct_force_closure(self) -> int:
        return len(self.distinct())

    def summary(self) -> dict:
        """Numbers a person looks at first (fractions, percentiles, counts, speed)."""
        fc, q = self.force_closure, self.quality
        reasons = np.asarray(self.reason)
        starts = len(fc)
        return {
            "starts": starts,
            "steps": self.steps,
            "objective": self.objective_name,
            "normals": self.normal_kind,
            "force_closure_fraction": float(fc.mean()) if starts else 0.0,
            "quality_percentiles": {p: float(np.percentile(q[fc], p)) if fc.any() else 0.0
                                    for p in (50, 90, 99, 100)},
            "distinct_force_closure": self.num_distinct_force_closure,
            "reasons": {r.name.lower(): int((reasons == r).sum()) for r in EndReason},
            "seconds": self.seconds,
            "start_steps_per_second": starts * self.steps / self.seconds if self.seconds else 0.0,
        }

    def __repr__(self) -> str:
        if not isinstance(self.points, (np.ndarray, jax.Array)) or isinstance(self.points, jax.core.Tracer):
            return f"OptimizeResult(objective={self.objective_name!r}, traced)"
        s = self.summary()
        return (f"OptimizeResult({s['starts']} starts x {s['steps']} steps, objective={self.objective_name!r}, "
                f"force-closure {100 * s['force_closure_fraction']:.1f}%, "
                f"Q median {s['quality_percentiles'][50]:.3f} / best {s['quality_percentiles'][100]:.3f}, "
                f"{s['distinct_force_closure']} distinct force-closure grasps, {self.seconds:.1f} s)")


def distinct_grasps(points: np.ndarray, quality: np.ndarray, cell: float, mask=None) -> np.ndarray:
    """Indices of distinct grasps of ``points: (S, n, d)``, best ``quality`` first (see
    :meth:`OptimizeResult.distinct`)."""
    points = np.asarray(points, dtype=np.float64)
    index = np.arange(len(points)) if mask is None else np.flatnonzero(mask)
    if len(index) == 0:
        return index
    cells = np.floor(points[index] / cell).astype(np.int64)  # (k, n, d)
    first, rest = cells[:, :1], cells[:, 1:]
    # c_2..c_n in a canonical order: sort their cell rows lexicographically.
    order = np.lexsort(tuple(rest[..., j] for j in reversed(range(rest.shape[-1]))), axis=-1) if rest.shape[1] else None
    if order is not None:
        rest = np.take_along_axis(rest, order[..., None], axis=1)
    keys = np.concatenate([first, rest], axis=1).reshape(len(index), -1)
    by_quality = np.argsort(-np.asarray(quality)[index], kind="stable")
    _, keep = np.unique(keys[by_quality], axis=0, return_index=True)
    return index[by_quality[np.sort(keep)]]


# ---------------------------------------------------------------------------------------------
# One start, one segment of steps.


def _segment(*args, treedef, kind: str, optimizer, length: int, total: int, monitor: bool, iterations: int,
             noise_flags=None):
    """Advance one start ``length`` steps. ``args``: the leaves of the start's state
    ``(contacts, optimizer state, travel, best contacts, best objective, best Q)`` (built in
    :func:`_run`; ``travel: (n, d)`` is the sum of the updates so far, the ``params`` the optimizer
    sees), then ``shared = (surface, (mu, model), offset, robust)`` (``robust``: the fixed
    perturbations of ``objective="robust"``, :class:`grasp_jax._noise.Reparameterized`, else
    ``None``; ``noise_flags``: their static structure).

    Returns ``(state leaves, values (length,), qualities (length,))``.
    """
    *leaves, (surface, (mu, model), offset, robust) = args
    contacts, opt_state, travel, best, best_value, best_q = jax.tree_util.tree_unflatten(treedef, leaves)
    n, d = contacts.face.shape[0], surface.dim
    dtype = contacts.coords.dtype
    zeros = jnp.zeros((n, d), dtype)
    margin = tolerances(dtype).margin

    def value(v, contacts):
        if kind == ROBUST:
            def closure(points, normals, mu_per_contact):
                return objective_one(points, normals, mu_per_contact, model, "closure", surface.center,
                                     surface.scale, iterations, best_effort=True)[0]

            mean, _ = _noise.robust_value(surface, contacts, v, mu, robust, closure, flags=noise_flags)
            return mean, {}
        points, normals = jax.vmap(surface.chart)(contacts, v * surface.scale)
        return objective_one(points, normals, mu, model, kind, surface.center, surface.scale, iterations,
                             best_effort=True)

    def step(carry, i):
        contacts, opt_state, travel, best, best_value, best_q = carry
        (val, mon), grad = jax.value_and_grad(value, has_aux=True)(zeros, contacts)
        grad = jnp.where(jnp.isfinite(grad), grad, 0.0)
        updates, new_opt = optimizer.update(-grad, opt_state, travel)
        moved = jax.vmap(surface.retract)(contacts, updates * surface.scale)
        active = offset + i < total
        keep = lambda new, old: jax.tree_util.tree_map(lambda a, b: jnp.where(active, a, b), new, old)
        if kind in _CLOSURE_KINDS:
            q = jnp.where(val > margin, mon["delta"], 0.0)
        elif monitor:
            points, normals = jax.vmap(surface.embed)(contacts)
            closure, aux = objective_one(points, normals, mu, model, "closure", surface.center, surface.scale,
                                         iterations, best_effort=True)
            q = jnp.where(closure > margin, aux["delta"], 0.0)
        else:
            q = jnp.zeros((), dtype)
        # The best iterate: force-closure ones (q > 0) by Q, before the others by objective; for
        # the robust objective, by it alone (the mean under noise is what is asked for).
        if kind == ROBUST:
            better = (val > best_value) & active
        else:
            better = jnp.where(q > 0, q > best_q, (best_q <= 0) & (val > best_value)) & active
        best = jax.tree_util.tree_map(lambda b, c: jnp.where(better, c, b), best, contacts)
        best_value = jnp.where(better, val, best_value)
        best_q = jnp.where(better, q, best_q)
        new = (moved, new_opt, travel + updates)
        return (*keep(new, (contacts, opt_state, travel)), best, best_value, best_q), (val, q)

    carry = (contacts, opt_state, travel, best, best_value, best_q)
    carry, (values, qualities) = jax.lax.scan(step, carry, jnp.arange(length))
    return tuple(jax.tree_util.tree_leaves(carry)), values, qualities


@functools.cache
def default_optimizer(steps: int, learning_rate: float = DEFAULT_LEARNING_RATE,
                      restart: bool = False) -> optax.GradientTransformation:
    """Adam with a cosine decay from ``learning_rate`` to 1% of it over ``steps`` (cached, so
    that repeated calls reuse the compiled step).

    ``restart`` (what :func:`optimize` uses from random starts): the decay spans the first
    :data:`RESTART_AT` of the steps, then a fresh Adam (moments reset) decays from
    :data:`RESTART_RATE` x ``learning_rate`` (reached by a linear ramp of :data:`RESTART_WARMUP`
    steps from the first decay's end) to 1% of that over the rest: the first phase finds
    force-closure, the second climbs the ridges of Q that a fully decayed rate crawls along (about
    twice as many starts end at a local optimum in 60 steps as with one decay).
    """
    first = round(steps * RESTART_AT) if restart else steps
    if not restart or first < 1 or steps - first < 1:
        return optax.adam(optax.cosine_decay_schedule(learning_rate, decay_steps=steps, alpha=0.01))
    explore = optax.adam(optax.cosine_decay_schedule(learning_rate, decay_steps=first, alpha=0.01))
    peak, rest = learning_rate * RESTART_RATE, steps - first
    warmup = min(RESTART_WARMUP, rest // 4)
    if warmup:
        schedule = optax.warmup_cosine_decay_schedule(0.01 * learning_rate, peak, warmup, rest, end_value=0.01 * peak)
    else:
        schedule = optax.cosine_decay_schedule(peak, decay_steps=rest, alpha=0.01)
    climb = optax.adam(schedule)
    return warm_restart(explore, climb, first)


def warm_restart(first: optax.GradientTransformation, second: optax.GradientTransformation,
                 boundary: int) -> optax.GradientTransformation:
    """``first`` for ``boundary`` updates, then ``second`` from its initial state (for example
    Adam with its moments reset: a warm restart)."""

    def init(params):
        return jnp.zeros((), jnp.int32), first.init(params), second.init(params)

    def update(updates, state, params=None):
        count, s1, s2 = state
        u1, n1 = first.update(updates, s1, params)
        u2, n2 = second.update(updates, s2, params)
        early = count < boundary
        pick = lambda a, b: jax.tree_util.tree_map(lambda x, y: jnp.where(early, x, y), a, b)
        return pick(u1, u2), (count + 1, pick(n1, s1), pick(s2, n2))

    return optax.GradientTransformation(init, update)


# ---------------------------------------------------------------------------------------------
# The public function.


def optimize(
    obj,
    key=0,
    *,
    fingers: int,
    mu,
    starts: int = 1024,
    steps: int = 200,
    num_edges: int = DEFAULT_NUM_EDGES,
    objective: str = "closure",
    optimizer: optax.GradientTransformation | None = None,
    learning_rate: float | None = None,
    init=None,
    normals: str = "smooth",
    dtype="float64",
    monitor: bool = True,
    iterations: int | None = None,
    progress: bool = False,
    contact: str = "hard",
    torsion=None,
    noise=None,
    robust_samples: int = _noise.OPTIMIZE_SAMPLES,
) -> OptimizeResult:
    """Move the contacts of many grasps over an object's surface to maximize an objective.

    Args:
        obj: an object of :mod:`grasp_jax.objects` (polygon, mesh, analytic shape, built-in) or a
            :class:`grasp_jax.surfaces.Surface`.
        key: a ``jax.random`` key or an integer seed for the random starts (the same key gives
            the same result).
        fingers: contacts per grasp, >= 2 (``c_1`` is contact 0).
        mu: friction coefficient > 0.
        starts: number of random starts (ignored when ``init`` is given).
        steps: optimizer steps, >= 1.
        num_edges: edges per 3D friction cone.
        objective: one of :data:`grasp_jax.OBJECTIVES` (see :mod:`grasp_jax._objectives`):
            ``"closure"`` (default), ``"closure_any"``, ``"min_weight"``, ``"signed_q"``, ``"dfc"``,
            ``"dfc_eig"``; or ``"robust"`` with ``noise``: the mean of ``"closure"`` over
            ``robust_samples`` perturbations drawn once from ``key`` (the contacts that
            :func:`grasp_jax.robust` would score under those draws, walked over the surface and
            across edges; the gradient moves each in its own chart; normals tilted, friction per
            contact), so that the grasps found hold under the noise; the best iterate is the one
            of the largest mean. Best as a refinement of nominal optima (``init=``): see
            ``experiments/robust_optimize.py``.
        optimizer: any ``optax.GradientTransformation`` on ``(n, d)`` updates in units of the
            object's radius (default: :func:`default_optimizer`, Adam with cosine decay, from
            random starts restarted after a third of the steps). Pass the
            same object again to reuse the compiled program. Its ``params`` are the sum of its
            updates so far (the displacement from the start, before the surface's retraction), so
            that transformations which read them (``optax.scale_by_lbfgs``, weight decay, here
            towards the start) see consistent iterates; line searches that need the objective
            (``optax.lbfgs()``'s ``value_fn``) are refused with a ``TypeError``.
        learning_rate: peak learning rate of the default optimizer, in object radii per step
            (default :data:`DEFAULT_LEARNING_RATE` = 0.3 from random starts,
            :data:`REFINE_LEARNING_RATE` = 0.02 with ``init``).
        init: your own starts instead of random ones: ``(S, fingers, d)`` points (or a
            ``(points, normals)`` pair, for example the best grasps of ``grasp-jax sample``); each
            is moved to the closest surface point.
        normals: ``"smooth"`` (interpolated vertex normals, sharp edges kept) or ``"flat"`` (face
            normals) on meshes and polygons; analytic shapes use their exact normals.
        dtype: ``"float64"`` (computed under a scoped x64 switch) or ``"float32"``.
        monitor: record Q per step (``quality_history``) for objectives other than the closure
            ones (costs one quality LP per step; free for the closure objectives).
        iterations: interior-point iterations of each LP of a step (default: the first-pass budget
            of :func:`grasp_jax.evaluate`, 10 for 4 fingers and 8 edges; 6 cost 10 to 25% less
            per step with the same convergence, but leave more LPs unfinished, so that
            ``quality_history`` is further from ``evaluate``'s Q). A vmapped LP loop runs
            until its slowest problem is done and a step cannot gather stragglers as ``evaluate``
            does, so the LPs stop there and an unfinished one gives its best iterate: a slightly
            inexact gradient, never a verdict (the reported grasps are scored by ``evaluate``
            with its full budget).
        progress: show a progress bar over the steps.
        contact, torsion: the contact model, as :func:`grasp_jax.evaluate` (the objective and the
            final evaluation both use it).
        noise: a :class:`grasp_jax.Noise`, for ``objective="robust"`` only.
        robust_samples: perturbations of the robust objective (>= 1; each costs a step's LPs).

    Returns:
        :class:`OptimizeResult`.

    Raises:
        ValueError / TypeError: bad arguments, said in one sentence before anything is computed.
    """
    t0 = time.perf_counter()
    surface = _surfaces.as_surface(obj, normals)
    fingers = check_int("fingers", fingers, 2)
    steps = check_int("steps", steps)
    mu = check_scalar("mu", mu)
    model = contact_model(contact, torsion, check_num_edges(num_edges), surface.dim)
    if iterations is not None:
        iterations = check_int("iterations", iterations)
    robust_samples = _check_objective(objective, noise, robust_samples)
    if learning_rate is None:
        learning_rate = DEFAULT_LEARNING_RATE if init is None else REFINE_LEARNING_RATE
    learning_rate = check_scalar("learning_rate", learning_rate)
    user_optimizer = optimizer is not None
    optimizer = _pick_optimizer(optimizer, steps, learning_rate, init is None, (fingers, surface.dim))
    dtype = _check_dtype(dtype)
    init_points = None if init is None else _check_init(init, fingers, surface.dim)
    if init_points is None:
        starts = check_int("starts", starts)
        key = check_key(key, "gj.optimize")
    else:
        starts = len(init_points)
    scope = float64_scope() if dtype == np.float64 else contextlib.nullcontext()
    with scope:
        # On the device once, not copied with every segment's call (methods cast to the contacts' dtype).
        surface = jax.device_put(surface)
        contacts = _initial_contacts(surface, key, starts, fingers, init_points, dtype)
        initial_points = np.asarray(jax.vmap(jax.vmap(surface.embed))(contacts)[0])
        robust = None
        if noise is not None:
            draw_key = jax.random.fold_in(key if init_points is None else check_key(key, "gj.optimize"), 24)
            robust = (_noise.reparameterized(noise, draw_key, robust_samples, fingers, surface.dim,
                                             float(surface.scale), dtype), noise._flags())
        result = _run(surface, contacts, mu, model, objective, optimizer, steps, monitor, iterations, progress,
                      robust)
        points, normals_out, best_value, history, qualities, path = result
        evaluation = evaluate(points, normals_out, mu=mu, num_edges=model.num_edges, contact=model.kind,
                              torsion=None if model.kind == "hard" else model.torsion)
    reason = _end_reasons(np.asarray(evaluation.force_closure), history)
    return OptimizeResult(
        points=points, normals=normals_out, evaluation=evaluation, objective=best_value, history=history,
        quality_history=qualities, reason=reason, initial_points=initial_points, path=path,
        objective_name=objective, normal_kind=surface.normal_kind, steps=steps,
        seconds=time.perf_counter() - t0, scale=float(surface.scale),
        learning_rate=None if user_optimizer else float(learning_rate),
    )


def _check_objective(objective: str, noise, robust_samples) -> int:
    """The objective's name and its noise checked; the robust objective's sample count."""
    if objective not in OBJECTIVES + (ROBUST,):
        raise ValueError(f"objective must be one of {', '.join(map(repr, OBJECTIVES + (ROBUST,)))}; got {objective!r}")
    if (objective == ROBUST) != (noise is not None):
        raise ValueError("objective='robust' needs noise=grasp_jax.Noise(...), and noise is only used by it")
    if noise is None:
        return robust_samples
    if not isinstance(noise, _noise.Noise):
        raise TypeError(f"noise must be a grasp_jax.Noise; got {type(noise).__name__}")
    return check_int("robust_samples", robust_samples)


def _pick_optimizer(optimizer, steps: int, learning_rate: float, random_starts: bool, shape: tuple):
    """The user's optax transformation (checked), else :func:`default_optimizer`."""
    if optimizer is None:
        return default_optimizer(steps, learning_rate, restart=random_starts)
    if not isinstance(optimizer, optax.GradientTransformation):
        raise TypeError(f"optimizer must be an optax.GradientTransformation (for example optax.adam(0.02)); "
                        f"got {type(optimizer).__name__}")
    _check_optimizer(optimizer, shape)
    return optimizer


def _initial_contacts(surface, key, starts: int, fingers: int, init_points, dtype):
    """``(starts, fingers)`` contacts: random on the surface, or the closest to ``init_points``."""
    if init_points is None:
        contacts = surface.sample(key, starts * fingers)
        contacts = jax.tree_util.tree_map(lambda a: a.reshape((starts, fingers) + a.shape[1:]), contacts)
    else:
        contacts = surface.locate(init_points)
    return jax.tree_util.tree_map(
        lambda a: jnp.asarray(a, dtype) if jnp.issubdtype(a.dtype, jnp.floating) else jnp.asarray(a), contacts
    )


def _run(surface, contacts, mu, model: ContactModel, kind, optimizer, steps, monitor, iterations, progress,
         robust=None):
    """All starts through ``steps`` steps in compiled calls of equal length (:data:`SEGMENTS`,
    :data:`MIN_SEGMENT`)."""
    starts, n = contacts.face.shape[:2]
    dtype = contacts.coords.dtype
    d = surface.dim
    opt_state = jax.vmap(optimizer.init)(jnp.zeros((starts, n, d), dtype))
    travel = jnp.zeros((starts, n, d), dtype)
    state = (contacts, opt_state, travel, contacts, jnp.full((starts,), -jnp.inf, dtype), jnp.zeros((starts,), dtype))
    leaves, treedef = jax.tree_util.tree_flatten(state)
    length = math.ceil(steps / min(SEGMENTS, max(1, steps // MIN_SEGMENT)))
    budget = iterations or first_pass_iterations(_lp_columns(n, d, model.num_edges, model.kind))
    draws, flags = robust if robust is not None else (None, None)
    fn = _bind(_segment, treedef=treedef, kind=kind, optimizer=optimizer, length=length, total=steps,
               monitor=monitor, iterations=budget, noise_flags=flags)
    mu = (jnp.asarray(mu, dtype), model.astype(dtype))
    values, qualities = [], []
    embed = jax.vmap(jax.vmap(surface.embed))
    path = [np.asarray(embed(contacts)[0])]
    segments = range(0, steps, length)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=steps, unit="step", desc=f"optimizing {starts:,} starts")
    for offset in segments:
        shared = (surface, mu, jnp.asarray(offset, jnp.int32), draws)
        leaves, vals, qs = map_grasps(fn, tuple(leaves), shared, (starts,))
        leaves = list(leaves)
        values.append(np.asarray(vals))
        qualities.append(np.asarray(qs))
        path.append(np.asarray(embed(jax.tree_util.tree_unflatten(treedef, leaves)[0])[0]))
        if bar is not None:
            bar.update(min(length, steps - offset))
            best = np.asarray(leaves[-2])
            bar.set_postfix(positive=f"{np.mean(best > tolerances(dtype).margin):.0%}",
                            median=f"{np.median(best):.3f}")
    if bar is not None:
        bar.close()
    contacts, _, _, best, best_value, _ = jax.tree_util.tree_unflatten(treedef, leaves)
    points, normals = jax.vmap(jax.vmap(surface.embed))(best)
    history = np.concatenate(values, axis=1)[:, :steps]
    track = monitor or kind in _CLOSURE_KINDS
    qualities = np.concatenate(qualities, axis=1)[:, :steps] if track else None
    return np.asarray(points), np.asarray(normals), np.asarray(best_value), history, qualities, np.stack(path, axis=1)


def _end_reasons(force_closure: np.ndarray, history: np.ndarray) -> np.ndarray:
    steps = history.shape[1]
    running = np.maximum.accumulate(history, axis=1)
    back = max(1, round(CONVERGED_WINDOW * steps))
    gain = running[:, -1] - running[:, max(0, steps - 1 - back)]
    converged = gain <= CONVERGED_TOL * np.maximum(1.0, np.abs(running[:, -1]))
    reason = np.where(force_closure, EndReason.FORCE_CLOSURE,
                      np.where(converged, EndReason.CONVERGED, EndReason.NOT_CONVERGED))
    return reason.astype(np.int8)


# ---------------------------------------------------------------------------------------------
# Checks of user input.


def _check_dtype(dtype):
    try:
        dt = np.dtype(dtype)
    except TypeError:
        dt = None
    if dt not in (np.float32, np.float64):
        raise ValueError(f"dtype must be 'float32' or 'float64'; got {dtype!r}")
    return dt


def _check_optimizer(optimizer: optax.GradientTransformation, shape: tuple) -> None:
    """One abstract update (shapes only, nothing computed): an optimizer that needs more than
    ``update(updates, state, params)`` gets one clear error instead of a failure inside the step."""
    probe = jax.ShapeDtypeStruct(shape, np.float32)
    try:
        jax.eval_shape(lambda p: optimizer.update(p, optimizer.init(p), p), probe)
    except TypeError as e:
        raise TypeError(f"the optimizer's update(updates, state, params) failed ({e}); gj.optimize gives an "
                        "optimizer its updates and params only, no value, grad or value_fn: a line search such as "
                        "optax.lbfgs()'s cannot run here (optax.scale_by_lbfgs() without one can)") from None


def _check_init(init, fingers: int, d: int) -> np.ndarray:
    if isinstance(init, tuple) and len(init) == 2:
        init = init[0]
    try:
        points = np.asarray(init, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"init must be an array of points of shape (starts, {fingers}, {d}); "
                         f"got {type(init).__name__}") from None
    if points.ndim == 2:
        points = points[None]
    if points.ndim != 3 or points.shape[1:] != (fingers, d) or len(points) == 0:
        raise ValueError(f"init must have shape (starts, {fingers}, {d}) for {fingers} fingers on a "
                         f"{d}D object; got {points.shape}")
    if not np.isfinite(points).all():
        raise ValueError("init must be finite")
    return points
