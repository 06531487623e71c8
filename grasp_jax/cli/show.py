"""``grasp-jax show``: draw the best grasps of a result file on their object, list them, and
optionally write an interactive page of them."""

from __future__ import annotations

import sys
from pathlib import Path

from .. import storage
from .. import summary as summaries
from . import _options as opt
from ._common import holes, load_object
from ._output import check_plot_path, plot_best, plot_robust


def add_parser(subparsers):
    p = subparsers.add_parser("show", help="draw the best grasps of a result file on their object",
                              description="Draw the --top best force-closure grasps of a result FILE on their "
                                          "object and list them.", formatter_class=opt.Formatter)
    p.add_argument("file", metavar="FILE", type=Path, help="result file (.npz or .parquet) with quality")
    p.add_argument("--object", default=None, help="the object (default: the file's metadata)")
    opt.add_hole(p, from_file=True)
    opt.add_plot(p, default_help="default: FILE with suffix .png, unless --html is given")
    p.add_argument("--html", type=Path, default=None, metavar="PAGE.html",
                   help="write an interactive, self-contained page of the --top best grasps (opens offline; "
                        "grasp_jax.interactive.result_page)")
    return p


def run(args) -> int:
    storage.check_input_path(args.file)
    page = None if args.html is None else storage.check_output_path(args.html, suffixes=(".html", ".htm"),
                                                                     what="page")
    plot = args.plot if args.plot is not None or page is not None else args.file.with_suffix(".png")
    check_plot_path(plot)
    best, meta = summaries.best_in_file(args.file, args.top)
    spec = args.object or meta.get("object")
    if spec is None:
        raise ValueError(f"{str(args.file)!r} names no object: pass --object")
    obj = load_object(spec, holes(args, meta))
    if page is not None:
        from ..viz import result_page

        result_page(args.file, page, top=args.top, obj=obj)
    if best is None or not len(best):
        print(f"{opt.PROG}: no force-closure grasp in {args.file}: nothing to draw"
              + (f" but the best tries, on page {page}" if page is not None else ""), file=sys.stderr)
        return 1 if page is None else 0
    if best.points.shape[-1] != obj.dim:
        raise ValueError(f"the grasps are {best.points.shape[-1]}D but object {obj.name!r} is {obj.dim}D")
    mu = float(meta.get("mu", opt.DEFAULT_MU))
    edges = int(meta.get("edges", 8))
    robust_plot = None
    if plot is not None:
        plot_best(obj, best, mu=mu, num_edges=edges, path=plot,
                  title=f"{obj.name}: best {len(best)} grasps of {args.file.name}")
        robust_plot = plot_robust(args.file, plot.with_name(plot.stem + ".robust" + plot.suffix))
    _list(best)
    if plot is not None:
        print(f"figure {plot}")
        if robust_plot is not None:
            print(f"figure {robust_plot} (nominal Q against P(force-closure))")
    if page is not None:
        print(f"page   {page}")
    return 0


def _list(best) -> None:
    print("rank  grasp        Q")
    for r, (i, q) in enumerate(zip(best.index, best.quality), 1):
        print(f"{r:4d}  {int(i):9d}  {q:.4f}")
