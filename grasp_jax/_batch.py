"""Batching, in one place: single-grasp functions in, any leading batch shape out.

Two paths:

* **traced** (the caller is inside ``jit``, ``grad`` or ``vmap``): a plain ``jax.vmap`` over the
  flattened batch, so the result composes with the caller's transformations.
* **concrete** (NumPy or JAX arrays): the batch is cut into fixed-size chunks, each scored by one
  compiled function (``lax.map`` over vmapped blocks of :data:`BLOCK` grasps, which keeps the
  working set in cache), optionally sharded over local devices. Memory stays flat however large
  the batch, and a chunk size compiles once.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ._validate import is_traced

#: Grasps per vmapped block inside a compiled chunk on a CPU (cache-sized; measured best of
#: 64..1024 for n = 4, m = 8).
BLOCK = 256
#: Grasps per compiled call on the concrete path, on a CPU.
CHUNK = 16384
#: On an accelerator a chunk is one vmapped block (no ``lax.map``): a GPU wants wide batches.
ACCELERATOR_CHUNK = 131072


def _sizes(devices: tuple, chunk: int | None) -> tuple[int, int]:
    """``(block, chunk)`` for the devices' platform."""
    if devices[0].platform == "cpu":
        return BLOCK, chunk or CHUNK
    chunk = chunk or ACCELERATOR_CHUNK
    return chunk, chunk


def _bucket(n: int, chunk: int, smallest: int = 256) -> int:
    """Padded size for a batch of ``n`` grasps: a power of two from ``smallest`` up to ``chunk``."""
    size = smallest
    while size < n and size < chunk:
        size *= 2
    return min(size, chunk) if n <= chunk else chunk


