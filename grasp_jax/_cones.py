"""Contact frames and linearized friction cones (eq. 2-3 in 3D, eq. 9 in 2D), for one grasp.

Normals are **outward**; fingers push into the object, so a cone's axis is ``z = -normal``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ._constants import tolerances


def safe_normalize(v: jax.Array, axis: int = -1) -> jax.Array:
    """``v / |v|`` along ``axis``, with a finite value and gradient where ``|v| = 0``."""
    tiny = tolerances(v.dtype).tiny
    sq = jnp.sum(v * v, axis=axis, keepdims=True)
    safe = jnp.where(sq > tiny, sq, 1.0)
    return jnp.where(sq > tiny, v / jnp.sqrt(safe), 0.0)


def tangent_frame(axis: jax.Array, tangent: jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
    """Two unit tangents ``(x, y)`` completing the unit ``axis: (3,)`` to a right-handed frame.

    Without ``tangent`` the frame is the branch-free construction of Duff et al. (2017, "Building
    an orthonormal basis, revisited"): deterministic, smooth except where ``axis_z`` changes
    sign, and free of divisions by zero. With ``tangent: (3,)`` the first tangent is its
    projection onto the plane orthogonal to ``axis`` (use this to rotate the cone pyramids with the
    object).
    """
    if tangent is not None:
        x = safe_normalize(tangent - jnp.dot(tangent, axis) * axis)
        return x, jnp.cross(axis, x)
    ax, ay, az = axis[0], axis[1], axis[2]
    sign = jnp.where(az >= 0, 1.0, -1.0).astype(axis.dtype)
    a = -1.0 / (sign + az)
    b = ax * ay * a
    x = jnp.stack([1.0 + sign * ax * ax * a, sign * b, -sign * ax])
    y = jnp.stack([b, sign + ay * ay * a, -ay])
    return x, y


def cone_edges(
    normals: jax.Array, mu, num_edges: int, tangents: jax.Array | None = None
) -> jax.Array:
    """Edges of the linearized friction cones of one grasp.

    Args:
        normals: ``(n, d)`` outward unit normals, ``d`` in {2, 3}.
        mu: friction coefficient ``tan(alpha)``: a scalar, or ``(n,)`` one per contact
            (:func:`grasp_jax.robust` draws friction per contact).
        num_edges: ``m`` edges per cone in 3D (eq. 3); ignored in 2D, where a cone has 2 (eq. 9).
        tangents: optional ``(n, 3)`` first tangent direction of each 3D contact frame.

    Returns:
        ``(n, m, d)`` edges ``v_ij = z_i + mu (cos t_j x_i + sin t_j y_i)``, ``t_j = 2 pi j / m``,
        each of length ``sqrt(1 + mu^2)``; in 2D ``(n, 2, 2)`` edges ``z_i -/+ mu t_i``.
    """
    z = -normals
    if jnp.ndim(mu) == 1:  # one coefficient per contact
        mu = jnp.reshape(mu, (-1,) + (1,) * (1 if normals.shape[-1] == 2 else 2))
    if normals.shape[-1] == 2:
        t = jnp.stack([-z[:, 1], z[:, 0]], axis=-1)  # z rotated by +90 degrees
        return jnp.stack([z - mu * t, z + mu * t], axis=1)
    if tangents is None:
        x, y = jax.vmap(tangent_frame)(z)
    else:
        x, y = jax.vmap(tangent_frame)(z, tangents)
    angles = 2.0 * jnp.pi * jnp.arange(1, num_edges + 1, dtype=normals.dtype) / num_edges
    cos, sin = jnp.cos(angles), jnp.sin(angles)
    return (
        z[:, None, :]
        + mu * cos[None, :, None] * x[:, None, :]
        + mu * sin[None, :, None] * y[:, None, :]
    )
