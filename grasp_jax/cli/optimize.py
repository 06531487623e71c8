"""``grasp-jax optimize``: move the contacts of many grasps over the surface by gradient (from
random starts, or from the best grasps of a result file), write and summarize the result."""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from .. import OBJECTIVES, evaluate, sampling, storage
from .. import optimize as optimize_grasps
from .. import summary as summaries
from .._optimize import DEFAULT_LEARNING_RATE, REFINE_LEARNING_RATE
from . import _options as opt
from ._common import contact_settings, load_object, say, setup, warn
from ._output import check_plot_path, mesh, rings, save_figure, write_optimized

#: Most random grasps drawn beside the optimization curves of ``optimize --plot``.
MAX_SAMPLED = 1 << 18


def add_parser(subparsers):
    p = subparsers.add_parser(
        "optimize", help="move contacts over the surface by gradient to make grasps better",
        description="Optimize --starts grasps of OBJECT by gradient (grasp_jax.optimize): every start moves\n"
                    "its contacts over the surface for --steps steps; the best iterate of each is scored\n"
                    "exactly (force-closure, Q), written to --out and summarized. Starts are random, or the\n"
                    "best grasps of a file written by 'grasp-jax sample' (--from: sample, then refine).",
        epilog=opt.epilog(), formatter_class=opt.Formatter)
    p.add_argument("object", metavar="OBJECT", nargs="?", default=None,
                   help="built-in name or mesh / polygon CSV file (default: the --from file's object)")
    opt.add_hole(p)
    _add_optimization(p)
    s = p.add_argument_group("scoring")
    opt.add_mu(s, None, f"friction coefficient (default: the --from file's, else {opt.DEFAULT_MU})")
    opt.add_edges(s, None, "edges of each linearized 3D friction cone (default: the --from file's, else 8)")
    opt.add_contact(s, " (default: the --from file's, else hard)")
    o = p.add_argument_group("output and performance")
    o.add_argument("--out", type=Path, default=None, metavar="FILE",
                   help="write every start's final grasp, scores, objective history and end reason to FILE "
                        "(.npz or .parquet), atomically")
    opt.add_devices(o)
    opt.add_reporting(o)
    opt.add_plot(p, help_text="draw Q against step (median and best over starts, beside as many random grasps) "
                              "and the best distinct grasps on the object")
    p.set_defaults(distributed=False)
    return p


def _add_optimization(p) -> None:
    g = p.add_argument_group("optimization")
    opt.add_fingers(g, None, "contacts per grasp (default: the --from file's, else 4)")
    g.add_argument("--starts", type=opt.count, default=1024,
                   help="grasps optimized together (random starts; with --from, its best STARTS grasps)")
    g.add_argument("--steps", type=opt.count, default=200, help="optimizer steps")
    opt.add_seed(g, "random seed of the starts (and of the figure's random grasps)")
    g.add_argument("--objective", choices=OBJECTIVES, default="closure",
                   help="what is maximized: 'closure' = min(signed Q, 4 x torque margin), positive exactly "
                        "at force-closure; 'closure_any' the same for every choice of c_1; 'min_weight' the "
                        "classical margin; 'signed_q'; 'dfc', 'dfc_eig' the DFC energies (baselines)")
    g.add_argument("--lr", type=opt.positive_float, default=None,
                   help=f"peak learning rate of Adam (cosine decay), in object radii per step (default "
                        f"{DEFAULT_LEARNING_RATE} from random starts, {REFINE_LEARNING_RATE} with --from)")
    g.add_argument("--normals", choices=("smooth", "flat"), default="smooth",
                   help="normals of meshes and polygons while optimizing: interpolated ('smooth', sharp "
                        "edges kept) or face normals ('flat'); analytic shapes use exact normals")
    g.add_argument("--from", dest="from_file", type=Path, default=None, metavar="FILE",
                   help="start from the best --starts grasps (by force-closure, then Q; all if fewer) of "
                        "FILE, a result of 'grasp-jax sample' (.npz or .parquet)")


