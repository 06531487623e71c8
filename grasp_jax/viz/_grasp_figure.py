"""The plotly figure of grasps on an object: mesh or polygon, contacts, cones, central axes, jaws,
hover text, the table of grasps and the Q histogram (see :mod:`grasp_jax.viz.pages`)."""

from __future__ import annotations

import html as _html
from typing import Mapping

import numpy as np
import plotly.graph_objects as go
import trimesh
from plotly.subplots import make_subplots

from .. import reference
from .._optimize import EndReason
from ..grippers import JawStatus, ParallelJaw, gripper_boxes
from ._draw import AXIS, CONE, CONTACT, FIRST, JAW, OBJECT_MESH, PATH, as_rings, decimate, mesh_arrays, unit
from ._shown import _SERIES, ShownGrasps

#: Faces of a displayed mesh; larger meshes are decimated (quadric decimation where
#: ``fast_simplification`` is installed, else :func:`grasp_jax.viz.decimate`'s vertex clustering).
MAX_FACES = 20_000
#: Values of an array column shown in a hover label (the rest elided).
_MAX_HOVER_VALUES = 12


def display_mesh(vertices, faces, max_faces: int = MAX_FACES):
    """``(vertices, faces, note)``: the mesh, decimated to at most ``max_faces`` faces for display
    (``note`` says so; ``None`` when unchanged)."""
    vertices = np.asarray(vertices, float)
    faces = np.asarray(faces, np.int64)
    if len(faces) <= max_faces:
        return vertices, faces, None
    how = "quadric decimation"
    try:
        import fast_simplification

        v, f = fast_simplification.simplify(vertices.astype(np.float32), faces.astype(np.int32),
                                            target_count=int(max_faces))
        v, f = np.asarray(v, float), np.asarray(f, np.int64)
        if not len(f) or len(f) > max_faces:
            raise ValueError("decimation missed its target")
    except Exception:  # noqa: BLE001 - not installed, or it failed on this mesh: cluster vertices

        how = "vertex clustering"
        v, f = decimate(vertices, faces, max_faces)
    note = f"mesh decimated for display ({how}): {len(f):,} of {len(faces):,} faces"
    return v, f, note


# --------------------------------------------------------------------------------------------------
# Hover text


def _format_value(name: str, value) -> str:
    a = np.asarray(value)
    if a.ndim == 0:
        v = a.item()
        if isinstance(v, (bool, np.bool_)):
            return "yes" if v else "no"
        if name == "reason":
            try:

                return EndReason(int(v)).message
            except Exception:  # noqa: BLE001
                return str(v)
        if name == "jaw_status":
            try:

                return JawStatus(int(v)).name
            except ValueError:
                return str(v)
        if isinstance(v, float):
            return f"{v:.6g}"
        return _html.escape(str(v))
    flat = a.reshape(-1)
    if np.issubdtype(a.dtype, np.floating):
        text = [f"{x:.4g}" for x in flat[:_MAX_HOVER_VALUES]]
    else:
        text = [_html.escape(str(x)) for x in flat[:_MAX_HOVER_VALUES]]
    more = ", ..." if flat.size > _MAX_HOVER_VALUES else ""
    shape = "x".join(str(s) for s in a.shape)
    return f"({shape}) [{', '.join(text)}{more}]"


def _verdict(columns: Mapping, r: int) -> str:
    if "force_closure" in columns:
        return "force-closure" if bool(columns["force_closure"][r]) else "not force-closure"
    return "not scored"


def _grasp_lines(shown: ShownGrasps, r: int) -> list[str]:
    cols = shown.columns
    lines = [f"<b>grasp #{int(shown.index[r])}</b> (rank {r + 1} of {len(shown)})", _verdict(cols, r)]
    if "quality" in cols:
        lines.append(f"Q = {float(cols['quality'][r]):.6g}")
    for name, values in cols.items():
        if name in ("force_closure", "quality") or name in _SERIES:
            if name in _SERIES:
                series = np.asarray(values[r], float)
                if series.size:
                    lines.append(f"{name}: {series.size} steps, last {series[-1]:.4g}, best {np.nanmax(series):.4g}")
            continue
        if np.asarray(values).ndim >= 3 and name != "initial_points":
            continue  # per-step contact paths: drawn, not listed
        lines.append(f"{_html.escape(name)} = {_format_value(name, values[r])}")
    return lines


