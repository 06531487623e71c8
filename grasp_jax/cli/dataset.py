"""``grasp-jax dataset``: sample and score grasps of many objects into one Parquet dataset
(resumable, sharded over processes)."""

from __future__ import annotations

from pathlib import Path

from ..summary import summary_json
from . import _options as opt
from ._common import jaw_settings, robust_settings, setup, warn


def add_parser(subparsers):
    p = subparsers.add_parser(
        "dataset", help="sample and score grasps of many objects into one Parquet dataset (resumable, sharded)",
        description="Sample and score --num grasps of every object of OBJECTS (a folder of mesh files, or a "
                    "manifest: one mesh path or built-in name per line, optionally followed by a scale) with one "
                    "configuration, optionally with robust labels, into DIR/object=<name>/part.parquet (a "
                    "hive-partitioned Parquet dataset) and DIR/_manifest.json. Run it again to resume; --shard i/N "
                    "(or a SLURM array) splits the objects over processes.",
        formatter_class=opt.Formatter)
    p.add_argument("objects", metavar="OBJECTS", type=Path, help="folder of mesh files, or a manifest text file")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="the dataset folder (created or resumed)")
    p.add_argument("--shard", default=None, metavar="i/N",
                   help="do objects i, i+N, i+2N, ... of the sorted list (default: SLURM_ARRAY_TASK_ID / "
                        "SLURM_ARRAY_TASK_COUNT in a SLURM array, else all)")
    opt.add_sampling(p, num=10_000)
    g = p.add_argument_group("scoring")
    opt.add_mu(g, opt.DEFAULT_MU, "friction coefficient tan(alpha)")
    opt.add_edges(g, 8, "edges of each friction cone")
    g.add_argument("--torque-test", choices=("exact", "paper"), default="exact", help="the torque test")
    opt.add_contact(g)
    opt.add_critical(g)
    opt.add_gripper(p)
    opt.add_robust(p)
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
    jaw, contact, torsion = jaw_settings(args)
    robust = robust_settings(args)
    dataset.list_objects(args.objects)  # an empty folder or a bad manifest: before JAX starts
    setup(args)
    summary = dataset.build(
        args.objects, args.out, num=args.num, fingers=args.fingers, mu=args.mu, num_edges=args.edges, seed=args.seed,
        torque_test=args.torque_test, contact=contact, torsion=torsion, robust=robust, chunk=args.chunk,
        shard=shard, progress=not args.quiet, critical=args.critical_friction, **jaw,
    )
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
