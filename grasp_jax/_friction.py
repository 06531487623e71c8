"""Critical friction: the smallest friction coefficient at which **one** grasp is force-closure.

Force-closure is monotone in ``mu``, so the grasp holds on ``(mu*, inf)``; ``mu*`` is the root of
``g(mu) = mu l*(mu)``, ``l*`` the min-weight margin on the contact model's wrenches (``_contact``),
nearly straight in ``mu``. The search keeps a bracket ``[lo, hi]`` with ``g(lo) <= 0 < g(hi)``
and takes a Newton step (with the LP's envelope derivative) where it falls inside, else false
position (Illinois), else bisection, until ``hi - lo <= rtol * hi`` (or ``hi <= ATOL * cap``). It
seeks ``l* = threshold`` and carries the root back to ``l* = 0`` by one Newton step.

A batch runs :data:`FIRST_STEPS` steps (:data:`FIRST_STAGE_STEPS` for every grasp, the rest for
the open searches, gathered: ``_batch.Staged``), then the open ones resume from their bracket with
:data:`MAX_STEPS` and the full budget (``_batch.Retry``). Each step's LP starts warm from the last
(``lp.warm_weight``). Derivatives come from the implicit function theorem on ``l*(mu*, ...) = 0``.
Torques are taken about the contacts' centroid, scaled by their largest distance from it; soft
contacts' torsion is held fixed while ``mu`` moves.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp

from ._closure import min_weight_value
from ._cones import cone_edges, safe_normalize
from ._constants import default_iterations, tolerances
from ._contact import ContactModel, columns_per_contact, wrench_columns
from ._programs import full_rank, gram_rank3, min_weight_lp
from ._status import StatusEnum
from .lp import Status, warm_weight

#: Relative accuracy of ``mu*`` in float64 (the final bracket's width over its upper end).
RTOL = 1e-6
#: ... and in float32, whose min-weight margins are accurate to about 1e-6 absolute.
RTOL_FLOAT32 = 3e-5
#: Root-finding steps at most (bisection alone would need ``log2(cap / (rtol mu*))``: 25 for
#: ``mu* = 0.5`` and the default cap; a Dex-Net soft grasp whose margin is flat at 0 below
#: ``mu* = 0.08`` took 40).
MAX_STEPS = 64
#: Steps of the first pass over a batch (``_batch.Retry``): a vmapped search runs until the slowest
#: grasp of its block has converged, and 95% of random 4-finger grasps need at most 7 steps (two
#: soft contacts 3 or 4); the searches left open go on in a second pass with :data:`MAX_STEPS`.
#: The fastest of 6, 7, 8 and 10.
FIRST_STEPS = 7
#: Of those, the steps every grasp of the first pass takes before the searches still open are
#: gathered into full blocks for the rest (``_batch.Staged``): 77% of random 4-finger searches
#: are closed after 5 steps.
FIRST_STAGE_STEPS = 5
#: Interior-point iterations per step in the first pass, beyond ``_constants.first_pass_iterations``
#: of the LP's size (14 for 4 hard fingers, 8 edges): a step whose LP is unfinished then proves
#: nothing (it becomes a lower end on credit, and a search that ends on such an end is searched
#: again with the full budget), while the full budget made every step of a block wait for its
#: slowest LP (about 15 iterations). The fastest of 0, 2 and 4 extra (fewer leave too many
#: searches to the second pass); ``mu*`` within 1.3e-7 relative of the full-budget search's.
FIRST_EXTRA_ITERATIONS = 2
#: A lower end whose slope of ``mu l*`` is below this fraction of the upper end's is on a piece where
#: ``l*`` is flat at 0 (:func:`_search`).
FLAT = 1e-3
#: The step up from such a lower end after a Newton step from the upper end fell on it, as a
#: fraction of the bracket.
UNDERSHOOT = 0.05
#: Default upper end of the search: a grasp not force-closure at this ``mu`` gets ``inf``
#: (status ``ABOVE_CAP``). ``mu = 4`` is a cone half-angle of 76 degrees.
DEFAULT_CAP = 4.0
#: Absolute accuracy of ``mu*``, as a fraction of the cap, where ``mu*`` is below it.
ATOL = 1e-9
#: Longest step back from the root of ``l* = threshold`` to that of ``l* = 0``, relative to ``mu*``.
BACK = 1e-3
#: Crossover pivots after each interior-point solve (``lp._crossover.polish``): none. The
#: crossover's feasibility tolerance (1e-6, set for float32) certifies vertices whose margin is 1e-8
#: too high where ``l*`` is 0 on an interval of ``mu``, which moves ``mu*`` far off.
CROSSOVER = 0


class FrictionStatus(StatusEnum):
    """Outcome of a critical friction search (``int8`` per grasp)."""

    #: ``mu*`` found to the relative accuracy :data:`RTOL` (float32: :data:`RTOL_FLOAT32`).
    FOUND = 0, "critical friction found"
    #: Not force-closure at the cap (or never: wrenches that do not span the wrench space):
    #: ``mu* = inf``.
    ABOVE_CAP = 1, "not force-closure at the friction cap"
    #: Force-closure without friction (``l*(0) > 0``: in 3D at least 7 hard contacts): ``mu* = 0``.
    FRICTIONLESS = 2, "force-closure without friction"
    #: An LP did not converge, or the bracket was not narrowed in :data:`MAX_STEPS` steps:
    #: ``mu*`` is the bracket's upper end, force-closure but maybe too large.
    NOT_CONVERGED = 3, "not converged: the bracket's upper end is reported"


def rtol_for(dtype) -> float:
    """The relative accuracy of ``mu*`` in ``dtype``."""
    return RTOL if jnp.dtype(dtype) == jnp.float64 else RTOL_FLOAT32


def _frame(points):
    """``(origin, scale)`` torques are taken about: the centroid, and the largest distance from it."""
    center = jnp.mean(points, axis=0)
    sq = jnp.max(jnp.sum((points - center) ** 2, axis=-1))
    spread = sq > tolerances(points.dtype).tiny
    return center, jnp.where(spread, jnp.sqrt(jnp.where(spread, sq, 1.0)), 1.0)


def _wrenches(points, normals, mu, num_edges, contact, torsion, tangents):
    center, scale = _frame(points)
    edges = cone_edges(normals, mu, num_edges, tangents)
    return wrench_columns(points, normals, edges, contact, torsion, center, scale).wrenches


def _spans(*vectors) -> tuple[jax.Array, ...]:
    """Whether each ``(K, D)`` set spans R^D (no LAPACK: ``_programs.full_rank``)."""
    rank = (lambda v: gram_rank3(v)[0]) if vectors[0].shape[1] == 3 else full_rank
    return tuple(rank(jax.lax.stop_gradient(v)) for v in vectors)


def threshold(dtype) -> float:
    """The margin ``l*`` a grasp must exceed to count as force-closure in the search: above the
    round-off of a certified vertex (up to 3e-9 seen where ``l*`` is 0 on a whole interval of
    ``mu``: a wrench cone that holds a line for every ``mu`` there), so that such an interval is
    below ``mu*``. The root of ``l* = threshold`` is then carried back to ``l* = 0`` along the slope
    (:func:`_search`), which removes the threshold's bias where ``l*`` rises slowly."""
    return 10.0 * tolerances(dtype).lp