def run(args) -> int:
    if args.out is not None:
        storage.check_output_path(args.out)
    check_plot_path(args.plot)
    src, meta_in = _start_file(args)
    if args.object is None:
        raise ValueError(f"--from file {str(args.from_file)!r} names no object: give OBJECT" if src is not None
                         else "no OBJECT: name a built-in object or a mesh / polygon file (or --from FILE)")
    fingers = args.fingers if args.fingers is not None else (src.fingers if src is not None else 4)
    mu = args.mu if args.mu is not None else float(meta_in.get("mu", opt.DEFAULT_MU))
    edges = args.edges if args.edges is not None else int(meta_in.get("edges", 8))
    contact, torsion = contact_settings(args, mu, meta_in)
    args.contact_model = (contact or "hard", torsion)
    setup(args)
    stored = meta_in.get("object")
    same = stored is not None and _same_object(args.object, stored, meta_in)
    holes = args.hole or (list(meta_in.get("object_holes") or ()) if same else [])
    obj = load_object(args.object, holes)
    init, starts = _starts(args, src, obj)
    result = _optimize(args, obj, fingers=fingers, starts=starts, mu=mu, edges=edges, init=init)
    meta = _metadata(args, obj, result, fingers=fingers, starts=starts, mu=mu, edges=edges,
                     from_file=src is not None, holes=holes)
    path = write_optimized(args.out, result, meta) if args.out is not None else None
    best = _distinct_best(result, max(args.top, 5))
    sampled = _sampled_quality(args, obj, fingers, mu, edges, starts) if args.plot is not None else None
    summary = summaries.optimize_summary(result, meta, best=best, output=path, sampled=sampled)
    if not args.quiet:
        print(summaries.summary_json(summary) if args.json else summaries.format_optimize(summary), flush=True)
    if args.plot is not None:
        _plot_optimization(args, obj, result, best, sampled, mu, edges)
        say(args, f"figure         {args.plot}")
    return 0


def _start_file(args) -> tuple[storage.ResultFile | None, dict]:
    """The --from file and its metadata (``(None, {})`` without --from), checked against --out,
    --fingers and OBJECT; OBJECT defaults to the file's."""
    if args.from_file is None:
        return None, {}
    storage.check_input_path(args.from_file, what="--from file")
    if args.out is not None and args.out.resolve() == args.from_file.resolve():
        raise ValueError("--out must differ from the --from file")
    src = storage.ResultFile(args.from_file)
    meta_in = dict(src.metadata)
    if args.fingers is not None and args.fingers != src.fingers:
        raise ValueError(f"--from file {str(args.from_file)!r} holds {src.fingers}-finger grasps, "
                         f"not {args.fingers} (--fingers)")
    stored = meta_in.get("object")
    if args.object is not None and stored is not None and not _same_object(args.object, stored, meta_in):
        raise ValueError(f"--from file {str(args.from_file)!r} holds grasps of {stored!r}, not of "
                         f"{args.object!r}: omit OBJECT to use the file's")
    if args.object is None:
        args.object = stored
    return src, meta_in


def _same_object(spec: str, stored: str, meta: dict) -> bool:
    """Whether OBJECT names the object a file's metadata names."""
    if spec in (stored, meta.get("object_name")):
        return True
    try:
        return os.path.exists(spec) and os.path.exists(stored) and os.path.samefile(spec, stored)
    except OSError:
        return False


def _starts(args, src, obj):
    """``(init, starts)``: random starts, or the best --starts grasps of the --from file."""
    if src is None:
        return None, args.starts
    if src.dim != obj.dim:
        raise ValueError(f"--from file {str(args.from_file)!r} holds {src.dim}D grasps but object "
                         f"{obj.name!r} is {obj.dim}D")
    best_in, _ = summaries.best_starts(args.from_file, args.starts)
    return (best_in.points, best_in.normals), len(best_in)


