"""Hand grasps: grasp_jax's closure objective against DexGraspNet's energy, real hands, YCB objects.

For each hand (Allegro, LEAP, the built-in default hand) and each YCB object of hand size in
``../shared/data/meshes``: ``grasp_jax.hands.synthesize`` from the same starts with
``objective="closure"`` (grasp_jax's force-closure objective, the same LPs as ``gj.optimize``)
and ``objective="dfc"`` (DexGraspNet's energy), scored by ``gj.evaluate`` (soft contacts,
mu = 0.5) on the mesh. Valid = the fingers within 2 mm of the surface (at least two) force-closure,
penetration <= 1 mm.
Reports valid rate, Q, penetration, distinct valid grasps (``HandGraspResult.distinct``: none
within 1 cm and 15 degrees of another's wrist pose), valid grasps per second (compilation
included; a total per hand and objective over the run) and the programs compiled for each object (0 after the first object: the SDF grid is data). Writes
``results.md``, ``results.json`` and ``best_grasps.png``.

    python experiments/hand_grasps.py --hands allegro --starts 256 --steps 200
    python experiments/hand_grasps.py --hands allegro --objectives dfc --dfc-steps 266 --out ...  # equal time
    python experiments/hand_grasps.py --hands leap --starts 64 --steps 200 --objects ycb_013_apple ...
"""

from __future__ import annotations

import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from _common import SHARED_MESHES, Timer, parser, table, write, write_json

from grasp_jax import _batch, hands, objects
from grasp_jax.hands import _geometry
from grasp_jax.hands._kinematics import forward

HANDS_DIR = SHARED_MESHES.parent / "hands"
HANDS = {
    "allegro": HANDS_DIR / "allegro_hand" / "allegro_hand_right.urdf",
    "leap": HANDS_DIR / "leap_hand" / "leap_hand_right.urdf",
    "default": "default",
}
#: The YCB objects of hand size: every ``ycb_*`` mesh whose largest extent is at most this (m).
HAND_SIZE = 0.125


def hand_size_objects() -> list[str]:
    names = []
    for path in sorted(SHARED_MESHES.glob("ycb_*.obj")):
        if objects.load(path).mesh.extents.max() <= HAND_SIZE:
            names.append(path.stem)
    return names


def run_one(hand, obj, args, objective):
    before = _batch.STATS["compiled"]
    t0 = time.perf_counter()
    steps = args.dfc_steps if objective == "dfc" and args.dfc_steps else args.steps
    result = hands.synthesize(hand, obj, starts=args.starts, steps=steps, seed=args.seed, objective=objective)
    seconds = time.perf_counter() - t0
    s = result.summary()
    return result, {
        "objective": objective, "steps": steps, "valid_fraction": s["valid_fraction"],
        "force_closure_fraction": s["force_closure_fraction"], "quality_median_valid": s["quality_median_valid"],
        "penetration_median_mm": s["penetration_median_mm"], "distinct_valid": s["distinct_valid"],
        "distance_median_mm": float(1e3 * np.median(np.abs(result.distance).max(axis=1))),
        "seconds": seconds, "valid_per_second": float(result.valid.sum() / seconds),
        "compiled": _batch.STATS["compiled"] - before, "status": s["status"],
    }


def draw(ax, hand, result, index, obj):
    """The object's mesh and the posed hand's collision geometry of grasp ``index``."""
    mesh = obj.mesh
    if len(mesh.faces) > 2000:
        mesh = mesh.simplify_quadric_decimation(face_count=2000)
    ax.plot_trisurf(*mesh.vertices.T, triangles=mesh.faces, color="tab:orange", alpha=1.0, linewidth=0)
    pose = np.concatenate([result.position[index], result.quaternion[index]])
    frames = np.asarray(forward(hand, pose, result.joints[index]))
    for c in hand.collisions:
        m = _geometry.element_mesh(c)
        m = m.simplify_quadric_decimation(face_count=200) if len(m.faces) > 400 else m
        v = (frames[c.link][:3, :3] @ m.vertices.T).T + frames[c.link][:3, 3]
        ax.plot_trisurf(*v.T, triangles=m.faces, color="tab:blue", alpha=0.25, linewidth=0)
    ax.scatter(*result.points[index].T, color="red", s=30, depthshade=False)
    lo, hi = mesh.bounds[0] - 0.06, mesh.bounds[1] + 0.06
    center, half = (lo + hi) / 2, (hi - lo).max() / 2
    for set_lim, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), center):
        set_lim(c - half, c + half)
    ax.set_axis_off()


