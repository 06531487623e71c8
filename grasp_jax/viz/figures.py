"""Figures of grasps and of a multi-start optimization (matplotlib, Agg backend).

Every ``plot_*`` function returns the :class:`matplotlib.figure.Figure` and saves it as a PNG when
given ``path``; given ``ax`` it draws into it. ``points`` and ``normals`` of one grasp are
``(n, d)`` arrays, normals **outward**, ``c_1`` is index 0. Planar friction cones are drawn into
the object (the force directions); 3D cones by default outside it, mirrored through the contact.
"""

from __future__ import annotations

import math

import numpy as np
from matplotlib.patches import PathPatch, Polygon
from matplotlib.path import Path as MplPath
from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

from .._cones import cone_edges
from .._precision import float64_scope
from ._draw import (
    CONE,
    CONTACT,
    FIRST,
    OBJECT,
    as_rings,
    check_grasp,
    decimate,
    mesh_arrays,
    pyplot,
    save,
    signed_area,
)


def _quality_title(quality, extra: str | None = None) -> str | None:
    parts = []
    if quality is not None:
        parts.append(f"Q = {float(quality):.3f}")
    if extra:
        parts.append(extra)
    return ", ".join(parts) if parts else None


def plot_grasp_2d(rings_or_vertices, points, normals, *, mu, quality=None, ax=None, path=None,
                  title=None, cone_length=None):
    """Draw a planar grasp: the polygon (holes included), contacts and friction cones.

    Args:
        rings_or_vertices: the object: a ``(k, 2)`` vertex array, a list of ``(k_r, 2)`` rings (outer
            boundary first, then holes), or an object with a ``rings`` attribute.
        points: ``(n, 2)`` contact points; ``points[0]`` is ``c_1`` and is marked.
        normals: ``(n, 2)`` outward normals.
        mu: friction coefficient; each cone is a filled wedge of half-angle ``atan(mu)`` pointing into
            the object.
        quality: optional Q shown in the title.
        ax: matplotlib axes to draw into (default: a new figure).
        path: save the figure there as a PNG.
        title: extra text for the title.
        cone_length: wedge length (default: 16% of the polygon's larger extent).

    Returns:
        The matplotlib Figure.
    """
    points, normals = check_grasp(points, normals, 2)
    rings = as_rings(rings_or_vertices)
    plt = pyplot()

    if ax is None:
        fig, ax = plt.subplots(figsize=(4.2, 4.2), dpi=110)
    else:
        fig = ax.figure
    # Outer boundary counter-clockwise, holes clockwise: the non-zero fill rule leaves holes empty.
    verts, codes = [], []
    for k, ring in enumerate(rings):
        ccw = signed_area(ring) > 0
        if ccw != (k == 0):
            ring = ring[::-1]
        verts.extend(list(ring) + [ring[0]])
        codes.extend([MplPath.MOVETO] + [MplPath.LINETO] * (len(ring) - 1) + [MplPath.CLOSEPOLY])
    ax.add_patch(PathPatch(MplPath(np.asarray(verts), codes), facecolor=OBJECT, edgecolor="#4d5b6b",
                           lw=1.2, zorder=1))
    allv = np.concatenate(rings + [points])
    lo, hi = allv.min(0), allv.max(0)
    extent = float(np.max(hi - lo))
    length = 0.16 * extent if cone_length is None else float(cone_length)
    alpha = math.atan(float(mu))
    for i, (p, nrm) in enumerate(zip(points, normals)):
        base = math.atan2(-nrm[1], -nrm[0])
        arc = np.linspace(base - alpha, base + alpha, 16)
        wedge = np.concatenate([p[None], p + length * np.stack([np.cos(arc), np.sin(arc)], -1)])
        ax.add_patch(Polygon(wedge, closed=True, facecolor=CONE, alpha=0.55, edgecolor=CONE, lw=0.8,
                             zorder=2))
        ax.plot(*(np.stack([p, p - 0.6 * length * nrm]).T), color=CONE, lw=0.8, ls=":", zorder=2)
        first = i == 0
        ax.plot(p[0], p[1], "o", ms=7 if first else 5.5, color=FIRST if first else CONTACT,
                mec="white", mew=0.8, zorder=4)
        off = p + 0.09 * extent * nrm
        ax.annotate(f"$c_{{{i + 1}}}$", off, ha="center", va="center", zorder=5,
                    fontsize=10 if first else 8.5, color=FIRST if first else CONTACT,
                    fontweight="bold" if first else "normal")
    pad = 0.14 * extent
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    label = _quality_title(quality, title)
    if label:
        ax.set_title(f"{len(points)} fingers, " + label if quality is not None else label, fontsize=10)
    return save(fig, path)


