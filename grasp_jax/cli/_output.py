"""What the commands write besides their summaries: figures of the best grasps and of robust
labels (each saved atomically), the printed summary, and the result file of ``optimize``.

matplotlib (through :mod:`grasp_jax.viz`) is imported inside the functions that draw.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .. import storage
from .. import summary as summaries
from ._common import say, warn

PLOT_SUFFIXES = (".png", ".pdf", ".svg")
#: Most grasps drawn in the scatter of :func:`plot_robust` (a seeded random subset beyond).
ROBUST_SCATTER = 20000


def check_plot_path(path: Path | None) -> Path | None:
    """``path`` checked as a figure to write (``None`` stays ``None``)."""
    return None if path is None else storage.check_output_path(path, suffixes=PLOT_SUFFIXES, what="figure")


def report(args, summary, best_lines: int = 0) -> None:
    """Print a run's summary (one JSON line with --json, nothing with --quiet)."""
    if args.quiet:
        return
    if args.json:
        print(summaries.summary_json(summary), flush=True)
        return
    print(summary.format(best=max(best_lines, 1)), flush=True)


def save_figure(fig, path: Path) -> None:
    """Write ``fig`` to ``path`` atomically (a temporary file renamed into place)."""
    storage.write_atomically(path, lambda f: fig.savefig(f, format=path.suffix.lower()[1:], dpi=fig.dpi,
                                                         bbox_inches="tight"), mode="wb", what="figure")


def rings(obj):
    """What plot_grasp_2d draws for a planar object."""
    for attr in ("rings", "polygon", "vertices"):
        if hasattr(obj, attr):
            return obj if attr == "rings" else getattr(obj, attr)
    raise ValueError(f"cannot draw object {obj.name!r}: it has no polygon rings")


def mesh(obj):
    """What plot_grasp_3d draws for a 3D object."""
    if hasattr(obj, "mesh") or (hasattr(obj, "vertices") and hasattr(obj, "faces")):
        return obj
    raise ValueError(f"cannot draw object {obj.name!r}: it has no mesh")


def plot_summary(args, obj, summary, mu, edges) -> None:
    """The --plot figure of a run: its --top best grasps (a warning where none is force-closure)."""
    if args.plot is None:
        return
    if summary.best is None or not len(summary.best):
        warn(f"no force-closure grasp: nothing drawn to {args.plot}")
        return
    best = summaries.BestGrasps(*(a[: args.top] for a in (summary.best.index, summary.best.points,
                                                           summary.best.normals, summary.best.quality)))
    plot_best(obj, best, mu=mu, num_edges=edges, path=args.plot,
              title=f"{obj.name}: best {len(best)} of {summary.num:,} grasps")
    say(args, f"figure         {args.plot}")