def _margin(points, normals, mu, torsion, *, num_edges, contact, tangents, iterations, warm=None, weight=0.0,
            solution=False, skip=None):
    """``(l*, status)`` of the min-weight LP at friction ``mu``, taking the wrenches' span as full
    (the caller checks it once: it does not depend on ``mu > 0``). The interior-point value, good
    to about 1e-8 where the LP is degenerate near the root (:data:`CROSSOVER`). ``warm, weight``:
    a warm start from a nearby step's LP; ``solution``: also this LP's ``lp.warm_point``; ``skip``:
    not solved (``lp.solve``; a finished search's step under ``vmap``)."""
    vectors = _wrenches(points, normals, mu, num_edges, contact, torsion, tangents)
    return min_weight_value(vectors, iterations, full=True, pivots=CROSSOVER, warm=warm, weight=weight,
                            solution=solution, skip=skip)


def _frictionless_possible(n: int, d: int, contact: str) -> bool:
    """Whether the wrenches at ``mu = 0`` can be numerous enough to positively span the wrench space
    (``D + 1`` distinct columns): static, so that most grasps skip the ``mu = 0`` LP."""
    distinct = {"hard": n, "soft": 2 * n, "dexnet-soft": 3 * n}[contact if d == 3 else "hard"]
    return distinct >= (6 if d == 3 else 3) + 1


