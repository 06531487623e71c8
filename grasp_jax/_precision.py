"""Floating-point precision, scoped to a call: grasp_jax never changes JAX's global configuration.

The concrete (NumPy-in, NumPy-out) paths compute in float64 inside :func:`float64_scope`, JAX's
scoped ``jax.enable_x64`` switch; under a caller's ``jit``/``vmap``/``grad`` the library computes
in the caller's dtype.
"""

from __future__ import annotations

import contextlib

import jax


def float64_scope():
    """A context in which float64 arrays can be made (a no-op where x64 is already on)."""
    if jax.config.jax_enable_x64:
        return contextlib.nullcontext()
    return jax.enable_x64(True)
