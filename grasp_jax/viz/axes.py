"""The central axes of a grasp's wrenches (Section III-C of the paper; its Fig. 2-4, 6, 7).

Random non-negative coefficients on the cone edges (eq. 2 / 9) give grasp wrenches (eq. 7), whose
central axes (eq. 10) are drawn through their intersections with the unit circle (2D, the dual
plane ``(theta_1, theta_2)`` of Fig. 2) or the unit sphere (3D, Fig. 4), after the grasp is
normalized into the unit disc / ball (centre at its contacts' centroid, farthest contact at
``fill``). Coverage measures how much of the line space the axes fill; ``reachable_axes_*``
decide it per cell without sampling (a force-closure grasp covers every cell).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Polygon
from scipy.optimize import linprog, nnls

from .._cones import cone_edges
from .._precision import float64_scope
from .._wrench import central_axis, primitive_wrenches
from ._draw import CONTACT, FIRST, check_grasp, pyplot, save


def _normalize(points, center, radius, fill):
    center = points.mean(0) if center is None else np.asarray(center, float)
    if radius is None:
        radius = float(np.max(np.linalg.norm(points - center, axis=-1)))
    radius = max(float(radius), 1e-300)
    return (points - center) * (fill / radius)


def _balancing_weights(prim: np.ndarray, floor: float = 0.5) -> np.ndarray:
    """Positive weights ``alpha (K,)``, ``sum alpha = 1``, making ``prim (D, K) @ alpha`` small.

    For a force-closure grasp, the min-weight LP's solution: ``prim @ alpha = 0`` with every weight
    at least ``l* > 0``. Otherwise the weights with ``alpha >= floor / K`` of least ``|prim @ alpha|_1``.
    Two HiGHS LPs at most (milliseconds).
    """

    d, k = prim.shape
    cost = np.zeros(k + 1)
    cost[-1] = -1.0
    a_eq = np.vstack([np.hstack([prim, np.zeros((d, 1))]), np.r_[np.ones(k), 0.0][None]])
    b_eq = np.r_[np.zeros(d), 1.0]
    a_ub = np.hstack([-np.eye(k), np.ones((k, 1))])
    res = linprog(cost, A_ub=a_ub, b_ub=np.zeros(k), A_eq=a_eq, b_eq=b_eq,
                  bounds=[(0, None)] * k + [(None, 1.0)], method="highs")
    if res.status == 0 and res.x[-1] > 1e-9:
        return np.maximum(res.x[:k], 0.0)
    cost = np.r_[np.zeros(k), np.ones(d)]
    a_ub = np.vstack([np.hstack([prim, -np.eye(d)]), np.hstack([-prim, -np.eye(d)])])
    res = linprog(cost, A_ub=a_ub, b_ub=np.zeros(2 * d), A_eq=np.r_[np.ones(k), np.zeros(d)][None],
                  b_eq=[1.0], bounds=[(floor / k, None)] * k + [(0, None)] * d, method="highs")
    return np.maximum(res.x[:k], 0.0) if res.status == 0 else np.full(k, 1.0 / k)



def _random_axes(*args):
    """Central axes of ``samples`` random grasp wrenches of one normalized grasp, in float64."""
    with float64_scope():
        return _random_axes_f64(*args)


def _random_axes_f64(points, normals, mu, num_edges, samples, seed, concentration, balanced, center, radius,
                     fill):
    """Central axes of ``samples`` random grasp wrenches of one normalized grasp (JAX, batched)."""


    if int(samples) < 1:
        raise ValueError(f"samples must be a positive integer; got {samples!r}")
    if not np.all(np.asarray(concentration, float) > 0) or np.size(concentration) not in (1, 2):
        raise ValueError(f"concentration must be > 0 or a (low, high) pair of them; got {concentration!r}")
    p = jnp.asarray(_normalize(points, center, radius, fill), jnp.float64)
    edges = cone_edges(jnp.asarray(normals, jnp.float64), float(mu), int(num_edges))  # (n, m, d)
    prim = primitive_wrenches(p, edges)  # (n, m, D), torques about the centre
    rng = np.random.default_rng(seed)
    # Gamma(k) weights (a Dirichlet direction), k log-uniform per sample: small k gives a few dominant
    # edges (the boundary of the wrench cone), large k balanced mixtures (its interior).
    shape = (int(samples),) + prim.shape[:2]
    if np.ndim(concentration) == 0:
        k = np.full((int(samples), 1, 1), float(concentration))
    else:
        lo, hi = (float(c) for c in concentration)
        k = np.exp(rng.uniform(np.log(lo), np.log(hi), size=(int(samples), 1, 1)))
    coef = rng.gamma(np.broadcast_to(k, shape))
    balanced = float(balanced)
    if not 0.0 <= balanced <= 1.0:
        raise ValueError(f"balanced must be a fraction in [0, 1] (or a bool); got {balanced!r}")
    if balanced > 0:
        # Centre part of the random wrenches on a balanced combination (zero wrench for a
        # force-closure grasp), so that their directions, hence their axes, spread over the cone.
        weights = _balancing_weights(np.asarray(prim).reshape(-1, prim.shape[-1]).T).reshape(shape[1:])
        count = int(round(balanced * shape[0]))
        coef[:count] *= weights * (coef.shape[1] * coef.shape[2])
    coef = jnp.asarray(coef, jnp.float64)
    wrench = jnp.einsum("sij,ijk->sk", coef, prim)  # eq. (7)
    axis = jax.vmap(central_axis)(wrench)  # eq. (10)
    return (np.asarray(axis.point), np.asarray(axis.direction), np.asarray(axis.pure_torque))


def central_axes_2d(points, normals, *, mu, samples=20000, seed=0, concentration=(0.1, 10.0), balanced=0.5,
                    center=None, radius=None, fill=0.9):
    """Dual-plane coordinates ``(theta_1, theta_2)`` of random central axes of a planar grasp (Fig. 2-3).

    Random non-negative coefficients ``a_i1, a_i2`` on the cone edges (eq. 9; Gamma(k) distributed,
    ``k`` = ``concentration`` or log-uniform in the ``(low, high)`` range it gives, per sample) give
    grasp wrenches (eq. 7) whose central axes (eq. 10) are lines in the plane. After normalizing the
    grasp (centre ``center``, default the centroid of the contacts; the point at distance ``radius``,
    default the farthest contact, is put at distance ``fill``), each line meets the unit circle at
    ``A`` and ``B``; their polar angles in ``[0, 2 pi)``, sorted so that ``theta_2 >= theta_1``, form
    one point of the dual plane's upper triangle. Lines that miss the circle and pure torques
    (``F = 0``) are dropped.

    Args:
        points: ``(n, 2)`` contacts; normals: ``(n, 2)`` outward normals; mu: friction coefficient.
        samples: number of random grasp wrenches.
        seed: seed of the NumPy generator.
        concentration: shape ``k`` of the Gamma weights, or a ``(low, high)`` range for a log-uniform
            ``k`` per sample (the default mixes sparse and balanced combinations, which covers the
            reachable axes better than any single ``k``).
        balanced: fraction of the samples whose coefficients are multiplied by fixed positive weights
            that balance the grasp (the min-weight LP's solution for a force-closure grasp, else a
            least-imbalance one): their wrenches are centred on zero, so their axes spread over every
            reachable line. The other samples have i.i.d. coefficients, as in the paper; their axes
            crowd around the axis of the mean wrench but reach lines far from the centre better.
            ``0`` (or ``False``) is the paper's scheme. Every sample is a valid grasp wrench.
        center, radius, fill: the normalization described above.

    Returns:
        ``(theta1 (k,), theta2 (k,))`` float arrays, ``k <= samples``, ``0 <= theta1 <= theta2 < 2 pi``.
    """
    points, normals = check_grasp(points, normals, 2)
    point, direction, pure = _random_axes(points, normals, mu, 2, samples, seed, concentration, balanced,
                                          center, radius, fill)
    r2 = np.sum(point * point, axis=-1)
    keep = ~pure & (r2 < 1.0)
    point, direction = point[keep], direction[keep]
    half = np.sqrt(1.0 - r2[keep])[:, None]  # the foot point I is orthogonal to the direction
    a, b = point - half * direction, point + half * direction
    ta = np.mod(np.arctan2(a[:, 1], a[:, 0]), 2 * np.pi)
    tb = np.mod(np.arctan2(b[:, 1], b[:, 0]), 2 * np.pi)
    return np.minimum(ta, tb), np.maximum(ta, tb)


def central_axes_3d(points, normals, *, mu, num_edges=8, samples=20000, seed=0, concentration=(0.1, 10.0),
                    balanced=0.5, center=None, radius=None, fill=0.9):
    """Intersections of random central axes of a 3D grasp with the unit sphere (Fig. 4).

    As :func:`central_axes_2d` with the m-sided pyramids of eq. (2)-(3): each central axis (eq. 10) of
    a random grasp wrench, directed along its force ``F_g``, enters the unit sphere at ``entry`` and
    leaves it at ``exit`` (``exit - entry`` is parallel to ``F_g``). Axes that miss the sphere and pure
    torques are dropped.

    Args:
        points: ``(n, 3)`` contacts; normals: ``(n, 3)`` outward normals; mu: friction coefficient.
        num_edges: edges per linearized cone.
        samples, seed, concentration, balanced, center, radius, fill: as :func:`central_axes_2d`.

    Returns:
        ``(entry (k, 3), exit (k, 3))`` unit vectors, ``k <= samples``.
    """
    points, normals = check_grasp(points, normals, 3)
    point, direction, pure = _random_axes(points, normals, mu, num_edges, samples, seed, concentration,
                                          balanced, center, radius, fill)
    r2 = np.sum(point * point, axis=-1)
    keep = ~pure & (r2 < 1.0)
    point, direction = point[keep], direction[keep]
    half = np.sqrt(1.0 - r2[keep])[:, None]
    return point - half * direction, point + half * direction


def dual_plane_coverage(theta1, theta2, bins: int = 36) -> float:
    """Fraction of the dual plane's upper triangle covered by central axes.

    The square ``[0, 2 pi)^2`` is cut into ``bins x bins`` cells; the result is the fraction of cells
    on or above the diagonal (``j >= i``) holding at least one ``(theta1, theta2)`` point.

    Args:
        theta1, theta2: ``(k,)`` from :func:`central_axes_2d`.
        bins: cells per side.

    Returns:
        float in ``[0, 1]``.
    """
    upper = np.triu(np.ones((bins, bins), bool))
    return float(dual_plane_hits(theta1, theta2, bins)[upper].mean())


def dual_plane_hits(theta1, theta2, bins: int = 36) -> np.ndarray:
    """``(bins, bins)`` bool: the cells of ``[0, 2 pi)^2`` holding at least one ``(theta1, theta2)``
    point (``[i, j]``: ``theta1`` in cell ``i``, ``theta2`` in cell ``j``)."""
    t1, t2 = np.asarray(theta1, float), np.asarray(theta2, float)
    i = np.clip((t1 / (2 * np.pi) * bins).astype(int), 0, bins - 1)
    j = np.clip((t2 / (2 * np.pi) * bins).astype(int), 0, bins - 1)
    hit = np.zeros((bins, bins), bool)
    hit[i, j] = True
    return hit


def _sphere_cells(v, bands: int):
    """Equal-area cell index of unit vectors: ``bands`` bands in z, ``2 bands`` sectors in azimuth."""
    zb = np.clip(((v[:, 2] + 1.0) / 2.0 * bands).astype(int), 0, bands - 1)
    az = np.mod(np.arctan2(v[:, 1], v[:, 0]), 2 * np.pi)
    ab = np.clip((az / (2 * np.pi) * 2 * bands).astype(int), 0, 2 * bands - 1)
    return zb * 2 * bands + ab


def sphere_coverage(entry, exit, bands: int = 3) -> float:
    """Fraction of (entry cell, exit cell) pairs reached by directed central axes through the sphere.

    The sphere is cut into ``2 bands^2`` equal-area cells (``bands`` bands of equal height in z times
    ``2 bands`` sectors of azimuth); a directed axis falls into the pair of cells of its entry and exit
    points. A force-closure grasp generates every directed line, so it reaches every pair. Pairs of a
    cell with itself (axes grazing the sphere) are left out.

    Args:
        entry, exit: ``(k, 3)`` from :func:`central_axes_3d`.
        bands: resolution (``(2 bands^2)^2`` pairs).

    Returns:
        float in ``[0, 1]``.
    """
    hit = sphere_pair_hits(entry, exit, bands)
    return float(hit[~np.eye(len(hit), dtype=bool)].mean())


def sphere_pair_hits(entry, exit, bands: int = 3) -> np.ndarray:
    """``(C, C)`` bool, ``C = 2 bands^2``: the (entry cell, exit cell) pairs of :func:`sphere_coverage`
    holding at least one directed axis (``[a, b]``: entry in cell ``a``, exit in cell ``b``)."""
    a = _sphere_cells(np.asarray(entry, float), bands)
    b = _sphere_cells(np.asarray(exit, float), bands)
    cells = 2 * bands * bands
    hit = np.zeros((cells, cells), bool)
    hit[a, b] = True
    return hit


def _primitive_matrix(points, normals, mu, num_edges, center, radius, fill):
    """``(D, K)`` primitive wrenches of the normalized grasp, torques about its centre (float64)."""


    with float64_scope():
        p = jnp.asarray(_normalize(points, center, radius, fill), jnp.float64)
        prim = primitive_wrenches(p, cone_edges(jnp.asarray(normals, jnp.float64), float(mu), int(num_edges)))
        return np.asarray(prim, float).reshape(-1, prim.shape[-1]).T


def _in_cone(prim, target, extra=None, tol=1e-9) -> bool:
    """Whether ``target (D,)`` is a non-negative combination of the columns of ``prim (D, K)`` (plus
    any multiple of ``extra (D,)`` when given): the NNLS residual is ~0."""

    a = prim if extra is None else np.column_stack([prim, extra, -extra])
    _, res = nnls(a, target, maxiter=50 * a.shape[1])
    return bool(res <= tol * max(1.0, float(np.linalg.norm(target))))


def _line_wrench_2d(t1, t2):
    """The unit-force wrench ``(u, A x u)`` of the line through the circle points at ``t1``, ``t2``."""
    a = np.array([np.cos(t1), np.sin(t1)])
    u = np.array([np.cos(t2), np.sin(t2)]) - a
    if np.linalg.norm(u) < 1e-9:  # the tangent at A
        u = np.array([-np.sin(t1), np.cos(t1)])
    u /= np.linalg.norm(u)
    return np.array([u[0], u[1], a[0] * u[1] - a[1] * u[0]])


def reachable_axes_2d(points, normals, *, mu, bins=36, subdivisions=3, center=None, radius=None, fill=0.9):
    """Which cells of the dual plane hold a central axis the grasp can generate (decided, not sampled).

    The line through the unit-circle points ``A``, ``B`` at angles ``theta_1 <= theta_2`` is a central
    axis of some grasp wrench iff the wrench ``(u, A x u)`` (``u`` along ``AB``) or its opposite is a
    non-negative combination of the primitive wrenches (an NNLS residual of 0). A cell counts as
    reachable when one of its ``subdivisions x subdivisions`` regularly spaced lines is. A grasp is
    force-closure iff every line is reachable (Section III-C), so the whole triangle is then set.

    Args:
        points, normals, mu, center, radius, fill: as :func:`central_axes_2d`.
        bins: cells per side of ``[0, 2 pi)^2``, as :func:`dual_plane_coverage`.
        subdivisions: lines tested per cell side (each NNLS about 20 us; the loop stops at the first
            reachable line of a cell).

    Returns:
        ``(bins, bins)`` bool, set on reachable cells of the upper triangle (``j >= i``), unset below.
    """
    points, normals = check_grasp(points, normals, 2)
    prim = _primitive_matrix(points, normals, mu, 2, center, radius, fill)
    width = 2 * np.pi / bins
    offsets = (np.arange(int(subdivisions)) + 0.5) / int(subdivisions) * width
    out = np.zeros((bins, bins), bool)
    for i, j in zip(*np.triu_indices(bins)):
        for d1 in offsets:
            for d2 in offsets:
                t1, t2 = sorted((i * width + d1, j * width + d2))
                w = _line_wrench_2d(t1, t2)
                if _in_cone(prim, w) or _in_cone(prim, -w):
                    out[i, j] = True
                    break
            if out[i, j]:
                break
    return out


def _sphere_point(z, az):
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    return np.stack([r * np.cos(az), r * np.sin(az), z], -1)


def _cell_points(bands, sub):
    """``(C, sub^2, 3)`` regularly spaced points inside each cell of :func:`_sphere_cells`."""
    dz, da = 2.0 / bands, np.pi / bands
    frac = (np.arange(sub) + 0.5) / sub
    zb, ab = np.meshgrid(np.arange(bands), np.arange(2 * bands), indexing="ij")
    fz, fa = np.meshgrid(frac, frac, indexing="ij")
    z = -1.0 + (zb.reshape(-1, 1) + fz.reshape(1, -1)) * dz
    az = (ab.reshape(-1, 1) + fa.reshape(1, -1)) * da
    return _sphere_point(z, az)


def reachable_axes_3d(points, normals, *, mu, num_edges=8, bands=3, subdivisions=2, center=None, radius=None,
                      fill=0.9):
    """Which (entry cell, exit cell) pairs of the unit sphere a grasp's central axes can join (decided).

    The directed line from ``A`` to ``B`` on the sphere (direction ``u``) is a central axis of a grasp
    wrench iff ``(u, A x u + h u)`` is a non-negative combination of the primitive wrenches for some
    pitch ``h`` (an NNLS residual of 0). A pair of cells (those of :func:`sphere_coverage`) counts as
    reachable when one of the lines between ``subdivisions^2`` regularly spaced points of the entry cell
    and as many of the exit cell is.

    Args:
        points, normals, mu, num_edges, center, radius, fill: as :func:`central_axes_3d`.
        bands: resolution (``2 bands^2`` cells).
        subdivisions: points per cell side in z and azimuth.

    Returns:
        ``(C, C)`` bool, ``C = 2 bands^2``; the diagonal (entry and exit in one cell) is unset.
    """
    points, normals = check_grasp(points, normals, 3)
    prim = _primitive_matrix(points, normals, mu, num_edges, center, radius, fill)
    cells = _cell_points(int(bands), int(subdivisions))
    c = len(cells)
    out = np.zeros((c, c), bool)
    for ia, ib in zip(*np.nonzero(~np.eye(c, dtype=bool))):
        for a in cells[ia]:
            for b in cells[ib]:
                u = (b - a) / np.linalg.norm(b - a)
                if _in_cone(prim, np.concatenate([u, np.cross(a, u)]), extra=np.concatenate([0 * u, u])):
                    out[ia, ib] = True
                    break
            if out[ia, ib]:
                break
    return out


def plot_central_axes_2d(points, normals, *, mu, samples=20000, seed=0, ax=None, path=None, title=None,
                         bins=36, reachable=True, **kwargs):
    """Scatter the central axes of a planar grasp in the dual plane's upper triangle (Fig. 3).

    Each dot is one random central axis (:func:`central_axes_2d`). With ``reachable``, cells where no
    line was shown reachable (neither a sampled axis nor a test line of :func:`reachable_axes_2d`) are
    grey: there are none for a force-closure grasp.

    Args:
        points, normals, mu, samples, seed: as :func:`central_axes_2d` (``kwargs`` are passed on).
        ax: axes to draw into (default: a new figure).
        path: save the figure there as a PNG.
        title: title text; the covered fraction (:func:`dual_plane_coverage` with ``bins``) is added.
        bins: resolution of the coverage measure and of the reachable map.
        reachable: compute and draw the exact reachable region (about 1 ms per 1000 cells).

    Returns:
        The matplotlib Figure.
    """
    t1, t2 = central_axes_2d(points, normals, mu=mu, samples=samples, seed=seed, **kwargs)
    plt = pyplot()
    if ax is None:
        fig, ax = plt.subplots(figsize=(4.0, 4.0), dpi=110)
    else:
        fig = ax.figure
    two_pi = 2 * np.pi
    ax.fill([0, 0, two_pi], [0, two_pi, two_pi], color="#eef1f5", zorder=0)
    label = f"sampled {100 * dual_plane_coverage(t1, t2, bins):.0f}%"
    if reachable:
        keep = {k: kwargs[k] for k in ("center", "radius", "fill") if k in kwargs}
        ok = reachable_axes_2d(points, normals, mu=mu, bins=bins, **keep)
        ok |= dual_plane_hits(t1, t2, bins)  # a sampled axis proves its cell reachable too
        upper = np.triu(np.ones((bins, bins), bool))
        blocked = np.where(upper & ~ok, 1.0, np.nan)  # [i, j] = (theta1 cell, theta2 cell)
        edges = np.linspace(0, two_pi, bins + 1)
        mesh = ax.pcolormesh(edges, edges, blocked.T, cmap="Greys", vmin=0, vmax=3, zorder=0.5,
                             shading="flat", rasterized=True)

        triangle = Polygon([[0, 0], [0, two_pi], [two_pi, two_pi]], closed=True, transform=ax.transData)
        mesh.set_clip_path(triangle)  # diagonal cells are half inside the triangle
        label = f"reachable {100 * ok[upper].mean():.0f}%, " + label
    ax.scatter(t1, t2, s=0.6, color=CONTACT, alpha=0.35, linewidths=0, rasterized=True, zorder=1)
    ax.plot([0, two_pi], [0, two_pi], color="k", lw=0.8)
    # the legend goes into the empty lower-right triangle (theta1 > theta2 is never drawn)

    handles = [Line2D([], [], ls="", marker="o", ms=3, color=CONTACT, label="sampled central axis")]
    if reachable:
        handles += [Patch(facecolor="#eef1f5", edgecolor="#b0b0b0", lw=0.5, label="reachable cell"),
                    Patch(facecolor=plt.get_cmap("Greys")(1 / 3), edgecolor="#b0b0b0", lw=0.5,
                          label="no reachable line")]
    ax.legend(handles=handles, loc="lower right", fontsize=7, frameon=False, handlelength=1.2,
              borderaxespad=0.3)
    ax.set_xlim(0, two_pi)
    ax.set_ylim(0, two_pi)
    ax.set_aspect("equal")
    ticks = [0, np.pi / 2, np.pi, 3 * np.pi / 2, two_pi]
    names = ["0", r"$\pi/2$", r"$\pi$", r"$3\pi/2$", r"$2\pi$"]
    ax.set_xticks(ticks, names)
    ax.set_yticks(ticks, names)
    ax.set_xlabel(r"$\theta_1$")
    ax.set_ylabel(r"$\theta_2$")
    ax.set_title(f"{title}\n{label}" if title else label, fontsize=9)
    return save(fig, path)


def plot_central_axes_3d(points, normals, *, mu, num_edges=8, samples=20000, seed=0, axes=None,
                         path=None, title=None, bands=3, reachable=True, **kwargs):
    """Map the central axes of a 3D grasp by where they enter and leave the unit sphere (Fig. 4).

    Three panels: the entry points and the exit points of the directed axes (direction of the grasp
    force) on equal-area maps (azimuth vs ``z = sin(elevation)``), and the ``C x C`` matrix of
    (entry cell, exit cell) pairs (cells of :func:`sphere_coverage`): dark where a sampled axis falls,
    light where a test line of :func:`reachable_axes_3d` is reachable but no axis was sampled (with
    ``reachable``), white where neither. A force-closure grasp reaches every pair.

    Args:
        points, normals, mu, num_edges, samples, seed: as :func:`central_axes_3d` (``kwargs`` too).
        axes: three axes to draw into (default: a new 1 x 3 figure).
        path: save the figure there as a PNG.
        title: title text of the figure.
        bands: resolution of the cells (``2 bands^2`` of them).
        reachable: compute the exact reachable pairs (about 20 us per pair).

    Returns:
        The matplotlib Figure.
    """
    entry, exit_ = central_axes_3d(points, normals, mu=mu, num_edges=num_edges, samples=samples,
                                   seed=seed, **kwargs)
    plt = pyplot()
    if axes is None:
        fig, axes = plt.subplots(1, 3, figsize=(10.5, 2.9), dpi=110,
                                 gridspec_kw={"width_ratios": [1.25, 1.25, 0.8]})
        own = True
    else:
        fig, own = axes[0].figure, False
    for ax, v, name, colour in ((axes[0], entry, "entry points", CONTACT),
                                (axes[1], exit_, "exit points", FIRST)):
        az = np.degrees(np.arctan2(v[:, 1], v[:, 0]))
        ax.set_facecolor("#eef1f5")
        ax.scatter(az, v[:, 2], s=0.6, color=colour, alpha=0.35, linewidths=0, rasterized=True)
        ax.set_xlim(-180, 180)
        ax.set_ylim(-1, 1)
        ax.set_xticks([-180, -90, 0, 90, 180])
        ax.set_xlabel("azimuth (deg)", fontsize=8)
        ax.set_ylabel(r"$z = \sin(\mathrm{elevation})$", fontsize=8)
        ax.set_title(name, fontsize=9)
    c = 2 * bands * bands
    hit = np.zeros((c, c))
    hit[_sphere_cells(entry, bands), _sphere_cells(exit_, bands)] = 2.0
    label = f"sampled {100 * sphere_coverage(entry, exit_, bands):.0f}%"
    if reachable:
        keep = {k: kwargs[k] for k in ("center", "radius", "fill") if k in kwargs}
        ok = reachable_axes_3d(points, normals, mu=mu, num_edges=num_edges, bands=bands, **keep)
        ok |= hit > 0  # a sampled axis proves its pair reachable too
        off = ~np.eye(c, dtype=bool)
        hit = np.maximum(hit, np.where(ok, 1.0, 0.0))
        label = f"reachable {100 * ok[off].mean():.0f}%, " + label
    hit[np.eye(c, dtype=bool)] = np.nan
    axes[2].imshow(hit, cmap="Blues", vmin=0, vmax=2.4, origin="lower", interpolation="nearest")
    axes[2].set_xlabel("exit cell", fontsize=8)
    axes[2].set_ylabel("entry cell", fontsize=8)
    axes[2].set_xticks([])
    axes[2].set_yticks([])
    axes[2].set_title("entry x exit cell pairs\n(dark: sampled, light: reachable,\nwhite: unreachable)",
                      fontsize=8)
    text = f"{title}: {label}" if title else label
    if own:
        fig.suptitle(text, fontsize=10)
        fig.tight_layout()
    else:
        axes[0].set_title(f"{text}\nentry points", fontsize=9)
    return save(fig, path)