# --------------------------------------------------------------------------------------------------
# Figure


def _paths(shown: ShownGrasps):
    """``(k, S, n, d)`` contact paths (start to end), or ``None``."""
    k, n, d = shown.points.shape
    for name, values in shown.columns.items():
        a = np.asarray(values)
        if a.ndim == 4 and a.shape[0] == k and a.shape[2:] == (n, d) and a.shape[1] > 1:
            return np.asarray(a, float), name
    if "initial_points" in shown.columns:
        start = np.asarray(shown.columns["initial_points"], float)
        if start.shape == shown.points.shape:
            return np.stack([start, shown.points], axis=1), "initial_points"
    return None


def _gaps(segments):
    """Segments ``(S, L, d)`` as one polyline with NaN gaps: ``(S * (L + 1), d)``."""
    segments = np.asarray(segments, float)
    pad = np.full(segments.shape[:1] + (1,) + segments.shape[2:], np.nan)
    return np.concatenate([segments, pad], axis=1).reshape(-1, segments.shape[-1])


def _xyz(a, d):
    a = np.asarray(a, np.float32 if d == 3 else float)
    out = dict(x=a[:, 0], y=a[:, 1])
    if d == 3:
        out["z"] = a[:, 2]
    return out


def _jaw_meshes(shown: ShownGrasps, gripper):
    """``(k, V, 3)`` vertices and ``(T, 3)`` faces of each grasp's gripper body (finger boxes and
    palm, :func:`grasp_jax.grippers.gripper_boxes`), or ``None`` where the columns hold no jaw
    poses (``center``, ``axis``, ``approach``, ``width``)."""
    cols = shown.columns
    if shown.points.shape[-1] != 3 or not all(c in cols for c in ("center", "axis", "approach", "width")):
        return None


    widths = np.asarray(cols["width"], float)
    if isinstance(gripper, dict):
        gripper = ParallelJaw.from_dict(gripper)
    if gripper is None:
        gripper = ParallelJaw.scaled(float(widths.max()))
    if not gripper.has_body:  # no collision body: draw the proportional one
        gripper = ParallelJaw.scaled(gripper.max_width, gripper.min_width)
    axes, approaches = unit(cols["axis"]), unit(cols["approach"])
    approaches = unit(approaches - np.sum(approaches * axes, -1, keepdims=True) * axes)
    extents, transforms = gripper_boxes(gripper, np.asarray(cols["center"], float), axes, approaches, widths)
    unit_box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    corners, faces = np.asarray(unit_box.vertices, float), np.asarray(unit_box.faces, np.int64)
    local = corners[None] * extents[:, None]  # (B, 8, 3)
    world = np.einsum("kbij,bvj->kbvi", transforms[..., :3, :3], local) + transforms[:, :, None, :3, 3]
    boxes = len(extents)
    tri = np.concatenate([faces + 8 * b for b in range(boxes)])
    return world.reshape(len(widths), 8 * boxes, 3), tri


class _Canvas:
    """The figure being drawn and, per trace, the rank of the grasp it belongs to (-1: none), which
    the menu's visibility lists follow."""

    def __init__(self, fig):
        self.fig = fig
        self.owner: list[int] = []

    def add(self, trace, r=-1, row=1, col=1):
        self.fig.add_trace(trace, row=row, col=col)
        self.owner.append(r)


def _line(d: int):
    """The line trace type of dimension ``d``."""
    return go.Scatter3d if d == 3 else go.Scatter


