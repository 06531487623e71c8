"""Gradient optimization of contacts against random sampling, at equal wall-clock time (issue 7).

For every object and finger count (a *row*), each method gets the same time budget ``--seconds``
of work (compilation excluded, see below):

``sampling``
    random grasps (``sampling.sample_grasps``, contacts uniform by area) scored by
    ``gj.evaluate``, in rounds of ``--sample-round`` grasps until the budget is spent. To be
    conservative in its favour, sampling runs after the two optimizers of its row and gets the
    larger of ``--seconds`` and the time they actually took.
``optimize``
    ``gj.optimize`` (objective ``"closure"``) from random starts, in rounds of ``--starts`` starts
    of ``--steps`` steps (keys ``seed * 100003 + round``), until the budget is spent.
``refine``
    sample, then refine: ``--refine-fraction`` of the budget sampling as above, then
    ``gj.optimize(init=...)`` on the best distinct sampled grasps (force-closure ones by Q first,
    then the others by signed Q), in rounds of ``--starts``, for the rest. Its grasps are the
    sampled and the refined ones together (what the user holds at the end).
``dfc``, ``dfc_eig``, ``min_weight``, ``signed_q``
    the field's energies, optimized from the same random starts by the same machinery
    (``monitor=False``: no extra LP per step), then scored by the exact test (``gj.evaluate``,
    which ``gj.optimize`` runs on its results): DexGraspNet's ``||sum_i [n_i; p_i x n_i]||^2``,
    plus DFC's eigenvalue term (Liu et al. 2021), FRoGGeR's min-weight margin (Li et al. 2023),
    and signed Q alone.

Rounds: a method starts another round unless it would end more than half a round past the
budget (it always runs one), so its time lands within half a round of the budget; the column
``s`` says what it took. Timed is only the work (sampling, scoring, optimizing); the statistics
kept after each round for the Q-vs-time curves are not.

Tuning rule (the same for every row; nothing is set per object): ``--starts`` 256 per round (the
smallest batch ``gj.optimize`` compiles: fewer cost the same), ``--steps`` 100, and from random
starts ``gj.optimize``'s default optimizer (``--learning-rate``: its default peak of 0.3 object
radii per step, cosine decay, Adam restarted after a third of the steps at a sixth of the rate);
sample-then-refine uses
``gj.optimize``'s default 0.02 (``--refine-learning-rate``): its starts are already good, and
large steps would throw them across the object.

Compilation: before any timing, every method runs once on the shapes it will be timed on (one
round: a call with the same starts and steps, one sampling round); that warm-up (compile + one
round) is reported per row in the column ``warm-up s`` and is not in the budget. Compiled
programs are kept in the command line's XLA cache (``~/.cache/grasp_jax/xla``, ``--no-cache``
to disable), so a second run on the same shapes skips most compilation.

Columns: best Q; median Q of the best 100 *distinct* force-closure grasps
(``_optimize.distinct_grasps``: contacts in the same cells of a grid of 1% of the object's radius,
``c_2..c_n`` in any order, are one grasp; with fewer than 100 distinct the median is over those
and the count is shown); force-closure fraction of the starts (of the samples for ``sampling``);
how many results are not force-closure; distinct force-closure grasps; time. Friction 20 deg
(mu = tan 20 deg), m = 8 cone edges (``--edges``), all CPU cores as XLA devices.

Objects: the built-in glass and mechanical part, a sphere, and two real meshes from
``../shared/data/meshes`` (``ycb_011_banana.obj``, ``trimesh_featuretype.STL``) when present.

    python experiments/optimize_vs_sampling.py [--seconds 20] [--objects glass part sphere ...]
        [--fingers 3 4 5] [--methods ...] [--steps 100] [--starts 256] [--out DIR] [--quick]

``--quick`` (sphere, 3 fingers, 2 s per method, 20 steps) checks that the script works: under a
minute once its programs are in the compilation cache (the first run compiles them: a few
minutes on a loaded 2-core CPU). Writes ``results.md``, ``results.json`` and
``optimize_vs_sampling.png`` to ``--out`` (default ``experiments/results/optimize_vs_sampling/``).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402

from _common import (  # noqa: E402
    SHARED_MESHES,
    Timer,
    compilation_cache,
    mu_of,
    parser,
    table,
    use_cpu_cores,
    write,
    write_json,
)

DEFAULT_OBJECTS = ("glass", "part", "sphere", "ycb_011_banana.obj", "trimesh_featuretype.STL")
#: method -> objective of ``gj.optimize`` (``None``: sampling only).
METHODS = {"sampling": None, "optimize": "closure", "refine": "closure", "dfc": "dfc",
           "dfc_eig": "dfc_eig", "min_weight": "min_weight", "signed_q": "signed_q"}
BASELINES = ("dfc", "dfc_eig", "min_weight", "signed_q")


def gj_rate(rate):
    """The peak learning rate from random starts: ``--learning-rate`` or ``gj.optimize``'s default."""
    from grasp_jax._optimize import DEFAULT_LEARNING_RATE

    return DEFAULT_LEARNING_RATE if rate is None else rate


