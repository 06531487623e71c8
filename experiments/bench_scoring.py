"""Benchmark of the batched scorer against the one-grasp-at-a-time baselines, in one run.

For n = 3, 4, 7 contacts and m = 8, 25 cone edges, times ``gj.evaluate`` (force-closure + Q +
certificate) on 1k, 10k and 100k grasps of an ellipsoid, and
against it SciPy HiGHS solving only the Q LP one grasp at a time and qhull epsilon one grasp at a
time (both on a sample, timed per grasp). Each batch is timed ``--repeat`` times and the best is reported
(the machines are shared; every time goes into the JSON). Also checks accuracy on the HiGHS sample: the largest
|Q - Q_HiGHS| and the force-closure verdicts against the min-weight definition (HiGHS) on grasps
that are not marginal. Peak RSS after each batch shows that memory stays flat (scoring is chunked).

``gj.min_weight`` (the classical min-weight margin ``l*`` only) is timed on the same batches, warmed
up on every batch size first like ``evaluate``. When FRoGGeR (Li et al. 2023) is installed, its
min-weight LP (``frogger.metrics.min_weight_lp``: quantecon's numba simplex, one grasp per call) is
timed one grasp at a time on the baseline sample, best of ``--repeat`` passes, after a warm-up call
so that numba's JIT compilation is not counted (that call's seconds, JIT or loading numba's
on-disk cache, go into the JSON). It is handed the ``(6, n m)`` matrix of the same primitive
wrenches as grasp_jax's (``reference.wrenches``, built before timing: only the LP is timed), so it
solves the same problem, ``max l s.t. W alpha = 0, sum alpha = 1, alpha >= l``; ``l*`` does not
change when all wrenches are scaled alike, so its own unit-norm cone edges (ours are ``z + mu t``)
give the same ``l*`` too, and FRoGGeR's normalized margin is ``n m l*``. Its ``l*`` is checked against HiGHS (max ``|dl*|``, force-closure verdicts
on non-marginal grasps). The columns ``x FRoGGeR`` are grasps/s of ``evaluate`` and of
``min_weight`` over FRoGGeR's; without FRoGGeR they read n/a (null in the JSON). FRoGGeR is not a
dependency; to install what its ``frogger/metrics.py`` needs (numba, quantecon, SciPy; not Drake
or its other dependencies) into the environment that runs this script:

    git clone https://github.com/alberthli/frogger /tmp/frogger   # its data/ and models/ are not needed
    pip install numba quantecon
    pip install --no-deps -e /tmp/frogger

Compilation, per grasp shape (fingers, edges): the programs compiled (``evaluate`` has two, its
first pass and its retry pass, whatever the batch size), the XLA compile seconds of each and the
tracing + lowering seconds (from JAX's monitoring events), and the cost of the first call on a
batch size not seen before against a repeat of that call (the same compiled programs: no
compilation). The persistent cache is off unless ``--cache`` (else a second run would load the
programs instead of compiling them). Before timing, each batch size is run once on other grasps
of the same shape (the warm-up); the timed calls then only run.

    python experiments/bench_scoring.py                 # full table (a few minutes on 2 cores)
    python experiments/bench_scoring.py --quick         # smaller batches, for a smoke test
    python experiments/bench_scoring.py --devices 1     # one XLA CPU device (default: all cores)

Prints a table and writes ``experiments/results/bench_scoring.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import sys
import time
from pathlib import Path


def _parse():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="batches of 1k and 10k only, small baseline samples")
    ap.add_argument("--devices", type=int, default=os.cpu_count(), help="XLA CPU devices (default: cores)")
    ap.add_argument("--fingers", type=int, nargs="+", default=[3, 4, 7])
    ap.add_argument("--edges", type=int, nargs="+", default=[8, 25])
    ap.add_argument("--batches", type=int, nargs="+", default=None)
    ap.add_argument("--baseline-sample", type=int, default=200, help="grasps timed one at a time per baseline")
    ap.add_argument("--mu", type=float, default=0.364)
    ap.add_argument("--repeat", type=int, default=3, help="timed runs per batch; the best is reported")
    ap.add_argument("--cache", action="store_true", help="use grasp_jax's persistent compilation cache")
    ap.add_argument("--new-size", type=int, default=1234, help="batch size of the first-call-on-a-new-size check")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "bench_scoring.json")
    return ap.parse_args()


ARGS = _parse()
if ARGS.devices > 1 and "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (
        os.environ.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={ARGS.devices}"
    ).strip()

if not ARGS.cache:
    os.environ["GRASP_JAX_CACHE"] = "off"

import jax  # noqa: E402
import jax.monitoring  # noqa: E402
import numpy as np  # noqa: E402

import grasp_jax as gj  # noqa: E402
from grasp_jax import _batch  # noqa: E402
from grasp_jax import reference  # noqa: E402
from grasp_jax._baseline import epsilon_one  # noqa: E402

try:
    # frogger/metrics.py imports only numpy, numba, quantecon, SciPy and frogger.grasping (numpy,
    # numba) at module level, so the package installs with --no-deps (no Drake, torch, ...).
    from frogger.metrics import min_weight_lp as frogger_min_weight_lp  # noqa: E402
except ImportError:
    frogger_min_weight_lp = None

AXES = np.array([1.0, 0.7, 0.5])


def ellipsoid_grasps(num: int, n: int, seed: int):
    """``num`` grasps of ``n`` contacts uniform in direction on an ellipsoid, exact outward normals."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(num, n, 3))
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    points = u * AXES
    normals = points / AXES**2
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    return points, normals


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


