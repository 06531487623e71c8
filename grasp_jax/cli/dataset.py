"""``grasp-jax dataset``: sample and score grasps of many objects, or synthesize a hand's grasps of
them, into one Parquet dataset (resumable, sharded over processes)."""

from __future__ import annotations

from pathlib import Path

from ..summary import summary_json
from . import _options as opt
from ._common import jaw_settings, noise_given, robust_settings, setup, warn

#: ``--mu`` without ``--hand`` (the paper's); with ``--hand``, :data:`HAND_MU` (as ``grasp-jax hand``).
HAND_MU = 0.5


def add_parser(subparsers):
    p = subparsers.add_parser(
        "dataset", help="sample and score grasps of many objects into one Parquet dataset (resumable, sharded)",
        description="Sample and score --num grasps of every object of OBJECTS (a folder of mesh files, or a "
                    "manifest: one mesh path or built-in name per line, optionally followed by a scale) with one "
                    "configuration, optionally with robust labels, into DIR/object=<name>/part.parquet (a "
                    "hive-partitioned Parquet dataset) and DIR/_manifest.json. With --hand, each object's part is "
                    "instead the hand's grasps of it (grasp-jax hand: --starts rows, wrist pose and joint angles). "
                    "Run it again to resume; --shard i/N (or a SLURM array) splits the objects over processes.",
        formatter_class=opt.Formatter)
    p.add_argument("objects", metavar="OBJECTS", type=Path, help="folder of mesh files, or a manifest text file")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="the dataset folder (created or resumed)")
    p.add_argument("--shard", default=None, metavar="i/N",
                   help="do objects i, i+N, i+2N, ... of the sorted list (default: SLURM_ARRAY_TASK_ID / "
                        "SLURM_ARRAY_TASK_COUNT in a SLURM array, else all)")
    opt.add_sampling(p, num=10_000)
    g = p.add_argument_group("scoring")
    opt.add_mu(g, None, f"friction coefficient tan(alpha) (default {opt.DEFAULT_MU}; {HAND_MU} with --hand)")
    opt.add_edges(g, 8, "edges of each friction cone")
    g.add_argument("--torque-test", choices=("exact", "paper"), default="exact", help="the torque test")
    opt.add_contact(g)
    opt.add_critical(g)
    opt.add_gripper(p)
    opt.add_robust(p)
    h = p.add_argument_group("hand grasps (grasp_jax.hands)")
    h.add_argument("--hand", default=None, metavar="HAND",
                   help="synthesize this hand's grasps of every object instead of sampling contacts: a URDF or MJCF (.xml) file, "
                        "or 'default' (a small built-in 3-finger hand of primitives); soft contacts by default")
    h.add_argument("--starts", type=opt.integer(1, "an integer >= 1"), default=None,
                   help="with --hand: starts optimized per object, one row each (default 256)")
    h.add_argument("--steps", type=opt.integer(1, "an integer >= 1"), default=None,
                   help="with --hand: optimizer steps (default 200)")
    o = p.add_argument_group("performance and output")
    opt.add_chunk(o, "grasps per chunk (default 65536 on a CPU)")
    opt.add_devices(o, "CPU devices to split the cores into (default: one per core)")
    opt.add_reporting(o)
    p.set_defaults(distributed=False)
    return p


def run(args) -> int:
    from .. import dataset

    if args.first_contact is not None or args.scheme != "uniform":
        raise ValueError("a dataset samples every object uniformly: leave out --scheme and --first-contact")
    shard = dataset.parse_shard(args.shard) if args.shard is not None else dataset.shard_from_environment()
    settings = _hand_settings(args) if args.hand is not None else _grasp_settings(args)
    dataset.list_objects(args.objects)  # an empty folder or a bad manifest: before JAX starts
    setup(args)
    summary = dataset.build(args.objects, args.out, num_edges=args.edges, seed=args.seed, shard=shard,
                            progress=not args.quiet, **settings)
    for name, reason in summary.failed.items():
        warn(f"{name}: failed: {reason}")
    figure = dataset.plot_summary(summary.out)
    if args.json:
        print(summary_json({"out": str(summary.out), "shard": list(summary.shard), "done": summary.done,
                            "skipped": summary.skipped, "failed": summary.failed, "seconds": summary.seconds,
                            "objects": summary.rows}), flush=True)
    elif not args.quiet:
        print(summary.format(), flush=True)
        if figure is not None:
            print(f"figure         {figure} (every object done so far, all shards)", flush=True)
    return 0


def _grasp_settings(args) -> dict:
    """The keywords of :func:`grasp_jax.dataset.build` for sampled grasps (free contacts or a gripper's)."""
    given = [f for f, v in (("--starts", args.starts), ("--steps", args.steps)) if v is not None]
    if given:
        raise ValueError(f"{given[0]} sets the hand grasps: add --hand HAND.urdf (or --hand default)")
    args.mu = opt.DEFAULT_MU if args.mu is None else args.mu
    jaw, contact, torsion = jaw_settings(args)
    return dict(num=args.num, fingers=args.fingers, mu=args.mu, torque_test=args.torque_test, contact=contact,
                torsion=torsion, robust=robust_settings(args), chunk=args.chunk, critical=args.critical_friction,
                **jaw)


def _hand_settings(args) -> dict:
    """The keywords of :func:`grasp_jax.dataset.build` for a hand's grasps (``--hand``)."""
    gripper = [f for f, v in (("--gripper", args.gripper), ("--max-width", args.max_width),
                              ("--min-width", args.min_width), ("--collision", args.collision),
                              ("--finger-size", args.finger_size), ("--palm-size", args.palm_size)) if v]
    if gripper:
        raise ValueError(f"--hand and {gripper[0]} describe two grippers: give --hand or --gripper, not both")
    robust = [f for f, v in (("--robust", args.robust is not None), ("--no-margin", args.no_margin),
                             ("--robust-seed", args.robust_seed is not None), ("--quantile", args.quantile != 0.1))
              if v] + noise_given(args)
    if robust:
        raise ValueError(f"{robust[0]} sets robust labels, which a dataset of hand grasps does not have: leave it out "
                         "with --hand")
    other = [f for f, v in (("--fingers", args.fingers != 4), ("--critical-friction", args.critical_friction),
                            ("--torsion", args.torsion is not None), ("--patch-radius", args.patch_radius is not None),
                            ("--chunk", args.chunk is not None)) if v]
    if other:
        raise ValueError(f"{other[0]} does not apply to hand grasps (the hand's fingertips are the contacts, "
                         "soft ones with the torsion of a fingertip patch): leave it out with --hand")
    if args.contact not in (None, "soft", "hard"):
        raise ValueError(f"a hand's contacts are soft or hard; got --contact {args.contact}")
    return dict(hand=args.hand, starts=256 if args.starts is None else args.starts,
                steps=200 if args.steps is None else args.steps, mu=HAND_MU if args.mu is None else args.mu,
                contact=args.contact or "soft")
