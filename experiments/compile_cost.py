"""What compiling a chunk program costs on this machine, and where the cost comes from.

A concrete call of ``gj.evaluate``, ``gj.quality`` or ``gj.min_weight`` runs one compiled chunk
program per grasp shape and dtype (``grasp_jax._batch``). This script lowers each of those
programs the way a first call would (nothing is scored), compiles it with the library's XLA options
(``_batch.COMPILER_OPTIONS``) and reports, per function and dtype:

* the wall seconds of the compile and the CPU seconds of this process meanwhile (CPU above wall:
  XLA compiles on several threads);
* the kernels of the compiled program (fusions, dots and library calls outside fused code), in
  all and in its largest loop bodies (the interior-point loops, the crossover's pivot loop), and
  the milliseconds of compile per kernel. With XLA's CPU fusion emitters the compile time follows
  the kernel count: each fused kernel becomes an MLIR module of its own.

``--options`` compiles the same programs under other XLA options as well (the alternatives measured
for the compile-time target of issue #8): XLA's classic CPU emitters, the ``FAST_COMPILE`` preset,
LLVM optimization levels 0 and 3 (the library uses 1). A program is compiled once per option set
(JAX keeps a compiled program in memory; a second compile would not compile), so one run gives one
sample per cell: compare runs made at the same hour, the machine's speed varies by 1.5-2x.

    python experiments/compile_cost.py                          # 4 fingers, 8 edges, both dtypes
    python experiments/compile_cost.py --fingers 4 --edges 25 --options

Prints a table and writes ``experiments/results/compile_cost.json``. The persistent cache is off.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import resource
import sys
import time
import warnings
from pathlib import Path

os.environ["GRASP_JAX_CACHE"] = "off"  # compile, never load (before grasp_jax is imported)

import numpy as np  # noqa: E402

import grasp_jax as gj  # noqa: E402
from grasp_jax import _batch  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
FUNCTIONS = ("evaluate", "quality", "min_weight")
#: The alternatives of ``--options`` (added to the library's options).
ALTERNATIVES = {
    "classic emitters": {"xla_cpu_use_fusion_emitters": False},
    "FAST_COMPILE preset": {"xla_cpu_opt_preset": "CPU_OPT_PRESET_FAST_COMPILE"},
    "LLVM level 0": {"xla_backend_optimization_level": 0},
    "LLVM level 3 (XLA's default)": {"xla_backend_optimization_level": 3},
}
#: An instruction that is a kernel of its own in a compiled CPU program.
KERNEL = re.compile(r"= \S+ (fusion|dot|custom-call|convolution)\(")


class _Lowered(Exception):
    """Raised by :func:`_capture` to stop a call once its chunk program is lowered."""

    def __init__(self, lowered):
        super().__init__("lowered")
        self.lowered = lowered


def _capture(lowered, text, devices, options):  # stands in for ``_batch._compile``
    raise _Lowered(lowered)


def lower(function: str, fingers: int, edges: int, dtype) -> object:
    """The chunk program a first concrete call of ``gj.<function>`` compiles, lowered, not compiled."""
    rng = np.random.default_rng(0)
    normals = rng.normal(size=(64, fingers, 3))
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    points = normals * np.array([1.0, 0.7, 0.5])  # an ellipsoid's points, with the sphere's normals
    compile_ = _batch._compile
    _batch._compile = _capture
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            getattr(gj, function)(points.astype(dtype), normals.astype(dtype), mu=dtype(0.364), num_edges=edges)
    except _Lowered as got:
        return got.lowered
    finally:
        _batch._compile = compile_
    raise RuntimeError(f"gj.{function} compiled no chunk program")


def kernels(hlo: str) -> tuple[int, list[tuple[str, int]]]:
    """``(total, [(computation, kernels)] of the loop bodies, largest first)`` of a compiled program."""
    computations = re.split(r"\n(?=\S)", hlo)
    bodies = set(re.findall(r"body=(%[\w.-]+)", hlo))
    total, loops = 0, []
    for comp in computations:
        head = comp.split("\n", 1)[0]
        name = head.split(" ")[0]
        if "fused" in name or head.startswith("HloModule"):  # a kernel's body, or the module line
            continue
        count = len(KERNEL.findall(comp))
        total += count
        if name in bodies and count:
            loops.append((name, count))
    return total, sorted(loops, key=lambda kv: -kv[1])


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def compile_once(lowered, options: dict) -> dict:
    wall, cpu = time.perf_counter(), _cpu()
    compiled = lowered.compile(compiler_options=options)
    wall, cpu = time.perf_counter() - wall, _cpu() - cpu
    total, loops = kernels(compiled.as_text())
    return {"compile_s": wall, "cpu_s": cpu, "kernels": total, "loop_kernels": [k for _, k in loops[:5]],
            "ms_per_kernel": 1e3 * wall / max(total, 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--fingers", type=int, default=4)
    ap.add_argument("--edges", type=int, default=8)
    ap.add_argument("--functions", nargs="+", choices=FUNCTIONS, default=list(FUNCTIONS))
    ap.add_argument("--dtypes", nargs="+", choices=("float64", "float32"), default=["float64", "float32"])
    ap.add_argument("--options", action="store_true", help="also compile under the alternatives")
    ap.add_argument("--out", type=Path, default=RESULTS / "compile_cost.json")
    args = ap.parse_args()

    library = _batch._options("cpu")
    variants = {"library": library}
    if args.options:
        variants.update({name: {**library, **extra} for name, extra in ALTERNATIVES.items()})
    rows = []
    for dtype in args.dtypes:
        for function in args.functions:
            lowered = lower(function, args.fingers, args.edges, np.dtype(dtype).type)
            for variant, options in variants.items():
                try:
                    row = compile_once(lowered, options)
                except Exception as e:  # an option this XLA does not know
                    print(f"{function} {dtype} {variant}: {str(e).splitlines()[0]}", file=sys.stderr)
                    continue
                row.update(function=function, dtype=dtype, options=variant)
                rows.append(row)
                print(f"{function:10s} {dtype:8s} {variant:28s} {row['compile_s']:6.2f} s wall "
                      f"{row['cpu_s']:6.2f} s CPU  {row['kernels']:4d} kernels "
                      f"(loops {row['loop_kernels']})", flush=True)

    print(f"\n{args.fingers} fingers, {args.edges} edges; target: at most 5 s per program\n")
    print("| function | dtype | XLA options | compile s | CPU s | kernels | largest loops (kernels) | ms per kernel |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['function']} | {r['dtype']} | {r['options']} | {r['compile_s']:.2f} | {r['cpu_s']:.2f} "
              f"| {r['kernels']} | {', '.join(map(str, r['loop_kernels']))} | {r['ms_per_kernel']:.1f} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    meta = {"fingers": args.fingers, "edges": args.edges, "library_options": library,
            "machine": platform.machine(), "cpus": os.cpu_count(), "python": platform.python_version(),
            "jax": __import__("jax").__version__, "date": time.strftime("%Y-%m-%d %H:%M")}
    tmp = args.out.with_suffix(".tmp")
    tmp.write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    tmp.replace(args.out)
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
