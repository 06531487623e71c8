"""Speed of ``gj.optimize``: the cost of a batched step against ``gj.quality``, and force-closure
grasps per second refined to a local optimum (issue 7's speed targets).

1. **Step cost.** For each object (default: the sphere and the glass), ``n`` = ``--fingers``,
   ``m`` = ``--edges``, batches of ``--cost-starts`` starts: ``gj.optimize`` for ``--cost-steps`` steps per
   objective (``closure``, ``signed_q``, ``dfc``; ``monitor=False``), and ``gj.quality`` on the
   same batch size, n and m (the optimizer's final grasps, and random grasps of the object), each
   after a warm-up call on the same shapes, best of ``--repeat``, side by side in one run. The
   cost of a step per start is the optimize time less one ``gj.evaluate`` of the batch (the exact
   scoring ``gj.optimize`` ends with), over starts x steps; the ratio to ``gj.quality`` per grasp
   is the target (at most 2x).
2. **Refined force-closure grasps per second.** From the same random starts (same key), ``S`` and
   ``4 S`` steps for each ``S`` of ``--refine-steps``: a start counts when it ends force-closure at
   ``S`` steps with Q at least 99% of its Q at ``4 S`` steps (a local optimum: 4x more steps gain
   less than 1%), read two ways: a fresh ``4 S``-step run, and the ``S``-step run continued for
   ``3 S`` more steps from its results (``init=``). The rate is that count over the wall time of the ``S``-step call (target: 300
   per second on this 2-core CPU).
3. **The same, sampled then refined** (the common workflow): ``--refine-samples`` random grasps
   sampled and scored by ``gj.evaluate``, the best ``--starts`` distinct ones (force-closure by Q
   first) refined for ``S`` steps of ``--sample-refine-steps`` (``init=``, the refining rate), and
   counted as above against ``3 S`` more steps and a fresh ``4 S``-step refinement of the same
   starts. The rate is that count over the time of sampling, scoring, picking and refining.

Friction 20 deg, all CPU cores as XLA devices, the command line's compilation cache. Timings come
from a shared machine: only the ratios within one run compare.

0. **Learning-rate rule.** On ``--sweep-object`` (glass), ``--starts`` random starts x ``--steps``
   steps for each peak learning rate of ``--sweep-rates``: force-closure fraction and Q. The
   experiments use, for every object and finger count, the smallest rate at which >= 99.5% of
   the starts end force-closure (0.4 when measured).

    python experiments/bench_optimize.py [--objects sphere glass] [--fingers 4] [--starts 256]
        [--steps 100] [--cost-starts 256 1024] [--cost-steps 20] [--refine-steps 25 50 100]
        [--learning-rate LR] [--repeat 2] [--out DIR] [--quick]

Prints tables and writes ``results.md`` and ``results.json`` to ``--out`` (default
``experiments/results/bench_optimize/``).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402

from _common import Timer, compilation_cache, mu_of, parser, table, use_cpu_cores, write, write_json  # noqa: E402

OBJECTIVES = ("closure", "signed_q", "dfc")
#: Learning rates of the sweep that sets the experiments' rule (glass, 4 fingers).
LEARNING_RATES = (0.02, 0.05, 0.1, 0.2, 0.4, 0.8)


def main():
    ap = parser("bench_optimize", __doc__)
    ap.add_argument("--objects", nargs="+", default=["sphere", "glass"])
    ap.add_argument("--fingers", type=int, default=4)
    ap.add_argument("--edges", type=int, default=8)
    ap.add_argument("--starts", type=int, default=256, help="starts of the sweep and refine runs (default: %(default)s)")
    ap.add_argument("--steps", type=int, default=100, help="steps of the sweep (default: %(default)s)")
    ap.add_argument("--cost-starts", type=int, nargs="+", default=[256, 1024],
                    help="batch sizes of the step-cost runs (default: %(default)s)")
    ap.add_argument("--cost-steps", type=int, default=20, help="steps of the step-cost runs (default: %(default)s)")
    ap.add_argument("--objectives", nargs="+", default=list(OBJECTIVES))
    ap.add_argument("--refine-steps", type=int, nargs="+", default=[25, 50, 100])
    ap.add_argument("--refine-samples", type=int, default=16384,
                    help="grasps sampled for sample-then-refine (default: %(default)s)")
    ap.add_argument("--sample-refine-steps", type=int, nargs="*", default=[10, 20],
                    help="steps of sample-then-refine (default: %(default)s; none given: skipped)")
    ap.add_argument("--learning-rate", type=float, default=None,
                    help="peak learning rate of the step-cost and refine runs (default: gj.optimize's)")
    ap.add_argument("--sweep-object", default="glass", help="object of the learning-rate sweep ('none': skip)")
    ap.add_argument("--sweep-rates", type=float, nargs="+", default=list(LEARNING_RATES))
    ap.add_argument("--repeat", type=int, default=2, help="timed calls per measurement; the best counts")
    ap.add_argument("--no-cache", action="store_true")
    ap.add_argument("--quick", action="store_true", help="sphere only, 20 steps, refine steps 10")
    args = ap.parse_args()
    if args.quick:
        args.objects, args.cost_steps, args.refine_steps, args.repeat = ["sphere"], 10, [10], 1
        args.cost_starts, args.sample_refine_steps, args.refine_samples = [256], [10], 4096
        args.objectives, args.sweep_object = ["closure"], "none"
    devices = use_cpu_cores()
    import jax

    cache = compilation_cache(not args.no_cache)
    import grasp_jax as gj
    from grasp_jax import objects, sampling

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from optimize_vs_sampling import _resolve, candidates

    from grasp_jax._optimize import distinct_grasps

    mu = mu_of(20.0)
    n, m, B = args.fingers, args.edges, args.starts
    timer = Timer()

    def best_of(fn):
        times, out = [], None
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            out = fn()
            jax.block_until_ready(jax.tree_util.tree_leaves(out))
            times.append(time.perf_counter() - t0)
        return min(times), times, out

    def opt(obj, steps, objective="closure", key=1, lr=None, starts=None):
        return gj.optimize(obj, key, fingers=n, mu=mu, starts=starts or B, steps=steps, num_edges=m, objective=objective,
                           monitor=objective == "closure", learning_rate=lr or args.learning_rate)

    # ---- 0. the learning-rate rule: one sweep on one object ----------------------------------
    sweep_rows, sweep_json = [], []
    if args.sweep_object.lower() != "none":
        obj = objects.load(_resolve(args.sweep_object))
        for lr in args.sweep_rates:
            t0 = time.perf_counter()
            res = opt(obj, args.steps, lr=lr)
            sec = time.perf_counter() - t0  # with compilation: only the verdicts matter here
            s = res.summary()
            sweep_json.append(dict(object=obj.name, learning_rate=lr, seconds_with_compile=sec, **s))
            sweep_rows.append([obj.name, lr, s["force_closure_fraction"], s["quality_percentiles"][50],
                               s["quality_percentiles"][100], s["distinct_force_closure"],
                               s["reasons"]["converged"], s["reasons"]["not_converged"]])
            print(f"sweep {obj.name} lr {lr}: FC {s['force_closure_fraction']:.3f}, Q p50 "
                  f"{s['quality_percentiles'][50]:.3f}", file=sys.stderr, flush=True)
        timer.lap("learning-rate sweep")

    cost_rows, cost_json = [], []
    refine_rows, refine_json = [], []
    sampled_rows, sampled_json = [], []
    for name in args.objects:
        obj = objects.load(_resolve(name))
        # ---- 1. step cost -------------------------------------------------------------------
        for Bc in args.cost_starts:
            rp, rn = sampling.sample_grasps(obj, Bc, n, seed=args.seed)
            gj.quality(rp, rn, mu=mu, num_edges=m)  # warm-up
            gj.evaluate(rp, rn, mu=mu, num_edges=m)
            t_q_rand, all_q_rand, _ = best_of(lambda: gj.quality(rp, rn, mu=mu, num_edges=m))
            t_eval, all_eval, _ = best_of(lambda: gj.evaluate(rp, rn, mu=mu, num_edges=m))
            for objective in args.objectives:
                S = args.cost_steps
                t0 = time.perf_counter()
                opt(obj, S, objective, key=10**6, starts=Bc)  # warm-up: compile + one call
                warm = time.perf_counter() - t0
                t_opt, all_opt, res = best_of(lambda: opt(obj, S, objective, starts=Bc))
                fp, fnrm = np.asarray(res.points), np.asarray(res.normals)
                gj.quality(fp, fnrm, mu=mu, num_edges=m)
                t_q_final, all_q_final, _ = best_of(lambda: gj.quality(fp, fnrm, mu=mu, num_edges=m))
                per_step = max(t_opt - t_eval, 1e-12) / (Bc * S)
                per_q = min(t_q_rand, t_q_final) / Bc
                row = dict(object=obj.name, objective=objective, fingers=n, edges=m, starts=Bc, steps=S,
                           optimize_s=t_opt, optimize_all_s=all_opt, warmup_s=warm, evaluate_s=t_eval,
                           quality_random_s=t_q_rand, quality_final_s=t_q_final,
                           step_us_per_start=per_step * 1e6, quality_us_per_grasp_random=t_q_rand / Bc * 1e6,
                           quality_us_per_grasp_final=t_q_final / Bc * 1e6, ratio=per_step / per_q,
                           ratio_random=per_step / (t_q_rand / Bc), ratio_final=per_step / (t_q_final / Bc),
                           start_steps_per_s=Bc * S / t_opt,
                           force_closure_fraction=float(res.force_closure.mean()))
                cost_json.append(row)
                cost_rows.append([obj.name, objective, f"{n}, {m}", Bc, S, f"{t_opt:.2f}", f"{t_eval:.3f}",
                                  f"{row['step_us_per_start']:.1f}", f"{row['quality_us_per_grasp_random']:.1f}",
                                  f"{row['quality_us_per_grasp_final']:.1f}", f"{row['ratio_random']:.1f}",
                                  f"{row['ratio_final']:.1f}", row["ratio"] <= 2.0,
                                  f"{row['start_steps_per_s']:,.0f}", f"{warm:.1f}"])
                print(f"{obj.name} {objective} batch {Bc}: step {row['step_us_per_start']:.1f} us/start, quality "
                      f"{row['quality_us_per_grasp_random']:.1f} / {row['quality_us_per_grasp_final']:.1f} us/grasp, "
                      f"ratio {row['ratio']:.1f}", file=sys.stderr, flush=True)
        # ---- 2. force-closure grasps per second at a local optimum ----------------------------
        for S in args.refine_steps:
            opt(obj, S, key=10**6)  # warm-up of the timed shape
            t_s, all_s, short = best_of(lambda: opt(obj, S))
            long = opt(obj, 4 * S)  # the same starts (same key), 4x the steps
            # The same run continued: 3 S more steps from where it ended (refining, init=).
            more = gj.optimize(obj, fingers=n, mu=mu, steps=3 * S, num_edges=m,
                               init=(np.asarray(short.points), np.asarray(short.normals)))
            q_s, q_l = short.quality, long.quality
            fc = short.force_closure
            local = fc & (q_s >= 0.99 * q_l)
            count = int(local.sum())
            rate = count / t_s
            local_more = fc & (q_s >= 0.99 * more.quality)
            count_more = int(local_more.sum())
            refine_json.append(dict(object=obj.name, fingers=n, starts=B, steps=S, seconds=t_s, all_seconds=all_s,
                                    force_closure=int(fc.sum()), force_closure_long=int(long.force_closure.sum()),
                                    local_optimum=count, rate=rate, local_optimum_continued=count_more,
                                    rate_continued=count_more / t_s,
                                    median_q_continued=float(np.median(more.quality[fc])) if fc.any() else 0.0,
                                    median_q=float(np.median(q_s[fc])) if fc.any() else 0.0,
                                    median_q_long=float(np.median(q_l[long.force_closure]))
                                    if long.force_closure.any() else 0.0,
                                    distinct_local=int(len(short.distinct()))))
            refine_rows.append([obj.name, n, B, S, f"{fc.mean():.3f}", f"{long.force_closure.mean():.3f}",
                                refine_json[-1]["median_q"], refine_json[-1]["median_q_long"],
                                refine_json[-1]["median_q_continued"], f"{t_s:.2f}",
                                f"{count} ({count / B:.1%})", f"{rate:,.0f}",
                                f"{count_more} ({count_more / B:.1%})", f"{count_more / t_s:,.0f}",
                                max(rate, count_more / t_s) >= 300])
            print(f"{obj.name} S={S}: {count} / {count_more} of {B} force-closure at a local optimum in "
                  f"{t_s:.2f} s: {rate:.0f} / {count_more / t_s:.0f} per s", file=sys.stderr, flush=True)
        # ---- 3. the same, sampled then refined ------------------------------------------------
        def sample_and_pick(seed):
            p, nr = sampling.sample_grasps(obj, args.refine_samples, n, seed=seed)
            ev = gj.evaluate(p, nr, mu=mu, num_edges=m)
            top, rank = candidates(np.asarray(ev.force_closure), np.asarray(ev.quality), np.asarray(ev.delta), 4 * B)
            return p[top][distinct_grasps(p[top], rank, 0.01 * float(obj.radius))[:B]]

        def refine(init, steps):
            return gj.optimize(obj, fingers=n, mu=mu, steps=steps, num_edges=m, init=init)

        for S in args.sample_refine_steps:
            refine(sample_and_pick(10**6), S)  # warm-up of the timed shapes
            t0 = time.perf_counter()
            init = sample_and_pick(args.seed + S)
            t_pick = time.perf_counter() - t0
            t_r, all_r, short = best_of(lambda: refine(init, S))
            fresh = refine(init, 4 * S)
            more = gj.optimize(obj, fingers=n, mu=mu, steps=3 * S, num_edges=m,
                               init=(np.asarray(short.points), np.asarray(short.normals)))
            fc, q_s = short.force_closure, short.quality
            count_fresh = int((fc & (q_s >= 0.99 * fresh.quality)).sum())
            count_more = int((fc & (q_s >= 0.99 * more.quality)).sum())
            total = t_pick + t_r
            sampled_json.append(dict(object=obj.name, fingers=n, samples=args.refine_samples, starts=len(init),
                                     steps=S, sample_seconds=t_pick, refine_seconds=t_r, refine_all_seconds=all_r,
                                     force_closure=int(fc.sum()), local_optimum=count_fresh,
                                     local_optimum_continued=count_more, rate=count_fresh / total,
                                     rate_continued=count_more / total,
                                     median_q=float(np.median(q_s[fc])) if fc.any() else 0.0,
                                     median_q_continued=float(np.median(more.quality[fc])) if fc.any() else 0.0))
            sampled_rows.append([obj.name, n, args.refine_samples, len(init), S, f"{fc.mean():.3f}",
                                 sampled_json[-1]["median_q"], sampled_json[-1]["median_q_continued"],
                                 f"{t_pick:.2f} + {t_r:.2f}", f"{count_fresh} ({count_fresh / len(init):.1%})",
                                 f"{count_fresh / total:,.0f}", f"{count_more} ({count_more / len(init):.1%})",
                                 f"{count_more / total:,.0f}", max(count_fresh, count_more) / total >= 300])
            print(f"{obj.name} sampled + refined S={S}: {count_fresh} / {count_more} of {len(init)} at a local "
                  f"optimum in {total:.2f} s: {count_fresh / total:.0f} / {count_more / total:.0f} per s",
                  file=sys.stderr, flush=True)
    timer.lap("benchmarks")

    lines = ["# gj.optimize: step cost and refined force-closure grasps per second\n"]
    if sweep_rows:
        lines += [f"## Learning-rate rule ({B} random starts x {args.steps} steps, {n} fingers, objective closure)\n",
                  "Adam with cosine decay to 1% of the peak learning rate (object radii per step). The rule the "
                  "experiments use for every object and finger count: the smallest rate of the sweep at which "
                  "at least 99.5% of the starts end force-closure (larger rates trade Q for force-closure).\n",
                  table(["object", "learning rate", "FC fraction", "Q p50 (FC)", "best Q", "distinct FC",
                         "converged below FC", "not converged"], sweep_rows), ""]
    lines += ["## Step cost against gj.quality\n",
             f"Friction 20 deg (mu = {mu:.3f}), {devices} XLA CPU devices, best of {args.repeat} timed calls "
             "after a warm-up on the same shapes. Step cost per start = (optimize time - one `gj.evaluate` of "
             "the batch) / (starts x steps); `gj.quality` per grasp on the same n, m and batch size, on random "
             "grasps of the object and on the optimizer's final grasps. The target is a ratio <= 2 (against "
             "the faster of the two `gj.quality` figures).\n",
             table(["object", "objective", "n, m", "starts", "steps", "optimize s", "evaluate s",
                    "step us/start", "quality us/grasp (random)", "quality us/grasp (final)",
                    "ratio (random)", "ratio (final)", "<= 2x", "start-steps/s", "warm-up s"], cost_rows),
             "\n## Force-closure grasps per second at a local optimum\n",
             "Counted are the starts force-closure after S steps with Q >= 0.99 x the Q that 4x the steps "
             "give, read two ways: a fresh run of 4 S steps from the same starts (its cosine schedule is "
             "stretched over 4 S: another trajectory), and the same run continued for 3 S more steps "
             "(`init=` its results, the refining rate). The rate is that count over the time of the S-step "
             "call (target >= 300/s).\n",
             table(["object", "fingers", "starts", "S", "FC fraction (S)", "FC fraction (4 S)",
                    "median Q (S)", "median Q (4 S)", "median Q (S + 3 S)", "s (S steps)",
                    "local optima (4 S)", "per s", "local optima (S + 3 S)", "per s", ">= 300/s"],
                   refine_rows),
             "\n## The same, sampled then refined\n",
             f"{args.refine_samples:,} random grasps sampled and scored, the best {B} distinct ones refined for S "
             "steps (`init=`, the refining rate 0.02); counted as above against a fresh 4 S-step refinement of "
             "the same starts and against the S-step result refined 3 S steps more. The rate is that count "
             "over the time of sampling, scoring, picking and refining (target >= 300/s).\n",
             table(["object", "fingers", "samples", "starts", "S", "FC fraction", "median Q (S)",
                    "median Q (S + 3 S)", "s (sample + refine)", "local optima (4 S)", "per s",
                    "local optima (S + 3 S)", "per s", ">= 300/s"], sampled_rows),
             "\n" + timer.report()]
    write_json(args.out, dict(meta=dict(args={k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
                                        mu=mu, devices=devices, jax=jax.__version__, compilation_cache=cache),
                              learning_rate_sweep=sweep_json, step_cost=cost_json, refined=refine_json,
                              sampled_then_refined=sampled_json))
    path = write(args.out, "\n".join(lines))
    print(path.read_text())


if __name__ == "__main__":
    main()