#: JAX's compile-time events, in order: ``(event, seconds, function name)``.
EVENTS: list = []
COMPILE = "/jax/core/compile/backend_compile_duration"
TRACE = ("/jax/core/compile/jaxpr_trace_duration", "/jax/core/compile/jaxpr_to_mlir_module_duration")
jax.monitoring.register_event_duration_secs_listener(
    lambda event, seconds, **kw: EVENTS.append((event, seconds, str(kw.get("fun_name", "")))))


def time_evaluate(points, normals, mu, m):
    t0 = time.perf_counter()
    res = gj.evaluate(points, normals, mu=mu, num_edges=m)
    jax.block_until_ready(res)
    return time.perf_counter() - t0, res


def time_min_weight(points, normals, mu, m):
    t0 = time.perf_counter()
    res = gj.min_weight(points, normals, mu=mu, num_edges=m)
    jax.block_until_ready(res)
    return time.perf_counter() - t0, res


def frogger_baseline(points, normals, mu, m, l_ref, clear):
    """FRoGGeR's min-weight LP one grasp at a time on the sample: ``(grasps/s, JIT s, max |dl*|,
    verdicts agreeing, primal-feasible answers)``, or ``None`` without FRoGGeR. Each call gets a
    C-contiguous float64 ``(6, n m)`` wrench matrix, the layout the warm-up compiled for."""
    if frogger_min_weight_lp is None:
        return None
    mats = [np.ascontiguousarray(reference.wrenches(p, nr, mu, m).T) for p, nr in zip(points, normals)]
    t0 = time.perf_counter()
    frogger_min_weight_lp(mats[0])  # numba JIT (or its on-disk cache): not timed
    jit_s = time.perf_counter() - t0
    passes = []
    for _ in range(ARGS.repeat):
        t0 = time.perf_counter()
        for W in mats:
            frogger_min_weight_lp(W)
        passes.append(time.perf_counter() - t0)
    rate = len(mats) / min(passes)
    xs = [frogger_min_weight_lp(W)[0] for W in mats]
    l_frog = np.array([x[-1] for x in xs])
    # min_weight_lp returns no status: check that its alpha solves the equalities.
    feasible = sum(bool(np.abs(W @ x[:-1]).max() < 1e-8 and abs(x[:-1].sum() - 1.0) < 1e-8)
                   for W, x in zip(mats, xs))
    finite = np.isfinite(l_ref)
    dl = float(np.max(np.abs(l_frog - l_ref)[finite])) if finite.any() else float("nan")
    agree = int(np.sum(((l_frog > 0) == (l_ref > 0))[clear]))
    return rate, jit_s, dl, agree, feasible


def _ratio(x) -> str:
    return "n/a" if x is None else f"{x:,.0f}"


