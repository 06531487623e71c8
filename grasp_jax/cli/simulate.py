"""``grasp-jax simulate``: does each grasp of a result file hold in MuJoCo? Adds the columns
``sim_success``, ``sim_status`` and one per force direction to the file, atomically."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import storage
from . import _options as opt
from ._common import load_object, say


def add_parser(subparsers):
    p = subparsers.add_parser("simulate", help="check in MuJoCo whether the jaw grasps of a result file hold",
                              description="Replay every parallel-jaw grasp of FILE in MuJoCo (close, squeeze, then "
                                          "a force along +-x, +-y, +-z in turn) and add sim_success, sim_status "
                                          "and the per-direction outcomes to FILE (or --out), atomically. Needs "
                                          "pip install 'grasp_jax[sim]'.",
                              formatter_class=opt.Formatter)
    p.add_argument("file", metavar="FILE", type=Path,
                   help="a result file of grasp-jax sample --gripper parallel-jaw (.npz or .parquet)")
    p.add_argument("--object", default=None, help="the object's mesh (default: the file's metadata)")
    p.add_argument("--out", type=Path, default=None, metavar="FILE",
                   help="write here instead of replacing FILE (same format)")
    opt.add_seed(p, "seed of the simulation")
    p.add_argument("--workers", type=opt.integer(1, "an integer >= 1"), default=None, metavar="N",
                   help="worker processes (default: one per core)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no summary")
    return p


def run(args) -> int:
    try:
        from .. import sim
    except ImportError as exc:  # mujoco or coacd missing
        raise ValueError(f"grasp-jax simulate needs MuJoCo and CoACD: pip install 'grasp_jax[sim]' ({exc})") from None

    storage.check_input_path(args.file)
    if args.out is not None:
        storage.check_output_path(args.out)
    meta = storage.ResultFile(args.file).metadata
    spec = args.object or meta.get("object")
    if spec is None:
        raise ValueError(f"{str(args.file)!r} names no object: pass --object")
    obj = load_object(spec)
    if obj.dim != 3:
        raise ValueError(f"simulation needs a 3D object; {spec!r} is {obj.dim}D")
    path = sim.add_sim_columns(args.file, obj, out=args.out, seed=args.seed, workers=args.workers,
                               progress=not args.quiet, mesh_name=str(spec))
    success = np.asarray(storage.ResultFile(path).read(["sim_success"])["sim_success"], bool)
    say(args, f"{int(success.sum()):,} of {len(success):,} grasps hold ({100 * success.mean():.1f}%); wrote {path}")
    return 0
