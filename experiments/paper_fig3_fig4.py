"""Central-axis distributions of force-closure and non-force-closure grasps (paper Fig. 3 and 4).

2D (friction 10 deg, as the paper's Fig. 3): a 2-finger, a 3-finger and a 4-finger grasp that are
not force-closure and a 4-finger force-closure grasp on the built-in quadrilateral. 3D (20 deg,
Fig. 4): a 3-finger and a 4-finger non-force-closure grasp and a force-closure grasp on the
built-in mechanical part. Grasps are drawn at random (``grasp_jax.sampling``) and labelled by
``gj.evaluate``; each example is picked by rank, not by hand: the force-closure one has the median
Q, the non-force-closure ones the 75th percentile of the signed margin ``delta`` (so they are not the
hopeless kind with ``delta = -1``).

For each grasp: the central axes of 20,000 random grasp wrenches (``plotting.central_axes_2d/3d``)
and two coverage figures: *sampled*, the fraction of the dual plane's upper triangle (2D, 36 x 36
cells) or of the sphere's (entry cell, exit cell) pairs (3D, 18 equal-area cells) that the random
axes hit, and *reachable*, the fraction of cells shown to hold a line the grasp can generate as a
central axis (a sampled axis, or a test line that passes an NNLS membership test). The paper's
claim (Section III-C) is that a grasp is force-closure iff it generates every central axis:
reachable = 100% exactly for force-closure grasps. A check over many random grasps per finger
count closes the report.

    python experiments/paper_fig3_fig4.py [--out DIR] [--samples 20000] [--check 40]
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import Timer, mu_of, parser, table, write  # noqa: E402


def main():
    ap = parser("paper_fig3_fig4", __doc__)
    ap.add_argument("--samples", type=int, default=20000, help="random wrenches per example grasp")
    ap.add_argument("--pool", type=int, default=400, help="random grasps drawn to pick examples from")
    ap.add_argument("--check", type=int, default=40, help="random grasps per finger count in the check")
    ap.add_argument("--edges", type=int, default=8, help="cone edges in 3D")
    ap.add_argument("--object2d", default="quad")
    ap.add_argument("--object3d", default="part")
    args = ap.parse_args()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    import grasp_jax as gj
    from grasp_jax import objects, plotting, sampling

    timer = Timer()
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    mu2, mu3 = mu_of(10.0), mu_of(20.0)
    obj2, obj3 = objects.load(args.object2d), objects.load(args.object3d)
    bins, bands = 36, 3

    def pick(obj, fingers, want_fc, mu, num_edges, seed):
        """The median grasp of the wanted class among ``args.pool`` random ones."""
        p, n = sampling.sample_grasps(obj, args.pool, fingers, seed=seed)
        ev = gj.evaluate(p, n, mu=mu, num_edges=num_edges)
        fc = np.asarray(ev.force_closure) & np.asarray(ev.converged)
        ok = np.nonzero(fc if want_fc else (~fc & np.asarray(ev.converged)))[0]
        if len(ok) == 0:
            raise SystemExit(f"no {'force-closure' if want_fc else 'non-force-closure'} {fingers}-finger "
                             f"grasp among {args.pool} on {obj.name}; raise --pool")
        key = np.asarray(ev.quality if want_fc else ev.delta)[ok]
        k = ok[np.argsort(key)[(len(ok) * (2 if want_fc else 3)) // 4]]
        return p[k], n[k], bool(fc[k]), float(ev.quality[k]), float(ev.delta[k])

    rows, lines = [], []
    # ------------------------------------------------------------------ 2D, Fig. 3
    cases2 = [(2, False), (3, False), (4, False), (4, True)]
    fig, axes = plt.subplots(2, len(cases2), figsize=(3.6 * len(cases2), 7.4), dpi=110)
    for col, (fingers, want_fc) in enumerate(cases2):
        p, n, fc, q, delta = pick(obj2, fingers, want_fc, mu2, args.edges, args.seed + col)
        label = "force-closure" if fc else "not force-closure"
        plotting.plot_grasp_2d(obj2, p, n, mu=mu2, quality=q, ax=axes[0, col], title=label)
        t1, t2 = plotting.central_axes_2d(p, n, mu=mu2, samples=args.samples, seed=args.seed)
        reach = plotting.reachable_axes_2d(p, n, mu=mu2, bins=bins)
        reach |= plotting.dual_plane_hits(t1, t2, bins)  # sampled axes are reachable lines too
        sampled = plotting.dual_plane_coverage(t1, t2, bins)
        reachable = float(reach[np.triu(np.ones((bins, bins), bool))].mean())
        plotting.plot_central_axes_2d(p, n, mu=mu2, samples=args.samples, seed=args.seed, ax=axes[1, col],
                                      bins=bins, title=f"({'abcd'[col]}) {fingers} fingers, {label}")
        rows.append([f"2D {obj2.name}", f"({'abcd'[col]})", fingers, fc, q, delta, sampled, reachable])
    fig.tight_layout()
    fig.savefig(out / "fig3_2d_central_axes.png", bbox_inches="tight")
    plt.close(fig)
    timer.lap("2D examples")

    # ------------------------------------------------------------------ 3D, Fig. 4
    cases3 = [(3, False), (4, False), (4, True)]
    fig = plt.figure(figsize=(14.5, 3.5 * len(cases3)), dpi=100)
    grid = fig.add_gridspec(len(cases3), 4, width_ratios=[1.0, 1.2, 1.2, 0.75])
    for row, (fingers, want_fc) in enumerate(cases3):
        p, n, fc, q, delta = pick(obj3, fingers, want_fc, mu3, args.edges, args.seed + 10 + row)
        label = "force-closure" if fc else "not force-closure"
        ax3 = fig.add_subplot(grid[row, 0], projection="3d")
        plotting.plot_grasp_3d(obj3, p, n, mu=mu3, num_edges=args.edges, quality=q, ax=ax3, title=label)
        axes = [fig.add_subplot(grid[row, k]) for k in (1, 2, 3)]
        entry, exit_ = plotting.central_axes_3d(p, n, mu=mu3, num_edges=args.edges, samples=args.samples,
                                                seed=args.seed)
        reach = plotting.reachable_axes_3d(p, n, mu=mu3, num_edges=args.edges, bands=bands)
        reach |= plotting.sphere_pair_hits(entry, exit_, bands)
        sampled = plotting.sphere_coverage(entry, exit_, bands)
        reachable = float(reach[~np.eye(len(reach), dtype=bool)].mean())
        plotting.plot_central_axes_3d(p, n, mu=mu3, num_edges=args.edges, samples=args.samples,
                                      seed=args.seed, axes=axes, bands=bands,
                                      title=f"({'abc'[row]}) {fingers} fingers, {label}")
        rows.append([f"3D {obj3.name}", f"({'abc'[row]})", fingers, fc, q, delta, sampled, reachable])
    fig.tight_layout()
    fig.savefig(out / "fig4_3d_central_axes.png", bbox_inches="tight")
    plt.close(fig)
    timer.lap("3D examples")

    # ------------------------------------------------------------------ check on many grasps
    check = []
    for dim, obj, mu, num_edges, counts in ((2, obj2, mu2, args.edges, (2, 3, 4)),
                                            (3, obj3, mu3, args.edges, (3, 4, 5))):
        for fingers in counts:
            p, n = sampling.sample_grasps(obj, args.check, fingers, seed=args.seed + 100 + fingers)
            ev = gj.evaluate(p, n, mu=mu, num_edges=num_edges)
            fc = np.asarray(ev.force_closure)
            conv = np.asarray(ev.converged)
            reach = np.zeros(len(p))
            for k in range(len(p)):
                if dim == 2:
                    r = plotting.reachable_axes_2d(p[k], n[k], mu=mu, bins=bins)
                    reach[k] = r[np.triu(np.ones((bins, bins), bool))].mean()
                else:
                    r = plotting.reachable_axes_3d(p[k], n[k], mu=mu, num_edges=num_edges, bands=bands)
                    reach[k] = r[~np.eye(len(r), dtype=bool)].mean()
            full = reach >= 1.0
            nf = ~fc & conv
            check.append([f"{dim}D {obj.name}", fingers, len(p), int(fc.sum()), int((fc & full).sum()),
                          int(nf.sum()), int((nf & ~full).sum()),
                          float(np.median(reach[nf])) if nf.any() else float("nan"),
                          float(reach[nf].max()) if nf.any() else float("nan"), int((~conv).sum())])
    timer.lap("check")

    lines.append("# Central axes of force-closure and non-force-closure grasps (paper Fig. 3, 4)\n")
    lines.append(f"2D: `{obj2.name}`, friction 10 deg (mu = {mu2:.3f}); 3D: `{obj3.name}`, 20 deg "
                 f"(mu = {mu3:.3f}), m = {args.edges} cone edges. {args.samples} random grasp wrenches per "
                 "grasp. *sampled*: fraction of the dual plane's upper triangle (36 x 36 cells) or of the "
                 "sphere's (entry, exit) cell pairs (18 equal-area cells, 306 ordered pairs) hit by a "
                 "sampled "
                 "central axis; *reachable*: the cells shown to hold a line that is the central axis of some "
                 "grasp wrench: a sampled axis, or one of 3 x 3 (2D) or 4 x 4 (3D) regularly spaced test "
                 "lines "
                 "per cell that passes an NNLS membership test. It is a lower bound of the truly reachable "
                 "fraction (a thin reachable sliver can slip between test lines) and exactly 100% for a "
                 "force-closure grasp.\n")
    lines.append("Figures: `fig3_2d_central_axes.png`, `fig4_3d_central_axes.png`.\n")
    lines.append(table(["object", "grasp", "fingers", "force-closure", "Q", "delta", "sampled", "reachable"],
                       rows))
    lines.append("\n## Check: reachable fraction on random grasps\n")
    lines.append("Proposition (Section III-C): force-closure iff every central axis can be generated. "
                 "Here *reachable* uses the test lines only (no sampling). "
                 "Columns: force-closure grasps whose every cell is reachable, non-force-closure grasps "
                 "with some unreachable cell. A non-force-closure grasp can still show 100% when its "
                 "unreachable lines are thinner than a cell (nearly force-closure grasps).\n")
    lines.append(table(["object", "fingers", "grasps", "FC", "FC with 100% reachable", "not FC",
                        "not FC with < 100%", "median reachable (not FC)", "max reachable (not FC)",
                        "unconverged"], check))
    lines.append("\n" + timer.report())
    path = write(out, "\n".join(lines))
    print(path.read_text())


if __name__ == "__main__":
    main()