def main():
    batches = ARGS.batches or ([1_000, 10_000] if ARGS.quick else [1_000, 10_000, 100_000])
    sample = 50 if ARGS.quick else ARGS.baseline_sample
    mu = ARGS.mu
    rows = []
    print(f"grasp_jax {gj.__version__}, jax {jax.__version__}, {jax.device_count()} x {jax.devices()[0].platform}, "
          f"{os.cpu_count()} cores, {platform.processor() or platform.machine()}", flush=True)
    print("FRoGGeR min_weight_lp: " + ("found" if frogger_min_weight_lp is not None else
                                        "not installed (columns x FRoGGeR: n/a)"), flush=True)
    for m in ARGS.edges:
        for n in ARGS.fingers:
            # Compile (first call, on one grasp), then warm up on every batch size that is timed
            # (other grasps of the same shape); report what was compiled.
            warm_p, warm_n = ellipsoid_grasps(max(batches), n, seed=99)
            mark, made = len(EVENTS), dict(_batch.STATS)
            t_first, _ = time_evaluate(warm_p[:1], warm_n[:1], mu, m)
            for b in sorted(set(batches)):
                time_evaluate(warm_p[:b], warm_n[:b], mu, m)
            for b in sorted(set(batches)):  # gj.min_weight: compiled and warmed up on the same shapes
                time_min_weight(warm_p[:b], warm_n[:b], mu, m)
            ours = [(e, t) for e, t, name in EVENTS[mark:] if _batch.PROGRAM_NAME in name]
            compiles = [round(t, 2) for e, t in ours if e == COMPILE]  # the chunk programs only
            trace_s = sum(t for e, t in ours if e in TRACE)
            programs = {k: v - made.get(k, 0) for k, v in _batch.STATS.items() if v != made.get(k, 0)}
            # The first call on a batch size never seen before, against the same call again.
            new_p, new_n = ellipsoid_grasps(ARGS.new_size, n, seed=5)
            mark = len(EVENTS)
            t_new, _ = time_evaluate(new_p, new_n, mu, m)
            new_compiles = sum(e == COMPILE for e, _, _ in EVENTS[mark:])
            t_again, _ = time_evaluate(new_p, new_n, mu, m)
            t_compile = float(sum(compiles))
            print(f"n={n} m={m:2d}: compiled {len(compiles)} programs, XLA {compiles} s, tracing + lowering "
                  f"{trace_s:.1f} s, first call {t_first:.1f} s ({programs}); first call on {ARGS.new_size:,} "
                  f"grasps {t_new:.3f} s, again {t_again:.3f} s, {new_compiles} compilations", flush=True)

            # Baselines, one grasp at a time, and the accuracy check on the same grasps.
            bp, bn = ellipsoid_grasps(sample, n, seed=7)
            t0 = time.perf_counter()
            q_ref = np.array([reference.quality_highs(bp[k], bn[k], mu, m)[0] for k in range(sample)])
            highs_rate = sample / (time.perf_counter() - t0)
            qh = max(10, sample // 4)
            t0 = time.perf_counter()
            for k in range(qh):
                epsilon_one(reference.wrenches(bp[k], bn[k], mu, m))
            qhull_rate = qh / (time.perf_counter() - t0)
            l_ref = np.array([reference.min_weight_highs(bp[k], bn[k], mu, m) for k in range(sample)])
            ev = gj.evaluate(bp, bn, mu=mu, num_edges=m)
            q = np.asarray(ev.quality)
            clear = np.abs(l_ref) > 1e-6
            q_clear = clear & (np.abs(q_ref) > 1e-6)
            q_err = float(np.max(np.abs(q - q_ref)[q_clear])) if q_clear.any() else 0.0
            agree = int(np.sum((np.asarray(ev.force_closure) == (l_ref > 0))[clear]))
            frog = frogger_baseline(bp, bn, mu, m, l_ref, clear)
            frog_rate = None if frog is None else frog[0]
            if frog is not None:
                _, jit_s, dl, frog_agree, feasible = frog
                print(f"n={n} m={m:2d}: FRoGGeR min_weight_lp {frog_rate:,.0f} grasps/s (first call "
                      f"{jit_s:.1f} s: JIT or numba's cache), max |l* - l*_HiGHS| {dl:.1e}, verdicts "
                      f"{frog_agree}/{int(clear.sum())}, primal feasible {feasible}/{sample}", flush=True)

            for b in batches:
                p, nr = ellipsoid_grasps(b, n, seed=b)
                times = []
                for _ in range(ARGS.repeat):  # best of a few: the machine is shared and noisy
                    t, res = time_evaluate(p, nr, mu, m)
                    times.append(t)
                t = min(times)
                rate = b / t
                mw_times = [time_min_weight(p, nr, mu, m)[0] for _ in range(ARGS.repeat)]
                mw_rate = b / min(mw_times)
                row = dict(
                    fingers=n, edges=m, batch=b, seconds=t, all_seconds=times, grasps_per_s=rate,
                    compile_s=t_compile, compile_s_each=compiles, programs_compiled=len(compiles),
                    trace_lower_s=trace_s, first_call_s=t_first, new_size=ARGS.new_size,
                    new_size_first_s=t_new, new_size_again_s=t_again, new_size_compilations=new_compiles,
                    highs_q_per_s=highs_rate, qhull_eps_per_s=qhull_rate,
                    ratio_vs_highs=rate / highs_rate, ratio_vs_qhull=rate / qhull_rate,
                    min_weight_seconds=min(mw_times), min_weight_all_seconds=mw_times,
                    min_weight_per_s=mw_rate, frogger_min_weight_per_s=frog_rate,
                    ratio_vs_frogger=None if frog is None else rate / frog_rate,
                    min_weight_ratio_vs_frogger=None if frog is None else mw_rate / frog_rate,
                    frogger_jit_s=None if frog is None else frog[1],
                    frogger_max_abs_dl=None if frog is None else frog[2],
                    frogger_verdicts_agree=None if frog is None else frog[3],
                    frogger_feasible=None if frog is None else frog[4],
                    fc_rate=float(np.mean(np.asarray(res.force_closure))),
                    max_abs_q_err=q_err, verdicts_agree=agree, verdicts_checked=int(clear.sum()),
                    peak_rss_mb=peak_rss_mb(),
                )
                rows.append(row)
                print(
                    f"n={n} m={m:2d} batch={b:>7,}: {rate:>9,.0f} grasps/s  (x{row['ratio_vs_highs']:,.0f} HiGHS "
                    f"{highs_rate:,.0f}/s, x{row['ratio_vs_qhull']:,.0f} qhull {qhull_rate:,.0f}/s, "
                    + ("FRoGGeR n/a)  " if frog is None else
                       f"x{row['ratio_vs_frogger']:,.0f} FRoGGeR {frog_rate:,.0f}/s)  ")
                    + f"min_weight {mw_rate:,.0f}/s (x{_ratio(row['min_weight_ratio_vs_frogger'])} FRoGGeR)  "
                    f"compile {t_compile:.1f}s  FC {row['fc_rate']:.2f}  |dQ|max {q_err:.1e}  "
                    f"verdicts {agree}/{int(clear.sum())}  RSS {row['peak_rss_mb']:.0f} MB",
                    flush=True,
                )

    print()
    print("| n | m | batch | grasps/s | x HiGHS (Q LP) | x qhull (eps) | x FRoGGeR (l* LP) "
          "| min_weight grasps/s | min_weight x FRoGGeR | compile s (programs) | new size: first / again s "
          "| max abs dQ | verdicts | peak RSS MB |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['fingers']} | {r['edges']} | {r['batch']:,} | {r['grasps_per_s']:,.0f} | {r['ratio_vs_highs']:,.0f} "
            f"| {r['ratio_vs_qhull']:,.0f} | {_ratio(r['ratio_vs_frogger'])} | {r['min_weight_per_s']:,.0f} "
            f"| {_ratio(r['min_weight_ratio_vs_frogger'])} | {r['compile_s']:.1f} ({r['programs_compiled']}) "
            f"| {r['new_size_first_s']:.3f} / {r['new_size_again_s']:.3f} | {r['max_abs_q_err']:.1e} "
            f"| {r['verdicts_agree']}/{r['verdicts_checked']} | {r['peak_rss_mb']:.0f} |"
        )
    ARGS.out.parent.mkdir(parents=True, exist_ok=True)
    meta = dict(
        grasp_jax=gj.__version__, jax=jax.__version__, devices=jax.device_count(),
        platform=jax.devices()[0].platform, device_kind=jax.devices()[0].device_kind,
        cores=os.cpu_count(), mu=mu, python=sys.version.split()[0], cache=ARGS.cache,
        frogger=frogger_min_weight_lp is not None,
    )
    tmp = ARGS.out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(dict(meta=meta, rows=rows), indent=2))
    os.replace(tmp, ARGS.out)
    print(f"\nwrote {ARGS.out}")


if __name__ == "__main__":
    main()