#: Length of the state a search ends with and another resumes from (:func:`_search`): whether it
#: is a bracket at all, the last lower end an LP proved (``mu``, ``g``, ``g'``, whether ``g`` is
#: known there), the upper end (``mu``, ``g``, ``g'``). The full state (:func:`resume_size`) goes on
#: with the friction of the last LP solved and that LP's solution ``(x, y, s)``, to warm-start the
#: next step from; a search resumed from these 8 alone starts its first LP cold. (The full state is
#: carried between the two stages of a chunk; a whole batch's second pass resumes from the 8, so
#: that a batch of 10^6 grasps holds 8 floats of state each, not 80.)
RESUME = 8

#: Grasps per vmapped block of the search on a CPU (``_batch.map_grasps``, the first size the batch
#: fills). In a block of 512 the LPs of each step stream through ``lp.LANES`` lanes
#: (``lp._stream``), each taking the iterations it needs, and a finished search's LP takes none
#: (``skip``); a smaller batch runs lock-step blocks of 32, where every LP waits for the block's
#: slowest (warm-started LPs vary much). Larger blocks are slower: the slowest search sets its steps.
BLOCK = (512, 32)

def _lp_shape(n: int, d: int, contact: str, num_edges: int) -> tuple[int, int]:
    """``(rows, columns)`` of the min-weight LP of a grasp of ``n`` contacts in ``d`` dimensions."""
    k = n * (2 if d == 2 else columns_per_contact(contact, num_edges))
    return min_weight_lp(jnp.zeros((k, d + (1 if d == 2 else 3)))).A.shape


def resume_size(n: int, d: int, contact: str, num_edges: int) -> int:
    """Length of a search's full state (:func:`_search`): :data:`RESUME`, the friction of the last
    LP and that LP's ``(x, y, s)``."""
    rows, cols = _lp_shape(n, d, contact, num_edges)
    return RESUME + 1 + 2 * cols + rows


def fresh(dtype) -> jax.Array:
    """``(RESUME,)`` the state that starts a search from nothing (:func:`_search`)."""
    return jnp.zeros(RESUME, dtype)