def grasp_figure(geometry, shown: ShownGrasps, *, mu: float, num_edges: int = 8, contact: str = "hard",
                 torsion: float | None = None, title: str | None = None, max_faces: int = MAX_FACES,
                 central_axis: bool = True, gripper=None):
    """A plotly figure of the grasps of ``shown`` on ``geometry`` (see the module docstring).

    Args:
        geometry: 3D: an object of :mod:`grasp_jax.objects` with a mesh, a ``trimesh.Trimesh``, or a
            ``(vertices (V, 3), faces (F, 3))`` pair; 2D: a polygon (``rings``), a ``(k, 2)`` vertex
            array or a list of rings.
        shown: the grasps (:func:`select_grasps`, or :class:`ShownGrasps` built from arrays).
        mu, num_edges: the friction pyramids drawn (and of the central axis's LP).
        contact, torsion: the contact model of the central axis's LP.
        title: the page's title.
        max_faces: meshes with more faces are decimated for display.
        central_axis: draw each grasp's balancing central axis.
        gripper: the :class:`grasp_jax.grippers.ParallelJaw` (or its ``to_dict()``, as result files
            store it) whose body is drawn at each grasp where ``shown`` has jaw poses (columns
            ``center``, ``axis``, ``approach``, ``width``); default, and for a gripper without a
            collision body: the proportions of :meth:`ParallelJaw.scaled`.

    Returns:
        A :class:`plotly.graph_objects.Figure`.
    """
    k = len(shown)
    if k == 0:
        raise ValueError("no grasp to draw")
    pts = np.asarray(shown.points, float)
    nrm = unit(shown.normals)
    if pts.ndim != 3 or pts.shape != nrm.shape or pts.shape[-1] not in (2, 3):
        raise ValueError(f"points and normals must be (k, n, d) with d in {{2, 3}}; got {pts.shape}, {nrm.shape}")
    d = pts.shape[-1]
    series = _series(shown)
    canvas = _Canvas(_grid(shown, d, series is not None))
    lo, hi, note = _draw_object(canvas, geometry, d, max_faces)
    lo = np.minimum(lo, pts.reshape(-1, d).min(0))
    hi = np.maximum(hi, pts.reshape(-1, d).max(0))
    extent = float(np.max(hi - lo)) or 1.0
    centre = 0.5 * (lo + hi)
    hover_rows = [_grasp_lines(shown, r) for r in range(k)]
    jaws = _jaw_meshes(shown, gripper)
    paths = _paths(shown)
    axis = dict(mu=mu, num_edges=num_edges, contact=contact, torsion=torsion) if central_axis else None
    for r in range(k):
        _draw_grasp(canvas, shown, r, pts[r], nrm[r], hover_rows[r], length=0.1 * extent, mu=mu,
                    num_edges=num_edges, jaws=jaws)
        if axis is not None:
            _draw_axis(canvas, r, pts[r], nrm[r], hover_rows[r][0], centre, extent, axis)
        if paths is not None:
            _draw_path(canvas, r, paths, hover_rows[r][0])
    _draw_table(canvas, shown)
    _draw_quality(canvas, shown, hover_rows, series)
    _set_axes(canvas.fig, shown, d, centre, extent, series is not None)
    _add_menu(canvas, shown, d, title, note)
    return canvas.fig


def _series(shown: ShownGrasps):
    """``(k, steps)`` Q per optimizer step of the drawn grasps, or ``None``."""
    cols = shown.columns
    series = np.asarray(cols["quality_history"], float) if "quality_history" in cols else None
    if series is not None and (series.ndim != 2 or series.shape[0] != len(shown)):
        return None
    return series


