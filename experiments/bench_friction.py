"""Throughput of ``gj.critical_friction`` against ``gj.evaluate`` on the same grasps, in one run
(issue 23's target: at least 1/6 of ``evaluate``'s throughput, n = 4, m = 8).

Two workloads, each ``--grasps`` grasps of the ellipsoid with semi-axes (1, 0.7, 0.5) and exact
normals:

* **hard-4**: four hard contacts uniform in direction (the benchmark grasps of
  ``bench_scoring.py``); ``evaluate`` at ``mu = --mu``;
* **soft-pairs**: two soft contacts (torsion ``--torsion``) on near-antipodal pairs, the second
  contact where the line from the first along its inward normal, tilted by ``N(0, 0.25^2)`` per
  axis, leaves the ellipsoid (the parallel-jaw case).

Each call is warmed up on other grasps of the same shape and batch size (the same compiled
programs), then ``evaluate`` and ``critical_friction`` are timed alternately ``--repeat`` times;
the table gives the best of each and the ratio of the bests, and the JSON every time. It also
reports the search's statuses, and the split of ``critical_friction``'s time between its first
pass and the second pass that resumes the searches the first leaves open (``_batch.Retry``).

    python experiments/bench_friction.py [--grasps 8192] [--repeat 3] [--out DIR]

Prints a table and writes ``results.md`` and ``results.json`` to ``--out`` (default
``experiments/results/bench_friction/``). Timings come from a shared machine: only the ratios
within one run compare.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import Timer, parser, table, use_cpu_cores, write, write_json  # noqa: E402

AXES = (1.0, 0.7, 0.5)


def _args():
    ap = parser("bench_friction", __doc__)
    ap.add_argument("--grasps", type=int, default=8192)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--mu", type=float, default=0.364, help="friction of the evaluate calls")
    ap.add_argument("--torsion", type=float, default=0.02, help="torsion of the soft contacts")
    return ap.parse_args()


def _surface(directions, np):
    ax = np.asarray(AXES)
    points = directions / np.linalg.norm(directions, axis=-1, keepdims=True) * ax
    normals = points / ax**2
    return points, normals / np.linalg.norm(normals, axis=-1, keepdims=True)


def hard_grasps(count, seed, np):
    """``count`` grasps of 4 contacts uniform in direction on the ellipsoid."""
    return _surface(np.random.default_rng(seed).normal(size=(count, 4, 3)), np)


def soft_pairs(count, seed, np):
    """``count`` near-antipodal pairs: the first contact uniform, the second where the line along
    its tilted inward normal leaves the ellipsoid."""
    rng = np.random.default_rng(seed)
    p1, n1 = _surface(rng.normal(size=(count, 3)), np)
    line = -n1 + 0.25 * rng.normal(size=n1.shape)
    line /= np.linalg.norm(line, axis=-1, keepdims=True)
    ax = np.asarray(AXES)
    a = np.sum((line / ax) ** 2, axis=-1)
    b = 2 * np.sum(p1 * line / ax**2, axis=-1)
    p2 = p1 + (-b / a)[:, None] * line
    n2 = p2 / ax**2
    n2 /= np.linalg.norm(n2, axis=-1, keepdims=True)
    return np.stack([p1, p2], axis=1), np.stack([n1, n2], axis=1)


def main():
    args = _args()
    devices = use_cpu_cores()
    import jax
    import numpy as np

    jax.config.update("jax_enable_x64", True)
    import grasp_jax as gj
    from grasp_jax import _batch

    timer = Timer()
    passes = []
    score = _batch._score

    def timed_score(*a, **k):  # the time of each pass of map_grasps
        t = time.perf_counter()
        out = score(*a, **k)
        passes.append((int(a[4]), time.perf_counter() - t))
        return out

    workloads = {
        "hard-4": (hard_grasps, {}),
        "soft-pairs": (soft_pairs, {"contact": "soft", "torsion": args.torsion}),
    }
    rows, results = [], {}
    for name, (make, kw) in workloads.items():
        points, normals = make(args.grasps, 1, np)
        warm_p, warm_n = make(args.grasps, 2, np)
        gj.evaluate(warm_p, warm_n, mu=args.mu, **kw)
        gj.critical_friction(warm_p, warm_n, **kw)
        t_eval, t_crit, split = [], [], []
        for _ in range(args.repeat):
            t = time.perf_counter()
            gj.evaluate(points, normals, mu=args.mu, **kw)
            t_eval.append(time.perf_counter() - t)
            passes.clear()
            _batch._score = timed_score
            try:
                t = time.perf_counter()
                mu, status = gj.critical_friction(points, normals, **kw)
                t_crit.append(time.perf_counter() - t)
            finally:
                _batch._score = score
            split.append(list(passes))
        status = np.asarray(status)
        e, c = args.grasps / min(t_eval), args.grasps / min(t_crit)
        best = int(np.argmin(t_crit))
        first, second = split[best][0][1], sum(s for _, s in split[best][1:])
        reopened = sum(n for n, _ in split[best][1:])
        counts = {s.name: int(np.sum(status == s)) for s in gj.FrictionStatus}
        rows.append([name, args.grasps, f"{e:,.0f}", f"{c:,.0f}", f"1/{e / c:.1f}", c / e >= 1 / 6,
                     f"{first:.2f}", f"{second:.2f} ({reopened})", counts["FOUND"]])
        results[name] = {"evaluate_s": t_eval, "critical_s": t_crit, "passes": split, "status_counts": counts,
                         "evaluate_per_s": e, "critical_per_s": c, "ratio": c / e}
        print(name, rows[-1], flush=True)
        timer.lap(name)

    header = ["grasps", "count", "evaluate /s", "critical_friction /s", "ratio", ">= 1/6",
              "first pass s", "second pass s (searches)", "FOUND"]
    text = "\n\n".join([
        "# gj.critical_friction against gj.evaluate",
        f"Ellipsoid {AXES}, 8-edge pyramids, `evaluate` at mu = {args.mu}, {devices} XLA CPU devices, "
        f"best of {args.repeat} alternating timed calls after a warm-up on other grasps of the same shape.",
        table(header, rows),
        timer.report(),
    ])
    print(text)
    write(args.out, text)
    write_json(args.out, {"settings": vars(args) | {"devices": devices}, "results": results})


if __name__ == "__main__":
    main()
