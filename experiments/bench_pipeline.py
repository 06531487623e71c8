"""End-to-end pipeline throughput and memory on this machine.

Measures, in one run:

1. **end to end**: ``grasp-jax sample glass --fingers 4 --num N --out FILE.npz`` through
   :func:`grasp_jax.pipeline.run` in this process (sampling in a background thread, scoring on every
   CPU device, streaming to ``.npz``), after a warm-up run that compiles; the compilation time is
   reported separately;
2. **raw**: :func:`grasp_jax.evaluate` alone on the same ``N`` grasps, already in memory;
3. **peak RSS** of the real command (``grasp_jax.cli.main(["sample", ..., "--out", ...])``) at
   ``N / 10`` and ``N`` grasps, each in a fresh subprocess that reports its own ``VmHWM`` (the
   child's ``ru_maxrss`` would include this process's memory, which Linux carries over fork/exec).

Targets: end-to-end at least 70% of raw throughput; peak RSS at N at most 1.5x the one at N / 10.

    python experiments/bench_pipeline.py                 # N = 1e6 (a few minutes on 2 cores)
    python experiments/bench_pipeline.py --num 100000    # quicker

Writes ``experiments/results/bench_pipeline.json`` (``--json`` elsewhere).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent


def _count(text: str) -> int:
    return int(float(text))


# Runs the real command line in a fresh interpreter and reports the peak resident memory of that
# interpreter's own address space (VmHWM). ``ru_maxrss`` of a child is no good here: Linux carries the
# parent's peak over the fork and exec, and the parent of this benchmark holds 10^6 grasps.
_CHILD = """
import resource, sys
from grasp_jax.cli import main
code = main(sys.argv[1:])
peak = None
try:
    with open('/proc/self/status') as f:
        peak = next(int(l.split()[1]) for l in f if l.startswith('VmHWM:'))
