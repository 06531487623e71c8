"""Batching, in one place: single-grasp functions in, any leading batch shape out.

Two paths:

* **traced** (inside the caller's ``jit``, ``grad`` or ``vmap``): a plain ``jax.vmap`` over the
  flattened batch, so the result composes with the caller's transformations.
* **concrete** (NumPy or JAX arrays): the batch is cut into chunks of one fixed size, each scored
  by one compiled program (a loop over vmapped blocks of :data:`BLOCK` grasps, over the blocks
  that hold real grasps only), sharded over the local devices with no collective. One compilation
  per grasp shape, dtype and device set serves any batch size (kept by :mod:`grasp_jax._cache`),
  and memory stays flat. A :class:`Retry` pass reruns the unfinished grasps; a :class:`Staged`
  function's second stage runs only on the grasps its first stage leaves, gathered into blocks.

A program that calls LAPACK runs on one device (:func:`_blocking_calls`): jaxlib's CPU LAPACK
kernels block XLA's intra-op pool threads, and with one device per core that deadlocks.
"""

from __future__ import annotations

import collections
import dataclasses
import re
import threading
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from . import _cache
from ._validate import is_traced

#: Grasps per vmapped block inside a compiled chunk on a CPU (cache-sized; the fastest of 64..1024
#: for n = 4, m = 8).
BLOCK = 256
#: Grasps per compiled call on the concrete path, on a CPU (all devices together).
CHUNK = 16384
#: On an accelerator a chunk is one vmapped block per device: a GPU wants wide batches.
ACCELERATOR_CHUNK = 131072
#: The retry pass scores the unfinished grasps ``chunk / RETRY_FRACTION`` at a time.
RETRY_FRACTION = 32

#: XLA options of the chunk programs, by platform. On a CPU, LLVM's optimization level 1: about a
#: fifth to a third less compile time than the default and the same run time, results within the LP
#: tolerance (level 0 runs 4x slower). XLA's classic CPU emitters are not used: their rounding ends
#: an ill-posed quality LP at a wrong optimum (tests/test_closure.py).
COMPILER_OPTIONS: dict = {"cpu": {"xla_backend_optimization_level": 1}}

#: Programs the concrete path has made in this process: ``"traced"`` (a program was traced and
#: lowered), ``"compiled"`` (XLA compiled it), ``"loaded"`` (taken from the persistent cache) and
#: ``"one_device"`` (a LAPACK program kept to one device). Tests count compilations with it.
STATS: collections.Counter = collections.Counter()


