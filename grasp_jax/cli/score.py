"""``grasp-jax score``: score the grasps stored in a file, optionally writing the scores."""

from __future__ import annotations

from pathlib import Path

from .. import storage
from . import _options as opt
from ._common import contact_settings, holes, load_object, robust_settings, setup
from ._output import check_plot_path, plot_summary, report


def add_parser(subparsers):
    p = subparsers.add_parser("score", help="score grasps stored in a .npz or .parquet file",
                              description="Score the grasps (arrays 'points' and 'normals', shape (N, n, d)) "
                                          "of FILE, print a summary and optionally write the scores to --out.",
                              formatter_class=opt.Formatter)
    p.add_argument("file", metavar="FILE", type=Path, help=".npz or .parquet file with points and normals")
    p.add_argument("--object", default=None,
                   help="the object the grasps are on, for --epsilon and --plot (default: the file's metadata)")
    opt.add_hole(p, from_file=True)
    opt.add_scoring(p, from_file=True)
    opt.add_plot(p)
    return p


def run(args) -> int:
    from .. import pipeline

    _check_paths(args)
    robust = robust_settings(args)
    setup(args)
    meta = storage.read_metadata(args.file)
    obj = _object(args, meta, robust)
    contact, torsion = contact_settings(args, args.mu if args.mu is not None else meta.get("mu", opt.DEFAULT_MU), {})
    summary = pipeline.score_file(
        args.file, mu=args.mu, num_edges=args.edges, torque_test=args.torque_test, chunk=args.chunk,
        epsilon=args.epsilon, origin=args.origin, torque_scale=args.torque_scale, obj=obj, out=args.out,
        progress=not args.quiet, top=max(args.top, 5), contact=contact, torsion=torsion,
        critical=bool(args.critical_friction), robust=robust_settings(args, obj),
    )
    report(args, summary, best_lines=5)
    if obj is not None:
        plot_summary(args, obj, summary, summary.metadata["mu"], summary.metadata["edges"])
    return 0


def _check_paths(args) -> None:
    storage.check_input_path(args.file)
    if args.out is not None:
        storage.check_output_path(args.out)
        if args.out.resolve() == args.file.resolve():
            raise ValueError("--out must differ from the input file")
    check_plot_path(args.plot)


def _object(args, meta: dict, robust):
    """The object, where --epsilon, --plot or noise that moves contacts needs it (else ``None``)."""
    need_obj = (args.epsilon and (args.origin is None or args.torque_scale is None)) or args.plot is not None
    need_obj = need_obj or (robust is not None and robust.noise.moves_contacts)
    if not need_obj:
        return None
    spec = args.object or meta.get("object")
    if spec is None:
        raise ValueError("the file names no object: pass --object (needed for --epsilon, --plot and noise that "
                         "moves contacts)")
    return load_object(spec, holes(args, meta))
