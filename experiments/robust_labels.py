"""Robust labels (``gj.robust``): throughput, memory and Monte Carlo agreement on this machine.

Measures, each size in a fresh process (one XLA device per CPU core, as the command line):

1. **throughput**: ``gj.robust`` of N random 4-finger grasps of the ellipsoid (m = 8 cone edges)
   x S perturbations (contact position 0.02 R, normal 0.05 rad, friction x U[0.8, 1.2], pose
   0.02 rad / 0.01 R), after a warm-up call that compiles, with and without the min-weight margin;
   perturbed grasps scored per second, and the perturbation's share of the time;
2. **peak RSS** (``VmHWM``) of the process at each N: memory should not grow with N;
3. **agreement**: P(force-closure) from S samples against an independent 10x larger sample
   (another key), on held-out grasps: the fraction within 3 combined standard errors.

Targets (issue 24): 10^5 grasps x 100 perturbations in at most 4 minutes on a 2-core CPU, peak
memory at 10^5 at most 1.3x that at 10^4; P(force-closure) within 3 standard errors of a 10x
larger sample on at least 98% of held-out grasps.

    python experiments/robust_labels.py                        # N = 1e3, 1e4 (a few minutes)
    python experiments/robust_labels.py --sizes 1e4,1e5        # the issue's sizes (~10 min on 2 cores)

Prints a table and writes ``experiments/results/robust_labels/results.json`` and ``results.md``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import _common  # noqa: E402

NOISE = dict(position=0.02, normal=0.05, friction=(0.8, 1.2), rotation=0.02, translation=0.01)

# One size in a fresh interpreter: prints one JSON line with the timings and its own peak RSS.
_CHILD = """
import json, sys, time
sys.path.insert(0, sys.argv[1])
import _common
_common.use_cpu_cores()
import jax, numpy as np, grasp_jax as gj
from grasp_jax import objects, sampling, _robust
num, samples, margin, seed = int(sys.argv[2]), int(sys.argv[3]), sys.argv[4] == "1", int(sys.argv[5])
noise = gj.Noise(**json.loads(sys.argv[6]))
obj = objects.Ellipsoid()
p, n = sampling.sample_grasps(obj, num, 4, seed=seed)
warm = gj.robust(obj, p[:_robust.ROWS // samples], n[:_robust.ROWS // samples], mu=0.364, noise=noise, key=jax.random.key(1), samples=samples, margin=margin)
spent = {"perturb": 0.0}
inner = _robust._Perturber.__call__
def timed(self, start, stop):
    t = time.perf_counter(); out = inner(self, start, stop); spent["perturb"] += time.perf_counter() - t; return out
_robust._Perturber.__call__ = timed
t = time.perf_counter()
res = gj.robust(obj, p, n, mu=0.364, noise=noise, key=jax.random.key(1), samples=samples, margin=margin)
wall = time.perf_counter() - t
with open("/proc/self/status") as f:
    peak = next(int(l.split()[1]) for l in f if l.startswith("VmHWM:")) / 1024
print(json.dumps({"num": num, "samples": samples, "margin": margin, "seconds": wall, "perturb_seconds": spent["perturb"],
                  "per_second": num * samples / wall, "peak_rss_mib": peak, "devices": len(jax.local_devices()),
                  "p_fc_mean": float(res.p_fc.mean()), "unconverged": int(res.unconverged.sum())}))
"""


def run_size(num: int, samples: int, margin: bool, seed: int) -> dict:
    out = subprocess.run([sys.executable, "-c", _CHILD, str(HERE), str(num), str(samples), "1" if margin else "0",
                          str(seed), json.dumps(NOISE)], capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"size {num} failed ({out.returncode}): {out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def agreement(held_out: int, samples: int, seed: int) -> dict:
    """P(FC) of ``samples`` draws against 10x as many (an independent key) on held-out grasps."""
    import jax
    import numpy as np

    import grasp_jax as gj
    from grasp_jax import objects, sampling

    obj = objects.Ellipsoid()
    p, n = sampling.sample_grasps(obj, held_out, 4, seed=seed + 1000)  # not the throughput grasps
    noise = gj.Noise(**NOISE)
    small = gj.robust(obj, p, n, mu=0.364, noise=noise, key=jax.random.key(seed + 1), samples=samples, margin=False)
    large = gj.robust(obj, p, n, mu=0.364, noise=noise, key=jax.random.key(seed + 2), samples=10 * samples,
                      margin=False)
    se = np.sqrt(small.p_fc_se**2 + large.p_fc_se**2)
    diff = np.abs(small.p_fc - large.p_fc)
    within = diff <= 3 * se + 1e-12
    # the grasps whose P(FC) is 0 or 1 in both have se = 0 and agree exactly; count the others too
    mixed = (large.p_fc > 0) & (large.p_fc < 1)
    return {"held_out": held_out, "samples": samples, "within_3se": float(within.mean()),
            "within_3se_uncertain_grasps": float(within[mixed].mean()) if mixed.any() else None,
            "uncertain_grasps": int(mixed.sum()), "max_abs_difference": float(diff.max())}


def main(argv=None) -> int:
    ap = _common.parser("robust_labels", __doc__)
    ap.add_argument("--sizes", default="1e3,1e4", help="grasps per run, comma-separated (default %(default)s)")
    ap.add_argument("--samples", type=int, default=100)
    ap.add_argument("--held-out", type=int, default=1000, help="grasps of the agreement check")
    ap.add_argument("--no-margin-runs", action="store_true", help="only runs without the min-weight margin")
    args = ap.parse_args(argv)
    sizes = [int(float(s)) for s in args.sizes.split(",")]
    timer = _common.Timer()
    runs = []
    for num in sizes:
        for margin in ((False,) if args.no_margin_runs else (False, True)):
            r = run_size(num, args.samples, margin, args.seed)
            runs.append(r)
            print(f"{num:>8,} grasps x {r['samples']} ({'with' if margin else 'no'} margin): {r['seconds']:7.1f} s, "
                  f"{r['per_second']:9,.0f} perturbed grasps/s, perturbation {r['perturb_seconds']:.1f} s, "
                  f"peak RSS {r['peak_rss_mib']:,.0f} MiB", flush=True)
    timer.lap("throughput")
    _common.use_cpu_cores()
    agree = agreement(args.held_out, args.samples, args.seed)
    timer.lap("agreement")
    rows = [[f"{r['num']:,}", r["samples"], "yes" if r["margin"] else "no", round(r["seconds"], 1),
             f"{r['per_second']:,.0f}", round(r["perturb_seconds"], 1), f"{r['peak_rss_mib']:,.0f}", r["devices"]]
            for r in runs]
    header = ["grasps", "samples", "margin", "seconds", "perturbed grasps/s", "perturb s", "peak RSS MiB", "devices"]
    text = ["# Robust labels: throughput, memory, agreement", "",
            f"Ellipsoid, 4 fingers, m = 8, noise {NOISE}.", "", _common.table(header, rows), ""]
    for margin in (False, True):
        sel = [r for r in runs if r["margin"] == margin]
        if len(sel) >= 2:
            ratio = sel[-1]["peak_rss_mib"] / sel[0]["peak_rss_mib"]
            text.append(f"Peak RSS at {sel[-1]['num']:,} / at {sel[0]['num']:,} grasps ({'with' if margin else 'no'} "
                        f"margin): {ratio:.2f}x.")
    text += ["", f"Agreement: P(FC) from {agree['samples']} samples within 3 standard errors of {10 * agree['samples']} "
             f"samples (independent key) on {100 * agree['within_3se']:.1f}% of {agree['held_out']:,} held-out grasps "
             f"({agree['uncertain_grasps']} with 0 < P < 1)."]
    text += ["", timer.report()]
    print("\n".join(text))
    _common.write(args.out, "\n".join(text))
    _common.write_json(args.out, {"runs": runs, "agreement": agree, "noise": NOISE})
    return 0


if __name__ == "__main__":
    sys.exit(main())