# --------------------------------------------------------------------------------------------------
# 3D grasps


def plot_grasp_3d(mesh_or_vertices_faces, points, normals, *, mu, num_edges=8, quality=None, ax=None,
                  path=None, title=None, cone_length=None, max_faces=10000, view=(22.0, -60.0),
                  cones="outside"):
    """Draw a 3D grasp: the mesh (light and translucent), contacts and friction-cone edge fans.

    Args:
        mesh_or_vertices_faces: a ``trimesh.Trimesh`` (or anything with ``vertices``/``faces``, or
            with a ``mesh`` attribute) or a ``(vertices (V, 3), faces (F, 3))`` pair.
        points: ``(n, 3)`` contact points; ``points[0]`` is ``c_1`` and is marked.
        normals: ``(n, 3)`` outward normals.
        mu, num_edges: the linearized cones (eq. 3), drawn as ``num_edges`` short segments from each
            contact and the polygon joining their ends.
        quality: optional Q shown in the title.
        ax: a 3D axes to draw into (default: a new figure).
        path: save the figure there as a PNG.
        title: extra text for the title.
        cone_length: length of the cone edges (default: 18% of the mesh's largest extent).
        max_faces: the mesh is decimated (:func:`decimate`) to at most this many faces. Agg draws 10k
            faces in about 0.1 s; vertex clustering can merge the two sides of thin walls, so
            decimate only what is much larger.
        view: ``(elevation, azimuth)`` in degrees.
        cones: ``"outside"`` (default) draws each cone on the finger's side, mirrored through the
            contact (the directions a finger can push from), which stays visible on thin or
            concave objects; ``"inside"`` draws the force directions themselves, into the object.

    Returns:
        The matplotlib Figure.
    """
    if cones not in ("outside", "inside"):
        raise ValueError(f'cones must be "outside" or "inside"; got {cones!r}')
    points, normals = check_grasp(points, normals, 3)
    vertices, faces = mesh_arrays(mesh_or_vertices_faces)
    vertices, faces = decimate(vertices, faces, max_faces)
    plt = pyplot()


    if ax is None:
        fig = plt.figure(figsize=(4.6, 4.6), dpi=110)
        ax = fig.add_subplot(projection="3d")
    else:
        fig = ax.figure
    tri = vertices[faces]
    # Flat shading from a fixed light so the shape reads without a depth buffer.
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
    light = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    shade = 0.55 + 0.45 * np.abs(fn @ light)
    base = np.array([0.72, 0.78, 0.86])
    colors = np.concatenate([np.clip(shade[:, None] * base, 0, 1), np.full((len(tri), 1), 0.28)], 1)
    ax.add_collection3d(Poly3DCollection(tri, facecolors=colors, edgecolors="none", linewidths=0))
    lo, hi = vertices.min(0), vertices.max(0)
    extent = float(np.max(hi - lo))
    length = 0.18 * extent if cone_length is None else float(cone_length)
    with float64_scope():
        edges = np.asarray(cone_edges(np.asarray(normals, np.float64), float(mu), int(num_edges)))
    edges = edges / np.linalg.norm(edges, axis=-1, keepdims=True)
    if cones == "outside":
        edges = -edges
    segs = np.stack([np.broadcast_to(points[:, None], edges.shape), points[:, None] + length * edges], 2)
    ax.add_collection3d(Line3DCollection(segs.reshape(-1, 2, 3), colors=CONE, linewidths=0.9, alpha=0.9))
    rim = points[:, None] + length * edges  # the pyramid's rim, closed
    rim = np.concatenate([rim, rim[:, :1]], axis=1)
    for r in rim:
        ax.plot(*r.T, color=CONE, lw=0.7, alpha=0.9)
    ax.scatter(*points[1:].T, s=22, color=CONTACT, depthshade=False, edgecolors="white", linewidths=0.5)
    ax.scatter(*points[:1].T, s=36, color=FIRST, depthshade=False, edgecolors="white", linewidths=0.5)
    for i, (p, nrm) in enumerate(zip(points, normals)):
        q = p + (1.25 * length if cones == "outside" else 0.08 * extent) * nrm
        ax.text(*q, f"$c_{{{i + 1}}}$", color=FIRST if i == 0 else CONTACT, fontsize=8, ha="center")
    centre, half = 0.5 * (lo + hi), 0.5 * extent * 1.02
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(elev=view[0], azim=view[1])
    ax.set_xticklabels([])
    ax.set_yticklabels([])
    ax.set_zticklabels([])
    label = _quality_title(quality, title)
    ax.set_title(f"{len(points)} fingers" + (", " + label if label else ""), fontsize=10)
    return save(fig, path)


