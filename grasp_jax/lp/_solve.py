"""``solve``: the entry point of the LP solver, for one problem (batch with ``jax.vmap``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ._loop import _loop
from ._problem import LP, LPSolution
from ._stream import _single


def solve(*lps: LP, iterations: int | jax.Array | None = None, consistent: bool = False,
          best_effort: bool = False, restarts: int | jax.Array | None = None, warm=None,
          weight=0.0, skip=None) -> tuple[LPSolution, ...]:
    """Solve one or more independent LPs in a single fused iteration loop.

    Each iteration advances every LP by one step; the loop ends when all are done (under
    ``vmap``: all problems of the batch) or after ``iterations`` (faster on the CPU than padding
    the LPs to one shape and stacking them).

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