def _grid(shown: ShownGrasps, d: int, with_series: bool):
    """The subplots: the scene (left), the table, the Q histogram and (``with_series``) Q against
    step (right)."""
    rows = 3 if with_series else 2
    spec_main = {"type": "scene" if d == 3 else "xy", "rowspan": rows}
    specs = [[spec_main, {"type": "table"}], [None, {"type": "xy"}]]
    heights = [0.45, 0.55]
    if rows == 3:
        specs.append([None, {"type": "xy"}])
        heights = [0.36, 0.32, 0.32]
    titles = ["", "", "Q of the file's force-closure grasps (red: the drawn grasps)"
              if shown.histogram is not None else "Q of the drawn grasps"]
    if rows == 3:
        titles.append("Q against step (drawn grasps)")
    return make_subplots(rows=rows, cols=2, column_widths=[0.64, 0.36], row_heights=heights, specs=specs,
                         horizontal_spacing=0.03, vertical_spacing=0.11, subplot_titles=titles)


def _draw_object(canvas: _Canvas, geometry, d: int, max_faces: int):
    """The mesh (3D) or the polygon's rings (2D); ``(lo, hi, note)``: its bounds ``(d,)`` and the
    decimation note."""
    note = None
    if d == 3:
        v, f = mesh_arrays(geometry)
        v, f, note = display_mesh(v, f, max_faces)
        canvas.add(go.Mesh3d(**_xyz(v, 3), i=f[:, 0].astype(np.int32), j=f[:, 1].astype(np.int32),
                             k=f[:, 2].astype(np.int32), color=OBJECT_MESH, opacity=0.55, flatshading=False,
                             lighting=dict(ambient=0.55, diffuse=0.7, specular=0.15, roughness=0.8),
                             hoverinfo="skip", name="object", showlegend=True, legendgroup="object"))
        return v.min(0), v.max(0), note
    rings = as_rings(geometry)
    allv = np.concatenate(rings)
    for i, ring in enumerate(rings):
        closed = np.concatenate([ring, ring[:1]])
        canvas.add(go.Scatter(x=closed[:, 0], y=closed[:, 1], mode="lines", fill="toself",
                              fillcolor=OBJECT_MESH if i == 0 else "white", line=dict(color="#4d5b6b", width=1.5),
                              hoverinfo="skip", name="object" if i == 0 else f"hole {i}",
                              showlegend=i == 0, legendgroup="object"))
    return allv.min(0), allv.max(0), note


def _draw_grasp(canvas: _Canvas, shown: ShownGrasps, r: int, p, nr, hover: list, *, length: float, mu: float,
                num_edges: int, jaws) -> None:
    """Grasp ``r``: its contacts ``p`` ``(n, d)`` with their hover text, the gripper body (where
    ``jaws``), the outward normals ``nr`` and the friction pyramids (3D) or cones (2D)."""
    n, d = p.shape
    group = dict(legendgroup=f"grasp {r}")
    label = f"#{r + 1}: grasp {int(shown.index[r])}"
    if "quality" in shown.columns:
        label += f", Q {float(shown.columns['quality'][r]):.3f}"
    text = ["<br>".join([f"contact c_{j + 1}"] + hover) for j in range(n)]
    colours = [FIRST] + [CONTACT] * (n - 1)
    sizes = [9] + [6] * (n - 1) if d == 3 else [13] + [10] * (n - 1)
    marker = dict(color=colours, size=sizes, line=dict(color="white", width=1))
    labels = [f"c{j + 1}" for j in range(n)]
    if d == 3:
        canvas.add(go.Scatter3d(**_xyz(p, 3), mode="markers+text", marker=marker, text=labels,
                                hovertext=text, hovertemplate="%{hovertext}<extra></extra>",
                                textposition="top center", textfont=dict(size=10, color=CONTACT),
                                name=label, showlegend=True, **group), r)
    else:
        canvas.add(go.Scatter(**_xyz(p, 2), mode="markers+text", marker=marker, text=labels, hovertext=text,
                              hovertemplate="%{hovertext}<extra></extra>", textposition="top center",
                              name=label, showlegend=True, **group), r)
    if jaws is not None:  # the gripper: finger boxes and palm at the jaw pose
        jv, jf = jaws
        canvas.add(go.Mesh3d(**_xyz(jv[r], 3), i=jf[:, 0].astype(np.int32), j=jf[:, 1].astype(np.int32),
                             k=jf[:, 2].astype(np.int32), color=JAW, opacity=0.45, flatshading=True,
                             hovertext=["gripper<br>" + "<br>".join(hover)] * len(jv[r]),
                             hovertemplate="%{hovertext}<extra></extra>", name="gripper", showlegend=False,
                             **group), r)
    seg = np.stack([p, p + 1.35 * length * nr], axis=1)  # normals, outward
    canvas.add(_line(d)(**_xyz(_gaps(seg), d), mode="lines", line=dict(color="#333333", width=3 if d == 3 else 1.5),
                        hoverinfo="skip", name="normals", showlegend=False, **group), r)
    _draw_cones(canvas, r, p, nr, length=length, mu=mu, num_edges=num_edges)


