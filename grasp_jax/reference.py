"""Plain NumPy / SciPy reference implementations, one grasp at a time.

They share no code with the JAX engine: cone edges and wrenches are rebuilt here with NumPy loops,
and the LPs are solved by SciPy's HiGHS. The tests compare the engine with them, and the
benchmarks time them as the baseline. They are slow (milliseconds per grasp).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import linprog


def frame(axis: np.ndarray, tangent: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Tangents ``(x, y)`` completing the unit 3D ``axis`` (Duff et al. 2017, as the engine)."""
    if tangent is not None:
        x = tangent - np.dot(tangent, axis) * axis
        x = x / np.linalg.norm(x)
        return x, np.cross(axis, x)
    ax, ay, az = axis
    sign = 1.0 if az >= 0 else -1.0
    a = -1.0 / (sign + az)
    b = ax * ay * a
    return (
        np.array([1.0 + sign * ax * ax * a, sign * b, -sign * ax]),
        np.array([b, sign + ay * ay * a, -ay]),
    )


def cone_edges(normals: np.ndarray, mu: float, num_edges: int, tangents=None) -> np.ndarray:
    """``(n, m, d)`` edges of the linearized friction cones of one grasp (outward normals)."""
    normals = np.asarray(normals, float)
    out = []
    for i, nrm in enumerate(normals):
        z = -nrm / np.linalg.norm(nrm)
        if len(z) == 2:
            t = np.array([-z[1], z[0]])
            out.append([z - mu * t, z + mu * t])
            continue
        x, y = frame(z, None if tangents is None else np.asarray(tangents[i], float))
        out.append(
            [z + mu * (np.cos(2 * np.pi * j / num_edges) * x + np.sin(2 * np.pi * j / num_edges) * y)
             for j in range(1, num_edges + 1)]
        )
    return np.array(out)


def _cross(a, b):
    return a[0] * b[1] - a[1] * b[0] if len(a) == 2 else np.cross(a, b)


def wrenches(points, normals, mu, num_edges, origin=None, torque_scale=1.0, tangents=None, contact="hard",
             torsion=0.0) -> np.ndarray:
    """``(K, D)`` primitive wrenches ``(v, (c - o) x v / torque_scale)`` of one grasp.

    ``contact="soft"``: each edge twice, its torque ``+/- torsion z`` apart (``z`` the inward
    normal, ``K = 2 n m``); ``"dexnet-soft"``: the hard wrenches and ``(0, +/- torsion n)`` per
    contact (``K = n m + 2 n``), moments divided by ``torque_scale`` as torques are."""
    points = np.asarray(points, float)
    origin = np.zeros(points.shape[1]) if origin is None else np.asarray(origin, float)
    edges = cone_edges(normals, mu, num_edges, tangents)
    rows = []
    for c, nrm, cone in zip(points, np.asarray(normals, float), edges):
        unit = nrm / np.linalg.norm(nrm)
        for v in cone:
            torque = np.atleast_1d(_cross(c - origin, v))
            if contact == "soft":
                for sign in (1.0, -1.0):
                    rows.append(np.concatenate([v, (torque - sign * torsion * unit) / torque_scale]))
            else:
                rows.append(np.concatenate([v, torque / torque_scale]))
    if contact == "dexnet-soft":
        for nrm in np.asarray(normals, float):
            unit = nrm / np.linalg.norm(nrm)
            for sign in (1.0, -1.0):
                rows.append(np.concatenate([np.zeros(len(unit)), sign * torsion * unit / torque_scale]))
    return np.array(rows)


