"""Primitive wrenches (eq. 6), the grasp wrench (eq. 7) and central axes (eq. 10-11).

A wrench is ``(force, torque)``: shape ``(6,)`` in 3D and ``(3,)`` in 2D, where the planar torque
is the scalar ``c_x f_y - c_y f_x``.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ._constants import tolerances
from ._precision import scope_for, working_dtype
from ._validate import is_traced


def cross(a: jax.Array, b: jax.Array) -> jax.Array:
    """Cross product over the last axis: a vector for 3D, the scalar ``a_x b_y - a_y b_x`` for 2D."""
    if a.shape[-1] == 2:
        return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return jnp.cross(a, b)


def torque_dim(d: int) -> int:
    """Dimension of the torque space: 1 in the plane, 3 in space."""
    return 1 if d == 2 else 3


def primitive_wrenches(points: jax.Array, edges: jax.Array, origin: jax.Array | None = None):
    """Primitive contact wrenches ``w_ij = (v_ij, (c_i - o) x v_ij)`` (eq. 6) of one grasp.

    Args:
        points: ``(n, d)`` contact points.
        edges: ``(n, m, d)`` cone edges from :func:`cone_edges`.
        origin: ``(d,)`` point the torques are taken about (default: the frame origin).

    Returns:
        ``(n, m, d + t)`` wrenches, ``t = 1`` in 2D and 3 in 3D.
    """
    arm = points if origin is None else points - origin
    torque = cross(arm[:, None, :], edges)
    if points.shape[-1] == 2:
        torque = torque[..., None]
    return jnp.concatenate([edges, torque], axis=-1)


def grasp_wrench(points: jax.Array, edges: jax.Array, coefficients: jax.Array) -> jax.Array:
    """Net wrench ``W_g = sum_ij a_ij w_ij`` (eq. 7) about the frame origin.

    Args:
        points: ``(n, d)``; edges: ``(n, m, d)``; coefficients: ``(n, m)`` non-negative ``a_ij``.

    Returns:
        ``(d + t,)`` wrench.
    """
    return jnp.einsum("ij,ijk->k", coefficients, primitive_wrenches(points, edges))


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class CentralAxis:
    """The central axis of a wrench (Poinsot), eq. (10)-(11).

    Attributes:
        point: ``(..., d)`` the point of the axis closest to the origin,
            ``I = F x tau / |F|^2`` (the origin for a pure torque).
        direction: ``(..., d)`` unit direction ``F/|F|``; for a pure torque in 3D, ``tau/|tau|``;
            for a pure torque in 2D the axis is normal to the plane and this is zero.
        pitch: ``(...)`` ``F.tau/|F|^2``: the torque about the axis is ``pitch * F``. Always 0 in
            2D for a non-zero force; ``+/-inf`` for a pure torque (sign of the torque in 2D).
        pure_torque: ``(...)`` bool, the ``F = 0`` branch of eq. (10).
    """

    point: jax.Array
    direction: jax.Array
    pitch: jax.Array
    pure_torque: jax.Array

    def __repr__(self) -> str:
        """A short summary, e.g. ``CentralAxis(batch=(10,), 2D, 1 pure torque, dtype float64)``."""
        shape = tuple(np.shape(self.pitch))
        d = np.shape(self.point)[-1]
        dtype = np.dtype(self.point.dtype).name
        if any(isinstance(x, jax.core.Tracer) for x in (self.point, self.direction, self.pitch, self.pure_torque)):
            return f"CentralAxis(batch={shape}, {d}D, traced, dtype {dtype})"
        pure = int(np.sum(np.asarray(self.pure_torque)))
        return f"CentralAxis(batch={shape}, {d}D, {pure} pure torque{'s' if pure != 1 else ''}, dtype {dtype})"


def central_axis(wrench) -> CentralAxis:
    """Central axis of one or many wrenches.

    Args:
        wrench: ``(..., 6)`` (3D) or ``(..., 3)`` (2D) wrenches ``(force, torque)``, torque about
            the origin.

    Returns:
        :class:`CentralAxis` with the leading shape of ``wrench``. Finite values and gradients
        everywhere except the documented infinite pitch of a pure torque.
    """
    traced = is_traced(wrench)
    if not traced:
        wrench = np.asarray(wrench)
        if wrench.dtype == object or not (
            np.issubdtype(wrench.dtype, np.floating) or np.issubdtype(wrench.dtype, np.integer)
            or wrench.dtype == bool
        ):
            raise ValueError(f"wrench must be an array of real numbers; got dtype {wrench.dtype}")
    if wrench.ndim == 0 or wrench.shape[-1] not in (3, 6):
        raise ValueError(
            f"wrench must have shape (..., 6) in 3D or (..., 3) in 2D; got {wrench.shape}"
        )
    dtype = working_dtype(wrench.dtype, traced=traced)
    with scope_for(dtype, traced):
        return _central_axis(jnp.asarray(wrench, dtype) if not traced else wrench.astype(dtype))


def _central_axis(wrench: jax.Array) -> CentralAxis:
    d = 2 if wrench.shape[-1] == 3 else 3
    f, tau = wrench[..., :d], wrench[..., d:]
    tol = tolerances(wrench.dtype)
    f2 = jnp.sum(f * f, axis=-1)
    t2 = jnp.sum(tau * tau, axis=-1)
    scale = jnp.maximum(f2, t2)
    pure = f2 <= 1e3 * jnp.finfo(wrench.dtype).eps ** 2 * scale + tol.tiny
    f2_safe = jnp.where(pure, 1.0, f2)
    if d == 3:
        point = jnp.cross(f, tau) / f2_safe[..., None]
        pitch = jnp.sum(f * tau, axis=-1) / f2_safe
        t_safe = jnp.where(t2 > tol.tiny, t2, 1.0)
        direction = jnp.where(
            pure[..., None],
            tau / jnp.sqrt(t_safe)[..., None],
            f / jnp.sqrt(f2_safe)[..., None],
        )
        pitch = jnp.where(pure, jnp.inf, pitch)
    else:
        t = tau[..., 0]
        point = jnp.stack([f[..., 1] * t, -f[..., 0] * t], axis=-1) / f2_safe[..., None]
        direction = jnp.where(pure[..., None], 0.0, f / jnp.sqrt(f2_safe)[..., None])
        pitch = jnp.where(pure, jnp.where(t >= 0, jnp.inf, -jnp.inf), 0.0)
    point = jnp.where(pure[..., None], 0.0, point)
    return CentralAxis(point=point, direction=direction, pitch=pitch.astype(wrench.dtype), pure_torque=pure)
