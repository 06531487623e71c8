"""Devices and processes: how many XLA devices the CPU is split into, and multi-process runs.

Devices
    :func:`configure_cpu_devices` splits the CPU into one XLA device per core
    (``XLA_FLAGS=--xla_force_host_platform_device_count``), which about doubles throughput on two
    cores. It must run before JAX starts its backend (the first computation or ``jax.devices()``).

Several hosts
    With ``distributed=True`` (``grasp-jax sample --distributed``), or when
    ``JAX_COORDINATOR_ADDRESS``, ``JAX_NUM_PROCESSES`` and ``JAX_PROCESS_ID`` are set,
    :func:`initialize_distributed` calls :func:`jax.distributed.initialize`. Process ``i`` of ``P``
    then scores the slice :func:`slice_bounds` of the grasps and writes its own file
    :func:`part_path` (see :mod:`grasp_jax.pipeline`).

Nothing here imports JAX at module level.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

_DEVICE_FLAG = "--xla_force_host_platform_device_count"
_DISTRIBUTED_ENV = ("JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES", "JAX_PROCESS_ID")


def available_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def _backend_started() -> bool:
    if "jax" not in sys.modules:
        return False
    try:
        from jax._src import xla_bridge

        return bool(xla_bridge.backends_are_initialized())
    except (ImportError, AttributeError):  # private API moved: assume the worst
        return True


def configure_cpu_devices(count: int | None = None) -> int | None:
    """Split the host CPU into ``count`` XLA devices (default: one per available core).

    Sets ``XLA_FLAGS=--xla_force_host_platform_device_count=<count>`` (keeping other flags) when
    JAX has not started its backend yet and the flag is not already set. Only the CPU platform
    reads it; on a GPU machine it is harmless.

    Returns:
        The device count now requested, or ``None`` when nothing was changed (the backend already
        runs, or ``XLA_FLAGS`` already chooses a count: the user's setting wins).
    """
    count = available_cores() if count is None else int(count)
    if count < 1:
        raise ValueError(f"device count must be >= 1; got {count}")
    flags = os.environ.get("XLA_FLAGS", "")
    if _DEVICE_FLAG in flags or _backend_started():
        return None
    os.environ["XLA_FLAGS"] = f"{flags} {_DEVICE_FLAG}={count}".strip()
    return count


def distributed_requested() -> bool:
    """Whether the standard JAX multi-process variables are all set."""
    return all(os.environ.get(k) for k in _DISTRIBUTED_ENV)


def initialize_distributed(force: bool = False) -> tuple[int, int]:
    """Join a multi-process JAX job when asked (``force``) or when its variables are set.

    Calls :func:`jax.distributed.initialize` with ``JAX_COORDINATOR_ADDRESS``,
    ``JAX_NUM_PROCESSES`` and ``JAX_PROCESS_ID`` when they are set, else with no arguments so that
    JAX detects the cluster (SLURM, Open MPI, Cloud TPU). Must run before any JAX computation.

    Returns:
        ``(process_index, process_count)``; ``(0, 1)`` when not distributed.
    """
    if not (force or distributed_requested()):
        return 0, 1
    import jax

    kwargs = {}
    if distributed_requested():  # jax reads only the address from the environment itself
        try:
            kwargs = dict(coordinator_address=os.environ["JAX_COORDINATOR_ADDRESS"],
                          num_processes=int(os.environ["JAX_NUM_PROCESSES"]),
                          process_id=int(os.environ["JAX_PROCESS_ID"]))
        except ValueError:
            raise ValueError("JAX_NUM_PROCESSES and JAX_PROCESS_ID must be integers") from None
    try:
        jax.distributed.initialize(**kwargs)
    except (RuntimeError, ValueError) as e:
        if "already" not in str(e).lower():
            raise ValueError(f"could not join the distributed JAX job ({e})") from None
    return jax.process_index(), jax.process_count()


def process_slot() -> tuple[int, int]:
    """``(process_index, process_count)`` of this process in the JAX job (``(0, 1)`` alone)."""
    import jax

    return jax.process_index(), jax.process_count()


def slice_bounds(num: int, index: int, count: int) -> tuple[int, int]:
    """The contiguous slice ``[start, stop)`` of ``num`` grasps scored by process ``index``."""
    return num * index // count, num * (index + 1) // count


def part_path(path, index: int, count: int) -> Path:
    """``results.npz`` -> ``results.3-of-8.npz`` for process 3 of 8 (unchanged for one process)."""
    path = Path(path)
    if count <= 1:
        return path
    return path.with_name(f"{path.stem}.{index}-of-{count}{path.suffix}")


__all__ = [
    "available_cores",
    "configure_cpu_devices",
    "distributed_requested",
    "initialize_distributed",
    "part_path",
    "process_slot",
    "slice_bounds",
]
