"""float32 against float64: force-closure verdicts and Q of ``gj.evaluate`` on random grasps.

For each object shape of the test suite's reference sets (``tests/_grasps.py``: the quadrilateral
and the star in 2D, the box, cylinder and sphere in 3D) and finger count, the same grasps are
scored from float64 and from float32 inputs (the float32 path computes in float32 only; there is
no float64 re-solve). Reported per shape:

* ``max |dQ|``: the largest ``|Q32 - Q64|`` (target <= 1e-4) of ``evaluate``, the same of
  ``gj.quality`` (float32 against ``evaluate``'s float64 Q), and the largest ``|delta32 - delta64|``;
* ``dQ > 1e-4``: how many grasps exceed it, of all and of those outside the 1e-4 band (below);
* ``disagree``: force-closure verdicts that differ on grasps *outside* the 1e-4 band, i.e. whose
  float64 verdict does not change when both margins (``delta`` and ``torque_margin``) move by
  1e-4 (target 0); ``in band``: how many grasps are within it;
* ``unconv32`` / ``unconv64``: grasps with an LP not converged;
* ``bounded32``: quality LPs unfinished in float32 whose dual bound proved ``delta* < 0`` (status
  ``BOUNDED``: not in equilibrium, Q = 0), and how many of those float64 calls in equilibrium
  (``bounded_wrong``, target 0).

Usage::

    python experiments/float32_accuracy.py                 # 100,000 grasps per shape
    python experiments/float32_accuracy.py --num 20000 --configs box:3:4:8 quad:2:3
    python experiments/float32_accuracy.py --isa AVX2      # XLA compiles for AVX2 at most

``--isa`` sets ``--xla_cpu_max_isa`` (``SSE4_2``, ``AVX``, ``AVX2``, ``AVX512``...; the default is
the host's): XLA compiles for the host's instruction set, so vector width, FMA contraction and the
order of reductions, and with them float32 results, differ between CPUs; this reproduces a narrower
CPU on a wider one. The ``halfspace`` shape (every contact on the side of a cylinder: the torques
about ``c_1`` lie in a half-space, the quality LP is ill-posed) is the hardest case for float32.

Writes ``experiments/results/float32_accuracy/results.json`` and ``results.md`` (with ``--isa``: in
``float32_accuracy/<isa>/``).
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import _common
from _grasps import (MU, QUAD, STAR, grasps, sample_box, sample_cylinder, sample_cylinder_side, sample_polygon,
                     sample_sphere)

BAND = 1e-4
SAMPLERS = {
    "quad": lambda c, r: sample_polygon(QUAD, c, r),
    "star": lambda c, r: sample_polygon(STAR, c, r),
    "box": sample_box,
    "cylinder": sample_cylinder,
    "sphere": sample_sphere,
    "halfspace": sample_cylinder_side,
}
#: shape:d:n[:m]
DEFAULT_CONFIGS = ["quad:2:3", "star:2:4", "box:3:4:8", "cylinder:3:4:8", "sphere:3:4:8", "box:3:3:8",
                   "cylinder:3:7:8", "sphere:3:4:25", "halfspace:3:4:8"]


def clear_of_band(delta, torque_margin, band=BAND):
    """Grasps whose float64 verdict does not change when both margins move by ``band``."""
    hi = (delta > -band) & (torque_margin > -band)
    lo = (delta > band) & (torque_margin > band)
    return hi == lo


def compare(name: str, d: int, n: int, m: int, num: int, seed: int) -> dict:
    import grasp_jax as gj

    rng = np.random.default_rng(seed)
    p, nr = grasps(SAMPLERS[name], num, n, rng)
    t0 = time.perf_counter()
    e64 = gj.evaluate(p, nr, mu=MU, num_edges=m)
    t64 = time.perf_counter() - t0
    t0 = time.perf_counter()
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # unconverged counts are reported below
        e32 = gj.evaluate(p.astype(np.float32), nr.astype(np.float32), mu=np.float32(MU), num_edges=m)
        t32 = time.perf_counter() - t0
        q32 = np.asarray(gj.quality(p.astype(np.float32), nr.astype(np.float32), mu=np.float32(MU), num_edges=m))
    f = {k: np.asarray(getattr(e64, k)) for k in ("force_closure", "quality", "delta", "torque_margin")}
    g = {k: np.asarray(getattr(e32, k)).astype(np.float64) for k in ("quality", "delta", "torque_margin")}
    fc32 = np.asarray(e32.force_closure)
    assert np.asarray(e32.quality).dtype == np.float32
    clear = clear_of_band(f["delta"], f["torque_margin"])
    dq = np.abs(g["quality"] - f["quality"])
    dq_quality = np.abs(q32.astype(np.float64) - f["quality"])
    dd = np.abs(g["delta"] - f["delta"])
    disagree = clear & (fc32 != f["force_closure"])
    worst = int(np.argmax(dq))
    return {
        "shape": name, "d": d, "n": n, "m": m, "num": num, "seed": seed,
        "force_closure_64": float(f["force_closure"].mean()),
        "max_abs_dQ": float(dq.max()),
        "p999_abs_dQ": float(np.quantile(dq, 0.999)),
        "max_abs_ddelta": float(dd.max()),
        "grasps_dQ_over_1e-4": int(np.sum(dq > 1e-4)),
        "max_abs_dQ_quality": float(dq_quality.max()),
        "grasps_dQ_over_1e-4_outside_band": int(np.sum(clear & (dq > 1e-4))),
        "in_band": int(np.sum(~clear)),
        "disagree_outside_band": int(disagree.sum()),
        "disagree_in_band": int(np.sum(~clear & (fc32 != f["force_closure"]))),
        "unconverged_32": int(np.sum(~e32.converged)),
        "bounded_32": int(np.sum(np.asarray(e32.quality_status) == gj.Status.BOUNDED)),
        "bounded_wrong": int(np.sum((np.asarray(e32.quality_status) == gj.Status.BOUNDED)
                                    & (np.asarray(e64.equilibrium) | (f["delta"] > g["delta"] + 1e-6)))),
        "unconverged_64": int(np.sum(~e64.converged)),
        "worst": {"index": worst, "Q64": float(f["quality"][worst]), "Q32": float(g["quality"][worst]),
                  "status32": int(np.asarray(e32.quality_status)[worst])},
        "seconds_64": t64, "seconds_32": t32,
    }


def main(argv=None) -> int:
    ap = _common.parser("float32_accuracy", __doc__)
    ap.add_argument("--num", type=int, default=100_000, help="grasps per shape (default %(default)s)")
    ap.add_argument("--configs", nargs="*", default=DEFAULT_CONFIGS, help="shape:d:n[:m] (default: %(default)s)")
    ap.add_argument("--isa", default=None, help="--xla_cpu_max_isa for XLA (SSE4_2, AVX, AVX2, ...; default: the host's)")
    args = ap.parse_args(argv)
    if args.isa:  # before JAX is imported (compare() imports it)
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} --xla_cpu_max_isa={args.isa}".strip()
    isa = args.isa or "host"
    if args.isa and args.out == _common.RESULTS / "float32_accuracy":
        args.out = args.out / args.isa.lower()
    rows, results = [], []
    for k, spec in enumerate(args.configs):
        name, d, n, *rest = spec.split(":")
        d, n = int(d), int(n)
        m = int(rest[0]) if rest else 8
        r = compare(name, d, n, m, args.num, args.seed + 7919 * k)
        results.append(r)
        rows.append([f"{name} {d}D", n, m if d == 3 else "-", r["num"], r["max_abs_dQ"], r["max_abs_dQ_quality"], r["max_abs_ddelta"],
                     f"{r['grasps_dQ_over_1e-4']} / {r['grasps_dQ_over_1e-4_outside_band']}", r["disagree_outside_band"], r["in_band"], r["unconverged_32"],
                     r["unconverged_64"], f"{r['bounded_32']} / {r['bounded_wrong']}", f"{r['seconds_32']:.1f} / {r['seconds_64']:.1f}"])
        print(json.dumps(r), flush=True)
    text = _common.table(
        ["shape", "n", "m", "grasps", "max abs dQ", "max abs dQ of quality()", "max abs d delta", "dQ > 1e-4 all / outside band", "disagree outside band",
         "in band", "unconv f32", "unconv f64", "bounded f32 / wrong", "s f32 / f64"], rows)
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps({"band": BAND, "mu": MU, "isa": isa, "results": results}, indent=1))
    _common.write(args.out, f"# float32 against float64 (XLA ISA: {isa})\n\n" + text)
    ok = all(max(r["max_abs_dQ"], r["max_abs_dQ_quality"]) <= 1e-4 and r["disagree_outside_band"] == 0 and r["unconverged_32"] == 0
             for r in results)
    print("targets met" if ok else "targets NOT met")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