def _draw_cones(canvas: _Canvas, r: int, p, nr, *, length: float, mu: float, num_edges: int) -> None:
    """The friction pyramids of contacts ``p`` ``(n, 3)`` (faces and edges), or the friction cones
    of 2D contacts (wedges), mirrored outside through each contact."""
    n, d = p.shape
    group = dict(legendgroup=f"grasp {r}")
    edges = unit(reference.cone_edges(nr, float(mu), int(num_edges)))  # (n, m, d), inward
    if d == 2:
        wedge = np.stack([p, p + length * edges[:, 0], p + length * edges[:, 1], p], axis=1)
        canvas.add(go.Scatter(**_xyz(_gaps(wedge), 2), mode="lines", fill="toself", fillcolor="rgba(232,131,58,0.45)",
                              line=dict(color=CONE, width=1), hoverinfo="skip", name="friction cones",
                              showlegend=False, **group), r)
        return
    rim = p[:, None] - length * edges  # outside, mirrored through the contact
    m = rim.shape[1]
    verts = np.concatenate([p[:, None], rim], axis=1).reshape(-1, 3)  # (n (m + 1), 3)
    base = (np.arange(n) * (m + 1))[:, None]
    j = np.arange(m)[None]
    tri_i = np.broadcast_to(base, (n, m)).reshape(-1)
    tri_j = (base + 1 + j).reshape(-1)
    tri_k = (base + 1 + (j + 1) % m).reshape(-1)
    canvas.add(go.Mesh3d(**_xyz(verts, 3), i=tri_i.astype(np.int32), j=tri_j.astype(np.int32),
                         k=tri_k.astype(np.int32), color=CONE, opacity=0.35, hoverinfo="skip",
                         name="friction pyramids", showlegend=False, **group), r)
    ring = np.concatenate([rim, rim[:, :1]], axis=1)
    spokes = np.stack([np.broadcast_to(p[:, None], rim.shape), rim], axis=2).reshape(-1, 2, 3)
    lines = np.concatenate([_gaps(ring), _gaps(spokes)])
    canvas.add(go.Scatter3d(**_xyz(lines, 3), mode="lines", line=dict(color=CONE, width=2),
                            hoverinfo="skip", name="pyramid edges", showlegend=False, **group), r)


def _draw_axis(canvas: _Canvas, r: int, p, nr, heading: str, centre, extent: float, settings: dict) -> None:
    """The balancing central axis of grasp ``r`` (:func:`grasp_jax.reference.balancing_axis` with
    ``settings``), a segment through the point nearest the scene's ``centre``; none where it has none."""
    axis = reference.balancing_axis(p, nr, **settings)
    if axis is None:
        return
    d = p.shape[-1]
    a0, u = axis
    mid = a0 + float((centre - a0) @ u) * u
    seg = np.stack([mid - 0.75 * extent * u, mid + 0.75 * extent * u])
    hover = "central axis \u0394<sub>r</sub>* of contacts 2..n at the quality LP's optimum" "<br>" + heading
    canvas.add(_line(d)(**_xyz(seg, d), mode="lines", line=dict(color=AXIS, width=4 if d == 3 else 2, dash="dash"),
                        hovertext=[hover, hover], hovertemplate="%{hovertext}<extra></extra>", name="central axis",
                        showlegend=False, legendgroup=f"grasp {r}"), r)


