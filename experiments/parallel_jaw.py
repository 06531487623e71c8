"""Parallel-jaw grasps of YCB objects: grasp_jax's labels beside Dex-Net's and GraspNet's.

For each YCB mesh of ``../shared/data/meshes``: ``--num`` antipodal candidates
(``grasp_jax.grippers.antipodal_grasps``, closing directions in the friction cone of
``--sample-mu``, a gripper opening of ``--max-width`` m), and on the contacts of those with two
contacts (``JawStatus.OK``):

* grasp_jax: the verdict of two **soft** contacts at ``--mu`` (``gj.evaluate(contact="soft")``,
  torsion ``gj.patch_torsion(--patch-radius, --mu)``, 8-edge pyramids), the critical friction
  ``gj.critical_friction`` (same torsion, held fixed) and its GraspNet label ``gj.friction_label``;
* Dex-Net's antipodal test (``PointGraspMetrics3D.force_closure``, re-implemented in NumPy, with
  its ``use_abs_value=True``): the closing line inside both **circular** friction cones;
* GraspNet-1Billion's list procedure: the smallest ``mu`` of 0.2, 0.4, ..., 1.2 at which
  Dex-Net's test passes (-1 where none).

Reported: agreement counts (verdicts at ``--mu``; labels equal, within one level), grasps/s of
each, ``results.json``, ``results.md`` and ``parallel_jaw.png`` (grasp_jax's critical friction
against Dex-Net's, ``max(tan alpha_1, tan alpha_2)``). What to expect: an 8-edge pyramid is
inscribed in the cone, so grasp_jax needs up to ``1 / cos(pi / 8) = 1.082`` times Dex-Net's
friction, less by the torsion's help (about ``0.33 torsion / |c_2 - c_1|``).

    python experiments/parallel_jaw.py [--num 2000] [--out DIR]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import SHARED_MESHES, Timer, parser, table, use_cpu_cores, write, write_json  # noqa: E402

MESHES = ("ycb_006_mustard_bottle", "ycb_011_banana", "ycb_025_mug", "ycb_050_medium_clamp", "ycb_065-a_cups")
GRASPNET = (0.2, 0.4, 0.6, 0.8, 1.0, 1.2)


def dexnet_force_closure(points, normals, mu, use_abs_value=True):
    """Dex-Net's ``PointGraspMetrics3D.force_closure`` for ``(k, 2, 3)`` contacts: for each contact,
    the angle between its inward normal and the line to the other contact is at most
    ``atan(mu)``. ``(k,) bool``."""
    import numpy as np

    p1, p2 = points[:, 0], points[:, 1]
    ok = ~np.all(p1 == p2, axis=1)
    for normal, contact, other in ((-normals[:, 0], p1, p2), (-normals[:, 1], p2, p1)):
        diff = other - contact
        proj = np.einsum("ij,ij->i", normal, diff) / np.linalg.norm(normal, axis=1)
        if use_abs_value:
            proj = np.abs(proj)
        with np.errstate(invalid="ignore", divide="ignore"):
            alpha = np.arccos(np.clip(proj / np.linalg.norm(diff, axis=1), -1, 1))
        ok &= (proj >= 0) & (alpha <= np.arctan(mu))
    return ok


def dexnet_critical(points, normals):
    """The smallest ``mu`` at which :func:`dexnet_force_closure` passes: ``max(tan alpha_i)``."""
    import numpy as np

    d = points[:, 1] - points[:, 0]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    tans = []
    for normal, direction in ((-normals[:, 0], d), (-normals[:, 1], -d)):
        c = np.abs(np.einsum("ij,ij->i", normal, direction))
        tans.append(np.sqrt(np.maximum(1 - c * c, 0)) / np.maximum(c, 1e-300))
    return np.maximum(*tans)


def graspnet_label(points, normals, levels=GRASPNET):
    """GraspNet-1Billion's procedure: try the levels in turn with Dex-Net's test; the first that
    passes, -1 where none."""
    import numpy as np

    label = np.full(len(points), -1.0)
    todo = np.ones(len(points), bool)
    for mu in levels:
        passed = todo & dexnet_force_closure(points, normals, mu)
        label[passed] = mu
        todo &= ~passed
    return label


def _rate(fn, count, repeat=1):
    t = time.perf_counter()
    for _ in range(repeat):
        out = fn()
    return out, count * repeat / (time.perf_counter() - t)


def main():
    ap = parser("parallel_jaw", __doc__)
    ap.add_argument("--num", type=int, default=2000, help="antipodal candidates per mesh")
    ap.add_argument("--mu", type=float, default=0.5, help="friction of the verdicts")
    ap.add_argument("--sample-mu", type=float, default=1.0, help="friction cone the closing directions are drawn in")
    ap.add_argument("--max-width", type=float, default=0.085, help="gripper opening (m)")
    ap.add_argument("--patch-radius", type=float, default=0.005, help="soft contact patch radius (m)")
    ap.add_argument("--meshes", nargs="+", default=list(MESHES))
    args = ap.parse_args()
    use_cpu_cores()

    import warnings

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    import grasp_jax as gj
    from grasp_jax import grippers, objects

    timer = Timer()
    gripper = grippers.ParallelJaw(args.max_width)
    torsion = float(gj.patch_torsion(args.patch_radius, args.mu))
    # compile once, outside the timings
    warm = np.array([[[-0.03, 0, 0], [0.03, 0.001, 0]]])
    gj.evaluate(warm, warm / 0.03, mu=args.mu, contact="soft", torsion=torsion)
    gj.critical_friction(warm, warm / 0.03, contact="soft", torsion=torsion)
    timer.lap("compile")
    results, rows, scatter = {}, [], {}
    for name in args.meshes:
        path = SHARED_MESHES / f"{name}.obj"
        if not path.is_file():
            print(f"skip {name}: {path} not found")
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            obj = objects.load(path)
        grasps, sample_rate = _rate(lambda: grippers.antipodal_grasps(obj, args.num, mu=args.sample_mu,
                                                                      gripper=gripper, seed=args.seed), args.num)
        ok = grasps.status == grippers.JawStatus.OK
        p, n = grasps.points[ok], grasps.normals[ok]
        k = int(ok.sum())
        res, eval_rate = _rate(lambda: gj.evaluate(p, n, mu=args.mu, contact="soft", torsion=torsion), k)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            (mu_star, status), crit_rate = _rate(
                lambda: gj.critical_friction(p, n, contact="soft", torsion=torsion), k)
        mu_star, status = np.asarray(mu_star), np.asarray(status)
        label = gj.friction_label(mu_star)
        dex, dex_rate = _rate(lambda: dexnet_force_closure(p, n, args.mu), k, repeat=20)
        gn, gn_rate = _rate(lambda: graspnet_label(p, n), k, repeat=20)
        dex_mu = dexnet_critical(p, n)
        fc = np.asarray(res.force_closure)
        levels = np.array(GRASPNET)

        def level_index(x):
            return np.where(x < 0, len(levels), np.searchsorted(levels, x))

        gap = np.abs(level_index(label) - level_index(gn))
        finite = np.isfinite(mu_star) & (dex_mu < 2.0)
        ratio = mu_star[finite] / np.maximum(dex_mu[finite], 1e-12)
        entry = {
            "candidates": int(args.num),
            "status_counts": {s.name: int(np.sum(grasps.status == s)) for s in grippers.JawStatus},
            "two_contacts": k,
            "verdicts": {"grasp_jax_soft": int(fc.sum()), "dexnet": int(dex.sum()),
                         "agree": int(np.sum(fc == dex)), "grasp_jax_only": int(np.sum(fc & ~dex)),
                         "dexnet_only": int(np.sum(~fc & dex))},
            "labels": {"equal": int(np.sum(gap == 0)), "within_one_level": int(np.sum(gap <= 1)),
                       "grasp_jax_higher": int(np.sum(level_index(label) > level_index(gn))),
                       "grasp_jax_lower": int(np.sum(level_index(label) < level_index(gn)))},
            "critical_status_counts": {s.name: int(np.sum(status == s)) for s in gj.FrictionStatus},
            "critical_warnings": [str(w.message) for w in caught],
            "mu_ratio_grasp_jax_over_dexnet": {"min": float(ratio.min()) if ratio.size else None,
                                               "median": float(np.median(ratio)) if ratio.size else None,
                                               "max": float(ratio.max()) if ratio.size else None},
            "grasps_per_second": {"antipodal_sampler": sample_rate, "evaluate_soft": eval_rate,
                                  "critical_friction": crit_rate, "dexnet_test": dex_rate,
                                  "graspnet_list": gn_rate},
        }
        results[name] = entry
        scatter[name] = (dex_mu, mu_star)
        v, lab, r = entry["verdicts"], entry["labels"], entry["grasps_per_second"]
        rows.append([name, k, v["grasp_jax_soft"], v["dexnet"], v["agree"], lab["equal"], lab["within_one_level"],
                     r["antipodal_sampler"], r["evaluate_soft"], r["critical_friction"], r["dexnet_test"],
                     r["graspnet_list"]])
        timer.lap(name)
        print(name, entry["verdicts"], entry["labels"], flush=True)

    meta = {"num": args.num, "mu": args.mu, "sample_mu": args.sample_mu, "max_width": args.max_width,
            "patch_radius": args.patch_radius, "torsion": torsion, "num_edges": 8, "seed": args.seed,
            "graspnet_levels": list(GRASPNET)}
    write_json(args.out, {"settings": meta, "meshes": results})

    fig, ax = plt.subplots(figsize=(6.2, 5.4), dpi=120)
    for name, (dex_mu, mu_star) in scatter.items():
        keep = np.isfinite(mu_star) & (dex_mu < 1.5)
        ax.scatter(dex_mu[keep], mu_star[keep], s=4, alpha=0.5, label=name.replace("ycb_", ""))
    line = np.linspace(0, 1.5, 10)
    ax.plot(line, line, "k-", lw=0.8, label="equal")
    ax.plot(line, line / np.cos(np.pi / 8), "k--", lw=0.8, label="1 / cos(pi/8)")
    for level in GRASPNET:
        ax.axvline(level, color="0.85", lw=0.6, zorder=0)
        ax.axhline(level, color="0.85", lw=0.6, zorder=0)
    ax.set_xlim(0, 1.5)
    ax.set_ylim(0, 1.5)
    ax.set_xlabel("Dex-Net's critical friction max(tan alpha_i) (circular cones)")
    ax.set_ylabel("grasp_jax critical friction (soft, 8-edge pyramids)")
    ax.set_title(f"parallel-jaw grasps of YCB objects (torsion {torsion:.2g} m)", fontsize=10)
    ax.legend(fontsize=7, markerscale=3)
    fig.tight_layout()
    args.out.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out / "parallel_jaw.png")
    plt.close(fig)

    header = ["mesh", "2 contacts", "FC soft", "FC Dex-Net", "verdicts agree", "labels equal", "labels +/-1",
              "sampler /s", "evaluate /s", "critical /s", "Dex-Net /s", "GraspNet list /s"]
    text = [__doc__.split("\n\n")[0], "", f"Settings: {meta}", "", table(header, rows), "",
            "![grasp_jax against Dex-Net](parallel_jaw.png)", "", timer.report()]
    print(write(args.out, "\n".join(text)))


if __name__ == "__main__":
    main()
