"""Interactive, self-contained HTML pages of grasps and result files (plotly).

A page opens in any browser without a network (plotly's script embedded) and shows the object, the
best ``top`` grasps (contacts, outward normals, friction pyramids, and the central axis of each
grasp's balancing wrench, Proposition 1 of the paper), the gripper at jaw poses, every column of a
grasp on hover, a table of the drawn grasps, a histogram of Q over the file, and for an optimizer
result Q against step and the contacts' paths. Only the drawn grasps travel to the page.
"""

from __future__ import annotations

import html as _html
import os
from pathlib import Path

import numpy as np

from .. import objects, storage
from ._grasp_figure import MAX_FACES, display_mesh, grasp_figure
from ._shown import DEFAULT_TOP, ShownGrasps, select_grasps

__all__ = ["ShownGrasps", "select_grasps", "grasp_figure", "grasp_page", "result_page", "write_page", "html_page",
           "display_mesh", "MAX_FACES", "DEFAULT_TOP"]


def write_page(fig, page, *, title: str = "grasp_jax") -> Path:
    """Write ``fig`` as one self-contained HTML file (plotly's script embedded: it opens offline),
    atomically: a complete page or none at ``page``."""

    page = storage.check_output_path(page, suffixes=(".html", ".htm"), what="page")
    text = fig.to_html(include_plotlyjs=True, full_html=True, div_id="grasp-jax-page",
                       config={"displaylogo": False, "responsive": True, "scrollZoom": True})
    text = text.replace("<head>", f"<head><title>{_html.escape(title)}</title>", 1)
    return storage.write_atomically(page, lambda out: out.write(text), what="page")


def grasp_page(geometry, points, normals, page, *, mu: float, num_edges: int = 8, columns=None, index=None,
               contact: str = "hard", torsion: float | None = None, title: str | None = None,
               max_faces: int = MAX_FACES) -> Path:
    """A page of grasps held in memory (e.g. the best of a :func:`grasp_jax.evaluate` call).

    Args:
        geometry: the object (as :func:`grasp_figure` takes it).
        points, normals: ``(k, n, d)`` float, the grasps to draw, best first.
        page: the ``.html`` file to write.
        mu, num_edges, contact, torsion: the friction model.
        columns: optional mapping of column name -> ``(k, ...)`` values shown on hover and in the
            table (``quality`` and ``force_closure`` are read as Q and the verdict).
        index: ``(k,)`` the grasps' numbers (default ``0..k-1``).
        title, max_faces: as :func:`grasp_figure`.

    Returns:
        The page's path.
    """
    points = np.asarray(points, float)
    if points.ndim == 2:
        points, normals = points[None], np.asarray(normals, float)[None]
    k = len(points)
    cols = {name: np.asarray(v) for name, v in (columns or {}).items()}
    for name, v in cols.items():
        if len(v) != k:
            raise ValueError(f"column {name!r} has {len(v)} rows; points has {k}")
    index = np.arange(k) if index is None else np.asarray(index, np.int64)
    shown = ShownGrasps(index, points, np.asarray(normals, float), cols, num=k)
    fig = grasp_figure(geometry, shown, mu=mu, num_edges=num_edges, contact=contact, torsion=torsion,
                       title=title, max_faces=max_faces)
    return write_page(fig, page, title=title or "grasp_jax")


def result_page(path, page=None, *, top: int = DEFAULT_TOP, obj=None, holes=(), max_faces: int = MAX_FACES,
                title: str | None = None) -> Path:
    """The interactive page of a result file (what ``grasp-jax show FILE --html PAGE`` writes).

    Args:
        path: a result file (``.npz`` / ``.parquet``) of ``grasp-jax sample``, ``score`` or
            ``optimize``, or any file with ``points`` and ``normals``.
        page: the ``.html`` file to write (default: ``path`` with suffix ``.html``).
        top: grasps drawn (:func:`select_grasps`).
        obj: the object: an object of :mod:`grasp_jax.objects`, a built-in name or a file (default:
            the file's metadata).
        holes: polygon holes, when ``obj`` is a polygon file (default: the file's).
        max_faces, title: as :func:`grasp_figure` (default title: the object, the file and its counts).

    Returns:
        The page's path.
    """
    path = Path(path)
    page = path.with_suffix(".html") if page is None else Path(page)

    storage.check_input_path(path)
    storage.check_output_path(page, suffixes=(".html", ".htm"), what="page")
    shown, meta = select_grasps(path, top)
    if not len(shown):
        raise ValueError(f"{str(path)!r} holds no grasps")
    if obj is None or isinstance(obj, (str, os.PathLike)):

        spec = obj if obj is not None else meta.get("object")
        if spec is None:
            raise ValueError(f"{str(path)!r} names no object: pass obj= (--object)")
        use_holes = holes or (meta.get("object_holes") or () if obj is None else ())
        obj = objects.load(spec, holes=use_holes)
    if shown.points.shape[-1] != obj.dim:
        raise ValueError(f"the grasps are {shown.points.shape[-1]}D but object {obj.name!r} is {obj.dim}D")
    mu = float(meta.get("mu", 0.364))
    edges = int(meta.get("edges", 8))
    if title is None:
        counts = f"best {len(shown)} of {shown.num:,} grasps"
        if shown.num_force_closure is not None:
            counts += f" ({shown.num_force_closure:,} force-closure)"
        model = meta.get("contact", "hard")
        extra = "" if model == "hard" else f", {model} contacts (torsion {meta.get('torsion')})"
        title = f"{obj.name}: {counts} of {path.name}, mu {mu:g}, {edges} edges{extra}"
    geometry = obj if obj.dim == 2 else (obj.mesh if hasattr(obj, "mesh") else obj)
    fig = grasp_figure(geometry, shown, mu=mu, num_edges=edges, contact=meta.get("contact", "hard"),
                       torsion=meta.get("torsion"), title=title, max_faces=max_faces, gripper=meta.get("gripper"))
    return write_page(fig, page, title=title)


def html_page(path, page=None, *, top=10, obj=None, max_faces=20000, title=None):
    """An interactive, self-contained HTML page of the best ``top`` grasps of a result file, the
    same as ``grasp-jax show FILE --html PAGE`` (:func:`result_page`: turn the
    object around, pick a grasp, hover a contact for its grasp's columns; plotly, opens offline).

    Args:
        path: a result file (``.npz`` / ``.parquet``).
        page: the ``.html`` file to write (default: ``path`` with suffix ``.html``).
        top: grasps drawn, best first (force-closure ones first).
        obj: the object (default: the one the file's metadata names).
        max_faces: larger meshes are decimated for display (the page says so).
        title: the page's title.

    Returns:
        The page's :class:`pathlib.Path`.
    """
    return result_page(path, page, top=top, obj=obj, max_faces=max_faces, title=title)
