"""Forward kinematics of one hand configuration, in pure JAX (differentiable, float32 or float64).

A pose is ``(7,)``: the wrist (root link) position ``(3,)`` then its orientation as a unit
quaternion in **wxyz** order (scalar first, as MuJoCo and trimesh). Batch with ``jax.vmap`` or
through ``grasp_jax._batch``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ._hand import FIXED, PRISMATIC, REVOLUTE, Hand


def quat_to_matrix(quat) -> jax.Array:
    """``(3, 3)`` rotation of a quaternion ``(4,)`` wxyz (normalized here, so any non-zero one)."""
    q = quat / jnp.sqrt(jnp.sum(quat * quat))
    w, x, y, z = q[0], q[1], q[2], q[3]
    return jnp.stack([
        jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)]),
        jnp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)]),
        jnp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]),
    ])


def matrix_to_quat(matrix) -> jax.Array:
    """``(4,)`` wxyz unit quaternion (``w >= 0``) of a ``(3, 3)`` rotation (NumPy or JAX)."""
    m = jnp.asarray(matrix)
    t = jnp.trace(m)
    cands = jnp.stack([
        jnp.stack([1 + t, m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]]),
        jnp.stack([m[2, 1] - m[1, 2], 1 + m[0, 0] - m[1, 1] - m[2, 2], m[0, 1] + m[1, 0], m[0, 2] + m[2, 0]]),
        jnp.stack([m[0, 2] - m[2, 0], m[0, 1] + m[1, 0], 1 - m[0, 0] + m[1, 1] - m[2, 2], m[1, 2] + m[2, 1]]),
        jnp.stack([m[1, 0] - m[0, 1], m[0, 2] + m[2, 0], m[1, 2] + m[2, 1], 1 - m[0, 0] - m[1, 1] + m[2, 2]]),
    ])
    k = jnp.argmax(jnp.stack([1 + t, 1 + m[0, 0] - m[1, 1] - m[2, 2], 1 - m[0, 0] + m[1, 1] - m[2, 2],
                              1 - m[0, 0] - m[1, 1] + m[2, 2]]))
    q = cands[k]
    q = q / jnp.sqrt(jnp.sum(q * q))
    return jnp.where(q[0] < 0, -q, q)


def _axis_angle(axis, angle) -> jax.Array:
    """Rodrigues' rotation ``(3, 3)`` about a unit ``axis`` by ``angle``."""
    x, y, z = axis[0], axis[1], axis[2]
    zero = jnp.zeros_like(x)
    k = jnp.stack([jnp.stack([zero, -z, y]), jnp.stack([z, zero, -x]), jnp.stack([-y, x, zero])])
    eye = jnp.eye(3, dtype=axis.dtype)
    return eye + jnp.sin(angle) * k + (1 - jnp.cos(angle)) * (k @ k)


def pose_matrix(pose) -> jax.Array:
    """``(4, 4)`` homogeneous transform of a pose ``(7,)`` (position, quaternion wxyz)."""
    rot = quat_to_matrix(pose[3:])
    top = jnp.concatenate([rot, pose[:3, None]], axis=1)
    bottom = jnp.array([[0, 0, 0, 1]], dtype=top.dtype)
    return jnp.concatenate([top, bottom], axis=0)


def link_values(hand: Hand, joints) -> jax.Array:
    """``(L,)`` each link's joint value from the actuated ``joints: (J,)`` (mimic joints follow)."""
    src = jnp.asarray([max(s, 0) for s in hand.source], dtype=jnp.int32)
    return jnp.where(jnp.asarray(hand.source) >= 0, hand.multiplier * joints[src] + hand.offset, 0.0)


def forward(hand: Hand, pose, joints) -> jax.Array:
    """World transforms of every link for **one** configuration.

    Args:
        hand: a :class:`Hand`.
        pose: ``(7,)`` wrist position then unit quaternion **wxyz** (normalized here).
        joints: ``(J,)`` actuated joint values (``hand.joint_names`` order), radians or metres.

    Returns:
        ``(L, 4, 4)`` each link's frame in the world, ``hand.link_names`` order.

    Raises:
        ValueError: at trace time, for a batched or misshaped ``pose`` or ``joints`` (use ``jax.vmap``).
    """
    pose = jnp.asarray(pose)
    joints = jnp.asarray(joints)
    if pose.shape != (7,):
        raise ValueError(f"pose must have shape (7,) (position, quaternion wxyz) for one hand; got {pose.shape} "
                         "(batch with jax.vmap)")
    if joints.shape != (hand.num_joints,):
        raise ValueError(f"joints must have shape ({hand.num_joints},) for hand {hand.name!r}; got {joints.shape} "
                         "(batch with jax.vmap)")
    dtype = jnp.result_type(pose.dtype, joints.dtype, jnp.float32)
    pose, joints = pose.astype(dtype), joints.astype(dtype)
    origin = jnp.asarray(hand.origin, dtype)
    axis = jnp.asarray(hand.axis, dtype)
    values = link_values(hand, joints).astype(dtype)
    eye = jnp.eye(4, dtype=dtype)
    frames = []
    for i, (parent, kind) in enumerate(zip(hand.parent, hand.joint_kind)):
        base = pose_matrix(pose) if parent < 0 else frames[parent]
        local = origin[i]
        if kind == REVOLUTE:
            motion = eye.at[:3, :3].set(_axis_angle(axis[i], values[i]))
            local = local @ motion
        elif kind == PRISMATIC:
            local = local @ eye.at[:3, 3].set(axis[i] * values[i])
        else:
            assert kind == FIXED
        frames.append(base @ local)
    return jnp.stack(frames)


def transform_points(frames, link, points) -> jax.Array:
    """``points: (..., 3)`` given in the frames of links ``link`` (broadcast with the points'
    leading shape) mapped to the world by ``frames: (L, 4, 4)``."""
    t = frames[link]
    return jnp.einsum("...ij,...j->...i", t[..., :3, :3], points) + t[..., :3, 3]


def rotate_vectors(frames, link, vectors) -> jax.Array:
    """Like :func:`transform_points` for directions (rotation only)."""
    return jnp.einsum("...ij,...j->...i", frames[link][..., :3, :3], vectors)