def _blocked(fn: Callable, num_batched: int, size: int, block: int) -> Callable:
    """``lax.map`` over blocks of ``block`` grasps of ``vmap(fn)``, for ``size`` grasps of which
    the first ``count`` are real: blocks of padding only are skipped (zeros come out)."""
    block = min(block, size)
    in_axes = (0,) * num_batched + (None,)

    def run(batched, shared, count):
        blocks = jax.tree_util.tree_map(lambda a: a.reshape((size // block, block) + a.shape[1:]), batched)
        scored = lambda xs: jax.vmap(fn, in_axes=in_axes)(*xs, shared)  # noqa: E731
        shapes = jax.eval_shape(scored, jax.tree_util.tree_map(lambda a: a[0], blocks))

        def one_block(args):
            k, xs = args
            skip = lambda xs: jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)  # noqa: E731
            return jax.lax.cond(k * block < count, scored, skip, xs)

        out = jax.lax.map(one_block, (jnp.arange(size // block), blocks))
        return jax.tree_util.tree_map(lambda a: a.reshape((size,) + a.shape[2:]), out)

    return run


@dataclasses.dataclass(frozen=True)
class Retry:
    """A second pass for the grasps a fast first pass leaves unfinished.

    A vmapped interior-point loop runs until the *slowest* problem of its block has converged,
    and a few problems in a hundred need twice the median iteration count: most of a block's
    work would be spent on them. So the chunk is first scored by a function with a small
    iteration budget; the grasps for which ``unfinished(out)`` holds are gathered, bad ones first,
    into blocks of a fraction of the chunk and scored again by ``fn`` with the full budget, and
    their results are scattered back. Everything happens inside the one compiled chunk function.

    Attributes:
        fn: the single-grasp function with the full budget.
        unfinished: ``out -> (batch,) bool`` on the first pass's batched output.
    """

    fn: Callable
    unfinished: Callable


#: The second pass scores blocks of ``size / RETRY_FRACTION`` gathered grasps at a time.
RETRY_FRACTION = 32


def _with_retry(first: Callable, second: Callable, unfinished: Callable, size: int, cap: int) -> Callable:
    """``first`` on ``size`` grasps, then ``second`` on the unfinished ones, ``cap`` at a time."""

    def run(batched, shared, count):
        out = first(batched, shared, count)
        bad = unfinished(out) & (jnp.arange(size) < count)
        num_bad = jnp.sum(bad)
        order = jnp.argsort(~bad, stable=True)  # unfinished grasps first
        rounds = (num_bad + cap - 1) // cap

        def redo(r, out):
            idx = jax.lax.dynamic_slice(order, (r * cap,), (cap,))
            valid = r * cap + jnp.arange(cap) < num_bad
            sub = jax.tree_util.tree_map(lambda a: a[idx], batched)
            res = second(sub, shared, jnp.minimum(cap, num_bad - r * cap))

            def put(old, new):
                mask = valid.reshape((cap,) + (1,) * (new.ndim - 1))
                return old.at[idx].set(jnp.where(mask, new, old[idx]))

            return jax.tree_util.tree_map(put, out, res)

        return jax.lax.fori_loop(0, rounds, redo, out)

    return run


def _local(fn: Callable, num_batched: int, size: int, block: int, retry: Retry | None) -> Callable:
    """The scorer of ``size`` grasps on one device."""
    if retry is None:
        return _blocked(fn, num_batched, size, block)
    cap = max(block, (size // RETRY_FRACTION) // block * block)
    cap = min(cap, size)
    return _with_retry(
        _blocked(fn, num_batched, size, block),
        _blocked(retry.fn, num_batched, cap, block),
        retry.unfinished,
        size,
        cap,
    )


@functools.lru_cache(maxsize=None)
def _compiled(fn: Callable, num_batched: int, size: int, block: int, devices: tuple, retry: Retry | None) -> Callable:
    """Compiled scorer of ``size`` grasps, sharded over ``devices`` when there are several."""
    if len(devices) <= 1:
        return jax.jit(_local(fn, num_batched, size, block, retry))
    P = jax.sharding.PartitionSpec
    mesh = jax.sharding.Mesh(np.array(devices), ("batch",))
    local = _local(fn, num_batched, size // len(devices), block, retry)
    sharded = jax.shard_map(
        lambda batched, shared, counts: local(batched, shared, counts[0]),
        mesh=mesh, in_specs=(P("batch"), P(), P("batch")), out_specs=P("batch"), check_vma=False,
    )
    return jax.jit(sharded)


def _layout(start: int, stop: int, size: int, ndev: int) -> tuple[np.ndarray | None, np.ndarray]:
    """Where grasps ``start..stop`` go in a chunk of ``size`` slots on ``ndev`` devices.

    A partial chunk is spread evenly over the devices, each device's real grasps first and
    padding after them (its blocks of padding are skipped). Returns ``(source, counts)``: the
    grasp index of each slot (``None`` for a full chunk, taken as it is) and the number of real
    grasps on each device.
    """
    local = size // ndev
    real = stop - start
    if real == size:
        return None, np.full(ndev, local, np.int32)
    per = -(-real // ndev)
    slot = np.arange(size)
    device, offset = divmod(slot, local)
    source = start + device * per + offset
    valid = (offset < per) & (source < stop)
    counts = valid.reshape(ndev, local).sum(axis=1).astype(np.int32)
    return np.where(valid, source, start), counts


def map_grasps(
    fn: Callable,
    batched: tuple,
    shared,
    batch_shape: tuple,
    *,
    chunk: int | None = None,
    progress: bool = False,
    devices: tuple | None = None,
    retry: Retry | None = None,
):
    """Apply a single-grasp function to every grasp of a batch.

    Args:
        fn: ``fn(*per_grasp_arrays, shared) -> pytree`` for one grasp. Must be hashable and stable
            (a module-level function or a ``functools.partial`` of one) so that compilations are
            cached.
        batched: arrays of shape ``batch_shape + per_grasp_shape`` (``None`` entries allowed).
        shared: a pytree passed unbatched to every call (``mu`` and the like).
        batch_shape: leading shape to map over.
        chunk: grasps per compiled call on the concrete path (default :data:`CHUNK` on a CPU,
            :data:`ACCELERATOR_CHUNK` on an accelerator).
        progress: show a progress bar over chunks (tqdm).
        devices: devices to shard each chunk over (default: all local devices of the default
            backend).
        retry: on the concrete path, ``fn`` is a fast first pass and ``retry`` scores again the
            grasps it leaves unfinished (see :class:`Retry`). The traced path calls ``retry.fn``
            alone: under the caller's transformations there is no chunk to compact.

    Returns:
        ``fn``'s pytree with ``batch_shape`` prepended to every leaf.
    """
    present = [a for a in batched if a is not None]
    traced = is_traced(*present, *jax.tree_util.tree_leaves(shared))
    if retry is not None and traced:
        fn, retry = retry.fn, None
    if retry is not None:
        missing = tuple(a is None for a in batched)
        retry = Retry(_with_optional(retry.fn, missing), retry.unfinished)
    total = int(np.prod(batch_shape, dtype=np.int64))
    flat = tuple(
        None if a is None else a.reshape((total,) + a.shape[len(batch_shape):]) for a in batched
    )
    call = _with_optional(fn, tuple(a is None for a in batched))
    flat = tuple(a for a in flat if a is not None)

    def unflatten(tree):
        return jax.tree_util.tree_map(lambda a: a.reshape(batch_shape + a.shape[1:]), tree)

    if traced or total == 0:
        in_axes = (0,) * len(flat) + (None,)
        if total == 0:
            out = jax.eval_shape(lambda *xs: jax.vmap(call, in_axes=in_axes)(*xs), *flat, shared)
            return jax.tree_util.tree_map(lambda s: jnp.zeros(batch_shape + s.shape[1:], s.dtype), out)
        return unflatten(jax.vmap(call, in_axes=in_axes)(*flat, shared))

    if devices is None:
        devices = tuple(jax.local_devices())
    ndev = len(devices)
    block, chunk = _sizes(devices, chunk)
    size = _bucket(-(-total // ndev), max(chunk // ndev, BLOCK), min(BLOCK, block)) * ndev
    run = _compiled(call, len(flat), size, block, tuple(devices) if ndev > 1 else (), retry)
    starts = range(0, total, size)
    if progress:
        from tqdm.auto import tqdm

        starts = tqdm(starts, total=len(starts), unit="chunk", desc=f"scoring {total:,} grasps")
    outs = []
    for start in starts:
        stop = min(start + size, total)
        source, counts = _layout(start, stop, size, ndev)
        if source is None:
            pieces = tuple(a[start:stop] for a in flat)
        else:
            pieces = tuple(a[source] for a in flat)
        # To the host at once: indexing or concatenating arrays sharded over several CPU devices
        # would run small cross-device programs between the chunks, whose collectives can wait
        # on a thread pool that the chunks occupy (seen: a 40 s rendezvous timeout, then abort).
        res = jax.device_get(run(pieces, shared, counts if ndev > 1 else counts[0]))
        if source is not None:
            keep = np.flatnonzero(np.arange(size) % (size // ndev) < np.repeat(counts, size // ndev))
            res = jax.tree_util.tree_map(lambda a, keep=keep: a[keep], res)
        outs.append(res)
    out = outs[0] if len(outs) == 1 else jax.tree_util.tree_map(lambda *xs: np.concatenate(xs), *outs)
    return unflatten(jax.tree_util.tree_map(jnp.asarray, out))


@functools.lru_cache(maxsize=None)
def _with_optional(fn: Callable, missing: tuple) -> Callable:
    """Adapt ``fn`` so that ``None`` entries of the batched tuple are passed as ``None``."""
    if not any(missing):
        return fn

    def call(*args):
        *given, shared = args
        it = iter(given)
        full = [None if m else next(it) for m in missing]
        return fn(*full, shared)

    return call