#: Refining sampled grasps (already good): ``gj.optimize``'s default, 0.02 radii per step, so that a
#: start climbs to its own local optimum instead of being thrown across the object.
REFINE_LEARNING_RATE = 0.02
#: The Q statistics are over the best this many distinct force-closure grasps.
TOP = 100
#: Distinct grasps kept between rounds for the Q-vs-time curves.
KEEP = 2000


@dataclasses.dataclass
class Run:
    """One method on one row: everything it found and how long it took."""

    method: str
    objective: str | None
    cell: float  # grid cell of distinct grasps (object units)
    seconds: float = 0.0  # work time
    warmup: float = 0.0  # compile + one round, not in the budget
    tried: int = 0  # samples (sampling) or starts (optimizers)
    fc: int = 0  # force-closure among them
    samples: int = 0  # refine: grasps sampled before refining
    rounds: int = 0
    points: list = dataclasses.field(default_factory=list)  # force-closure grasps, (k, n, d) each
    quality: list = dataclasses.field(default_factory=list)
    objective_values: list = dataclasses.field(default_factory=list)  # optimizers: per start
    reasons: dict = dataclasses.field(default_factory=dict)
    curve: list = dataclasses.field(default_factory=list)  # (seconds, best, median of top, distinct so far)
    _top: tuple | None = None  # (points, quality) of the best KEEP distinct so far

    def add(self, points, quality, force_closure, seconds):
        """Record one round: all its grasps' verdicts, its force-closure grasps and their Q."""
        from grasp_jax._optimize import distinct_grasps

        fc = np.asarray(force_closure, bool)
        self.tried += len(fc)
        self.fc += int(fc.sum())
        self.seconds += seconds
        self.rounds += 1
        p, q = np.asarray(points)[fc], np.asarray(quality)[fc]
        self.points.append(p)
        self.quality.append(q)
        if self._top is not None:
            p, q = np.concatenate([self._top[0], p]), np.concatenate([self._top[1], q])
        keep = distinct_grasps(p, q, self.cell)[:KEEP]
        self._top = (p[keep], q[keep])
        top = self._top[1][:TOP]
        self.curve.append((self.seconds, float(top[0]) if len(top) else 0.0,
                           float(np.median(top)) if len(top) else 0.0, len(self._top[1])))

    def stats(self) -> dict:
        from grasp_jax._optimize import distinct_grasps

        if self.points:
            p, q = np.concatenate(self.points), np.concatenate(self.quality)
        else:
            p, q = np.zeros((0, 1, 3)), np.zeros(0)
        idx = distinct_grasps(p, q, self.cell) if len(q) else np.zeros(0, int)
        top = q[idx[:TOP]]
        objective = np.concatenate(self.objective_values) if self.objective_values else np.zeros(0)
        return dict(
            method=self.method, objective=self.objective, seconds=self.seconds, warmup_seconds=self.warmup,
            rounds=self.rounds, tried=self.tried, samples=self.samples, force_closure=self.fc,
            force_closure_fraction=self.fc / self.tried if self.tried else 0.0,
            not_force_closure=self.tried - self.fc, distinct_force_closure=int(len(idx)),
            best_q=float(top[0]) if len(top) else 0.0,
            median_q_top=float(np.median(top)) if len(top) else 0.0, top_count=int(len(top)),
            q_percentiles_all_fc={k: float(np.percentile(q, k)) for k in (10, 50, 90)} if len(q) else {},
            objective_percentiles={k: float(np.percentile(objective, k)) for k in (10, 50, 90)}
            if len(objective) else {},
            reasons=self.reasons, curve=self.curve,
        )


