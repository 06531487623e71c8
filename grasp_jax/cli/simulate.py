"""``grasp-jax simulate``: does each grasp hold in MuJoCo? Adds ``sim_success``, ``sim_status`` and
one column per force direction to a result file of jaw or hand grasps, or to every part of a
dataset folder, atomically."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import storage
from . import _options as opt
from ._common import load_object, say

#: Columns that make a result file one of hand grasps (``grasp-jax hand --out``).
_HAND_FIELDS = ("quaternion", "joints", "pregrasp")


def add_parser(subparsers):
    p = subparsers.add_parser("simulate", help="check in MuJoCo whether the grasps of a result file hold",
                              description="Replay every grasp of FILE in MuJoCo (pre-grasp, close, squeeze, then a "
                                          "force along +-x, +-y, +-z in turn) and add sim_success, sim_status and "
                                          "the per-direction outcomes to it, atomically. FILE: parallel-jaw grasps "
                                          "(grasp-jax sample --gripper parallel-jaw), hand grasps (grasp-jax hand "
                                          "--out), or a dataset folder (grasp-jax dataset: every part). Needs "
                                          "pip install 'grasp_jax[sim]'.",
                              formatter_class=opt.Formatter)
    p.add_argument("file", metavar="FILE", type=Path, help="a result file (.npz or .parquet) or a dataset folder")
    p.add_argument("--object", default=None,
                   help="the object's mesh (default: the file's metadata; a dataset's own objects)")
    p.add_argument("--hand", default=None, metavar="HAND",
                   help="for hand grasps: the URDF or MJCF file, or 'default' (default: the file's hand if built in)")
    p.add_argument("--out", type=Path, default=None, metavar="FILE",
                   help="write here instead of replacing FILE (same format; not for a dataset folder)")
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
    if args.file.is_dir():
        return _dataset(args, sim)
    storage.check_input_path(args.file)
    if args.out is not None:
        storage.check_output_path(args.out)
    source = storage.ResultFile(args.file)
    spec = args.object or source.metadata.get("object_path") or source.metadata.get("object")
    if spec is None:
        raise ValueError(f"{str(args.file)!r} names no object: pass --object")
    try:
        obj = _object(spec)
    except ValueError as exc:
        if args.object is not None:
            raise
        raise ValueError(f"{str(args.file)!r} names the object {spec!r}, which cannot be loaded here ({exc}): "
                         "pass --object MESH") from None
    path = _simulate(args, sim, args.file, source, obj, str(spec), args.out)
    _report(args, path)
    return 0


def _object(spec):
    obj = load_object(spec) if not hasattr(spec, "dim") else spec
    if obj.dim != 3:
        raise ValueError(f"simulation needs a 3D object; {getattr(obj, 'name', spec)!r} is {obj.dim}D")
    return obj


def _simulate(args, sim, file: Path, source, obj, name: str, out) -> Path:
    """One result file through the jaw or the hand simulation (by its columns)."""
    options = {"out": out, "seed": args.seed, "workers": args.workers, "progress": not args.quiet,
               "mesh_name": name}
    if all(f in source.fields for f in _HAND_FIELDS):
        return sim.add_hand_sim_columns(file, _hand(args, source.metadata), obj, **options)
    return sim.add_sim_columns(file, obj, **options)


def _hand(args, meta: dict):
    from .. import hands

    spec = args.hand
    if spec is None:
        if meta.get("hand") != hands.DEFAULT_NAME:
            raise ValueError(f"the file's grasps are of the hand {meta.get('hand')!r}: pass --hand HAND.urdf")
        spec = hands.DEFAULT_NAME
    return hands.load(spec)


def _dataset(args, sim) -> int:
    """Every done part of a dataset folder, each on its own (scaled) object."""
    from .. import dataset

    if args.out is not None:
        raise ValueError("--out is for one result file; a dataset's parts are updated in place")
    found = dataset.parts(args.file)
    if not found:
        raise ValueError(f"{str(args.file)!r} has no finished object to simulate")
    for entry, part in found:
        obj = _object(dataset.load_entry(entry))
        say(args, f"{entry.name}:")
        path = _simulate(args, sim, part, storage.ResultFile(part), obj, entry.spec, None)
        _report(args, path)
    return 0


def _report(args, path: Path) -> None:
    success = np.asarray(storage.ResultFile(path).read(["sim_success"])["sim_success"], bool)
    share = 100 * success.mean() if len(success) else 0.0
    say(args, f"{int(success.sum()):,} of {len(success):,} grasps hold ({share:.1f}%); wrote {path}")