except (OSError, StopIteration):
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print('PEAK_KIB', peak, file=sys.stderr)
sys.exit(code)
"""


def peak_rss_mib(args: list[str], env: dict, cwd: str) -> tuple[float, float]:
    """``(peak RSS MiB, wall seconds)`` of ``grasp-jax *args`` in a fresh process."""
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", _CHILD, *args], env=env, cwd=cwd, stdout=subprocess.DEVNULL,
                         stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    if out.returncode != 0:
        raise RuntimeError(f"grasp-jax {' '.join(args)} failed ({out.returncode}): {out.stderr[-2000:]}")
    kib = int(out.stderr.split("PEAK_KIB")[-1].split()[0])
    return kib / 1024, wall


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--num", type=_count, default=1_000_000, help="grasps (default 1e6)")
    ap.add_argument("--object", default="glass")
    ap.add_argument("--fingers", type=int, default=4)
    ap.add_argument("--chunk", type=_count, default=None, help="pipeline chunk (default: the CLI's)")
    ap.add_argument("--devices", type=int, default=None, help="CPU devices (default: one per core)")
    ap.add_argument("--skip-rss", action="store_true", help="skip the two memory subprocesses")
    ap.add_argument("--json", type=Path, default=HERE / "results" / "bench_pipeline.json")
    args = ap.parse_args(argv)

    from grasp_jax import devices as _devices
    from grasp_jax import pipeline

    _devices.configure_cpu_devices(args.devices)  # before JAX starts its backend

    import warnings

    import jax
    import numpy as np

    warnings.filterwarnings("ignore", message=r".*did not converge", category=RuntimeWarning)

    import grasp_jax as gj
    from grasp_jax import objects, sampling

    obj = objects.load(args.object)
    chunk = args.chunk or pipeline.default_chunk()
    num, fingers = args.num, args.fingers
    devices = len(jax.local_devices())
    print(f"{args.object}, {fingers} fingers, {num:,} grasps, chunk {chunk:,}, {devices} CPU devices "
          f"({_devices.available_cores()} cores)", flush=True)

    with tempfile.TemporaryDirectory(prefix="bench_pipeline_") as tmp:
        tmp = Path(tmp)
        # Warm-up: compiles the chunk programs (one full chunk and the padded last one).
        t = time.perf_counter()
        warm = pipeline.run(obj, min(chunk, num), fingers, seed=1, chunk=chunk)
        compile_s = time.perf_counter() - t
        print(f"warm-up ({warm.num:,} grasps, includes compilation): {compile_s:.1f} s", flush=True)

        # 1. End to end, streaming to .npz.
        out = tmp / "e2e.npz"
        summary = pipeline.run(obj, num, fingers, seed=0, chunk=chunk, out=out)
        e2e_s = summary.seconds
        size_mib = out.stat().st_size / 2**20
        print(f"end to end: {e2e_s:.1f} s, {summary.grasps_per_second:,.0f} grasps/s "
              f"({size_mib:.0f} MiB written)", flush=True)
        out.unlink()

        # 2. Raw evaluate on the same grasps, in memory.
        t = time.perf_counter()
        points, normals = sampling.sample_grasps(obj, num, fingers, seed=0)
        sample_s = time.perf_counter() - t
        t = time.perf_counter()
        res = gj.evaluate(points, normals, mu=pipeline.DEFAULT_MU)
        fc = np.asarray(res.force_closure)
        raw_s = time.perf_counter() - t
        same = int(fc.sum()) == summary.force_closure
        print(f"raw evaluate: {raw_s:.1f} s, {num / raw_s:,.0f} grasps/s (sampling alone {sample_s:.1f} s; "
              f"same force-closure count: {same})", flush=True)
        del points, normals, res, fc

        # 3. Peak RSS of the command at num / 10 and num, fresh processes.
        rss = {}
        if not args.skip_rss:
            env = dict(os.environ)
            env.setdefault("GRASP_JAX_CACHE", str(tmp / "xla-cache"))

            def measure(n: int) -> tuple[float, float]:
                cmd = ["sample", args.object, "--fingers", str(fingers), "--num", str(n), "--chunk", str(chunk),
                       "--out", str(tmp / "rss.npz"), "--quiet"]
                if args.devices:
                    cmd += ["--devices", str(args.devices)]
                result = peak_rss_mib(cmd, env, str(tmp))
                (tmp / "rss.npz").unlink()
                return result

            small = max(num // 10, 1)
            # A first, unmeasured run fills the compilation cache, so that neither measured run
            # compiles (compiling takes a few hundred MiB of its own).
            mib, wall = measure(small)
            print(f"(cache warm-up run: {mib:,.0f} MiB, {wall:.1f} s)", flush=True)
            for n in (small, num):
                rss[n] = measure(n)
                print(f"peak RSS at {n:,} grasps: {rss[n][0]:,.0f} MiB ({rss[n][1]:.1f} s)", flush=True)

    e2e_rate = num / e2e_s
    raw_rate = num / raw_s
    compile_est = max(compile_s - warm.num / raw_rate, 0.0)  # the warm-up also scored one chunk
    result = {
        "machine": {"platform": platform.platform(), "python": platform.python_version(),
                    "jax": jax.__version__, "cores": _devices.available_cores(), "devices": devices},
        "object": args.object, "fingers": fingers, "num": num, "chunk": chunk,
        "warmup_seconds": compile_s,
        "compile_seconds_estimate": compile_est,
        "end_to_end": {"seconds": e2e_s, "grasps_per_second": e2e_rate, "output_mib": size_mib,
                       "first_chunk_seconds": summary.first_chunk_seconds,
                       "force_closure_rate": summary.force_closure_rate},
        "raw_evaluate": {"seconds": raw_s, "grasps_per_second": raw_rate, "sampling_seconds": sample_s},
        "ratio_end_to_end_over_raw": e2e_rate / raw_rate,
        "peak_rss_mib": {str(n): v[0] for n, v in rss.items()},
        "rss_ratio": (rss[num][0] / rss[max(num // 10, 1)][0]) if rss else None,
        "targets": {"ratio_end_to_end_over_raw": ">= 0.70", "rss_ratio": "<= 1.5"},
    }
    rows = [
        ("compile (warm-up run minus its scoring)", f"{compile_est:.1f} s", f"warm-up {compile_s:.1f} s"),
        ("end to end (sample + score + .npz)", f"{e2e_s:.1f} s", f"{e2e_rate:,.0f} grasps/s"),
        ("raw gj.evaluate (in memory)", f"{raw_s:.1f} s", f"{raw_rate:,.0f} grasps/s"),
        ("end to end / raw", f"{e2e_rate / raw_rate:.2f}", "target >= 0.70"),
    ]
    for n, (mib, _) in rss.items():
        rows.append((f"peak RSS, {n:,} grasps", f"{mib:,.0f} MiB", ""))
    if rss:
        rows.append((f"RSS ratio {num:,} / {max(num // 10, 1):,}", f"{result['rss_ratio']:.2f}", "target <= 1.5"))
    w = max(len(r[0]) for r in rows)
    print()
    print(f"{'measure':<{w}}  {'value':>12}  note")
    for name, value, note in rows:
        print(f"{name:<{w}}  {value:>12}  {note}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=2) + "\n")
    print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
