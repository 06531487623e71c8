"""Scoring parallel-jaw grasps with grasp_jax's scorer: two soft contacts per grasp."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._api import critical_friction, evaluate
from .._friction import FrictionStatus
from ._gripper import JawStatus


class JawScores(NamedTuple):
    """Scores of ``k`` parallel-jaw grasps (:func:`score_grasps`).

    Attributes:
        force_closure: ``(k,) bool``, ``False`` wherever the jaw status is not ``OK``.
        quality: ``(k,) float64`` Q, 0 where the jaw status is not ``OK``.
        converged: ``(k,) bool`` (every LP of the grasp ended optimal or certified).
        critical_mu: ``(k,) float64`` the smallest friction coefficient at which the grasp is
            force-closure (:func:`grasp_jax.critical_friction`), ``inf`` where the jaw status is
            not ``OK``; ``None`` when not asked for.
        critical_status: ``(k,) int8`` :class:`grasp_jax.FrictionStatus` (``ABOVE_CAP`` where the
            jaw status is not ``OK``), or ``None``.
    """

    force_closure: np.ndarray
    quality: np.ndarray
    converged: np.ndarray
    critical_mu: np.ndarray | None
    critical_status: np.ndarray | None


def mask_failed(status, force_closure, quality, critical_mu=None, critical_status=None):
    """The scores with every grasp whose jaw ``status`` is not ``OK`` set to not force-closure,
    Q 0, critical friction ``inf`` (status ``ABOVE_CAP``). Returns the four arrays (or ``None``)."""
    failed = np.asarray(status) != JawStatus.OK
    fc = np.asarray(force_closure, bool) & ~failed
    q = np.where(failed, 0.0, np.asarray(quality, float))
    mu = None if critical_mu is None else np.where(failed, np.inf, np.asarray(critical_mu, float))
    st = None if critical_status is None else np.where(
        failed, np.int8(FrictionStatus.ABOVE_CAP), np.asarray(critical_status)).astype(np.int8)
    return fc, q, mu, st


def score_grasps(points, normals, status, *, mu: float, torsion: float, contact: str = "soft",
                 num_edges: int = 8, critical: bool = True, cap: float | None = None) -> JawScores:
    """Force-closure, Q and critical friction of parallel-jaw contacts, by :func:`grasp_jax.evaluate`
    and :func:`grasp_jax.critical_friction` on the two contacts of each grasp.

    Args:
        points: ``(k, 2, 3)`` contacts (:func:`jaw_contacts` or :func:`antipodal_grasps`).
        normals: ``(k, 2, 3)`` outward unit normals.
        status: ``(k,)`` :class:`JawStatus`; grasps that are not ``OK`` get verdict ``False``, Q 0
            and critical friction ``inf``, whatever their (fill) contacts score.
        mu: friction coefficient.
        torsion: soft contacts' torsional coefficient, a length (:func:`grasp_jax.patch_torsion`).
        contact: ``"soft"`` (default) or ``"dexnet-soft"`` (or ``"hard"``, with ``torsion=None``:
            two hard contacts are never force-closure in 3D).
        num_edges: edges of each linearized friction cone.
        critical: also compute the critical friction.
        cap: largest friction coefficient the critical friction search tries (default
            :func:`grasp_jax.critical_friction`'s).

    Returns:
        :class:`JawScores`.
    """
    points = np.asarray(points, np.float64)
    normals = np.asarray(normals, np.float64)
    status = np.asarray(status)
    if points.ndim != 3 or points.shape[1:] != (2, 3) or normals.shape != points.shape:
        raise ValueError(f"points and normals must have shape (k, 2, 3); got {points.shape}, {normals.shape}")
    if status.shape != points.shape[:1]:
        raise ValueError(f"status must have shape ({len(points)},); got {status.shape}")
    res = evaluate(points, normals, mu=mu, num_edges=num_edges, contact=contact, torsion=torsion)
    crit_mu = crit_status = None
    if critical:
        kwargs = {} if cap is None else {"cap": cap}
        crit_mu, crit_status = critical_friction(points, normals, num_edges=num_edges, contact=contact,
                                                 torsion=torsion, **kwargs)
    fc, q, crit_mu, crit_status = mask_failed(status, res.force_closure, res.quality, crit_mu, crit_status)
    return JawScores(fc, q, np.asarray(res.converged, bool), crit_mu, crit_status)
