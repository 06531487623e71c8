"""``grasp-jax hand``: grasps of a hand (wrist pose and joint angles) on an object, by gradient."""

from __future__ import annotations

import json
from pathlib import Path

from .. import storage
from . import _options as opt
from ._common import load_object, say, setup


def add_parser(subparsers):
    p = subparsers.add_parser("hand", help="synthesize grasps of a hand (wrist pose, joint angles) on an object",
                              description="Optimize STARTS grasps of a hand on OBJECT by gradient (wrist pose and "
                                          "joint angles; grasp_jax's force-closure objective on the fingertip "
                                          "contacts, penetration, contact distance, self-collision and joint "
                                          "limits), score each with grasp_jax.evaluate and write them to --out.",
                              epilog=opt.epilog(), formatter_class=opt.Formatter)
    p.add_argument("object", metavar="OBJECT", help="built-in name or mesh file (3D)")
    g = p.add_argument_group("hand and optimizer")
    g.add_argument("--hand", default="default", metavar="HAND",
                   help="a URDF or MJCF (.xml) file, or 'default' (a small built-in 3-finger hand of primitives)")
    g.add_argument("--starts", type=opt.integer(1, "an integer >= 1"), default=256, help="starts optimized at once")
    g.add_argument("--steps", type=opt.integer(1, "an integer >= 1"), default=200, help="optimizer steps")
    g.add_argument("--objective", choices=("closure", "dfc"), default="closure",
                   help="'closure': grasp_jax's force-closure objective; 'dfc': DexGraspNet's energy (baseline)")
    g.add_argument("--contact", choices=("soft", "hard"), default="soft", help="contact model of the objective "
                   "and of the final verdict")
    opt.add_mu(g, 0.5, "friction coefficient")
    opt.add_edges(g, 8, "friction cone edges")
    opt.add_seed(g, "seed of the starts")
    g.add_argument("--dtype", choices=("float64", "float32"), default="float64", help="precision")
    o = p.add_argument_group("output")
    o.add_argument("--out", type=Path, default=None, metavar="FILE", help="result file (.npz or .parquet)")
    o.add_argument("--html", type=Path, default=None, metavar="PAGE",
                   help="an interactive page of the best valid grasps: the posed hand around the object")
    o.add_argument("--top", type=opt.integer(1, "an integer >= 1"), default=6, help="grasps listed and drawn")
    opt.add_reporting(o)
    opt.add_devices(o)
    p.set_defaults(distributed=False)
    return p


def run(args) -> int:
    from .. import hands

    if args.out is not None:
        storage.check_output_path(args.out)
    if args.html is not None:
        storage.check_output_path(args.html, suffixes=(".html", ".htm"), what="page")
    setup(args)
    hand = hands.load(args.hand)
    obj = load_object(args.object)
    if obj.dim != 3:
        raise ValueError(f"a hand grasps a 3D object; {args.object!r} is {obj.dim}D")
    result = hands.synthesize(hand, obj, starts=args.starts, steps=args.steps, mu=args.mu, contact=args.contact,
                              seed=args.seed, objective=args.objective, num_edges=args.edges, dtype=args.dtype,
                              progress=not args.quiet and not args.json)
    if args.out is not None:
        result.save(args.out)
    if args.html is not None:
        from ..viz import hand_page

        hand_page(result, hand, obj, args.html, top=args.top)
    _report(args, result)
    return 0


def _report(args, result) -> None:
    summary = result.summary()
    if args.json:
        print(json.dumps(summary), flush=True)
        return
    say(args, repr(result))
    say(args, "status: " + ", ".join(f"{name} {count:,}" for name, count in summary["status"].items()))
    for rank, i in enumerate(result.best(args.top)):
        say(args, f"  #{rank + 1} start {i}: Q {result.quality[i]:.4f}, penetration "
                  f"{1e3 * result.penetration[i]:.2f} mm, {int(result.active[i].sum())} of "
                  f"{result.active.shape[1]} fingers touch (largest distance "
                  f"{1e3 * abs(result.distance[i][result.active[i]]).max():.2f} mm)")
    for path in (args.out, args.html):
        if path is not None:
            say(args, f"wrote {path}")
