"""The paper's baseline: Ferrari-Canny epsilon and the hull volume of the primitive wrenches,
through qhull (``scipy.spatial.ConvexHull``), one grasp at a time on the CPU."""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from . import reference
from ._api import check_contact
from ._constants import DEFAULT_NUM_EDGES
from ._validate import check_grasps, check_num_edges, check_scalar, is_traced


def epsilon_one(wrenches: np.ndarray) -> tuple[float, float]:
    """``(epsilon, volume)`` of one set of ``(K, D)`` wrenches.

    ``epsilon`` is the radius of the largest origin-centred ball inside the convex hull (from the
    facet equations ``n.x + b <= 0``: ``min(-b)``), 0 unless the origin is strictly inside.
    ``volume`` is the hull's volume (0 when the wrenches do not span the space).
    """
    try:
        hull = ConvexHull(wrenches)
    except (QhullError, ValueError):
        return 0.0, 0.0
    offsets = -hull.equations[:, -1]
    eps = float(offsets.min())
    return (eps if eps > 0 else 0.0), float(hull.volume)


def ferrari_canny(
    points,
    normals,
    *,
    mu,
    num_edges: int = DEFAULT_NUM_EDGES,
    origin=None,
    torque_scale: float = 1.0,
    tangents=None,
    progress: bool = False,
    contact: str = "hard",
    torsion=None,
):
    """Ferrari-Canny epsilon (L2) and hull volume of each grasp, with qhull.

    Args:
        points, normals: ``(..., n, d)`` as :func:`grasp_jax.evaluate`.
        mu, num_edges, tangents: as :func:`grasp_jax.evaluate`.
        origin: ``(d,)`` point torques are taken about (default: the frame origin). Epsilon depends
            on it (GraspIt takes the centre of mass).
        torque_scale: torques are divided by this length (GraspIt: the largest distance from the
            centre of mass to the object's surface).
        progress: show a progress bar.
        contact, torsion: the contact model, as :func:`grasp_jax.evaluate` (torsion moments are
            divided by ``torque_scale`` like the torques).

    Returns:
        ``(epsilon, volume)``: two NumPy arrays of the leading batch shape.

    Raises:
        TypeError: an argument is a JAX tracer (inside ``jit``, ``vmap`` or ``grad``): qhull runs
            on concrete NumPy arrays. Call it outside the transformation, or use
            :func:`grasp_jax.min_weight` or :func:`grasp_jax.quality`, which compose.
    """
    if is_traced(points, normals, tangents, mu, origin, torque_scale, torsion):
        raise TypeError(
            "grasp_jax.ferrari_canny computes the convex hull with qhull (SciPy) on concrete NumPy "
            "arrays and cannot be traced by jax.jit, jax.vmap or jax.grad. Call it outside the "
            "transformation, or use grasp_jax.min_weight (the force-closure margin l*) or "
            "grasp_jax.quality (Q), which compose with jit, vmap and grad."
        )
    points, normals, tangents, batch = check_grasps(points, normals, tangents)
    mu = check_scalar("mu", mu)
    num_edges = check_num_edges(num_edges)
    torque_scale = check_scalar("torque_scale", torque_scale)
    points, normals = np.asarray(points, float), np.asarray(normals, float)
    d = points.shape[-1]
    contact, torsion = check_contact(contact, torsion, d)
    if origin is not None:
        origin = np.asarray(origin, float)
        if origin.shape != (d,):
            raise ValueError(f"origin must have shape ({d},); got {origin.shape}")
    n = points.shape[-2]
    flat_p = points.reshape(-1, n, d)
    flat_n = normals.reshape(-1, n, d)
    flat_t = None if tangents is None else np.asarray(tangents, float).reshape(-1, n, d)
    eps = np.zeros(len(flat_p))
    vol = np.zeros(len(flat_p))
    indices = range(len(flat_p))
    if progress:
        from tqdm.auto import tqdm

        indices = tqdm(indices, unit="grasp", desc="qhull epsilon")
    for k in indices:
        w = reference.wrenches(flat_p[k], flat_n[k], mu, num_edges, origin, torque_scale,
                               None if flat_t is None else flat_t[k], contact, torsion)
        eps[k], vol[k] = epsilon_one(w)
    return eps.reshape(batch), vol.reshape(batch)