def candidates(fc, q, delta, count: int):
    """``(indices, rank)`` of the ``count`` best sampled grasps for refining, best first:
    force-closure grasps by Q above every other grasp, those by signed Q."""
    rank = np.where(fc, 1.0 + q, np.minimum(delta, 0.0) - 1.0)
    top = np.argsort(-rank)[:count]
    return top, rank[top]


def _resolve(name: str) -> str:
    """A built-in name, a path, or a file name in ``../shared/data/meshes``."""
    from grasp_jax import objects

    if name.lower() in objects.BUILTIN_NAMES or Path(name).is_file():
        return name
    return str(SHARED_MESHES / name)


class Row:
    """The methods of one (object, fingers) row and their shared settings."""

    def __init__(self, obj, fingers: int, args, mu: float):
        self.obj, self.fingers, self.args, self.mu = obj, fingers, args, mu
        self.cell = float(args.distinct_tol) * float(obj.radius)
        self.sample_round = 0
        self.key_round = 0

    # -- the work, timed by the callers ------------------------------------------------------
    def sample(self, seed: int):
        import grasp_jax as gj
        from grasp_jax import sampling

        p, n = sampling.sample_grasps(self.obj, self.args.sample_round, self.fingers, seed=seed)
        ev = gj.evaluate(p, n, mu=self.mu, num_edges=self.args.edges)
        return p, n, np.asarray(ev.force_closure), np.asarray(ev.quality), np.asarray(ev.delta)

    def optimize(self, objective: str, *, key=None, init=None):
        import grasp_jax as gj

        if init is not None:  # refining good starts: small steps (the rule of the module docstring)
            extra = dict(init=init, learning_rate=self.args.refine_learning_rate)
        else:
            extra = dict(key=key, starts=self.args.starts, learning_rate=self.args.learning_rate)
        return gj.optimize(self.obj, fingers=self.fingers, mu=self.mu, steps=self.args.steps,
                           num_edges=self.args.edges, objective=objective,
                           monitor=objective == "closure",  # free for closure; no extra LP for the others
                           **extra)

    # -- methods -----------------------------------------------------------------------------
    def warm_up(self, methods) -> dict:
        """One round of every method on the shapes it will be timed on: ``{method: seconds}``."""
        out = {}
        t0 = time.perf_counter()
        p, n, fc, q, delta = self.sample(seed=10**6)
        out["sampling"] = time.perf_counter() - t0
        for method in methods:
            objective = METHODS[method]
            if objective is None:
                continue
            t0 = time.perf_counter()
            if method == "refine":
                self.optimize(objective, init=p[: self.args.starts])
            else:
                self.optimize(objective, key=10**6)
            out[method] = time.perf_counter() - t0
        return out

    def run_sampling(self, budget: float, run: Run | None = None, keep: int = 0):
        """Sampling rounds until ``budget`` seconds; with ``keep``, also the best ``keep``
        candidates for refining (points, ranked)."""
        run = run or Run("sampling", None, self.cell)
        cand_p, cand_key = [], []
        spent = 0.0
        while True:
            t0 = time.perf_counter()
            p, _, fc, q, delta = self.sample(seed=self.args.seed * 1000 + self.sample_round)
            dt = time.perf_counter() - t0
            self.sample_round += 1
            spent += dt
            run.add(p, q, fc, dt)
            if keep:
                top, rank = candidates(fc, q, delta, 4 * keep)
                cand_p.append(p[top])
                cand_key.append(rank)
            if spent + 0.5 * dt > budget:
                break
        if not keep:
            return run, None
        from grasp_jax._optimize import distinct_grasps

        p, key = np.concatenate(cand_p), np.concatenate(cand_key)
        order = distinct_grasps(p, key, self.cell)[:keep]
        return run, p[order]

    def run_optimize(self, method: str, budget: float, init=None, run: Run | None = None,
                     spent: float = 0.0) -> Run:
        objective = METHODS[method]
        run = run or Run(method, objective, self.cell)
        starts, k = self.args.starts, 0
        reasons = np.zeros(3, int)
        while True:
            if init is not None:
                chunk = init[k * starts:(k + 1) * starts]
                if not len(chunk):
                    break
                t0 = time.perf_counter()
                res = self.optimize(objective, init=chunk)
            else:
                t0 = time.perf_counter()
                res = self.optimize(objective, key=self.args.seed * 100003 + self.key_round)
                self.key_round += 1
            dt = time.perf_counter() - t0
            k += 1
            spent += dt
            run.add(res.points, res.quality, res.force_closure, dt)
            run.objective_values.append(np.asarray(res.objective))
            reasons += np.bincount(np.asarray(res.reason), minlength=3)[:3]
            if spent + 0.5 * dt > budget:
                break
        from grasp_jax import EndReason

        run.reasons = {r.name.lower(): int(reasons[r]) for r in EndReason}
        return run

    def run_refine(self, budget: float) -> Run:
        run = Run("refine", "closure", self.cell)
        sample_budget = self.args.refine_fraction * budget
        # Enough candidates for every refining round the rest of the budget could hold.
        keep = self.args.starts * self.args.refine_rounds
        run, init = self.run_sampling(sample_budget, run, keep=keep)
        sampled = (run.tried, run.fc)
        run.samples = run.tried
        run = self.run_optimize("refine", budget, init=init, run=run, spent=run.seconds)
        # The force-closure fraction is the refined starts' (the samples' is the sampling row's).
        run.tried, run.fc = run.tried - sampled[0], run.fc - sampled[1]
        return run


