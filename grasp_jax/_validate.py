"""Checks of user input, done before anything is traced. Each failure is one ``ValueError``
that names the argument and says what was expected."""

from __future__ import annotations

import math
import numbers

import jax
import numpy as np

from ._precision import working_dtype


def is_traced(*xs) -> bool:
    """Whether any argument is a JAX tracer (we are inside ``jit``/``grad``/``vmap``)."""
    return any(isinstance(x, jax.core.Tracer) for x in xs)


def _as_float_array(name: str, x):
    if is_traced(x):
        arr = x
    else:
        try:
            arr = np.asarray(x)
        except Exception as exc:  # noqa: BLE001 - any conversion failure is a user error
            raise ValueError(f"{name} must be an array of numbers; got {type(x).__name__}") from exc
        if arr.dtype == object or not (
            np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)
        ):
            raise ValueError(f"{name} must be an array of real numbers; got dtype {arr.dtype}")
    return arr


def check_scalar(name: str, value, *, positive: bool = True, minimum: float | None = None):
    """A finite (positive, or at least ``minimum``) real scalar; tracers pass through unchecked."""
    if is_traced(value):
        return value
    try:
        v = float(np.asarray(value).item()) if np.ndim(value) == 0 else None
    except (TypeError, ValueError):
        v = None
    if v is None:
        raise ValueError(f"{name} must be a real scalar; got {value!r}")
    if not math.isfinite(v) or (positive and v <= 0):
        raise ValueError(f"{name} must be a finite number{' > 0' if positive else ''}; got {value!r}")
    if minimum is not None and v < minimum:
        raise ValueError(f"{name} must be a finite number >= {minimum:g}; got {value!r}")
    return v


def check_int(name: str, value, minimum: int = 1, note: str = "") -> int:
    """A Python or NumPy integer (not a bool) >= ``minimum``, as an ``int``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < minimum:
        expected = {0: "a non-negative integer", 1: "a positive integer"}.get(minimum, f"an integer >= {minimum}")
        raise ValueError(f"{name} must be {expected}{note}; got {value!r}")
    return int(value)


def check_num_edges(num_edges) -> int:
    return check_int("num_edges", num_edges, 3)


def check_grasps(points, normals, tangents=None):
    """Validate a batch of grasps.

    Args:
        points, normals: ``(..., n, d)``, ``d`` in {2, 3}, ``n >= 2``; normals outward, non-zero.
        tangents: optional ``(..., n, 3)`` first tangent directions (3D only).

    Returns:
        ``(points, normals, tangents, batch_shape)`` as float arrays of one dtype, chosen by the
        rules of :mod:`grasp_jax._precision` (:func:`~grasp_jax._precision.working_dtype`):
        NumPy arrays on the concrete path, tracers under a transformation.
    """
    points = _as_float_array("points", points)
    normals = _as_float_array("normals", normals)
    if points.ndim < 2:
        raise ValueError(f"points must have shape (..., n, d); got {points.shape}")
    if normals.shape != points.shape:
        raise ValueError(
            f"normals must have the same shape as points {points.shape}; got {normals.shape}"
        )
    n, d = points.shape[-2:]
    if d not in (2, 3):
        raise ValueError(f"points must have d = 2 or 3 coordinates in the last axis; got d = {d}")
    if n < 2:
        raise ValueError(f"a grasp needs at least 2 contacts; points has n = {n} (shape {points.shape})")
    if tangents is not None:
        if d != 3:
            raise ValueError("tangents are only meaningful in 3D; got 2D points")
        tangents = _as_float_array("tangents", tangents)
        if tangents.shape != points.shape:
            raise ValueError(f"tangents must have shape {points.shape}; got {tangents.shape}")
    traced = is_traced(points, normals, tangents)
    dtype = working_dtype(points.dtype, normals.dtype, None if tangents is None else tangents.dtype, traced=traced)
    if not traced:
        for name, arr in (("points", points), ("normals", normals), ("tangents", tangents)):
            if arr is not None and not np.all(np.isfinite(arr)):
                bad = np.argwhere(~np.isfinite(arr))[0][:-1]
                raise ValueError(f"{name} must be finite; found a non-finite value at index {tuple(bad)}")
        lengths = np.linalg.norm(normals, axis=-1)
        if np.any(lengths <= 1e-12):
            bad = np.argwhere(lengths <= 1e-12)[0]
            raise ValueError(f"normals must be non-zero; found a zero-length normal at index {tuple(bad)}")
        if tangents is not None:
            unit = normals / lengths[..., None]
            along = np.sum(tangents * unit, axis=-1, keepdims=True)
            across = np.linalg.norm(tangents - along * unit, axis=-1)
            flat = across <= 1e-9 * np.maximum(np.linalg.norm(tangents, axis=-1), 1e-300)
            if np.any(flat):
                bad = tuple(np.argwhere(flat)[0])
                raise ValueError(
                    f"tangents must point along the tangent plane of their contact; the tangent at "
                    f"index {bad} is zero or parallel to its normal"
                )
    tangents = None if tangents is None else tangents.astype(dtype)
    return points.astype(dtype), normals.astype(dtype), tangents, points.shape[:-2]


def check_key(key, what: str = "this function"):
    """One ``jax.random`` key from a typed key, a legacy ``uint32[2]`` PRNGKey or a non-negative
    integer seed (``jax.random.key(seed)``); a clear ``ValueError`` for anything else (a traced
    key: ``what`` runs outside ``jit``)."""
    import jax.numpy as jnp

    if is_traced(key):
        raise ValueError(f"key must be a concrete jax.random.key ({what} runs outside jit)")
    if isinstance(key, (int, np.integer)) and not isinstance(key, bool):
        if key < 0:
            raise ValueError(f"key must be a jax.random key or a non-negative integer seed; got {key!r}")
        return jax.random.key(int(key))
    try:
        key = jnp.asarray(key)
        if not jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
            if key.shape != (2,) or key.dtype != jnp.uint32:
                raise TypeError
            key = jax.random.wrap_key_data(key)
    except TypeError:
        raise ValueError(f"key must be a jax.random key (or a legacy PRNGKey) or a non-negative integer seed; "
                         f"got {key!r}") from None
    if key.shape != ():
        raise ValueError(f"key must be one key; got a batch of shape {key.shape}")
    return key