def _draw_path(canvas: _Canvas, r: int, paths, heading: str) -> None:
    """The contact paths of grasp ``r`` (optimizer results) and their starts."""
    path, source = paths
    track = np.transpose(path[r], (1, 0, 2))  # (n, S, d)
    n, steps, d = track.shape
    group = dict(legendgroup=f"grasp {r}")
    what = ("start to end" if source == "initial_points" else
            f"{steps} positions from the start to the last step (column {source!r}; the grasp drawn is "
            "the best iterate)")
    canvas.add(_line(d)(**_xyz(_gaps(track), d), mode="lines", line=dict(color=PATH, width=3 if d == 3 else 1.5),
                        hovertext=[f"path of a contact, {what}<br>{heading}"] * (n * (steps + 1)),
                        hovertemplate="%{hovertext}<extra></extra>", name="contact paths", showlegend=False,
                        **group), r)
    canvas.add(_line(d)(**_xyz(track[:, 0], d), mode="markers",
                        marker=dict(color=PATH, size=4 if d == 3 else 7, symbol="circle-open"),
                        hovertext=[f"start of contact c_{j + 1}<br>{heading}" for j in range(n)],
                        hovertemplate="%{hovertext}<extra></extra>", name="starts", showlegend=False, **group), r)


def _draw_table(canvas: _Canvas, shown: ShownGrasps) -> None:
    """The table of the drawn grasps: rank, index, verdict, Q and every scalar column."""
    k, cols = len(shown), shown.columns
    header = ["rank", "grasp", "verdict", "Q"]
    cells = [list(range(1, k + 1)), [int(i) for i in shown.index], [_verdict(cols, r) for r in range(k)],
             [f"{float(q):.4f}" for q in cols["quality"]] if "quality" in cols else ["-"] * k]
    for name, values in cols.items():
        a = np.asarray(values)
        if name in ("force_closure", "quality") or a.ndim != 1:
            continue
        header.append(_html.escape(name))
        cells.append([_format_value(name, x) for x in a])
    canvas.add(go.Table(header=dict(values=[f"<b>{h}</b>" for h in header], fill_color="#e4e9f0", align="left",
                                    font=dict(size=11)),
                        cells=dict(values=cells, align="left", font=dict(size=11), height=22),
                        columnwidth=[34, 60, 110, 56] + [70] * (len(header) - 4)), -1, row=1, col=2)


def _draw_quality(canvas: _Canvas, shown: ShownGrasps, hover_rows: list, series) -> None:
    """The file's Q histogram (where ``shown`` has one), a line at each drawn grasp's Q, and each
    drawn grasp's Q against step (where ``series``)."""
    k, cols = len(shown), shown.columns
    qs = np.asarray(cols["quality"], float) if "quality" in cols else None
    top_count = 1.0
    if shown.histogram is not None:
        counts, edges_h = shown.histogram
        last = int(np.max(np.flatnonzero(counts))) + 1 if counts.any() else len(counts)
        centres = 0.5 * (edges_h[:-1] + edges_h[1:])[:last]
        canvas.add(go.Bar(x=centres, y=counts[:last], width=float(edges_h[1] - edges_h[0]), marker_color="#8ea3bf",
                          name="Q histogram", showlegend=False,
                          hovertemplate="Q %{x:.3f}: %{y} grasps<extra></extra>"), -1, row=2, col=2)
        top_count = float(counts.max())
    if qs is not None:
        for r in range(k):
            canvas.add(go.Scatter(x=[qs[r], qs[r]], y=[0, top_count], mode="lines", line=dict(color=FIRST, width=1.5),
                                  hovertext=[hover_rows[r][0]] * 2,
                                  hovertemplate="%{hovertext}<br>Q %{x:.4f}<extra></extra>",
                                  legendgroup=f"grasp {r}", showlegend=False), r, row=2, col=2)
    if series is not None:
        steps = np.arange(1, series.shape[1] + 1)
        for r in range(k):
            canvas.add(go.Scatter(x=steps, y=series[r], mode="lines", line=dict(width=1.5),
                                  hovertext=[hover_rows[r][0]] * len(steps),
                                  hovertemplate="%{hovertext}<br>step %{x}: Q %{y:.4f}<extra></extra>",
                                  legendgroup=f"grasp {r}", showlegend=False), r, row=3, col=2)


