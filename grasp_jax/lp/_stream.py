"""The batching rule of a single LP: a large ``vmap`` streams problems through lanes."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ._loop import _advance, _finished, _loop, _plan, _result, _start
from ._problem import LP, LPSolution

#: A vmapped :func:`solve` of at least this many problems streams them through :data:`LANES`
#: lanes (:func:`_stream`) instead of running them in lock step. Callers choose it by the size of
#: their vmapped blocks (``_batch.map_grasps(block=)``).
STREAM_MIN = 512
#: Lanes of a streamed solve: 64 to 128 lanes run full-budget or warm-started LPs 1.2x to 1.9x
#: faster than lock-step blocks of 256 (docs/guides/performance.md); more lanes are slower, the
#: refill's work growing with them.
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
        # Every finished lane takes its next problem at once.
        return jax.lax.cond(jnp.any(finished), refill, lambda c, f: c, carry, finished)

    first = jnp.arange(lanes, dtype=jnp.int32)
    index, lp, st = load(first)
    carry = (jnp.asarray(lanes, jnp.int32), index, lp, st, states)
    *_, out = jax.lax.while_loop(lambda c: jnp.any(c[1] < N), body, carry)
    return jax.vmap(lambda lp, st, check: _result(lp, st, check, plan, best_effort))(lps, out, checks)

