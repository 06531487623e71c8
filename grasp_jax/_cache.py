"""The persistent compilation cache of grasp_jax: compiled XLA programs kept between processes.

One folder serves the library and the command line: ``$GRASP_JAX_CACHE`` when set (``off``, ``0``,
``no``, ``none``, ``false`` or an empty value switch the cache off), else
``$XDG_CACHE_HOME/grasp_jax/xla``, by default ``~/.cache/grasp_jax/xla``.

The library changes no JAX configuration. It compiles ``_batch``'s chunk programs ahead of time
and serializes their executables (:mod:`jax.experimental.serialize_executable`), one file per
program, named by a hash of the lowered program, the compiler options, the JAX and jaxlib
versions, the platform, the host CPU (:func:`host_cpu`), ``XLA_FLAGS`` and the devices; a file
that cannot be read, written or loaded is ignored. Where the caller has set JAX's own
``jax_compilation_cache_dir``, this cache is only read: an executable JAX loaded from its cache
serializes incompletely. The folder is trusted (loading an executable can run code).
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

import jax

#: Values of ``GRASP_JAX_CACHE`` that switch the cache off.
OFF = ("", "0", "off", "no", "none", "false")
#: Prefix and suffix of the library's cache files.
PREFIX, SUFFIX = "grasp_jax-", ".xla"
#: Bumped when the file layout or the key changes.
_VERSION = "2"


def host_cpu() -> str:
    """The host CPU's model and instruction-set flags (``/proc/cpuinfo`` on Linux, else what
    :mod:`platform` says). XLA compiles a CPU program for the host's instruction set: a cache shared
    by machines of different CPUs (a home folder on a cluster) must not hand an AVX-512 program to
    an AVX2 machine (an illegal instruction), nor one CPU's float32 rounding to another."""
    import platform

    try:
        with open("/proc/cpuinfo") as f:
            lines = [ln for ln in f if ln.startswith(("model name", "flags", "Features", "CPU part"))]
        found = "".join(sorted(set(lines)))
    except OSError:
        found = ""
    return found or f"{platform.machine()} {platform.processor()}"


def directory() -> Path | None:
    """The cache folder now in effect (read from the environment on every call), or ``None`` when
    the cache is switched off."""
    where = os.environ.get("GRASP_JAX_CACHE")
    if where is not None:
        if where.strip().lower() in OFF:
            return None
        return Path(where).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "grasp_jax" / "xla"


def key(lowered_text: str, options: dict, devices: tuple) -> str:
    """The file key of a program: everything that decides the compiled executable."""
    import jaxlib

    client = devices[0].client
    parts = [
        _VERSION,
        jax.__version__,
        getattr(jaxlib, "__version__", "?"),
        client.platform,
        str(getattr(client, "platform_version", "")),
        os.environ.get("XLA_FLAGS", ""),
        host_cpu(),
        repr(sorted(options.items())),
        repr([(d.platform, d.device_kind, d.id, d.process_index) for d in devices]),
        lowered_text,
    ]
    h = hashlib.sha256()
    for p in parts:
        h.update(p.encode())
        h.update(b"\0")
    return h.hexdigest()[:40]


def _path(folder: Path, name: str) -> Path:
    return folder / f"{PREFIX}{name}{SUFFIX}"


def load(name: str, lowered, devices: tuple):
    """The cached executable ``name`` for ``lowered``, loaded on ``devices``; ``None`` if absent or
    unusable."""
    folder = directory()
    if folder is None:
        return None
    try:
        data = _path(folder, name).read_bytes()
    except OSError:
        return None
    try:
        from jax.experimental import serialize_executable

        in_tree = jax.tree_util.tree_structure(lowered.args_info)
        return serialize_executable.deserialize_and_load(
            data, in_tree, lowered.out_tree, backend=devices[0].client, execution_devices=list(devices)
        )
    except Exception:  # noqa: BLE001 - a stale or damaged file: compile instead
        return None


def jax_cache_active() -> bool:
    """Whether JAX's own persistent cache is switched on in this process (by the caller)."""
    return bool(jax.config.values.get("jax_compilation_cache_dir")) and bool(
        jax.config.values.get("jax_enable_compilation_cache", True))


def store(name: str, compiled) -> bool:
    """Write ``compiled`` to the cache (atomically); ``False`` when it could not be, or when JAX's
    own persistent cache is on (see the module docstring)."""
    folder = directory()
    if folder is None or jax_cache_active():
        return False
    try:
        from jax.experimental import serialize_executable

        data, _, _ = serialize_executable.serialize(compiled)
    except Exception:  # noqa: BLE001 - not serializable on this backend: no cache
        return False
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=".tmp-", suffix=SUFFIX)
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            os.replace(tmp, _path(folder, name))
        except BaseException:
            os.unlink(tmp)
            raise
    except OSError:
        return False  # read-only home and the like: run without a cache
    return True