def _sizes(devices: tuple, chunk: int | None, block: int | None = None) -> tuple[int, int]:
    """``(block, chunk)`` for the devices' platform: grasps per vmapped block (per device) and per
    compiled call (all devices together)."""
    if devices[0].platform == "cpu":
        return block or BLOCK, chunk or CHUNK
    chunk = chunk or ACCELERATOR_CHUNK
    return max(1, chunk // len(devices)), chunk


#: :func:`_pick_block` takes the largest block that leaves at most this share of a device's grasps
#: as padding (a vmapped block computes its padding rows like real ones).
PADDING = 1 / 8


def _pick_block(sizes: tuple, total: int, ndev: int, chunk: int) -> int:
    """The largest of ``sizes`` (largest first) whose padding of the grasps one device scores in
    a chunk is at most :data:`PADDING` of them; the smallest where none is."""
    per_device = -(-min(total, chunk) // ndev)
    for size in sizes:
        if -(-per_device // size) * size - per_device <= PADDING * per_device:
            return size
    return sizes[-1]


def _local_size(chunk: int, ndev: int, block: int) -> int:
    """Grasps per device in one compiled call: ``chunk / ndev`` rounded down to whole blocks, at
    least one block."""
    return max(block, (chunk // ndev) // block * block)


def _retry_sizes(devices: tuple, chunk: int, block: int) -> tuple[int, int]:
    """``(grasps per device, block)`` of the retry pass's program: ``chunk / RETRY_FRACTION``."""
    cap = max(1, chunk // RETRY_FRACTION)
    if devices[0].platform == "cpu":
        return _local_size(cap, len(devices), block), block
    local = max(1, cap // len(devices))
    return local, local


@dataclasses.dataclass(frozen=True)
class Staged:
    """A single-grasp function in two stages, the second run only on the grasps that need it.

    Where a cheap first stage settles most grasps (``gj.evaluate``: the torque LP proves about half
    of random grasps out of equilibrium, and their quality LP is not needed), a vmapped block
    would still run the second stage for all of them. On the concrete path a chunk program runs
    ``first`` over its grasps, gathers those with ``need``, and runs ``second`` on them only, in
    full blocks; the traced path runs both on every grasp.

    Attributes:
        first: ``(*grasp, shared) -> (out, carry, need)``: the result of a grasp the first stage
            settles, what the second stage needs from the first, and whether it needs it.
        second: ``(*grasp, carry, shared) -> out``: the result, correct for *every* grasp (those
            the first stage settled included, where it must equal the first stage's ``out``): a
            block of gathered grasps is padded with others.
    """

    first: Callable
    second: Callable

    def __call__(self, *args):
        *grasp, shared = args
        _, carry, _ = self.first(*args)
        return self.second(*grasp, carry, shared)


def _blocked(fn: Callable, num_batched: int, size: int, block: int) -> Callable:
    """``vmap(fn)`` over ``size`` grasps, ``block`` at a time, of which the first ``count`` are
    real: a loop over the blocks that hold real grasps; the others come out as zeros. A
    :class:`Staged` ``fn``: its first stage so, then its second over the gathered grasps that
    need it."""
    block = min(block, size)
    in_axes = (0,) * num_batched + (None,)
    staged = isinstance(fn, Staged)
    # One jitted object, so that its trace (for the output shapes, then in the loop) is reused.
    scored = jax.jit(lambda xs, shared: jax.vmap(fn.first if staged else fn, in_axes=in_axes)(*xs, shared))
    if staged:
        second = jax.jit(lambda xs, carry, shared: jax.vmap(fn.second, in_axes=in_axes[:-1] + (0, None))(
            *xs, carry, shared))

    def loop(count, run, out, take=None):
        """``out`` with ``run`` on the blocks ``k`` of grasps ``take[k block : (k + 1) block]``
        (consecutive grasps where ``take`` is ``None``), for the first ``count`` grasps."""

        def body(k, out):
            if take is None:
                rows = None
                pick = lambda a: jax.lax.dynamic_slice_in_dim(a, k * block, block)  # noqa: E731
            else:
                rows = jax.lax.dynamic_slice_in_dim(take, k * block, block)
                pick = lambda a: a[rows]  # noqa: E731
            res = run(pick)
            if rows is None:
                put = lambda o, r: jax.lax.dynamic_update_slice_in_dim(o, r, k * block, 0)  # noqa: E731
            else:
                put = lambda o, r: o.at[rows].set(r, unique_indices=True)  # noqa: E731
            return jax.tree_util.tree_map(put, out, res)

        blocks = (jnp.asarray(count, jnp.int32) + block - 1) // block
        return jax.lax.fori_loop(0, blocks, body, out)

    def zeros(shapes):
        return jax.tree_util.tree_map(lambda s: jnp.zeros((size,) + s.shape[1:], s.dtype), shapes)

    def run(batched, shared, count):
        first = jax.tree_util.tree_map(lambda a: a[:block], batched)
        out = loop(count, lambda pick: scored(jax.tree_util.tree_map(pick, batched), shared),
                   zeros(jax.eval_shape(scored, first, shared)))
        if not staged:
            return out
        out, carry, need = out
        need = need & (jnp.arange(size) < count)
        # The grasps that need the second stage first (a stable order), then the others; the
        # last block is padded with those, which the second stage scores correctly too.
        take = jnp.argsort(~need, stable=True).astype(jnp.int32)
        return loop(jnp.sum(need, dtype=jnp.int32),
                    lambda pick: second(*jax.tree_util.tree_map(pick, (batched, carry)), shared), out, take)

    return run


@dataclasses.dataclass(frozen=True)
class Retry:
    """A second pass for the grasps a fast first pass leaves unfinished.

    A vmapped interior-point loop runs until the *slowest* problem of its block has converged,
    and a few problems in a hundred need twice the median iteration count: most of a block's
    work would be spent on them. So the batch is first scored with a small iteration budget;
    the grasps for which ``unfinished(out)`` holds are scored again, gathered, with ``shared``
    (the full budget), and their results replace the first ones. Both passes run the *same*
    function with ``shared`` arguments of the same structure and types, hence the same compiled
    program on a CPU (its loop skips the blocks of padding, so a chunk of gathered grasps costs
    what they cost); an accelerator, whose chunk is one wide block, runs the retry through a
    program of ``chunk / RETRY_FRACTION`` grasps.

    Attributes:
        shared: the ``shared`` argument of the second pass (for example a larger budget).
        unfinished: ``out -> (batch,) bool`` on the first pass's output, as NumPy arrays.
        resume: optional ``(out, batched) -> batched``: the per-grasp inputs of the second pass
            from the first pass's output and inputs (the batched arrays that are not ``None``,
            flattened to ``(total, ...)``, NumPy), with the same shapes and types, so that a
            search can go on where the first pass left it (``gj.critical_friction``).
    """

    shared: object
    unfinished: Callable
    resume: Callable | None = None


# ---------------------------------------------------------------------------------------------
# Compiled programs.

#: Custom calls that are no kernels (sharding annotations of ``shard_map``).
_ANNOTATIONS = frozenset({"Sharding", "SPMDFullToShardShape", "SPMDShardToFullShape"})


def _blocking_calls(lowered_text: str) -> set[str]:
    """Custom-call targets of a lowered program that may wait on XLA's CPU thread pool.

    jaxlib's LAPACK kernels (``lapack_*``: eigh, cholesky, lu, qr, svd, triangular solves, ...)
    divide a batch into pieces, schedule them on the intra-op pool and wait for them inside the
    pool thread that runs the kernel (jaxlib 0.10, ``ParallelBatchMap``). Run on as many devices
    as the pool has threads, each device's kernel takes one pool thread and waits, and the pieces
    are never run. Any custom call other than a sharding annotation is treated as such a kernel.
    """
    return set(re.findall(r"custom_call @([\w.$-]+)", lowered_text)) - _ANNOTATIONS


@dataclasses.dataclass
class _Program:
    """One compiled chunk program and the devices it runs on."""

    run: Callable
    devices: tuple  # () for the default device
    size: int  # grasps per call, all devices together

    @property
    def ndev(self) -> int:
        return max(1, len(self.devices))


#: The compiled chunk programs of this process, by key (:func:`_program`), in order of last use:
#: the least recently used first (a caller that must free some drops them from the front).
_PROGRAMS: dict = {}
_LOCK = threading.Lock()
#: Keys whose programs call LAPACK: kept to one device.
_ONE_DEVICE: set = set()


def _aval_key(tree) -> tuple:
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    return treedef, tuple(jax.typeof(x) for x in leaves)


def _x64() -> bool:
    return jax.dtypes.canonicalize_dtype(np.float64) == np.float64


def _program(fn: Callable, grasp_specs: tuple, shared, local: int, block: int, devices: tuple) -> _Program:
    """The compiled program scoring ``local`` grasps per device with ``fn`` (cached)."""
    key = (fn, grasp_specs, _aval_key(shared), local, block, devices, _x64())
    with _LOCK:
        prog = _PROGRAMS.pop(key, None)
        if prog is None:
            prog = _build(fn, grasp_specs, shared, local, block, devices, key)
        _PROGRAMS[key] = prog  # (re)inserted: the dict is in order of last use, the oldest first
    return prog


def _build(fn, grasp_specs, shared, local, block, devices, key) -> _Program:
    if len(devices) > 1 and key not in _ONE_DEVICE:
        P = jax.sharding.PartitionSpec
        mesh = jax.sharding.Mesh(np.array(devices), ("batch",))
        body = _blocked(fn, len(grasp_specs), local, block)

        def on_device(batched, shared, counts):
            return body(batched, shared, counts[0])

        sharded = jax.shard_map(
            _named(on_device),
            mesh=mesh, in_specs=(P("batch"), P(), P("batch")), out_specs=P("batch"), check_vma=False,
        )
        size = local * len(devices)
        counts = jax.ShapeDtypeStruct((len(devices),), jnp.int32)
        named = jax.sharding.NamedSharding
        shardings = (named(mesh, P("batch")), named(mesh, P()), named(mesh, P("batch")))
        program = jax.jit(sharded, in_shardings=shardings, out_shardings=named(mesh, P("batch")))
        lowered = _lower(program, grasp_specs, size, shared, counts)
        text = lowered.as_text()
        if not _blocking_calls(text):
            return _Program(_compile(lowered, text, devices, _options(devices[0].platform)), devices, size)
        _ONE_DEVICE.add(key)
        STATS["one_device"] += 1
    program = jax.jit(_named(_blocked(fn, len(grasp_specs), local, block)))
    lowered = _lower(program, grasp_specs, local, shared, jax.ShapeDtypeStruct((), jnp.int32))
    default = (jax.local_devices()[0],)  # where jit runs a program without shardings
    options = _options(default[0].platform)
    return _Program(_compile(lowered, lowered.as_text(), default, options), (), local)


#: The name of every chunk program (in JAX's logs: ``jax.log_compiles``).
PROGRAM_NAME = "grasp_jax_chunk"


def _named(f: Callable) -> Callable:
    f.__name__ = f.__qualname__ = PROGRAM_NAME
    return f


def _lower(program, grasp_specs, size, shared, counts):
    specs = tuple(jax.ShapeDtypeStruct((size,) + shape, dtype) for shape, dtype in grasp_specs)
    STATS["traced"] += 1
    return program.trace(specs, shared, counts).lower()


def _options(platform: str) -> dict:
    """XLA options for a chunk program on ``platform`` (any dtype)."""
    return COMPILER_OPTIONS.get(platform, {})


def _compile(lowered, text: str, devices: tuple, options: dict):
    """``lowered`` compiled, or loaded from the persistent cache when it holds it."""
    name = _cache.key(text, options, devices)
    compiled = _cache.load(name, lowered, devices)
    if compiled is not None:
        STATS["loaded"] += 1
        return compiled
    compiled = lowered.compile(compiler_options=options)
    STATS["compiled"] += 1
    _cache.store(name, compiled)
    return compiled


# ---------------------------------------------------------------------------------------------
# Running a batch.


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


def _score(prog: _Program, flat: tuple, shared, index: np.ndarray | None, total: int, progress=None):
    """Run ``prog`` over grasps ``index`` of ``flat`` (all ``total`` when ``None``), chunk by
    chunk; returns the host (NumPy) results in order."""
    size, ndev = prog.size, prog.ndev
    local = size // ndev
    outs = []
    starts = range(0, total, size)
    if progress is not None:
        from tqdm.auto import tqdm

        starts = tqdm(starts, total=len(starts), unit="chunk", desc=progress)
    for start in starts:
        stop = min(start + size, total)
        source, counts = _layout(start, stop, size, ndev)
        rows = np.arange(start, stop) if source is None else source
        if index is not None:
            rows = index[rows]
        pieces = tuple(a[start:stop] if source is None and index is None else a[rows] for a in flat)
        # To the host at once: indexing or concatenating arrays sharded over several CPU devices
        # would run small cross-device programs between the chunks, whose collectives can wait
        # on a thread pool that the chunks occupy (seen: a 40 s rendezvous timeout, then abort).
        res = jax.device_get(prog.run(pieces, shared, counts if prog.devices else counts[0]))
        if source is not None:
            keep = np.flatnonzero(np.arange(size) % local < np.repeat(counts, local))
            res = jax.tree_util.tree_map(lambda a, keep=keep: a[keep], res)
        outs.append(res)
    return outs[0] if len(outs) == 1 else jax.tree_util.tree_map(lambda *xs: np.concatenate(xs), *outs)


def _check_devices(devices) -> tuple:
    devices = tuple(devices)
    if not devices:
        raise ValueError("devices must name at least one device")
    if len(set(devices)) != len(devices):
        raise ValueError(f"devices must not repeat a device; got {devices}")
    if len({d.platform for d in devices}) > 1:
        raise ValueError(f"devices must be of one platform; got {sorted({d.platform for d in devices})}")
    here = jax.process_index()
    if any(d.process_index != here for d in devices):
        raise ValueError(
            "devices must be local to this process (jax.local_devices()); in a multi-process job "
            "each process scores its own slice on its own devices"
        )
    return devices


def map_grasps(
    fn: Callable,
    batched: tuple,
    shared,
    batch_shape: tuple,
    *,
    chunk: int | None = None,
    progress: bool = False,
    devices: tuple | None = None,
    retry: Retry | tuple | None = None,
    block: int | None = None,
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
        retry: on the concrete path, a second pass with ``retry.shared`` scores again the grasps
            the first leaves unfinished (see :class:`Retry`); a tuple of them, passes in turn,
            each on what the passes before it left unfinished. The traced path runs with the
            last pass's ``shared`` alone: under the caller's transformations there is no chunk to
            compact.
        block: grasps per vmapped block on a CPU (default :data:`BLOCK`): a block runs each loop
            until its slowest grasp is done, so a function whose loops vary much from grasp to
            grasp (the critical friction search) wants smaller blocks; or a tuple of sizes, largest
            first: the largest that the batch fills (:func:`_pick_block`), so that a block of
            :data:`grasp_jax.lp.STREAM_MIN` or more streams its LPs (``lp._stream``) where the
            batch is large, without padding a small one to it. Ignored on accelerators.

    Returns:
        ``fn``'s pytree with ``batch_shape`` prepended to every leaf.
    """
    present = [a for a in batched if a is not None]
    traced = is_traced(*present, *jax.tree_util.tree_leaves(shared))
    retries = () if retry is None else (retry,) if isinstance(retry, Retry) else tuple(retry)
    if retries and traced:
        shared, retries = retries[-1].shared, ()
    missing = tuple(a is None for a in batched)
    total = int(np.prod(batch_shape, dtype=np.int64))
    call = _with_optional(fn, missing)
    lead = len(batch_shape)
    flat = tuple(a.reshape((total,) + a.shape[lead:]) for a in batched if a is not None)

    if traced or total == 0:
        in_axes = (0,) * len(flat) + (None,)
        if total == 0:
            out = _empty_shapes(call, tuple((a.shape[1:], a.dtype) for a in flat), shared, traced)
            return jax.tree_util.tree_map(lambda s: jnp.zeros(batch_shape + s.shape, s.dtype), out)
        out = jax.vmap(call, in_axes=in_axes)(*flat, shared)
        return jax.tree_util.tree_map(lambda a: a.reshape(batch_shape + a.shape[1:]), out)

    devices = _check_devices(jax.local_devices() if devices is None else devices)
    ndev = len(devices)
    sizes = block if isinstance(block, tuple) else None
    if sizes is not None:
        block = _pick_block(sizes, total, ndev, chunk or CHUNK)
    block, chunk = _sizes(devices, chunk, block)
    flat = tuple(np.asarray(a) for a in flat)
    shared = jax.device_get(shared)  # small: to each device from the host, not from device 0
    grasp_specs = tuple((a.shape[1:], a.dtype) for a in flat)
    multi = devices if ndev > 1 else ()
    first = _program(call, grasp_specs, shared, _local_size(chunk, ndev, block), block, multi)
    desc = f"scoring {total:,} grasps" if progress else None
    out = _score(first, flat, shared, None, total, desc)
    for retry in retries:
        again = np.flatnonzero(np.asarray(retry.unfinished(out)))
        if not again.size:
            break
        retry_shared = jax.device_get(retry.shared)
        if _aval_key(retry_shared) != _aval_key(shared):
            raise TypeError("Retry.shared must have the structure and types of the first pass's shared")
        second = first
        if devices[0].platform != "cpu":
            cap, cap_block = _retry_sizes(devices, chunk, block)
            second = _program(call, grasp_specs, shared, cap, cap_block, multi)
        elif sizes is not None and _pick_block(sizes, again.size, ndev, chunk) != block:
            # A few grasps again: in the block that they fill (a program of its own), not padded
            # to the first pass's wide block, whose padding rows would be scored like real ones.
            narrow = _pick_block(sizes, again.size, ndev, chunk)
            second = _program(call, grasp_specs, shared, _local_size(chunk, ndev, narrow), narrow, multi)
        again_flat = flat if retry.resume is None else tuple(np.asarray(a) for a in retry.resume(out, flat))
        if [(a.shape, a.dtype) for a in again_flat] != [(a.shape, a.dtype) for a in flat]:
            raise TypeError("Retry.resume must return the batched arrays with their shapes and types")
        redo = _score(second, again_flat, retry_shared, again, again.size)

        def put(old, new, again=again):
            old = np.array(old)  # device_get may hand out read-only arrays
            old[again] = new
            return old

        out = jax.tree_util.tree_map(put, out, redo)
    out = jax.tree_util.tree_map(lambda a: np.reshape(a, batch_shape + np.shape(a)[1:]), out)
    # jax.device_put, not jnp.asarray: the latter compiles a small copy program per shape.
    return jax.tree_util.tree_map(jax.device_put, out)


def pad_rows(a: np.ndarray, size: int) -> np.ndarray:
    """``a`` with its first row repeated up to ``size`` rows (a batch padded to a compiled size)."""
    if len(a) >= size:
        return a
    return np.concatenate([a, np.broadcast_to(a[:1], (size - len(a),) + a.shape[1:])])


_SHAPES: dict = {}


def _empty_shapes(fn: Callable, grasp_specs: tuple, shared, traced: bool):
    """The per-grasp output shapes of ``fn`` (for an empty batch; traced once per signature)."""
    key = None if traced else (fn, grasp_specs, _aval_key(shared), _x64())
    if key in _SHAPES:
        return _SHAPES[key]
    specs = tuple(jax.ShapeDtypeStruct(shape, dtype) for shape, dtype in grasp_specs)
    out = jax.eval_shape(fn, *specs, shared)
    if key is not None:
        _SHAPES[key] = out
    return out


_OPTIONAL: dict = {}


def _with_optional(fn: Callable, missing: tuple) -> Callable:
    """Adapt ``fn`` so that ``None`` entries of the batched tuple are passed as ``None`` (one
    stable adapter per ``(fn, missing)``, so that compiled programs are reused). A :class:`Staged`
    ``fn`` has both stages adapted."""
    if not any(missing):
        return fn
    key = (fn, missing)
    adapted = _OPTIONAL.get(key)
    if adapted is None:
        if isinstance(fn, Staged):
            adapted = Staged(_adapt(fn.first, missing, 1), _adapt(fn.second, missing, 2))
        else:
            adapted = _adapt(fn, missing, 1)
        adapted = _OPTIONAL.setdefault(key, adapted)
    return adapted


def _adapt(fn: Callable, missing: tuple, trailing: int) -> Callable:
    """``fn(*full, *rest)`` called as ``adapted(*given, *rest)``, where ``rest`` are the
    ``trailing`` arguments after the grasp's arrays and ``given`` leaves out the missing ones."""

    def adapted(*args):
        given, rest = args[: len(args) - trailing], args[len(args) - trailing :]
        it = iter(given)
        return fn(*(None if m else next(it) for m in missing), *rest)

    return adapted