def main():
    ap = parser("hand_grasps", __doc__)
    ap.add_argument("--starts", type=int, default=256)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--hands", nargs="+", default=list(HANDS), choices=list(HANDS))
    ap.add_argument("--objects", nargs="+", default=None, help="mesh stems (default: every YCB object of hand size)")
    ap.add_argument("--objectives", nargs="+", default=["closure", "dfc"], choices=["closure", "dfc"],
                    help="grasp_jax's closure objective and/or DexGraspNet's energy (the baseline)")
    ap.add_argument("--dfc-steps", type=int, default=None,
                    help="steps of DexGraspNet's energy (default --steps; more for a comparison at equal time)")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    timer = Timer()
    args.objects = args.objects or hand_size_objects()
    rows, records, best = [], [], []
    for hand_name in args.hands:
        hand = hands.load(HANDS[hand_name])
        for obj_name in args.objects:
            obj = objects.load(SHARED_MESHES / f"{obj_name}.obj")
            for objective in args.objectives:
                result, rec = run_one(hand, obj, args, objective)
                rec.update(hand=hand_name, object=obj_name)
                records.append(rec)
                print(hand_name, obj_name, objective, result, flush=True)
                rows.append([hand_name, obj_name, objective, 100 * rec["valid_fraction"],
                             100 * rec["force_closure_fraction"], rec["quality_median_valid"],
                             rec["penetration_median_mm"], rec["distance_median_mm"], rec["distinct_valid"],
                             rec["valid_per_second"],
                             rec["seconds"], rec["compiled"]])
                if objective == "closure" and len(result.best()):
                    best.append((hand, hand_name, obj_name, obj, result, int(result.best()[0])))
        timer.lap(hand_name)
    header = ["hand", "object", "objective", "valid %", "force-closure %", "Q median (valid)",
              "penetration median (mm)", "largest contact distance median (mm)",
              "distinct valid (1 cm, 15 deg)", "valid grasps/s",
              "seconds (compile incl.)", "programs compiled"]
    totals = []
    for hand_name in args.hands:
        for objective in ("closure", "dfc"):
            runs = [r for r in records if r["hand"] == hand_name and r["objective"] == objective]
            if runs:
                valid = sum(r["valid_fraction"] * args.starts for r in runs)
                seconds = sum(r["seconds"] for r in runs)
                totals.append([hand_name, objective, len(runs), 100 * valid / (args.starts * len(runs)), valid / seconds,
                               seconds])
    dfc = f" (DexGraspNet's energy: {args.dfc_steps})" if args.dfc_steps else ""
    text = (f"# Hand grasps\n\n{args.starts} starts x {args.steps} steps{dfc} per hand and object; soft contacts, "
            f"mu = 0.5; valid = the fingers within 2 mm force-closure, penetration <= 1 mm.\n\n"
            + table(header, rows) + "\n\n## Over the run (compilation included)\n\n"
            + table(["hand", "objective", "objects", "valid %", "valid grasps/s", "seconds"], totals) + "\n\n"
            + timer.report() + "\n")
    print(text)
    write(args.out, text)
    write_json(args.out, {"starts": args.starts, "steps": args.steps, "dfc_steps": args.dfc_steps or args.steps,
                          "runs": records})
    if best:
        cols = min(4, len(best))
        fig = plt.figure(figsize=(4 * cols, 4 * ((len(best) + cols - 1) // cols)))
        for k, (hand, hand_name, obj_name, obj, result, index) in enumerate(best):
            ax = fig.add_subplot((len(best) + cols - 1) // cols, cols, k + 1, projection="3d")
            draw(ax, hand, result, index, obj)
            ax.set_title(f"{hand_name} / {obj_name[4:]}\nQ = {result.quality[index]:.3f}", fontsize=9)
        fig.tight_layout()
        fig.savefig(Path(args.out) / "best_grasps.png", dpi=110)


if __name__ == "__main__":
    main()