def plot_best(obj, best, *, mu: float, num_edges: int, path: Path, title: str | None = None) -> Path:
    """Draw the grasps of a :class:`grasp_jax.summary.BestGrasps` on ``obj`` in one figure (atomic)."""
    from ..viz import plot_grasp_2d, plot_grasp_3d
    from ..viz import pyplot

    plt = pyplot()
    k = len(best)
    cols = k if k <= 3 else math.ceil(math.sqrt(k))
    rows = -(-k // cols)
    height = 4.2
    if obj.dim == 2 and hasattr(obj, "rings"):  # equal-aspect panels of a long, flat polygon
        w, h = np.ptp(np.concatenate(obj.rings), axis=0)  # would leave rows of white space
        if w > 0:
            height = float(np.clip(4.2 * h / w + 0.8, 2.0, 4.2))
    fig = plt.figure(figsize=(4.2 * cols, height * rows), dpi=100)
    try:
        for i in range(k):
            label = f"#{int(best.index[i])}"
            if obj.dim == 2:
                ax = fig.add_subplot(rows, cols, i + 1)
                plot_grasp_2d(rings(obj), best.points[i], best.normals[i], mu=mu,
                              quality=float(best.quality[i]), ax=ax, title=label)
            else:
                ax = fig.add_subplot(rows, cols, i + 1, projection="3d")
                plot_grasp_3d(mesh(obj), best.points[i], best.normals[i], mu=mu, num_edges=num_edges,
                              quality=float(best.quality[i]), ax=ax, title=label)
        if title:
            fig.suptitle(title, fontsize=11)
        fig.tight_layout()
        save_figure(fig, path)
    finally:
        plt.close(fig)
    return path


def plot_robust(file: Path, path: Path) -> Path | None:
    """Nominal Q against P(force-closure) of a result file with robust labels (``--robust N``:
    column ``p_fc``), and the histogram of P(force-closure) of the nominally force-closure grasps
    and of the others, in one figure (atomic); ``None`` where the file has no ``p_fc``."""
    from ..viz import pyplot

    src = storage.ResultFile(file)
    if "p_fc" not in src.fields:
        return None
    parts = list(src.iter_chunks(("quality", "force_closure", "p_fc")))
    q, fc, p = (np.concatenate([c[k] for c in parts]) for k in ("quality", "force_closure", "p_fc"))
    fc = fc.astype(bool)
    shown = np.arange(len(q))
    if len(q) > ROBUST_SCATTER:
        shown = np.sort(np.random.default_rng(0).choice(len(q), ROBUST_SCATTER, replace=False))
    plt = pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4.2), dpi=100)
    try:
        a.scatter(q[shown], p[shown], s=4, alpha=0.35, c=np.where(fc[shown], "tab:blue", "tab:gray"), linewidths=0)
        a.set_xlabel("nominal Q")
        a.set_ylabel("P(force-closure) under noise")
        a.set_ylim(-0.03, 1.03)
        a.set_title(f"{len(shown):,} of {len(q):,} grasps (blue: nominally force-closure)", fontsize=9)
        bins = np.linspace(0, 1, 21)
        b.hist([p[fc], p[~fc]], bins=bins, label=[f"force-closure ({fc.sum():,})", f"not ({(~fc).sum():,})"],
               color=["tab:blue", "tab:gray"], stacked=True)
        b.set_xlabel("P(force-closure) under noise")
        b.set_ylabel("grasps")
        b.legend(fontsize=8)
        fig.suptitle(_robust_title(file), fontsize=10)
        fig.tight_layout()
        save_figure(fig, path)
    finally:
        plt.close(fig)
    return path


def _robust_title(file: Path) -> str:
    """The title of :func:`plot_robust`: the file, the perturbations and the noise of its metadata."""
    robust = storage.read_metadata(file).get("robust", {})
    noise = robust.get("noise", {})
    noise = (", ".join(f"{k} {v}" for k, v in noise.items() if v and v != [1.0, 1.0]) or "none"
             if isinstance(noise, dict) else str(noise))
    return f"{file.name}: robust labels, {robust.get('samples', '?')} perturbations ({noise})"


def write_optimized(path: Path, result, meta: dict) -> Path:
    """The optimize result file: the fields of ``sample`` plus the per-start history, atomically."""
    ev = result.evaluation
    batch = {
        "points": np.asarray(result.points, float),
        "normals": np.asarray(result.normals, float),
        "force_closure": np.asarray(ev.force_closure, bool),
        "quality": np.asarray(ev.quality, float),
        "converged": np.asarray(ev.converged, bool),
        "initial_points": np.asarray(result.initial_points, float),
        "objective": np.asarray(result.objective, float),
        "reason": np.asarray(result.reason, np.int8),
        "history": np.asarray(result.history, float),
    }
    if result.quality_history is not None:
        batch["quality_history"] = np.asarray(result.quality_history, float)
    if result.path is not None:
        batch["path"] = np.asarray(result.path, float)
    fields = [*storage.RESULT_FIELDS, *(f for f in batch if f not in storage.RESULT_FIELDS)]
    with storage.open_writer(path, meta, fields, fingers=batch["points"].shape[1], dim=batch["points"].shape[2],
                             steps=batch["history"].shape[1],
                             frames=batch["path"].shape[1] if "path" in batch else None) as w:
        w.write(batch)
    return w.path
