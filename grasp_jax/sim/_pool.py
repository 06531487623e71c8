"""Grasps batched over processes: fixed chunks, one simulator per worker, results in order.

Every grasp is simulated from a reset state by a simulator built once per worker from the same
arguments, so the result of a grasp depends on neither the chunking nor the number of workers.
Workers are forked from the caller while no JAX backend runs in it (a cheap start), else from a
fresh server process (``forkserver``): a fork would copy JAX's threads mid-flight.
"""

from __future__ import annotations

import multiprocessing
import os
import sys

#: Grasps per task handed to a worker.
CHUNK = 16

_SIM = None


def default_workers() -> int:
    """One worker per core available to this process."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def _init(factory, args) -> None:
    global _SIM
    _SIM = factory(*args)


def _chunk(task):
    start, arrays = task
    return [_SIM.run(start + i, *(a[i] for a in arrays)) for i in range(len(arrays[0]))]


def _jax_running() -> bool:
    bridge = sys.modules.get("jax._src.xla_bridge")
    return bool(getattr(bridge, "_backends", True)) if bridge is not None else False


def _context():
    methods = multiprocessing.get_all_start_methods()
    if "fork" in methods and not _jax_running():
        return multiprocessing.get_context("fork")
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload([__name__, "mujoco", "numpy"])
    return ctx


def run_batched(factory, args: tuple, arrays: tuple, *, workers: int | None, progress: bool,
                desc: str, chunk: int = CHUNK) -> list:
    """``factory(*args).run(i, *(a[i] for a in arrays))`` for every row ``i``, in order, over
    ``workers`` processes (1: in this process) in chunks of ``chunk`` rows; a tqdm bar when
    ``progress``.

    Raises:
        ValueError: ``workers`` not a positive integer.
    """
    from tqdm.auto import tqdm

    workers = default_workers() if workers is None else workers
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be a positive integer; got {workers!r}")
    k = len(arrays[0])
    tasks = [(s, tuple(a[s:s + chunk] for a in arrays)) for s in range(0, k, chunk)]
    workers = min(workers, len(tasks)) or 1
    rows: list = []
    with tqdm(total=k, desc=desc, disable=not progress, unit="grasp") as bar:
        if workers == 1:
            sim = factory(*args)
            for start, part in tasks:
                for i in range(len(part[0])):
                    rows.append(sim.run(start + i, *(a[i] for a in part)))
                bar.update(len(part[0]))
            return rows
        with _context().Pool(workers, initializer=_init, initargs=(factory, args)) as pool:
            for out in pool.imap(_chunk, tasks):
                rows.extend(out)
                bar.update(len(out))
    return rows
