"""The iteration loop: one or more LPs advanced in one fused ``while_loop``."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from .._constants import default_iterations, tolerances
from ._ipm import _finish, _inconsistency, _init, _restart, _State, _step, _warm, _with_residuals
from ._problem import LP, LPSolution


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


