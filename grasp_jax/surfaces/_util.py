"""Small pieces shared by the surfaces: gradient-safe normalization, tangent projection, the
pytree-dataclass decorator and the one-contact check."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from .._validate import check_int
from ._base import Contact


def unit(x: jax.Array, fallback: jax.Array | None = None) -> jax.Array:
    """Rows of ``x: (..., d)`` scaled to unit length; ``fallback`` (default the last axis vector)
    where a row is zero, with finite gradients there (``where`` swap before the square root)."""
    sq = jnp.sum(x * x, axis=-1, keepdims=True)
    ok = sq > 0
    safe = jnp.where(ok, x, 1.0) / jnp.sqrt(jnp.where(ok, sq, x.shape[-1]))
    if fallback is None:
        fallback = jnp.zeros(x.shape[-1], x.dtype).at[-1].set(1.0)
    return jnp.where(ok, safe, fallback)


def norm(x: jax.Array) -> jax.Array:
    """``|x|`` over the last axis, with a finite (zero) gradient at 0."""
    sq = jnp.sum(x * x, axis=-1)
    ok = sq > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, sq, 1.0)), 0.0)


def tangent(v: jax.Array, normal: jax.Array) -> jax.Array:
    """The part of ``v: (d,)`` orthogonal to the unit ``normal: (d,)``."""
    return v - jnp.dot(v, normal) * normal


def sign(x: jax.Array) -> jax.Array:
    """+1 where ``x >= 0``, -1 elsewhere (never 0)."""
    return jnp.where(x >= 0, 1.0, -1.0).astype(jnp.result_type(x, float))


@dataclasses.dataclass(frozen=True, eq=False, kw_only=True)
class Fields:
    """The attributes every surface has (see :class:`~grasp_jax.surfaces.Surface`): ``center``
    (data), ``dim``, ``scale`` and ``normal_kind`` (static)."""

    center: jax.Array
    dim: int = 3
    scale: float = 1.0
    normal_kind: str = "exact"


def pytree(data: tuple[str, ...], meta: tuple[str, ...] = ()):
    """Register a frozen, keyword-only dataclass built on :class:`Fields` as a pytree: ``center``
    and the ``data`` fields are leaves (arrays); ``dim``, ``scale``, ``normal_kind`` and the
    ``meta`` fields are static (hashable)."""

    def wrap(cls):
        cls = dataclasses.dataclass(frozen=True, eq=False, kw_only=True)(cls)
        return jax.tree_util.register_dataclass(
            cls, data_fields=["center", *data], meta_fields=["dim", "scale", "normal_kind", *meta])

    return wrap


def check_one(name: str, contact: Contact, k: int, v: jax.Array | None = None) -> None:
    """Trace-time check that ``contact`` (and ``v``) describe ONE contact of a surface whose
    coordinates have ``k`` entries; raises ``ValueError`` naming the method."""
    coords = jnp.shape(contact.coords)
    if coords != (k,) or jnp.shape(contact.face) != ():
        raise ValueError(f"{name}: takes one contact (face (), coords ({k},)); got face "
                         f"{jnp.shape(contact.face)} and coords {coords}; batch with jax.vmap.")
    if v is not None and jnp.shape(v) != (k,):
        raise ValueError(f"{name}: v must be one displacement of shape ({k},); got {jnp.shape(v)}; "
                         "batch with jax.vmap.")


def check_count(count) -> int:
    """A static integer number of samples >= 0."""
    return check_int("sample: count", count, 0, " (static)")


def host_points(points, dim: int) -> np.ndarray:
    """``points`` as a float64 NumPy array of shape ``(..., dim)``."""
    points = np.asarray(points, dtype=float)
    if points.ndim < 1 or points.shape[-1] != dim or not np.isfinite(points).all():
        raise ValueError(f"locate: points must be finite with shape (..., {dim}); got shape "
                         f"{points.shape}")
    return points


def jit_method(static: tuple[str, ...] = ()):
    """Compile a surface method once per surface structure (the surface is an argument of the
    compiled function, so eager calls are fast too; under an outer ``jit``/``vmap``/``grad`` it is
    inlined)."""

    def wrap(fn):
        compiled = jax.jit(fn, static_argnames=static)

        @functools.wraps(fn)
        def method(self, *args, **kwargs):
            return compiled(self, *args, **kwargs)

        return method

    return wrap
