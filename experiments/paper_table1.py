"""3D grasps with 3, 5 and 7 fingers: Q3d against Ferrari-Canny epsilon and hull volume (paper Table I).

Objects: the built-in glass and mechanical part (the paper's Fig. 7 objects, rebuilt in code), and the
real meshes ``ycb_065-a_cups.obj`` and ``trimesh_featuretype.STL`` from ``../shared/data/meshes`` when
present. Friction 20 deg (mu = tan 20 deg), m = 25 cone edges, the paper's sampling scheme (first
contact fixed, the other n - 1 at random facet centroids).

For each object and finger count, grasps are scored with ``gj.evaluate`` (force-closure and Q) in
rounds of ``--num`` grasps (round ``r`` drawn with seed ``--seed + fingers + 1000 r``; round 0 is the
old single sample) until ``--eps-num`` force-closure grasps are found (``--eps-num-meshes`` for the
real meshes), at most ``--max-grasps`` grasps. A random subset of that many force-closure grasps (all
of them when fewer were found) then gets the qhull epsilon and hull volume, with torques about
``obj.center`` divided by ``obj.radius`` as ``gj.ferrari_canny``. qhull takes about 36 / 127 / 241 ms
per grasp with 3 / 5 / 7 fingers, so it runs in a process pool (``--workers``, default: every core;
``spawn`` context, so no worker is forked from the process that initialized JAX) with a progress bar.
The workers do not import JAX: they load ``grasp_jax/reference.py`` (``wrenches``, NumPy only) as a
standalone module and run ``epsilon_one`` taken from the source of ``grasp_jax/_baseline.py``, the
code ``gj.ferrari_canny`` runs; a few grasps per object and finger count are checked against
``gj.ferrari_canny`` in the main process.

Reported: grasps scored, force-closure rate, Q percentiles (all force-closure grasps), epsilon and
hull-volume percentiles and the Spearman rank correlations of Q with epsilon and with the hull volume
at fixed finger count over the qhull-scored grasps (how many is stated per row; by default at least
1,000 for the built-in objects, 200 for the real meshes), the across-finger-count comparison the paper
discusses (Q favours fewer fingers, epsilon more), a Table-I-like list of example grasps and a figure
of them (``table1_grasps.png``). The default run takes about 10 minutes on 2 cores.

    python experiments/paper_table1.py [--out DIR] [--num 16384] [--eps-num 1000]
        [--eps-num-meshes 200] [--max-grasps 200000] [--workers N] [--no-meshes]
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import SHARED_MESHES, Timer, mu_of, parser, table, write  # noqa: E402

MESHES = ("ycb_065-a_cups.obj", "trimesh_featuretype.STL")
#: The paper's Fig. 7 / Table I layout: (object, fingers, how many examples).
EXAMPLES = (("glass", 3, 2), ("glass", 7, 2), ("part", 3, 2), ("part", 5, 1))
#: Table I as printed: (Q3d, epsilon, the "V_ch 10^-1" row).
PAPER_TABLE = {"a": (0.538, 0.024, 0.088), "b": (0.885, 0.062, 0.099), "c": (0.627, 0.081, 0.449),
               "d": (0.794, 0.156, 0.604), "e": (0.761, 0.022, 0.059), "f": (0.831, 0.032, 0.036),
               "g": (0.806, 0.087, 0.225)}
#: Grasps per task sent to a qhull worker.
EPS_CHUNK = 20
PACKAGE = Path(__file__).resolve().parents[1] / "grasp_jax"

_QHULL = None  # (wrenches, epsilon_one) in a worker process


def _qhull_functions():
    """``(reference.wrenches, _baseline.epsilon_one)`` of the package, without importing ``grasp_jax``
    (its ``__init__`` imports JAX): ``reference.py`` imports only NumPy and SciPy and is loaded as a
    standalone module; ``epsilon_one`` is compiled from its source in ``_baseline.py`` (whose other
    imports need JAX)."""
    import ast
    import importlib.util

    import numpy as np
    from scipy.spatial import ConvexHull, QhullError

    spec = importlib.util.spec_from_file_location("_table1_gj_reference", PACKAGE / "reference.py")
    reference = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(reference)
    path = PACKAGE / "_baseline.py"
    source = path.read_text()
    node = next(n for n in ast.parse(source).body
                if isinstance(n, ast.FunctionDef) and n.name == "epsilon_one")
    module = ast.Module(body=[node], type_ignores=[])
    namespace = {"np": np, "ConvexHull": ConvexHull, "QhullError": QhullError}
    exec(compile(module, str(path), "exec"), namespace)
    return reference.wrenches, namespace["epsilon_one"]


def _qhull_init():
    global _QHULL
    _QHULL = _qhull_functions()


def _qhull_chunk(points, normals, mu, num_edges, origin, torque_scale):
    """Epsilon and hull volume of a few grasps, as ``gj.ferrari_canny``; in a worker process.
    Returns ``(eps, vol, seconds, jax_loaded)``."""
    import numpy as np

    wrenches, epsilon_one = _QHULL
    t0 = time.perf_counter()
    eps, vol = np.zeros(len(points)), np.zeros(len(points))
    for k in range(len(points)):
        eps[k], vol[k] = epsilon_one(wrenches(points[k], normals[k], mu, num_edges, origin, torque_scale))
    return eps, vol, time.perf_counter() - t0, "jax" in sys.modules


def _workers() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def main():
    ap = parser("paper_table1", __doc__)
    ap.add_argument("--num", type=int, default=16384,
                    help="grasps per scoring round with gj.evaluate (default: %(default)s)")
    ap.add_argument("--eps-num", type=int, default=1000,
                    help="force-closure grasps per built-in object and finger count scored with qhull; "
                         "the Spearman correlations are over them (default: %(default)s)")
    ap.add_argument("--eps-num-meshes", type=int, default=200,
                    help="the same for the real meshes (default: %(default)s)")
    ap.add_argument("--max-grasps", type=int, default=200_000,
                    help="stop drawing rounds after this many grasps per object and finger count, even "
                         "with fewer force-closure grasps than wanted (default: %(default)s)")
    ap.add_argument("--workers", type=int, default=_workers(),
                    help="qhull worker processes (default: the usable cores, %(default)s)")
    ap.add_argument("--fingers", type=int, nargs="+", default=[3, 5, 7])
    ap.add_argument("--edges", type=int, default=25)
    ap.add_argument("--no-meshes", action="store_true", help="built-in objects only")
    args = ap.parse_args()
    for name in ("num", "max_grasps", "workers"):
        if getattr(args, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be >= 1")
    if args.eps_num < 3 or args.eps_num_meshes < 3:
        ap.error("--eps-num and --eps-num-meshes must be >= 3 (a rank correlation needs 3 grasps)")

    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from scipy.stats import spearmanr
    from tqdm.auto import tqdm

    import grasp_jax as gj
    from grasp_jax import objects, plotting, sampling

    timer = Timer()
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    mu = mu_of(20.0)
    names = ["glass", "part"]
    builtin = set(names)
    if not args.no_meshes:
        names += [str(SHARED_MESHES / m) for m in MESHES if (SHARED_MESHES / m).is_file()]
    objs = [objects.load(name) for name in names]
    timer.lap("loading")

    def pct(x, k):
        return float(np.percentile(x, k)) if len(x) else float("nan")

    # 1. Force-closure and Q with gj.evaluate, in rounds until the epsilon sample can be filled.
    scored, data = {}, {}
    for obj in objs:
        want = args.eps_num if obj.name in builtin else args.eps_num_meshes
        first = sampling.default_first_contact(obj, args.seed)  # the same c_1 for every finger count
        for fingers in args.fingers:
            num = found = unconverged = rounds = 0
            ps, ns, qs = [], [], []
            while found < want and num < args.max_grasps:
                size = min(args.num, args.max_grasps - num)
                p, n = sampling.sample_grasps(obj, size, fingers, seed=args.seed + fingers + 1000 * rounds,
                                              scheme="paper", first_contact=first)
                ev = gj.evaluate(p, n, mu=mu, num_edges=args.edges)
                conv = np.asarray(ev.converged)
                fc = np.asarray(ev.force_closure) & conv
                q = np.asarray(ev.quality)
                ps.append(p[fc])
                ns.append(n[fc])
                qs.append(q[fc])
                num += size
                found += int(fc.sum())
                unconverged += int((~conv).sum())
                rounds += 1
            p, n, q = (np.concatenate(a) for a in (ps, ns, qs))
            rng = np.random.default_rng(args.seed + 7 * fingers)
            idx = np.sort(rng.choice(len(q), size=min(want, len(q)), replace=False))
            scored[obj.name, fingers] = dict(num=num, fc=found, unconverged=unconverged, want=want,
                                             q_all=q)
            data[obj.name, fingers] = dict(p=p[idx], n=n[idx], q=q[idx])
            print(f"{obj.name}, {fingers} fingers: {found:,} force-closure of {num:,} grasps "
                  f"({rounds} rounds); {len(idx)} to qhull", file=sys.stderr, flush=True)
    timer.lap("gj.evaluate")

    # 2. qhull epsilon in worker processes (spawned: none inherits this process's JAX runtime).
    tasks = []  # (object, fingers, start, stop), slowest (most fingers) first for the load balance
    for (name, fingers), d in sorted(data.items(), key=lambda kv: -kv[0][1]):
        tasks += [(name, fingers, s, min(s + EPS_CHUNK, len(d["q"])))
                  for s in range(0, len(d["q"]), EPS_CHUNK)]
    by_name = {o.name: o for o in objs}
    for d in data.values():
        d["eps"], d["vol"] = np.zeros(len(d["q"])), np.zeros(len(d["q"]))
    seconds, jax_in_worker = {}, False
    total = sum(len(d["q"]) for d in data.values())
    workers = min(args.workers, max(len(tasks), 1))
    t0 = time.perf_counter()
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                             initializer=_qhull_init) as pool, \
            tqdm(total=total, unit="grasp", desc=f"qhull epsilon ({workers} workers)", smoothing=0.05,
                 mininterval=0.5 if sys.stderr.isatty() else 30) as bar:
        futures = {}
        for name, fingers, s, e in tasks:
            d, obj = data[name, fingers], by_name[name]
            futures[pool.submit(_qhull_chunk, d["p"][s:e], d["n"][s:e], mu, args.edges,
                                np.asarray(obj.center, float), float(obj.radius))] = (name, fingers, s, e)
        for future in as_completed(futures):
            name, fingers, s, e = futures[future]
            eps, vol, sec, jax_loaded = future.result()
            data[name, fingers]["eps"][s:e], data[name, fingers]["vol"][s:e] = eps, vol
            seconds.setdefault(fingers, []).append((sec, e - s))
            jax_in_worker |= jax_loaded
            bar.update(e - s)
    qhull_wall = time.perf_counter() - t0
    # The workers' code path against gj.ferrari_canny itself, on the first two grasps of each sample.
    for (name, fingers), d in data.items():
        if not len(d["q"]):
            continue
        obj = by_name[name]
        eps, vol = gj.ferrari_canny(d["p"][:2], d["n"][:2], mu=mu, num_edges=args.edges, origin=obj.center,
                                    torque_scale=obj.radius)
        if not (np.allclose(eps, d["eps"][:2], rtol=1e-12, atol=1e-15)
                and np.allclose(vol, d["vol"][:2], rtol=1e-12, atol=1e-15)):
            raise RuntimeError(f"qhull workers disagree with gj.ferrari_canny on {name}, {fingers} fingers")
    per_grasp = {f: sum(s for s, _ in v) / sum(k for _, k in v) for f, v in sorted(seconds.items())}
    timer.lap(f"qhull epsilon ({workers} workers)")

    def spearman(x, y):
        return float(spearmanr(x, y).statistic) if len(x) > 2 else float("nan")

    def ci95(rho, k):
        """Approximate 95% interval of a Spearman correlation over ``k`` pairs (Fisher z, with the
        Fieller-Hartley-Pearson variance 1.06 / (k - 3))."""
        if not (k > 3 and np.isfinite(rho)):
            return "-"
        z, half = np.arctanh(np.clip(rho, -0.999999, 0.999999)), 1.96 * np.sqrt(1.06 / (k - 3))
        return f"{np.tanh(z - half):.3f} .. {np.tanh(z + half):.3f}"

    stats, across = [], []
    for obj in objs:
        for fingers in args.fingers:
            s, d = scored[obj.name, fingers], data[obj.name, fingers]
            k = len(d["q"])
            rho = spearman(d["q"], d["eps"])
            stats.append([obj.name, fingers, f"{s['num']:,}", f"{s['fc']:,}", s["fc"] / s["num"],
                          pct(s["q_all"], 10), pct(s["q_all"], 50), pct(s["q_all"], 90),
                          f"{k:,}" + ("" if k >= s["want"] else f" (of {s['want']:,} wanted)"),
                          pct(d["eps"], 10), pct(d["eps"], 50), pct(d["eps"], 90), pct(d["vol"], 50), rho,
                          ci95(rho, k), spearman(d["q"], d["vol"]), s["unconverged"]])

    for obj in objs:
        d = [data[obj.name, f] for f in args.fingers]
        q_all = [scored[obj.name, f]["q_all"] for f in args.fingers]
        med_q = [float(np.median(x)) if len(x) else float("nan") for x in q_all]
        med_e = [float(np.median(x["eps"])) if len(x["eps"]) else float("nan") for x in d]
        row = [obj.name, " / ".join(f"{x:.3f}" for x in med_q), " / ".join(f"{x:.3f}" for x in med_e),
               bool(np.all(np.diff(med_q) < 0)), bool(np.all(np.diff(med_e) > 0))]
        # Over every pair (grasp with fewer fingers, grasp with more) of the qhull-scored samples: how
        # often each measure prefers the one with fewer fingers.
        small, large = d[0], d[-1]
        if len(small["q"]) and len(large["q"]):
            row += [float(np.mean(small["q"][:, None] > large["q"][None, :])),
                    float(np.mean(small["eps"][:, None] > large["eps"][None, :]))]
        else:
            row += [float("nan"), float("nan")]
        across.append(row)

    # Table-I-like examples: grasps at the 50th and 90th Q percentile of the qhull-scored sample.
    examples, shown = [], []
    letters = iter("abcdefg")  # the paper's letters: fixed by (object, fingers), even when skipped
    for name, fingers, count in EXAMPLES:
        mine = [next(letters) for _ in range(count)]
        if (name, fingers) not in data or len(data[name, fingers]["q"]) == 0:
            continue
        d = data[name, fingers]
        order = np.argsort(d["q"])
        for letter, frac in zip(mine, (0.5, 0.9)):
            k = order[min(int(frac * len(order)), len(order) - 1)]
            pq, pe, pv = PAPER_TABLE[letter]
            examples.append([f"({letter})", name, fingers, d["q"][k], d["eps"][k], d["vol"][k], pq, pe, pv])
            shown.append((letter, name, fingers, d["p"][k], d["n"][k], d["q"][k], d["eps"][k]))
    fig = plt.figure(figsize=(16, 8.4), dpi=100)
    for i, (letter, name, fingers, p, n, q, e) in enumerate(shown):
        ax = fig.add_subplot(2, 4, i + 1, projection="3d")
        plotting.plot_grasp_3d(by_name[name], p, n, mu=mu, num_edges=args.edges, ax=ax)
        ax.set_title(f"({letter}) {name}, {fingers} fingers\nQ = {q:.3f}, eps = {e:.3f}", fontsize=10)
    fig.tight_layout()
    fig.savefig(out / "table1_grasps.png", bbox_inches="tight")
    plt.close(fig)
    timer.lap("examples")

    lines = ["# Paper Table I: Q3d against Ferrari-Canny epsilon on 3D objects\n"]
    eps_wanted = f"{args.eps_num:,} per built-in object and finger count"
    if any(name not in builtin for name in by_name):
        eps_wanted += f", {args.eps_num_meshes:,} per real mesh"
    lines.append(f"Friction 20 deg (mu = {mu:.3f}), m = {args.edges}, the paper's sampling scheme (first "
                 "contact fixed, the others at random facet centroids), seed "
                 f"{args.seed}. Grasps are scored with `gj.evaluate` in rounds of {args.num:,} until enough "
                 f"force-closure grasps are found ({eps_wanted}; at most {args.max_grasps:,} grasps); Q "
                 "percentiles are over all the force-closure grasps found. A random sample of that many "
                 "of them gets the qhull epsilon (torques about the object's centre / its radius) and "
                 "hull volume `V_ch`; the epsilon and `V_ch` percentiles and both Spearman correlations "
                 "are over that sample, whose size is the column `Spearman n`. qhull ran in "
                 f"{workers} worker processes ({qhull_wall:.0f} s wall for {total:,} grasps; "
                 + ", ".join(f"{t * 1e3:.0f} ms" for t in per_grasp.values())
                 + " per grasp in one worker for " + " / ".join(str(f) for f in per_grasp) + " fingers"
                 + ("" if not jax_in_worker else "; JAX was imported in a worker") + "). The "
                 "workers' epsilon and volume equal `gj.ferrari_canny`'s on the grasps checked (two per "
                 "object and finger count). 95% CI: Fisher z with variance 1.06 / (n - 3).\n")
    lines.append(table(["object", "fingers", "grasps", "FC grasps", "FC rate", "Q p10", "Q p50", "Q p90",
                        "Spearman n", "eps p10", "eps p50", "eps p90", "V_ch p50", "Spearman(Q, eps)",
                        "95% CI", "Spearman(Q, V_ch)", "unconverged"], stats))
    if len(set(args.fingers)) > 1:  # nothing to compare with a single finger count
        lines.append("\n## Across finger counts (the paper: Q favours fewer fingers, epsilon more)\n")
        lines.append("Median Q over all force-closure grasps found and median epsilon over the "
                     "qhull-scored sample, for "
                     + " / ".join(str(f) for f in args.fingers) + f" fingers. P(Q: {args.fingers[0]} > "
                     f"{args.fingers[-1]}): over every pair of a {args.fingers[0]}-finger and a "
                     f"{args.fingers[-1]}-finger grasp of the qhull-scored samples, how often Q rates the "
                     "one with fewer fingers higher; the same for epsilon. The paper's claim reads "
                     "P(Q) > 0.5 > P(eps).\n")
        lines.append(table(["object", "median Q", "median epsilon", "Q falls with n", "epsilon rises with n",
                            f"P(Q: {args.fingers[0]} > {args.fingers[-1]})",
                            f"P(eps: {args.fingers[0]} > {args.fingers[-1]})"], across))
    lines.append("\n## Table-I-like examples (grasps at the median and 90th percentile of Q)\n")
    lines.append("The paper's values are for its own grasps of Fig. 7, not these; its last column is the "
                 "table's `V_ch 10^-1` row as printed (the scaling is ambiguous) and its torque scaling "
                 "is not stated, so only the orders of "
                 "magnitude and the rankings compare. Figure: `table1_grasps.png`.\n")
    lines.append(table(["grasp", "object", "fingers", "Q3d", "epsilon", "V_ch", "paper Q3d", "paper eps",
                        "paper 'V_ch 10^-1'"], examples))
    lines.append("\n" + timer.report())
    path = write(out, "\n".join(lines))
    print(path.read_text())


if __name__ == "__main__":
    main()