def _search(points, normals, torsion, cap, steps=MAX_STEPS, start=None, *, num_edges, contact, tangents,
            iterations):
    """``(mu*, status, steps, state)`` by the bracketed root finding of the module docstring.

    ``start``: ``(resume_size(...),)`` the full ``state`` a search of the same grasp ended with
    (:func:`full_state` of :func:`fresh` to start from nothing). A first pass with few steps and a short interior-point budget leaves some
    searches open; the second pass resumes them from their last proven bracket instead of starting
    again from ``[0, cap]`` (a lower end that only an unfinished LP put there is dropped for the
    one before it). A resumed search solves no LP at ``cap`` (its upper end is in ``start``); the
    span is tested again (no LP).

    One function for one loop: the bracket, the Newton and bisection steps and the warm starts
    share the loop's carry, which the nested step functions read from the enclosing scope.
    """
    dt = points.dtype
    rtol = 0.5 * rtol_for(dt)  # mu* = hi is then within rtol / 2 + the LP's accuracy
    atol = ATOL * cap
    thr = threshold(dt)
    n, d = points.shape
    margin = partial(_margin, num_edges=num_edges, contact=contact, tangents=tangents, iterations=iterations)

    rows, cols = _lp_shape(n, d, contact, num_edges)

    def value_and_slope(mu, budget=iterations, warm=None, weight=0.0, skip=None):
        # The root sought is l* = thr, so that a margin flat at 0 (up to round-off) below mu* is
        # negative without doubt; the function searched is g = mu (l* - thr), with the same root
        # and nearly straight (module docstring). Also the LP's warm point, to start the next from.
        (f, status, point), (df, _, _) = jax.jvp(
            lambda m: margin(points, normals, m, torsion, iterations=budget, warm=warm, weight=weight,
                             solution=True, skip=skip), (mu,),
            (jnp.ones_like(mu),))
        return mu * (f - thr), (f - thr) + mu * df, status == Status.NOT_CONVERGED, point

    zero = jnp.zeros((), dt)
    # A resumed search knows its ends: the LPs at the cap (and at 0) get no iteration (under vmap
    # they would otherwise cost a full LP for every resumed grasp), and their values are not used.
    resume = jnp.asarray(False) if start is None else start[0] > 0
    budget = jnp.where(resume, 0, iterations) if start is not None else iterations
    f_hi, d_hi, bad_hi, sol_hi = value_and_slope(cap, budget)
    if _frictionless_possible(n, d, contact):
        spans, spans_lo = _spans(_wrenches(points, normals, cap, num_edges, contact, torsion, tangents),
                                 _wrenches(points, normals, zero, num_edges, contact, torsion, tangents))
        f_lo, bad_lo = margin(points, normals, zero, torsion, iterations=budget)
        f_lo, bad_lo = f_lo - thr, bad_lo == Status.NOT_CONVERGED
        frictionless = (f_lo > 0) & spans_lo
        known_lo = True
    else:
        (spans,) = _spans(_wrenches(points, normals, cap, num_edges, contact, torsion, tangents))
        bad_lo, frictionless, known_lo = jnp.asarray(False), jnp.asarray(False), False
    found = spans & (f_hi > 0) & ~frictionless
    # (at mu = 0 the function searched, mu (l* - thr), is 0 whatever l*(0) is)
    lower = (zero, zero, zero, jnp.asarray(known_lo))
    upper = (jnp.asarray(cap, dt), f_hi, d_hi)
    failed = jnp.where(bad_lo, zero, -jnp.ones((), dt))
    if start is not None:
        lower = tuple(jnp.where(resume, v, old) for v, old in zip((start[1], start[2], start[3], start[4] > 0), lower))
        upper = tuple(jnp.where(resume, v, old) for v, old in zip(start[5:8], upper))
        found, failed = found | resume, jnp.where(resume, -jnp.ones((), dt), failed)
        frictionless, bad_hi = frictionless & ~resume, bad_hi & ~resume
    # (step, lo, hi, f_lo, f_hi, slope at lo, slope at hi, f_lo known, steps without progress, side
    # kept by the last steps (Illinois), the last point whose LP failed and became the lower end, -1
    # if none, the last lower end an LP proved (mu, g, g', g known),
    # whether the last step was Newton from hi that fell on a flat piece of l*)
    state = (
        jnp.zeros((), jnp.int32), lower[0], upper[0], lower[1], upper[1], lower[2], upper[2],
        lower[3], jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32), failed, lower,
        jnp.zeros((), bool), sol_hi, jnp.asarray(cap, dt),
    )
    if start is not None:  # (the friction of the last LP is 0 where the state has no solution: cold)
        tail = start[RESUME + 1:]
        warm0 = (tail[:cols], tail[cols:cols + rows], tail[cols + rows:])
        state = state[:-2] + (tuple(jnp.where(resume, v, old) for v, old in zip(warm0, sol_hi)),
                              jnp.where(resume, start[RESUME], cap))

    def _closed(lo, hi):
        # relative accuracy, or mu* below atol: a grasp that holds at every mu > 0 but not at 0
        # (Dex-Net's moment columns at mu = 0) has mu* = 0 as an infimum, never closed relatively.
        return (hi - lo <= rtol * hi) | (hi <= atol)

    def cond(s):
        k, lo, hi, *_ = s
        return found & (k < steps) & ~_closed(lo, hi)

    def body(s):
        k, lo, hi, flo, fhi, dlo, dhi, known, stall, side, failed, proven, under, warm, last = s
        width = hi - lo
        inside = lambda x: (x > lo) & (x < hi) & jnp.isfinite(x)  # noqa: E731
        newton_hi = hi - fhi / jnp.where(dhi > 0, dhi, 1.0)
        newton_lo = lo - flo / jnp.where(dlo > 0, dlo, 1.0)
        ok_hi = (dhi > 0) & inside(newton_hi)
        ok_lo = known & (flo < 0) & (dlo > 0) & inside(newton_lo)
        # Of two Newton steps, the one from the end last moved (its model is the freshest).
        from_lo = ok_lo & (~ok_hi | (side > 0))
        newton = jnp.where(from_lo, newton_lo, newton_hi)
        secant = hi - fhi * width / jnp.where(fhi - flo > 0, fhi - flo, 1.0)
        ok_secant = known & (flo < 0) & inside(secant)
        # No model at all (nothing known below): a quarter of the way up, since mu* is more often
        # small than near the cap.
        fallback = jnp.where(known, lo + 0.5 * width, lo + 0.25 * width)
        x = jnp.where(ok_hi | ok_lo, newton, jnp.where(ok_secant, secant, fallback))
        # The last step, Newton from hi, fell below mu* onto a piece where l* is flat at 0 (the
        # wrench cone holds a line there; its slope says nothing): above the root g is concave,
        # and Newton from hi undershoots by about the square of hi's distance. A short step up
        # from lo then lands just above the root, and Newton from there much closer (false
        # position and bisection took 20 steps and more on such grasps). The same where lo is on
        # such a piece and Newton from hi points below it.
        flat_lo = known & (flo < 0) & (dlo <= FLAT * dhi) & (dhi > 0)
        jump = under | (flat_lo & (newton_hi <= lo))
        x = jnp.where(jump, lo + UNDERSHOOT * width, x)
        from_hi = ok_hi & ~from_lo & ~jump & (stall < 2)  # x is Newton's step from hi
        # Two steps that neither halved the bracket nor halved |g| on their side: bisect.
        x = jnp.where(stall >= 2, lo + 0.5 * width, x)
        # Kept half the accuracy from each end, in units of that end: a step from lo that lands
        # next to it then closes the bracket however far hi still is (with hi's unit it could not
        # while hi was the cap, and cost one more step).
        x = jnp.clip(x, lo + 0.5 * rtol * jnp.where(lo > 0, lo, hi), hi - 0.5 * rtol * hi)
        known_last = last > 0
        weight = jnp.where(known_last, warm_weight(jnp.abs(x - last) / jnp.where(known_last, last, 1.0)), 0.0)
        # Under vmap the body runs for every grasp of the block; a finished search's LP is skipped
        # (its result is discarded), so that a streamed solve (``lp._stream``) gives it no lane.
        fx, dx, bad_x, sol_x = value_and_slope(x, warm=warm, weight=weight, skip=~cond(s))
        # An LP that did not converge (near the friction at which the LP turns infeasible, say)
        # proves nothing: x is not taken as force-closure, and becomes a lower end on credit
        # (``failed``); mu* = hi stays a friction at which a converged LP says force-closure.
        holds = (fx > 0) & ~bad_x
        # Illinois: an end kept twice in a row has its value halved (the secant then moves it).
        hi_kept, lo_kept = ~holds & (side < 0), holds & (side > 0)
        lo2, flo2, dlo2 = (jnp.where(holds, lo, x), jnp.where(holds, jnp.where(lo_kept, 0.5 * flo, flo), fx),
                           jnp.where(holds, dlo, dx))
        hi2, fhi2, dhi2 = (jnp.where(holds, x, hi), jnp.where(holds, fx, jnp.where(hi_kept, 0.5 * fhi, fhi)),
                           jnp.where(holds, dx, dhi))
        side2 = jnp.where(holds, jnp.minimum(side, 0) - 1, jnp.maximum(side, 0) + 1)
        # Progress: the bracket halved, or |g| halved on the side x fell on (steps that alternate
        # between the ends, each Newton from the freshest, can halve |g| against the other end at
        # every step and the bracket at none).
        progress = (hi2 - lo2 <= 0.5 * width) | (jnp.abs(fx) <= 0.5 * jnp.where(holds, jnp.abs(fhi), jnp.abs(flo)))
        stall2 = jnp.where(progress, 0, stall + 1)
        failed2 = jnp.where(~holds & bad_x, x, failed)
        below = ~holds & ~bad_x
        proven2 = tuple(jnp.where(below, v, old) for v, old in zip((x, fx, dx, jnp.ones((), bool)), proven))
        under2 = from_hi & below & (dx <= FLAT * dhi)
        return (k + 1, lo2, hi2, flo2, fhi2, dlo2, dhi2, known | ~holds, stall2, side2, failed2, proven2,
                under2, sol_x, x)

    k, lo, hi, _, f_hi, _, d_hi, *_, failed, proven, _, warm, last = jax.lax.while_loop(cond, body, state)
    # a lower end that only an LP failure put there: mu* = hi is an upper bound
    converged = _closed(lo, hi) & (failed < lo)
    end = jnp.concatenate([jnp.stack([found.astype(dt), proven[0], proven[1], proven[2], proven[3].astype(dt), hi,
                                      f_hi, d_hi, last]), *warm])
    # l* = thr + f_hi at hi: the root of l* = 0 one Newton step back, where that step is short (the
    # slope is not ~0 there); the grasp holds for every mu above it.
    f_hi, d_hi = f_hi / hi, (d_hi - f_hi / hi) / hi  # back to l* - thr and its slope at hi
    back = (f_hi + thr) / jnp.where(d_hi > 0, d_hi, 1.0)
    hi = jnp.where((d_hi > 0) & (back >= 0) & (back <= BACK * hi), hi - back, hi)
    mu = jnp.where(frictionless, 0.0, jnp.where(found, hi, jnp.inf))
    status = jnp.where(
        frictionless,
        FrictionStatus.FRICTIONLESS,
        jnp.where(~found, jnp.where(bad_hi, FrictionStatus.NOT_CONVERGED, FrictionStatus.ABOVE_CAP),
                  jnp.where(converged, FrictionStatus.FOUND, FrictionStatus.NOT_CONVERGED)),
    )
    mu = jnp.where(~found & ~frictionless & bad_hi, jnp.inf, mu)
    return mu.astype(dt), status.astype(jnp.int8), k, end