def main():
    ap = parser("optimize_vs_sampling", __doc__)
    ap.add_argument("--seconds", type=float, default=20.0, help="time budget per method and row (default: %(default)s)")
    ap.add_argument("--objects", nargs="+", default=list(DEFAULT_OBJECTS),
                    help="built-in names, mesh paths or file names in ../shared/data/meshes")
    ap.add_argument("--fingers", type=int, nargs="+", default=[3, 4, 5])
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    ap.add_argument("--baseline-fingers", type=int, nargs="+", default=None,
                    help="finger counts the baselines run on (default: all of --fingers)")
    ap.add_argument("--steps", type=int, default=100, help="optimizer steps per start (default: %(default)s)")
    ap.add_argument("--learning-rate", type=float, default=None,
                    help="peak Adam learning rate from random starts, object radii per step (default: gj.optimize's)")
    ap.add_argument("--refine-learning-rate", type=float, default=REFINE_LEARNING_RATE,
                    help="peak learning rate when refining sampled grasps (default: %(default)s)")
    ap.add_argument("--devices", type=int, default=None, help="XLA CPU devices (default: one per core)")
    ap.add_argument("--starts", type=int, default=256, help="starts per optimizer round (default: %(default)s)")
    ap.add_argument("--sample-round", type=int, default=16384, help="grasps per sampling round (default: %(default)s)")
    ap.add_argument("--refine-fraction", type=float, default=0.25,
                    help="share of the budget sample-then-refine spends sampling (default: %(default)s)")
    ap.add_argument("--refine-rounds", type=int, default=16,
                    help="candidate sampled grasps kept for refining, in rounds of --starts (default: %(default)s)")
    ap.add_argument("--edges", type=int, default=8)
    ap.add_argument("--friction-deg", type=float, default=20.0)
    ap.add_argument("--distinct-tol", type=float, default=0.01,
                    help="grid cell of distinct grasps, in object radii (default: %(default)s)")
    ap.add_argument("--no-cache", action="store_true", help="do not use the XLA compilation cache")
    ap.add_argument("--quick", action="store_true",
                    help="smoke test: sphere, 3 fingers, 2 s per method, 20 steps, rounds of 4096 samples")
    ap.add_argument("--merge", type=Path, nargs="+", default=None, metavar="DIR",
                    help="only build the tables, JSON and figure in --out from the results.json of runs in "
                         "these folders (for example runs of different objects side by side)")
    args = ap.parse_args()
    if args.merge:
        return merge(args.merge, args.out, defaults=vars(ap.parse_args([])))
    if args.quick:
        args.objects, args.fingers, args.seconds, args.steps, args.sample_round = ["sphere"], [3], 2.0, 20, 4096
        args.refine_rounds = 2
    if args.seconds <= 0 or args.steps < 1 or args.starts < 1 or args.sample_round < 1:
        ap.error("--seconds, --steps, --starts and --sample-round must be positive")
    if not 0 < args.refine_fraction < 1:
        ap.error("--refine-fraction must be in (0, 1)")
    baseline_fingers = set(args.fingers if args.baseline_fingers is None else args.baseline_fingers)

    devices = use_cpu_cores(args.devices)
    cache = compilation_cache(not args.no_cache)

    import grasp_jax as gj  # noqa: F401
    from grasp_jax import objects

    timer = Timer()
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    mu = mu_of(args.friction_deg)
    objs = []
    for name in args.objects:
        try:
            objs.append(objects.load(_resolve(name)))
        except objects.ObjectError as exc:
            print(f"skipping {name}: {exc}", file=sys.stderr)
    timer.lap("loading")

    results, warmups = [], []
    for obj in objs:
        for fingers in args.fingers:
            row = Row(obj, fingers, args, mu)
            methods = [m for m in args.methods if m not in BASELINES or fingers in baseline_fingers]
            t0 = time.perf_counter()
            warm = row.warm_up(methods)
            warmups.append(dict(object=obj.name, fingers=fingers, seconds=warm))
            print(f"{obj.name}, {fingers} fingers: warm-up " + ", ".join(f"{k} {v:.1f} s" for k, v in warm.items()),
                  file=sys.stderr, flush=True)
            runs = {}
            if "optimize" in methods:
                runs["optimize"] = row.run_optimize("optimize", args.seconds)
            if "refine" in methods:
                runs["refine"] = row.run_refine(args.seconds)
            if "sampling" in methods:
                budget = max([args.seconds] + [r.seconds for r in runs.values()])
                runs["sampling"] = row.run_sampling(budget)[0]
            for method in BASELINES:
                if method in methods:
                    runs[method] = row.run_optimize(method, args.seconds)
            for method in methods:
                run = runs[method]
                run.warmup = warm.get(method, 0.0)
                s = run.stats()
                s.update(object=obj.name, fingers=fingers)
                results.append(s)
                print(f"  {method:>10}: {s['tried']:>8,} tried, FC {s['force_closure_fraction']:.3f}, "
                      f"{s['distinct_force_closure']:,} distinct, best Q {s['best_q']:.3f}, "
                      f"median Q top {s['top_count']} {s['median_q_top']:.3f}, {s['seconds']:.1f} s "
                      f"(warm-up {run.warmup:.1f} s)", file=sys.stderr, flush=True)
            print(f"  row took {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
            # After every row, so that an interrupted run keeps what it measured.
            write_json(out, dict(meta=dict(args={k: (str(v) if isinstance(v, Path) else v)
                                                 for k, v in vars(args).items()}, partial=True),
                                 warmups=warmups, results=results))
    timer.lap("methods")

    report(out, args, mu, devices, results, warmups, [o.name for o in objs], timer, cache)


def report(out: Path, args, mu: float, devices: int, results: list, warmups: list, names: list, timer,
           cache, notes=(), extra_meta=None) -> None:
    """Tables (printed and ``results.md``), ``results.json`` and the figure of one run's (or
    several merged runs') results."""
    import jax
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import grasp_jax as gj

    notes = list(notes)
    out.mkdir(parents=True, exist_ok=True)
    # ---- tables ------------------------------------------------------------------------------
    def median_cell(s):
        if not s["top_count"]:
            return "-"
        text = f"{s['median_q_top']:.3f}"
        return text if s["top_count"] >= TOP else f"{text} ({s['top_count']})"

    def tried_cell(s):
        if s["method"] == "refine":
            return f"{s['samples']:,} + {s['tried']:,}"
        return f"{s['tried']:,}"

    header = ["object", "fingers", "method", "grasps / starts", "FC fraction", "not FC", "distinct FC",
              "best Q", f"median Q best {TOP}", "s", "warm-up s"]
    rows = [[s["object"], s["fingers"], s["method"], tried_cell(s), s["force_closure_fraction"],
             f"{s['not_force_closure']:,}", f"{s['distinct_force_closure']:,}", s["best_q"], median_cell(s),
             f"{s['seconds']:.1f}", f"{s['warmup_seconds']:.1f}"] for s in results]

    by = {(s["object"], s["fingers"], s["method"]): s for s in results}
    keys = sorted({(s["object"], s["fingers"]) for s in results}, key=lambda k: (names.index(k[0]), k[1]))

    # Target 1: force-closure fraction from random starts, 4 fingers.
    t1 = [[o, f, by[o, f, "optimize"]["force_closure_fraction"], by[o, f, "optimize"]["not_force_closure"],
           by[o, f, "optimize"]["tried"], by[o, f, "optimize"]["force_closure_fraction"] >= 0.99,
           by[o, f, "optimize"]["reasons"].get("converged", 0), by[o, f, "optimize"]["reasons"].get("not_converged", 0)]
          for o, f in keys if (o, f, "optimize") in by]
    # Target 2: median Q of the best 100 distinct, optimization (better of the two) vs sampling.
    t2 = []
    for o, f in keys:
        if (o, f, "sampling") not in by:
            continue
        samp = by[o, f, "sampling"]
        opts = [by[o, f, m] for m in ("optimize", "refine") if (o, f, m) in by]
        if not opts:
            continue
        best = max(opts, key=lambda s: s["median_q_top"])
        t2.append([o, f, median_cell(samp)] + [median_cell(by[o, f, m]) if (o, f, m) in by else "-"
                                               for m in ("optimize", "refine")]
                  + [best["method"], best["median_q_top"] > samp["median_q_top"],
                     f"{samp['seconds']:.1f} / " + " / ".join(f"{s['seconds']:.1f}" for s in opts)])
    # Baselines: what the energies reach and how often it is truly force-closure.
    tb = []
    for o, f in keys:
        for m in ("optimize",) + BASELINES:
            if (o, f, m) not in by:
                continue
            s = by[o, f, m]
            tb.append([o, f, m, f"{s['tried']:,}", s["force_closure_fraction"], f"{s['not_force_closure']:,}",
                       _p50(s["q_percentiles_all_fc"]), median_cell(s), s["best_q"],
                       _p50(s["objective_percentiles"])])

    lines = ["# Contact optimization against random sampling at equal wall-clock time\n"]
    lines.append(
        f"Friction {args.friction_deg:g} deg (mu = {mu:.3f}), m = {args.edges} cone edges, {devices} XLA CPU "
        f"devices, budget {args.seconds:g} s of work per method and row (sampling: the larger of that and the "
        f"optimizers' time in its row). Optimizers: rounds of {args.starts} starts x {args.steps} steps, Adam "
        f"(peak learning rate {gj_rate(args.learning_rate):g} object radii per step from random starts, cosine decay "
        f"to 1%, restarted after a third of the steps at a sixth of the rate; {args.refine_learning_rate:g} when "
        f"refining, cosine decay to 1%); "
        f"refine samples for {args.refine_fraction:.0%} of the budget, then optimizes the best distinct "
        f"sampled grasps. Sampling rounds of {args.sample_round:,} grasps uniform by area. 'median Q best "
        f"{TOP}': over the best {TOP} distinct force-closure grasps (grid of {args.distinct_tol:g} object "
        "radii; a count in parentheses where fewer were found). 'FC fraction' is of the starts (of the samples "
        "for sampling; of the refined starts for refine, whose 'grasps / starts' reads samples + starts, and "
        "whose Q and distinct columns pool its sampled and refined grasps: what the user holds at the end). "
        "Every verdict and Q is `gj.evaluate`'s. 'warm-up s': compile + one round, not in the budget. "
        "Timings come from a 2-core CPU shared with other work: compare within this run only.\n")
    lines.append(table(header, rows))
    lines.append("\n## Target: force-closure from random starts (objective `closure`)\n")
    lines.append(table(["object", "fingers", "FC fraction", "not FC", "starts", ">= 99%", "converged below FC",
                        "not converged"], t1))
    lines.append(f"\n## Target: median Q of the best {TOP} distinct grasps, optimization vs sampling\n")
    lines.append(table(["object", "fingers", "sampling", "optimize", "refine", "better optimizer",
                        "optimization higher", "s (sampling / optimize / refine)"], t2))
    if any(r[2] in BASELINES for r in tb):
        lines.append("\n## Baselines: the field's energies, scored by the exact test\n")
        lines.append("Each objective is maximized from the same random starts for the same time; 'objective "
                     "p50' is the median over starts of the objective the optimizer maximized at its "
                     "reported grasp (`closure`: min(signed Q, 4 T, signed Q + 4 T); `dfc`, `dfc_eig`: minus the energy; "
                     "`min_weight`: K l*; `signed_q`: signed Q). 'not FC' counts the results the exact test "
                     "rejects.\n")
        lines.append(table(["object", "fingers", "objective", "starts", "FC fraction", "not FC",
                            "Q p50 (all FC)", f"median Q best {TOP}", "best Q", "objective p50"], tb))
    lines.append("\nFigure: `optimize_vs_sampling.png` (top: median Q of the best "
                 f"{TOP} distinct grasps per object and finger count; bottom: the same against work time, "
                 f"{_curve_fingers(args.fingers)} fingers).")

    # ---- figure --------------------------------------------------------------------------------
    shown = [m for m in METHODS if any(s["method"] == m for s in results)]
    fig, axes = plt.subplots(2, len(names), figsize=(4.2 * len(names), 7.5), squeeze=False)
    width = 0.8 / max(len(shown), 1)
    for j, name in enumerate(names):
        ax = axes[0, j]
        for i, m in enumerate(shown):
            ys = [by[name, f, m]["median_q_top"] if (name, f, m) in by else np.nan for f in args.fingers]
            ax.bar(np.arange(len(args.fingers)) + (i - (len(shown) - 1) / 2) * width, ys, width, label=m)
        ax.set_xticks(np.arange(len(args.fingers)), [str(f) for f in args.fingers])
        ax.set_xlabel("fingers")
        ax.set_title(name)
        if j == 0:
            ax.set_ylabel(f"median Q, best {TOP} distinct")
        ax = axes[1, j]
        f = _curve_fingers(args.fingers)
        for m in shown:
            if (name, f, m) in by and by[name, f, m]["curve"]:
                c = np.asarray(by[name, f, m]["curve"])
                ax.plot(c[:, 0], c[:, 2], marker=".", label=m)
        ax.set_xlabel("work time (s)")
        ax.set_title(f"{name}, {f} fingers")
        if j == 0:
            ax.set_ylabel(f"median Q, best {TOP} distinct so far")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", ncol=len(shown), fontsize=9, frameon=False)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    fig.savefig(out / "optimize_vs_sampling.png", dpi=100)
    plt.close(fig)
    timer.lap("tables and figure")

    lines += ["", *notes, timer.report()]
    meta = dict(args={k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
                mu=mu, devices=devices, jax=jax.__version__, grasp_jax=gj.__version__,
                learning_rate=gj_rate(args.learning_rate), compilation_cache=cache, top=TOP,
                timer=timer.report(), notes=notes, **(extra_meta or {}))
    meta.setdefault("git", _git_state())
    write_json(out, dict(meta=meta, warmups=warmups, results=results))
    path = write(out, "\n".join(lines))
    print(path.read_text())


def merge(folders: list, out: Path, defaults: dict) -> None:
    """One report from the ``results.json`` of several runs (their rows in the order given)."""
    import argparse
    import json

    results, warmups, names, notes, runs = [], [], [], [], []
    args = None
    for folder in folders:
        data = json.loads((Path(folder) / "results.json").read_text())
        meta = data["meta"]
        if meta.get("partial"):
            notes.append(f"`{folder}` was stopped before the end of its object list: its finished rows "
                         "are included.")
        run_args = argparse.Namespace(**{**defaults, **meta["args"]})
        if args is None:
            args = run_args
        else:
            for key in ("seconds", "steps", "starts", "learning_rate", "refine_learning_rate", "edges",
                        "friction_deg", "sample_round", "refine_fraction", "distinct_tol"):
                if getattr(run_args, key, None) != getattr(args, key, None):
                    notes.append(f"`{folder}` differs in {key}: {getattr(run_args, key, None)} "
                                 f"(the text above gives the first run's)")
        results += data["results"]
        warmups += data["warmups"]
        for s in data["results"]:
            if s["object"] not in names:
                names.append(s["object"])
        runs.append(dict(folder=str(folder), timer=meta.get("timer"), partial=bool(meta.get("partial"))))
        if meta.get("timer"):
            notes.append(f"`{folder}`: {meta['timer']}")
    args.fingers = sorted({s["fingers"] for s in results})
    args.out = out
    notes.insert(0, f"Merged from {len(folders)} runs that ran side by side on the same machine: "
                    + ", ".join(f"`{f}`" for f in folders) + ".")
    report(out, args, mu_of(args.friction_deg), args.devices or use_cpu_cores(None), results, warmups,
           names, Timer(), None, notes=notes, extra_meta=dict(merged=runs, git=dict(at_merge=_git_state())))


def _p50(percentiles: dict) -> float:
    """The median from a percentile dict (keys are ints in memory, strings once read from JSON)."""
    return percentiles.get(50, percentiles.get("50", float("nan")))


def _git_state() -> dict:
    """The repository's commit and the files changed in the working tree (the library is shared)."""
    import subprocess

    root = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "grasp_jax"], cwd=root, capture_output=True,
                               text=True).stdout.split("\n")
    except OSError:
        return {}
    return dict(head=head, changed=[line[3:] for line in dirty if line.strip()])


def _curve_fingers(fingers) -> int:
    return 4 if 4 in fingers else fingers[0]


if __name__ == "__main__":
    main()