def quality_highs(points, normals, mu, num_edges=8, tangents=None, contact="hard", torsion=0.0) -> tuple[float, bool]:
    """``(Q, equilibrium)`` from HiGHS on ``max delta s.t. A [a; delta] = 0, sum a = 1, a, delta >= 0``
    (the normalized eq. 17-20) over the wrenches of :func:`wrenches` about ``c_1``. ``Q = 0`` and
    ``equilibrium = False`` where infeasible or ``delta* = 0``."""
    points = np.asarray(points, float)
    d = points.shape[1]
    z1 = -np.asarray(normals[0], float) / np.linalg.norm(normals[0])
    A = wrenches(points, normals, mu, num_edges, points[0], 1.0, tangents, contact, torsion).T
    K = A.shape[1]
    A = np.concatenate([A, np.concatenate([z1, np.zeros(A.shape[0] - d)])[:, None]], axis=1)
    A_eq = np.vstack([A, np.concatenate([np.ones(K), [0.0]])])
    b_eq = np.zeros(A_eq.shape[0])
    b_eq[-1] = 1.0
    c = np.zeros(K + 1)
    c[-1] = -1.0
    res = linprog(c, A_eq=A_eq, b_eq=b_eq, bounds=(0, None), method="highs")
    if res.status != 0:
        return 0.0, False
    q = -res.fun
    return (q, True) if q > 0 else (0.0, False)


