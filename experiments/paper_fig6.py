"""Planar grasps of the quadrilateral and the star with their quality Q2d (paper Fig. 6).

Friction 20 deg (mu = tan 20 deg). Grasps are drawn as in the paper (first contact fixed, the
other n - 1 uniform on the boundary: ``grasp_jax.sampling`` with ``scheme="uniform"``, then contact
1 replaced by one fixed point; the library's ``"paper"`` scheme uses facet centroids, which on a
polygon are just its edge midpoints), scored with ``gj.evaluate``
(Q, eq. 23) and with the Ferrari-Canny epsilon (``gj.ferrari_canny``, torques about the object's
centre divided by its radius). Three force-closure grasps per object are shown, picked as those whose
Q is nearest the paper's values: quadrilateral (a-c) Q = 0.940, 0.766, 0.538 (3 fingers), star (d-f)
Q = 0.939, 0.651, 0.394 (4 fingers). The table says whether epsilon ranks them as Q does (the paper
found it did on the quadrilateral: epsilon 0.173, 0.088, 0.026). Over ``--num`` random grasps per
object and finger count, the Spearman rank correlation of Q and epsilon among force-closure grasps.

    python experiments/paper_fig6.py [--out DIR] [--num 1000]
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import Timer, mu_of, parser, table, write  # noqa: E402

PAPER = {"quad": (3, (0.940, 0.766, 0.538)), "star": (4, (0.939, 0.651, 0.394))}
PAPER_EPS_QUAD = (0.173, 0.088, 0.026)



def _chain(values) -> str:
    """``0.9 > 0.7 < 0.8``: the values with the relation between neighbours."""
    text = f"{values[0]:.3f}"
    for a, b in zip(values[:-1], values[1:]):
        text += f" {'>' if a > b else '<' if a < b else '='} {b:.3f}"
    return text

def main():
    ap = parser("paper_fig6", __doc__)
    ap.add_argument("--num", type=int, default=1000, help="random grasps per object and finger count")
    ap.add_argument("--fingers", type=int, nargs="+", default=[3, 4])
    args = ap.parse_args()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from scipy.stats import spearmanr

    import grasp_jax as gj
    from grasp_jax import objects, plotting, sampling

    timer = Timer()
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    mu = mu_of(20.0)
    pools = {}
    for name in PAPER:
        obj = objects.load(name)
        # The paper: "we choose the first point c_1 and generate randomly the n - 1 contacts". The
        # library's "paper" scheme puts contacts at facet centroids, which on a polygon are only its
        # few edge midpoints, so here: contacts uniform on the boundary, then c_1 fixed for all.
        c1, n1 = obj.sample_surface(1, np.random.default_rng(args.seed))
        for fingers in sorted(set(args.fingers) | {PAPER[name][0]}):
            seed = args.seed + 1000 * fingers + (0 if name == "quad" else 1)
            p, n = sampling.sample_grasps(obj, args.num, fingers, seed=seed)
            p[:, 0], n[:, 0] = c1[0], n1[0]
            ev = gj.evaluate(p, n, mu=mu)
            fc = np.asarray(ev.force_closure) & np.asarray(ev.converged)
            eps = np.zeros(len(p))
            vol = np.zeros(len(p))
            eps[fc], vol[fc] = gj.ferrari_canny(p[fc], n[fc], mu=mu, origin=obj.center,
                                                torque_scale=obj.radius)
            pools[name, fingers] = obj, p, n, fc, np.asarray(ev.quality), eps, vol, int((~ev.converged).sum())
    timer.lap("sampling and scoring")

    examples, fig_rows = [], []
    fig, axes = plt.subplots(2, 3, figsize=(11.5, 8.4), dpi=110)
    for r, name in enumerate(PAPER):
        fingers, targets = PAPER[name]
        obj, p, n, fc, q, eps, vol, _ = pools[name, fingers]
        chosen = []
        for t in targets:
            cand = np.nonzero(fc)[0]
            cand = cand[np.all(np.abs(q[cand, None] - q[None, chosen]) > 1e-6, axis=1)] if chosen else cand
            chosen.append(int(cand[np.argmin(np.abs(q[cand] - t))]))
        for c, (k, t) in enumerate(zip(chosen, targets)):
            letter = "abcdef"[3 * r + c]
            plotting.plot_grasp_2d(obj, p[k], n[k], mu=mu, quality=q[k], ax=axes[r, c],
                                   title=f"eps = {eps[k]:.3f}")
            axes[r, c].set_title(f"({letter}) {name}, {fingers} fingers\nQ = {q[k]:.3f} (paper {t:.3f}), "
                                 f"eps = {eps[k]:.3f}", fontsize=9)
            paper_eps = PAPER_EPS_QUAD[c] if name == "quad" else float("nan")
            examples.append([f"({letter})", name, fingers, t, q[k], eps[k], paper_eps, vol[k]])
        qs, es = q[chosen], eps[chosen]
        fig_rows.append([name, fingers, _chain(qs), _chain(es),
                         bool(np.all(np.diff(qs) < 0) and np.all(np.diff(es) < 0))])
    fig.tight_layout()
    fig.savefig(out / "fig6_grasps.png", bbox_inches="tight")
    plt.close(fig)
    timer.lap("figure")

    corr = []
    for (name, fingers), (obj, p, n, fc, q, eps, vol, unconverged) in sorted(pools.items()):
        rho, pval = spearmanr(q[fc], eps[fc]) if fc.sum() > 2 else (float("nan"), float("nan"))
        rv, _ = spearmanr(q[fc], vol[fc]) if fc.sum() > 2 else (float("nan"), float("nan"))
        corr.append([name, fingers, len(q), float(fc.mean()), float(np.median(q[fc])),
                     float(np.median(eps[fc])),
                     float(rho), float(pval), float(rv), unconverged])

    lines = ["# Paper Fig. 6: planar grasps, Q2d against Ferrari-Canny epsilon\n"]
    lines.append(f"Friction 20 deg (mu = {mu:.3f}); first contact fixed, the others uniform on the boundary; "
                 "epsilon "
                 "with torques about the object's centre divided by its radius (its value depends on that "
                 "choice, the paper does not say its own). Figure: `fig6_grasps.png`.\n")
    lines.append("## Example grasps (Q nearest the paper's)\n")
    lines.append(table(["grasp", "object", "fingers", "paper Q", "Q", "epsilon", "paper epsilon",
                        "hull area"],
                       examples))
    lines.append("\n## Do Q and epsilon rank the three examples alike?\n")
    lines.append(table(["object", "fingers", "Q (a, b, c)", "epsilon (a, b, c)", "same order"], fig_rows))
    lines.append(f"\n## Rank correlation over {args.num} random grasps (force-closure ones)\n")
    lines.append(table(["object", "fingers", "grasps", "FC rate", "median Q", "median epsilon",
                        "Spearman(Q, eps)", "p-value", "Spearman(Q, hull area)", "unconverged"], corr))
    lines.append("\n" + timer.report())
    path = write(out, "\n".join(lines))
    print(path.read_text())


if __name__ == "__main__":
    main()