def plot_optimization(quality_history, *, sampled_quality=None, grasps=(), geometry=None, mu=None,
                      num_edges=8, ylabel="Q", title=None, path=None):
    """A multi-start optimization at a glance: Q against step beside random sampling, and the best
    grasps it found.

    Args:
        quality_history: ``(S, steps)`` Q of every start at every step (0 while not force-closure;
            :attr:`grasp_jax.OptimizeResult.quality_history`), or any per-step score (``ylabel``).
        sampled_quality: ``(N,)`` Q of random grasps for comparison (0 for those not force-closure),
            drawn beside the curves as a horizontal histogram sharing their axis; its median and its
            best are drawn across the curves as dashed lines.
        grasps: ``[(points (n, d), normals (n, d), quality, label), ...]``: drawn in a row below.
        geometry: the object the grasps are on, as :func:`plot_grasp_2d` (rings or vertices) or
            :func:`plot_grasp_3d` (a mesh) take it; required with ``grasps``.
        mu, num_edges: the friction cones of the drawn grasps.
        ylabel: what ``quality_history`` holds.
        title: the figure's title.
        path: save the figure there.

    Returns:
        The :class:`matplotlib.figure.Figure`.
    """
    plt = pyplot()
    hist = np.asarray(quality_history, dtype=float)
    if hist.ndim != 2 or hist.shape[1] < 1 or hist.shape[0] < 1:
        raise ValueError(f"quality_history must have shape (starts, steps); got {hist.shape}")
    grasps = list(grasps)
    if grasps and geometry is None:
        raise ValueError("geometry is required to draw grasps")
    dim = np.asarray(grasps[0][0]).shape[-1] if grasps else None
    cols = max(len(grasps), 1)
    fig = plt.figure(figsize=(max(9.0, 3.2 * cols), 4.2 + (3.4 if grasps else 0.0)), dpi=100)
    outer = fig.add_gridspec(2 if grasps else 1, 1, height_ratios=[4.2, 3.4] if grasps else None, hspace=0.3)
    top = outer[0].subgridspec(1, 2, width_ratios=[4, 1], wspace=0.05)
    ax = fig.add_subplot(top[0])
    steps = np.arange(1, hist.shape[1] + 1)
    finite = np.where(np.isfinite(hist), hist, np.nan)
    lo, med, hi = np.nanpercentile(finite, [25, 50, 75], axis=0)
    ax.fill_between(steps, lo, hi, color=CONTACT, alpha=0.15, lw=0, label="25-75% of starts")
    ax.plot(steps, med, color=CONTACT, lw=2, label="median over starts")
    ax.plot(steps, np.nanmax(finite, axis=0), color=FIRST, lw=2, label="best over starts")
    ax.set_xlabel("step")
    ax.set_ylabel(ylabel)
    ax.set_xlim(1, max(steps[-1], 2))
    ax.xaxis.get_major_locator().set_params(integer=True)
    ax.grid(alpha=0.3)
    side = fig.add_subplot(top[1], sharey=ax)
    if sampled_quality is not None:
        q = np.asarray(sampled_quality, dtype=float).ravel()
        q = q[np.isfinite(q)]
        if q.size:
            top_value = max(float(np.nanmax(finite)), float(q.max()), 1e-12)
            side.hist(q, bins=np.linspace(0.0, top_value * 1.02, 41), orientation="horizontal",
                      color=CONE, alpha=0.8)
            side.set_xscale("log")
            side.set_xlim(left=0.7)  # bins of one grasp stay visible
            for value, style, what in ((np.median(q), "--", "median"), (q.max(), ":", "best")):
                ax.axhline(value, color=CONE, ls=style, lw=1.5,
                           label=f"{what} of {q.size:,} random grasps")
                side.axhline(value, color=CONE, ls=style, lw=1.5)
            fc = float((q > 0).mean())
            side.set_title(f"random grasps\n({100 * fc:.0f}% force-closure)", fontsize=9)
    side.set_xlabel("grasps")
    side.tick_params(labelleft=False)
    side.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8, framealpha=0.8)
    if grasps:
        row = outer[1].subgridspec(1, cols, wspace=0.1)
        for i, (points, normals, quality, label) in enumerate(grasps):
            if dim == 2:
                gax = fig.add_subplot(row[i])
                plot_grasp_2d(geometry, points, normals, mu=mu, quality=quality, ax=gax, title=label)
            else:
                gax = fig.add_subplot(row[i], projection="3d")
                plot_grasp_3d(geometry, points, normals, mu=mu, num_edges=num_edges, quality=quality, ax=gax,
                              title=label)
    if title:
        fig.suptitle(title, fontsize=11)
    return save(fig, path)