def _set_axes(fig, shown: ShownGrasps, d: int, centre, extent: float, with_series: bool) -> None:
    """Axis titles of the side plots; the scene a cube (3D) or equal axes (2D) around ``centre``."""
    fig.update_xaxes(title_text="Q", row=2, col=2)
    fig.update_yaxes(title_text="grasps" if shown.histogram is not None else "", row=2, col=2)
    if with_series:
        fig.update_xaxes(title_text="step", row=3, col=2)
        fig.update_yaxes(title_text="Q", row=3, col=2)
    half = 0.55 * extent
    if d == 3:
        rng = {a: [float(centre[i] - half), float(centre[i] + half)] for i, a in enumerate("xyz")}
        fig.update_scenes(aspectmode="cube", xaxis=dict(range=rng["x"], showbackground=False, title=""),
                          yaxis=dict(range=rng["y"], showbackground=False, title=""),
                          zaxis=dict(range=rng["z"], showbackground=False, title=""))
    else:
        fig.update_xaxes(range=[centre[0] - half, centre[0] + half], row=1, col=1, showgrid=False,
                         zeroline=False)
        fig.update_yaxes(range=[centre[1] - half, centre[1] + half], row=1, col=1, scaleanchor="x",
                         scaleratio=1, showgrid=False, zeroline=False)


def _add_menu(canvas: _Canvas, shown: ShownGrasps, d: int, title: str | None, note: str | None) -> None:
    """The selector (all grasps, or one; the best first), the title and the layout."""
    fig, owner, k, cols = canvas.fig, canvas.owner, len(shown), shown.columns
    qs = np.asarray(cols["quality"], float) if "quality" in cols else None

    def visible(rank):
        return [True if o < 0 or rank is None or o == rank else "legendonly" for o in owner]

    for trace, shown_now in zip(fig.data, visible(0)):  # the best grasp first
        trace.visible = shown_now
    buttons = [dict(label=f"all {k} grasps", method="restyle", args=[{"visible": visible(None)}])]
    for r in range(k):
        label = f"#{r + 1}: grasp {int(shown.index[r])}"
        if qs is not None:
            label += f", Q {qs[r]:.3f}"
        label += f" ({_verdict(cols, r)})"
        buttons.append(dict(label=label, method="restyle", args=[{"visible": visible(r)}]))
    heading = _html.escape(title) if title else "grasps"
    sub = [note] if note else []
    sub.append("drag to turn, scroll to zoom; hover a contact for its grasp's columns; "
               "the menu (or a legend entry) picks a grasp" if d == 3 else
               "hover a contact for its grasp's columns; the menu (or a legend entry) picks a grasp")
    fig.update_layout(
        title=dict(text=f"{heading}<br><sup>{'<br>'.join(_html.escape(s) for s in sub)}</sup>", x=0.01,
                   xanchor="left", font=dict(size=15)),
        updatemenus=[dict(type="dropdown", buttons=buttons, active=1, direction="down", x=0.0, xanchor="left",
                          y=0.99, yanchor="top", showactive=True, bgcolor="white", font=dict(size=11))],
        legend=dict(x=0.0, y=0.88, xanchor="left", yanchor="top", bgcolor="rgba(255,255,255,0.7)",
                    font=dict(size=10), groupclick="togglegroup"),
        margin=dict(l=10, r=10, t=90, b=40), height=820, template="plotly_white",
        hoverlabel=dict(align="left", font=dict(size=11)),
    )
