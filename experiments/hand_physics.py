"""Do synthesized hand grasps hold in MuJoCo? ``grasp_jax.hands.synthesize`` then ``grasp_jax.sim``.

For each hand (Allegro, LEAP by default) and each YCB object: ``--starts`` starts x ``--steps``
steps of ``hands.synthesize`` (grasp_jax's closure objective, soft contacts, mu = 0.5), then every
valid grasp (the fingers within 2 mm of the surface force-closure, penetration <= 1 mm) is
simulated by ``sim.simulate_hand`` (default ``Protocol``: the hand's joints under position control,
gain ``hand_kp``, pre-grasp -> grasp -> squeeze, then the six forces). Reported: valid grasps, the
held rate among them (BODex's benchmark: above 75%), split by whether every finger touches and by
whether the fingers were closed after the optimization, the statuses, the held rate per direction,
and the AUC of Q for held among the valid ones; the invalid
grasps are simulated too, for contrast. Writes ``results.md`` and ``results.json``.

    python experiments/hand_physics.py [--starts 64] [--steps 100] [--hands allegro leap]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import SHARED_MESHES, Timer, parser, table, use_cpu_cores, write, write_json  # noqa: E402
from labels_vs_physics import auc  # noqa: E402

HANDS_DIR = SHARED_MESHES.parent / "hands"
HANDS = {
    "allegro": HANDS_DIR / "allegro_hand" / "allegro_hand_right.urdf",
    "leap": HANDS_DIR / "leap_hand" / "leap_hand_right.urdf",
    "default": "default",
}
OBJECTS = ("ycb_013_apple", "ycb_005_tomato_soup_can", "ycb_077_rubiks_cube")


def main(argv=None):
    ap = parser("hand_physics", __doc__)
    ap.add_argument("--starts", type=int, default=64)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--hands", nargs="+", default=["allegro", "leap"], choices=list(HANDS))
    ap.add_argument("--objects", nargs="+", default=list(OBJECTS))
    ap.add_argument("--threshold", type=float, default=0.05, help="CoACD threshold")
    ap.add_argument("--workers", type=int, default=None)
    args = ap.parse_args(argv)
    use_cpu_cores()

    import warnings

    import numpy as np

    from grasp_jax import hands, objects, sim

    timer = Timer()
    protocol = sim.Protocol(decomposition=sim.Decomposition(threshold=args.threshold))
    rows, records = [], []
    for hand_name in args.hands:
        hand = hands.load(HANDS[hand_name])
        for obj_name in args.objects:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                obj = objects.load(SHARED_MESHES / f"{obj_name}.obj")
            t = time.perf_counter()
            result = hands.synthesize(hand, obj, starts=args.starts, steps=args.steps, seed=args.seed)
            synth_s = time.perf_counter() - t
            valid = np.flatnonzero(np.asarray(result.valid, bool))
            rec = {"hand": hand_name, "object": obj_name, "starts": args.starts, "valid": len(valid),
                   "synthesize_s": synth_s}
            t = time.perf_counter()
            every = sim.simulate_hand(hand, obj, result, protocol=protocol, seed=args.seed, workers=args.workers)
            invalid = np.setdiff1d(np.arange(args.starts), valid)
            rec.update(invalid_held_rate=float(every.success[invalid].mean()) if len(invalid) else float("nan"),
                       invalid_penetration=int(np.sum(every.status[invalid] == sim.SimStatus.PENETRATION)))
            if len(valid):
                res = sim.SimResult(*(a[valid] for a in every))
                rec.update(held=int(res.success.sum()), held_rate=float(res.success.mean()),
                           status={s.name: int(np.sum(res.status == s)) for s in sim.SimStatus},
                           directions_held=res.directions.mean(axis=0).tolist(),
                           q_auc=auc(np.asarray(result.quality)[valid], res.success),
                           # the valid grasps whose every finger touches, and those with one that does not
                           **{f"{name}_held": [int(res.success[m].sum()), int(m.sum())] for name, m in
                              (("all_touch", result.active[valid].all(axis=1)),
                               ("some_hover", ~result.active[valid].all(axis=1)),
                               ("closed", result.closed[valid]), ("as_optimized", ~result.closed[valid]))},
                           simulate_s=time.perf_counter() - t)
            records.append(rec)
            print(rec, flush=True)
            rows.append([hand_name, obj_name, rec["valid"], rec.get("held", 0), rec.get("held_rate", float("nan")),
                         rec["invalid_held_rate"], "{}/{}".format(*rec.get("all_touch_held", (0, 0))),
                         "{}/{}".format(*rec.get("some_hover_held", (0, 0))),
                         "{}/{}".format(*rec.get("closed_held", (0, 0))),
                         "{}/{}".format(*rec.get("as_optimized_held", (0, 0))),
                         rec.get("status", {}).get("NO_CONTACT", 0), rec.get("status", {}).get("PENETRATION", 0),
                         rec.get("q_auc", float("nan")), synth_s, rec.get("simulate_s", 0.0)])
        timer.lap(hand_name)
    valid = sum(r["valid"] for r in records)
    held = sum(r.get("held", 0) for r in records)
    header = ["hand", "object", "valid", "held", "held rate", "held rate of the invalid",
              "held / valid, every finger touching", "held / valid, a finger not touching",
              "held / valid, fingers closed", "held / valid, as optimized", "no contact",
              "penetration", "AUC of Q",
              "synthesize s", "simulate s"]
    text = (f"# Synthesized hand grasps in MuJoCo\n\n{args.starts} starts x {args.steps} steps; "
            f"held {held} of {valid} valid grasps ({held / max(valid, 1):.1%}).\n\n" + table(header, rows)
            + "\n\n" + timer.report())
    print(text)
    write(args.out, text)
    write_json(args.out, {"settings": {k: str(v) for k, v in vars(args).items()}, "protocol": repr(protocol),
                          "runs": records, "held": held, "valid": valid})


if __name__ == "__main__":
    main()
