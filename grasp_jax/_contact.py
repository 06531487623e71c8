"""Contact models: the primitive wrenches a contact transmits, for **one** grasp, which every metric
reads (derived in docs/guides/contact-models.md):

``"hard"`` (point contact with friction, the paper's)
    The ``m`` cone edges ``v_ij`` of contact ``i`` as wrenches ``(v_ij, c_i x v_ij)`` (eq. 6).
``"soft"`` (soft finger, coupled linearization)
    Each edge gives ``(v_ij, c_i x v_ij +/- torsion z_i)``: a moment about the normal bounded by
    ``torsion`` times the normal force (``torsion = (2/3) mu r`` for a patch of radius ``r``,
    :func:`patch_torsion`). 3D only.
``"dexnet-soft"`` (Dex-Net's soft fingers, to reproduce Dex-Net and GraspNet-1Billion labels)
    The hard columns plus two pure moments ``(0, +/- torsion normal_i)`` per contact, not tied to
    the normal force (:func:`dexnet_torsion`).

Condition (2) of Proposition 2 takes contact 1's soft torsion columns too; hard contacts leave
its columns out (:attr:`Columns.fixed`).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from ._cones import safe_normalize
from ._wrench import cross

#: Contact models, in the order of the module docstring.
CONTACTS: tuple[str, ...] = ("hard", "soft", "dexnet-soft")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ContactModel:
    """How every contact of a grasp transmits wrenches: one value, threaded through the
    single-grasp functions (``_programs``, ``_closure``, ``_objectives``) instead of three loose
    arguments.

    Attributes:
        kind: one of :data:`CONTACTS` (static).
        num_edges: edges of a 3D linearized friction cone (static; a 2D cone has 2).
        torsion: the torsional coefficient of ``"soft"`` (a length) and ``"dexnet-soft"`` (a
            moment) contacts, a scalar that may be traced; 0 for hard contacts.
    """

    kind: str = dataclasses.field(default="hard", metadata={"static": True})
    num_edges: int = dataclasses.field(default=8, metadata={"static": True})
    torsion: jax.Array | float = 0.0

    def astype(self, dtype) -> ContactModel:
        """The same model with ``torsion`` a JAX scalar of ``dtype`` (for a program's shared data)."""
        return dataclasses.replace(self, torsion=jnp.asarray(self.torsion, dtype))

    def columns_per_contact(self) -> int:
        """Wrench columns one 3D contact contributes (:func:`columns_per_contact`)."""
        return columns_per_contact(self.kind, self.num_edges)


def patch_torsion(radius, mu):
    """Torsional coefficient ``(2/3) mu r`` (a length) of a circular contact patch of radius ``r``
    under uniform pressure: the largest moment about the normal per unit normal force. For
    ``contact="soft"``."""
    return 2.0 / 3.0 * mu * radius


def dexnet_torsion(finger_radius, mu):
    """Dex-Net's soft-finger column magnitude ``pi r^2 mu`` (``PointGraspMetrics3D.grasp_matrix``;
    the default ``finger_radius`` of its ``grasp_matrix`` is 0.005 m). For ``contact="dexnet-soft"``."""
    return jnp.pi * finger_radius**2 * mu


def columns_per_contact(contact: str, num_edges: int) -> int:
    """Wrench columns one contact contributes (3D): ``m``, ``2 m`` (soft) or ``m + 2`` (Dex-Net)."""
    return {"hard": num_edges, "soft": 2 * num_edges, "dexnet-soft": num_edges + 2}[contact]


@dataclasses.dataclass(frozen=True)
class Columns:
    """The primitive wrenches of one grasp as LP columns.

    Attributes:
        force: ``(K, d)`` forces.
        torque: ``(K, t)`` torques (``t = 1`` in 2D, 3 in 3D) about the chosen point, scaled.
        fixed: the leading columns whose torque about ``c_1`` is zero by construction (contact 1's
            edges of a hard or Dex-Net contact; 0 for soft fingers), left out of the torque test.
    """

    force: jax.Array
    torque: jax.Array
    fixed: int

    @property
    def wrenches(self) -> jax.Array:
        """``(K, d + t)`` wrenches ``(force, torque)``."""
        return jnp.concatenate([self.force, self.torque], axis=-1)


def columns(edges: jax.Array, torque: jax.Array, normals: jax.Array, contact: str, torsion, scale=None) -> Columns:
    """The wrench columns of a contact model from the hard columns of one grasp.

    Args:
        edges: ``(n, m, d)`` cone edges; torque: ``(n, m, t)`` their torques (already scaled).
        normals: ``(n, d)`` outward unit normals.
        contact: one of :data:`CONTACTS`.
        torsion: soft-finger coefficient (a length, scalar); unused for ``"hard"``.
        scale: the length ``torque`` was divided by (``None``: 1); torsion moments are divided by it
            too.

    Returns:
        :class:`Columns`, ordered by contact (hard: contact ``i``'s ``m`` edges; soft: its ``m``
        edges with ``+torsion``, then with ``-torsion``; Dex-Net: all hard columns, then the two
        moment columns of each contact).
    """
    n, m, d = edges.shape
    t = torque.shape[-1]
    if contact == "hard" or d == 2:
        return Columns(edges.reshape(n * m, d), torque.reshape(n * m, t), m)
    moment = torsion * normals if scale is None else torsion * normals / scale  # (n, 3)
    if contact == "soft":
        # Edges have unit normal component, so each column carries torsion z_i per unit normal force.
        force = jnp.broadcast_to(edges[:, None], (n, 2, m, d)).reshape(2 * n * m, d)
        signed = jnp.stack([torque - moment[:, None, :], torque + moment[:, None, :]], axis=1)  # z = -normal
        return Columns(force, signed.reshape(2 * n * m, t), 0)
    if contact == "dexnet-soft":
        pure = jnp.stack([moment, -moment], axis=1).reshape(2 * n, t)
        force = jnp.concatenate([edges.reshape(n * m, d), jnp.zeros((2 * n, d), edges.dtype)])
        return Columns(force, jnp.concatenate([torque.reshape(n * m, t), pure]), m)
    raise ValueError(f"contact must be one of {CONTACTS}; got {contact!r}")


def wrench_columns(points, normals, edges, contact: str, torsion, origin=None, torque_scale=None) -> Columns:
    """:func:`columns` with torques about ``origin`` (default the frame origin) divided by
    ``torque_scale`` (default 1): the classical wrench set of the min-weight margin and the
    Ferrari-Canny baseline."""
    arm = points if origin is None else points - origin
    torque = cross(arm[:, None, :], edges)
    if points.shape[-1] == 2:
        torque = torque[..., None]
    if torque_scale is not None:
        torque = torque / torque_scale
    return columns(edges, torque, safe_normalize(normals), contact, torsion, torque_scale)