def _optimize(args, obj, *, fingers, starts, mu, edges, init):
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r".*did not converge", category=RuntimeWarning)
            return optimize_grasps(obj, args.seed, fingers=fingers, mu=mu, starts=starts, steps=args.steps,
                                   num_edges=edges, objective=args.objective, learning_rate=args.lr,
                                   normals=args.normals, init=init, progress=not args.quiet,
                                   contact=args.contact_model[0], torsion=args.contact_model[1])
    except (TypeError, NotImplementedError) as e:  # an object kind the optimizer cannot move contacts on
        raise ValueError(f"cannot optimize grasps of {obj.name!r}: {e}") from None


def _metadata(args, obj, result, *, fingers, starts, mu, edges, from_file, holes) -> dict:
    """The metadata of the result file (and of the summary)."""
    contact, torsion = args.contact_model
    meta = storage.metadata(
        command="optimize",
        object=storage.object_spec(obj, args.object),
        object_name=str(obj.name),
        dim=int(obj.dim),
        mu=float(mu),
        edges=int(edges),
        fingers=int(fingers),
        seed=int(args.seed),
        num=int(starts),
        torque_test="exact",
        **({"contact": contact} if contact == "hard" else {"contact": contact, "torsion": float(torsion)}),
        objective=args.objective,
        steps=int(args.steps),
        learning_rate=float(result.learning_rate),
        normals=result.normal_kind,
        init=str(args.from_file.resolve()) if from_file else "random",
        seconds=round(float(result.seconds), 3),
    )
    if holes:
        meta["object_holes"] = [storage.object_spec(obj, h) for h in holes]
    return meta


def _distinct_best(result, k: int):
    """The ``k`` best distinct force-closure grasps of an optimization, as :class:`BestGrasps`."""
    index = np.asarray(result.distinct(), np.int64)[:k]
    return summaries.BestGrasps(index, np.asarray(result.points, float)[index],
                                np.asarray(result.normals, float)[index], np.asarray(result.quality, float)[index])


def _sampled_quality(args, obj, fingers, mu, edges, starts):
    """Q (0 where not force-closure) of as many random grasps as starts x steps (at most
    :data:`MAX_SAMPLED`), for the figure."""
    num = int(min(starts * args.steps, MAX_SAMPLED))
    points, normals = sampling.sample_grasps(obj, num, fingers, seed=args.seed)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r".*did not converge", category=RuntimeWarning)
        contact, torsion = getattr(args, "contact_model", ("hard", None))
        res = evaluate(points, normals, mu=mu, num_edges=edges, contact=contact, torsion=torsion)
    return np.where(np.asarray(res.force_closure), np.asarray(res.quality, float), 0.0)


def _plot_optimization(args, obj, result, best, sampled, mu, edges) -> None:
    from ..viz import plot_optimization
    from ..viz import pyplot

    plt = pyplot()
    if result.quality_history is not None:
        curves, ylabel = result.quality_history, "Q (0 while not force-closure)"
    else:
        curves, ylabel, sampled = result.history, f"objective {result.objective_name!r}", None
    grasps = [(best.points[i], best.normals[i], float(best.quality[i]), f"start #{int(best.index[i])}")
              for i in range(min(args.top, len(best)))]
    if not grasps:
        warn("no force-closure grasp: only the curves are drawn")
    geometry = (rings(obj) if obj.dim == 2 else mesh(obj)) if grasps else None
    fc = float(np.mean(result.force_closure))
    title = (f"{obj.name}: {len(result.force_closure):,} starts x {result.steps} steps, objective "
             f"{result.objective_name!r}: {100 * fc:.0f}% force-closure")
    fig = plot_optimization(curves, sampled_quality=sampled, grasps=grasps, geometry=geometry, mu=mu,
                            num_edges=edges, ylabel=ylabel, title=title)
    try:
        save_figure(fig, args.plot)
    finally:
        plt.close(fig)
