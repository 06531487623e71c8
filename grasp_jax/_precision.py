"""Floating-point precision: the dtype rules of grasp_jax, in this one place.

grasp_jax never changes JAX's global configuration (``jax_enable_x64`` stays as the caller set
it). A call's precision follows from its inputs (``points``, ``normals``, ``tangents``; for
:func:`grasp_jax.central_axis`, ``wrench``):

1. **Traced inputs** (inside the caller's ``jit``, ``vmap``, ``grad``): the tracers' dtype.
2. **Concrete inputs**: NumPy's promotion, integers and booleans counting as float64. float64 is
   computed inside :func:`float64_scope` (JAX's scoped ``jax.enable_x64``) with float64 results;
   float32 in float32 (:data:`_constants._F32` tolerances); float16 and bfloat16 in float32.
3. Scalars (``mu``, ``origin``, ``torque_scale``) take the grasps' dtype; booleans stay bool,
   statuses int8, iteration counts int32.
4. float64 asked for where the backend cannot give it raises :class:`Float64Unavailable`.
   Without x64, JAX operations on float64 results compute in float32: ``np.asarray`` them first.
"""

from __future__ import annotations

import contextlib
import functools

import jax
import jax.numpy as jnp
import numpy as np


class Float64Unavailable(TypeError):
    """float64 was asked for (float64 inputs on the concrete path) and cannot be had."""


def _x64_enabled() -> bool:
    return bool(jax.config.jax_enable_x64)


@functools.cache
def _backend_has_float64(backend: str) -> str | None:
    """``None`` when the default device computes in float64, else why not (checked once)."""
    try:
        x = jax.device_put(np.full(2, 1.0 + 2.0**-40))
        if x.dtype != np.float64:
            return f"arrays made in the scope are {x.dtype}"
        y = np.asarray(jax.jit(lambda v: v - 1.0)(x))
        if y.dtype != np.float64 or not np.all(y == 2.0**-40):
            return "float64 arithmetic is rounded to a lower precision"
    except Exception as exc:  # noqa: BLE001 - any failure means: no float64 here
        return f"{type(exc).__name__}: {exc}"
    return None


@contextlib.contextmanager
def float64_scope():
    """A context in which JAX makes and computes float64 arrays, without touching the global
    configuration (a no-op where the caller has x64 on already).

    Raises:
        Float64Unavailable: the scope did not give float64 (see the module docstring, rule 4).
    """
    scope = contextlib.nullcontext() if _x64_enabled() else jax.enable_x64(True)
    with scope:
        why = None
        if jax.dtypes.canonicalize_dtype(np.float64) != np.float64:
            why = "JAX's x64 switch did not take effect"
        else:
            why = _backend_has_float64(jax.default_backend())
        if why is not None:
            raise Float64Unavailable(
                f"grasp_jax: float64 inputs ask for float64 computation, but the {jax.default_backend()} "
                f"backend cannot provide it ({why}). Pass float32 arrays to compute in float32."
            )
        yield


def scope_for(dtype, traced: bool):
    """The context a call with inputs of ``dtype`` runs in: :func:`float64_scope` for concrete
    float64 inputs, nothing otherwise (rules 1 and 2)."""
    if not traced and np.dtype(dtype) == np.float64:
        return float64_scope()
    return contextlib.nullcontext()


def working_dtype(*dtypes, traced: bool) -> np.dtype:
    """The dtype a call computes in, from its inputs' dtypes (``None`` entries ignored)."""
    dtypes = [np.dtype(d) for d in dtypes if d is not None]
    # Integers count as float64, which under a trace without x64 is float32.
    as_float = jax.dtypes.canonicalize_dtype(np.float64) if traced else np.dtype(np.float64)
    dtypes = [d if jnp.issubdtype(d, jnp.floating) else np.dtype(as_float) for d in dtypes]
    if traced:  # a concrete float64 argument beside tracers is what JAX makes of it (float32 without x64)
        dtypes = [np.dtype(jax.dtypes.canonicalize_dtype(d)) for d in dtypes]
    dtype = np.dtype(jnp.result_type(*dtypes)) if traced else np.result_type(*dtypes)
    if dtype not in (np.float32, np.float64):
        dtype = np.dtype(np.float32)  # float16, bfloat16: no half-precision tolerances
    return dtype