@partial(jax.custom_jvp, nondiff_argnums=(0, 1))
def _critical(num_edges, contact, points, normals, torsion, cap, steps, iterations, tangents, start):
    mu, status, _, end = _search(points, normals, torsion, cap, steps, start, num_edges=num_edges, contact=contact,
                                 tangents=tangents, iterations=iterations)
    return mu, status, end


@_critical.defjvp
def _critical_jvp(num_edges, contact, primals, tangents_in):
    points, normals, torsion, cap, steps, iterations, tangents, start = primals
    dp, dn, dtorsion, *_ = tangents_in
    mu, status, end = _critical(num_edges, contact, points, normals, torsion, cap, steps, iterations, tangents, start)
    ok = status == FrictionStatus.FOUND
    at = jnp.where(ok, mu, 1.0)
    # (the full interior-point budget: the search's may have been a short first pass)
    margin = partial(_margin, num_edges=num_edges, contact=contact, tangents=tangents, iterations=None)
    # l*(mu*, theta) = 0, so d mu* = -(d l/d theta . d theta) / (d l/d mu): one solve, two tangents.
    _, lin = jax.linearize(lambda p, nrm, t, m: margin(p, nrm, m, t)[0], points, normals, torsion, at)
    zeros = jnp.zeros_like
    dl_theta = lin(dp, dn, dtorsion, zeros(at))
    dl_mu = lin(zeros(points), zeros(normals), zeros(torsion), jnp.ones_like(at))
    usable = ok & (dl_mu > jnp.finfo(mu.dtype).eps)
    dmu = jnp.where(usable, -dl_theta / jnp.where(usable, dl_mu, 1.0), 0.0)
    return (mu, status, end), (dmu.astype(mu.dtype), jnp.zeros(status.shape, jax.dtypes.float0), jnp.zeros_like(end))


