"""Throughput of the MuJoCo check of jaw grasps (``grasp_jax.sim.simulate_jaws``).

Antipodal grasps of YCB meshes (``grasp_jax.grippers.antipodal_grasps``, collision-free bodies of
``ParallelJaw.scaled(--max-width)``) are simulated with 1 and with ``--workers`` processes; the
time includes starting the workers, not the convex decomposition (cached beforehand). Reported:
grasps/s per object and worker count, the statuses, and whether both runs agree.

    python experiments/bench_sim.py [--num 400] [--workers 2] [--threshold 0.05]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import SHARED_MESHES, parser, table, write, write_json  # noqa: E402

MESHES = ("ycb_006_mustard_bottle", "ycb_011_banana", "ycb_025_mug", "ycb_050_medium_clamp", "ycb_065-a_cups")


def main(argv=None):
    import numpy as np
    import trimesh

    from grasp_jax import grippers, sim

    ap = parser("bench_sim", __doc__)
    ap.add_argument("--num", type=int, default=400, help="antipodal candidates per object")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--max-width", type=float, default=0.1)
    ap.add_argument("--threshold", type=float, default=0.05, help="CoACD threshold")
    ap.add_argument("--objects", nargs="*", default=MESHES)
    args = ap.parse_args(argv)
    gripper = grippers.ParallelJaw.scaled(args.max_width)
    protocol = sim.Protocol(decomposition=sim.Decomposition(threshold=args.threshold))
    rows, data = [], {}
    for name in args.objects:
        tm = trimesh.load(SHARED_MESHES / f"{name}.obj", force="mesh")
        obj = sim.sim_object(tm, params=protocol.decomposition)
        g = grippers.antipodal_grasps(tm, args.num, mu=0.5, gripper=gripper, seed=args.seed, collision=True)
        ok = g.status == grippers.JawStatus.OK
        poses = (g.centers[ok], g.axes[ok], g.approaches[ok], g.widths[ok])
        out = {}
        for workers in (1, args.workers):
            t = time.perf_counter()
            res = sim.simulate_jaws(tm, *poses, gripper=gripper, protocol=protocol, seed=args.seed, workers=workers)
            out[workers] = (res, time.perf_counter() - t)
        (r1, t1), (r2, t2) = out[1], out[args.workers]
        same = all(np.array_equal(getattr(r1, f), getattr(r2, f), equal_nan=True) for f in sim.SimResult._fields)
        k = int(ok.sum())
        counts = np.bincount(r1.status, minlength=len(sim.SimStatus))
        rows.append([name, len(obj.parts), k, k / t1, k / t2, float(r1.success.mean()), *counts.tolist(), same])
        data[name] = {"parts": len(obj.parts), "grasps": k, "per_s_1": k / t1, f"per_s_{args.workers}": k / t2,
                      "success": float(r1.success.mean()), "status_counts": counts.tolist(), "agree": same}
        print(table(["object", "parts", "grasps", "1 worker /s", f"{args.workers} workers /s", "held",
                     *[s.name for s in sim.SimStatus], "agree"], rows[-1:]), flush=True)
    text = table(["object", "parts", "grasps", "1 worker /s", f"{args.workers} workers /s", "held",
                  *[s.name for s in sim.SimStatus], "agree"], rows)
    print(text)
    write(args.out, "# MuJoCo check of jaw grasps: throughput\n\n" + text)
    write_json(args.out, {"args": vars(args), "objects": data})


if __name__ == "__main__":
    main()
