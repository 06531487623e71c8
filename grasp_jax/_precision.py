"""Floating-point precision: the dtype rules of grasp_jax, written down in this one place.

grasp_jax never changes JAX's global configuration: importing it or calling it leaves
``jax_enable_x64`` as the caller set it. Which precision a call computes in follows from its
inputs (``points``, ``normals``, ``tangents``; for :func:`grasp_jax.central_axis`, ``wrench``):

1. **Traced inputs** (the call is inside the caller's ``jit``, ``vmap``, ``grad``, ...): the
   library computes in the tracers' dtype, JAX's promotion of the inputs. That is float32 in a
   program without x64 (a NumPy float64 array passed to a jitted function is float32 there), and
   float64 only where the caller has enabled x64. Nothing is switched on behind the caller's back.
2. **Concrete inputs** (NumPy arrays, lists, concrete JAX arrays): NumPy's promotion of the inputs
   decides, integers and booleans counting as float64 (as in NumPy):

   * float64 -> computed in float64, inside :func:`float64_scope` (JAX's scoped ``jax.enable_x64``
     switch, entered for the call and left when it returns). Results are float64 JAX arrays.
   * float32 (every input float32) -> computed in float32 (:data:`_constants._F32` tolerances),
     float32 results.
   * float16 / bfloat16 -> computed in float32 (there are no half-precision tolerances).

3. Scalars and small arguments (``mu``, ``origin``, ``torque_scale``) take the grasps' dtype;
   boolean results stay bool, statuses int8, iteration counts int32.
4. If float64 is asked for (rule 2) and the backend cannot give it (a platform without float64, or
   x64 that cannot be switched on), the call raises :class:`Float64Unavailable` (a ``TypeError``)
   saying so; pass float32 arrays to compute in float32.

A caveat for programs without x64: float64 JAX arrays returned by a concrete call are still
float64, but new JAX operations on them outside the scope (``res.quality.mean()``) compute in
float32, with JAX's "dtype float64 ... is not available" warning. Convert with ``np.asarray``
first, or run the code in ``with jax.enable_x64(True):``.
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