#: HiGHS options for margins near 0: its default feasibility tolerances (1e-7) and presolve report
#: ``l* = 0`` for margins up to about 2e-8 (Dex-Net's soft columns near the critical friction),
#: where a solution with a residual of 4e-17 has ``l* = 1.1e-8``.
TIGHT = {"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10, "presolve": False}


def min_weight_highs(points, normals, mu, num_edges=8, origin=None, torque_scale=1.0, tangents=None,
                     contact="hard", torsion=0.0, tight: bool = False) -> float:
    """``l*`` of ``max l s.t. W alpha = 0, sum alpha = 1, alpha >= l`` with HiGHS on the wrenches
    of :func:`wrenches`; 0 when they are rank deficient, ``-inf`` when infeasible. ``tight``: with
    :data:`TIGHT` options (slower), for margins that must be resolved near 0."""
    W = wrenches(points, normals, mu, num_edges, origin, torque_scale, tangents, contact, torsion).T
    D, K = W.shape
    if np.linalg.matrix_rank(W, tol=1e-9 * max(1.0, np.abs(W).max())) < D:
        return 0.0
    # variables (alpha, l); alpha - l >= 0
    c = np.zeros(K + 1)
    c[-1] = -1.0
    A_eq = np.vstack([np.hstack([W, np.zeros((D, 1))]), np.concatenate([np.ones(K), [0.0]])])
    b_eq = np.concatenate([np.zeros(D), [1.0]])
    A_ub = np.hstack([-np.eye(K), np.ones((K, 1))])
    for options in ([TIGHT, {**TIGHT, "presolve": True}, None] if tight else [None]):
        # (without presolve, HiGHS stops on a numerical difficulty now and then: try the next)
        res = linprog(c, A_ub=A_ub, b_ub=np.zeros(K), A_eq=A_eq, b_eq=b_eq,
                      bounds=[(None, None)] * (K + 1), method="highs", options=options)
        if res.status in (0, 2):
            break
    if res.status == 2:
        return -np.inf
    return float(-res.fun)


def critical_friction_highs(points, normals, num_edges=8, contact="hard", torsion=0.0, cap=4.0,
                            threshold=1e-10, rtol=1e-9) -> float:
    """The smallest ``mu`` at which ``l* > threshold`` (:func:`min_weight_highs`, tight, torques
    about the centroid over the largest distance from it) by plain bisection of ``[0, cap]`` to
    ``rtol``: ``inf`` when not force-closure at ``cap``, 0 when force-closure at 0; a grasp that
    holds at every ``mu > 0`` but not at 0 ends below ``1e-12``."""
    points, normals = np.asarray(points, float), np.asarray(normals, float)
    center = points.mean(0)
    scale = np.sqrt(((points - center) ** 2).sum(1).max())

    def holds(mu):
        return min_weight_highs(points, normals, mu, num_edges, center, scale, contact=contact, torsion=torsion,
                                tight=True) > threshold

    if not holds(cap):
        return np.inf
    if holds(0.0):
        return 0.0
    lo, hi = 0.0, float(cap)
    while hi - lo > rtol * hi and hi > 1e-12:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if holds(mid) else (mid, hi)
    return hi


def torque_span_highs(points, normals, mu, num_edges=8, tangents=None, contact="hard", torsion=0.0) -> bool:
    """Whether the torques about ``c_1`` of the wrenches (:func:`wrenches`) positively span the
    torque space (zero torques, contact 1's hard edges, take no part)."""
    points = np.asarray(points, float)
    d = points.shape[1]
    taus = wrenches(points, normals, mu, num_edges, points[0], 1.0, tangents, contact, torsion)[:, d:]
    taus = taus[np.abs(taus).max(axis=1) > 0]
    if len(taus) == 0:
        return False
    scale = np.abs(taus).max()
    if scale == 0:
        return False
    taus = taus / scale
    if taus.shape[1] == 1:
        return bool(taus.max() > 1e-9 and taus.min() < -1e-9)
    T = taus.T
    if np.linalg.matrix_rank(T, tol=1e-9) < 3:
        return False
    K = T.shape[1]
    c = np.zeros(K + 1)
    c[-1] = -1.0
    A_eq = np.vstack([np.hstack([T, np.zeros((3, 1))]), np.concatenate([np.ones(K), [0.0]])])
    b_eq = np.concatenate([np.zeros(3), [1.0]])
    A_ub = np.hstack([-np.eye(K), np.ones((K, 1))])
    res = linprog(c, A_ub=A_ub, b_ub=np.zeros(K), A_eq=A_eq, b_eq=b_eq,
                  bounds=[(None, None)] * (K + 1), method="highs")
    return bool(res.status == 0 and -res.fun > 1e-9)


def _column_owner(n: int, m: int, contact: str, d: int) -> np.ndarray:
    """The contact each column of :func:`grasp_jax.reference.wrenches` belongs to."""
    per = 2 if d == 2 else m
    if contact == "soft":
        return np.repeat(np.arange(n), 2 * per)
    owner = np.repeat(np.arange(n), per)
    if contact == "dexnet-soft":
        owner = np.concatenate([owner, np.repeat(np.arange(n), 2)])
    return owner


def balancing_axis(points, normals, *, mu, num_edges=8, contact="hard", torsion=None):
    """The central axis ``Delta_r*`` of one grasp, or ``None`` where the quality LP has no optimum
    with a non-zero force: at the optimum of the quality LP (HiGHS on :func:`wrenches`), the wrench
    of contacts ``2..n`` balances a force of contact 1 inside its cone (Proposition 1 of the
    paper); its central axis passes through ``c_1``.

    Returns:
        ``(point (d,), direction (d,))``: a point of the axis (the one nearest ``c_1``) and its unit
        direction, the direction of the force of contacts ``2..n``.
    """
    normals = np.asarray(normals, float)
    points, normals = np.asarray(points, float), normals / np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-300)
    n, d = points.shape
    torsion = 0.0 if torsion is None else float(torsion)
    contact = contact or "hard"
    try:
        W = wrenches(points, normals, mu, num_edges, points[0], 1.0, None, contact, torsion)
    except Exception:  # noqa: BLE001 - a model the reference does not know: no axis
        return None
    z1 = -normals[0]
    A = np.concatenate([W.T, np.concatenate([z1, np.zeros(W.shape[1] - d)])[:, None]], axis=1)
    K = W.shape[0]
    A_eq = np.vstack([A, np.concatenate([np.ones(K), [0.0]])])
    b_eq = np.zeros(len(A_eq))
    b_eq[-1] = 1.0
    c = np.zeros(K + 1)
    c[-1] = -1.0
    res = linprog(c, A_eq=A_eq, b_eq=b_eq, bounds=(0, None), method="highs")
    if res.status != 0 or -res.fun <= 0:
        return None
    a = res.x[:K]
    owner = _column_owner(n, int(num_edges), contact, d)
    if len(owner) != K:
        return None
    w = (a * (owner > 0)) @ W  # the wrench of contacts 2..n, torque about c_1
    f, tau = w[:d], w[d:]
    f2 = float(f @ f)
    if f2 <= 1e-24 * max(float(tau @ tau), 1e-300):
        return None
    if d == 3:
        offset = np.cross(f, tau) / f2
    else:
        offset = np.array([f[1] * tau[0], -f[0] * tau[0]]) / f2
    return points[0] + offset, f / math.sqrt(f2)