def critical_friction_one(points, normals, cap, model: ContactModel, tangents=None, iterations=None, steps=MAX_STEPS,
                          start=None):
    """``(mu*, status)`` of one grasp (``points, normals: (n, d)``) under the contact ``model``: the
    smallest friction coefficient at which it is force-closure (``inf`` above ``cap``),
    differentiable in ``points``, ``normals`` and ``model.torsion`` by the implicit function theorem. ``steps``: most root-finding steps,
    ``iterations``: interior-point iterations per step (default the full budget; both may be
    traced); a search left open after them has status ``NOT_CONVERGED``. See the module
    docstring. With ``start`` (``(RESUME,)`` or the full state of :func:`resume_size`, see
    :func:`_search`), returns ``(mu*, status, state)`` with ``state`` of the same length: the search
    resumes from ``start`` and ``state`` resumes it again."""
    normals = safe_normalize(normals)
    dt = points.dtype
    num_edges, contact, torsion = model.num_edges, model.kind, model.torsion
    # Symbolic zero tangents: custom_jvp needs every differentiable argument to be an array.
    if iterations is None:
        iterations = default_iterations(min_weight_columns(points.shape[0], points.shape[1], contact, num_edges))
    out = _critical(num_edges, contact, points, normals, jnp.asarray(torsion, dt), jnp.asarray(cap, dt),
                    jnp.asarray(steps, jnp.int32), jnp.asarray(iterations, jnp.int32), tangents,
                    full_state(fresh(dt) if start is None else jnp.asarray(start, dt), points.shape, contact,
                               num_edges))
    if start is None:
        return out[:2]
    return out if jnp.shape(start)[-1] != RESUME else (*out[:2], out[2][:RESUME])


def full_state(start, shape, contact: str, num_edges: int):
    """``start`` (the :data:`RESUME` floats a search resumes from, or its full state) as a full
    state (:func:`resume_size`): padded with zeros (no solution to warm-start from)."""
    size = resume_size(*shape, contact, num_edges)
    return start if start.shape[-1] == size else jnp.concatenate([start, jnp.zeros(size - start.shape[-1], start.dtype)])


def min_weight_columns(n: int, d: int, contact: str, num_edges: int) -> int:
    """Columns of the min-weight LP of a grasp (its ``K`` weights, the margin and the slacks)."""
    return _lp_shape(n, d, contact, num_edges)[1]
