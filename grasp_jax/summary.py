"""Summaries with flat memory: running counts, a histogram of Q, the best grasps, and how they
are printed (:class:`PipelineSummary` for ``grasp-jax sample`` / ``score``, :func:`format_optimize`
for ``grasp-jax optimize``).

Nothing here computes with JAX: the counts are NumPy.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from . import storage
from ._optimize import EndReason

#: Best grasps kept for the summary (and ``--plot``).
DEFAULT_TOP = 10
#: Bins of the Q histogram the percentiles are read from (resolution ``sqrt(1 + mu^2) / BINS``).
HISTOGRAM_BINS = 1 << 16
PERCENTILES = (5, 25, 50, 75, 95)



def contact_text(meta) -> str:
    """``", soft contacts (torsion 0.002)"`` for a file's soft contact model, ``""`` for hard."""
    contact = meta.get("contact", "hard")
    if contact == "hard":
        return ""
    return f", {contact} contacts (torsion {meta.get('torsion'):.4g})"

class _QualityHistogram:
    """Counts of Q on ``[0, upper]`` in :data:`HISTOGRAM_BINS` bins; percentiles by interpolation."""

    def __init__(self, upper: float):
        self.upper = float(upper)
        self.counts = np.zeros(HISTOGRAM_BINS, np.int64)
        self.total = 0
        self.sum = 0.0
        self.max = -math.inf

    def add(self, q: np.ndarray) -> None:
        if q.size == 0:
            return
        idx = np.clip((q / self.upper * HISTOGRAM_BINS).astype(np.int64), 0, HISTOGRAM_BINS - 1)
        self.counts += np.bincount(idx, minlength=HISTOGRAM_BINS)
        self.total += q.size
        self.sum += float(q.sum())
        self.max = max(self.max, float(q.max()))

    def _order_statistic(self, cum: np.ndarray, k: int) -> float:
        """The ``k``-th smallest value (0-based), values spread evenly inside their bin."""
        b = min(int(np.searchsorted(cum, k, side="right")), HISTOGRAM_BINS - 1)
        j = k - (int(cum[b - 1]) if b else 0)
        return (b + (j + 0.5) / max(int(self.counts[b]), 1)) * self.upper / HISTOGRAM_BINS

    def percentile(self, p: float) -> float:
        """As ``numpy.percentile`` (linear interpolation between order statistics), to within one
        bin."""
        if self.total == 0:
            return math.nan
        cum = np.cumsum(self.counts)
        rank = p / 100 * (self.total - 1)
        lo = int(math.floor(rank))
        hi = min(lo + 1, self.total - 1)
        a, b = self._order_statistic(cum, lo), self._order_statistic(cum, hi)
        return min(a + (rank - lo) * (b - a), self.max)


@dataclasses.dataclass(frozen=True)
class BestGrasps:
    """The best force-closure grasps seen, by decreasing Q (ties: lower index first).

    Attributes:
        index: ``(k,)`` int, position of each grasp in the scored stream (0-based).
        points, normals: ``(k, n, d)`` float.
        quality: ``(k,)`` float.
    """

    index: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    quality: np.ndarray

    def __len__(self) -> int:
        return len(self.index)


class _TopK:
    def __init__(self, k: int):
        self.k = int(k)
        self.best: BestGrasps | None = None

    def add(self, offset: int, points, normals, quality, mask) -> None:
        if self.k <= 0:
            return
        cand = np.flatnonzero(mask)
        if cand.size == 0:
            return
        if cand.size > self.k:
            part = np.argpartition(-quality[cand], self.k - 1)[: self.k]
            cand = np.sort(cand[part])
        new = BestGrasps(cand + offset, points[cand], normals[cand], quality[cand])
        if self.best is not None:
            new = BestGrasps(*(np.concatenate([a, b]) for a, b in zip(dataclasses.astuple(self.best),
                                                                       dataclasses.astuple(new))))
        order = np.lexsort((new.index, -new.quality))[: self.k]
        self.best = BestGrasps(*(a[order] for a in dataclasses.astuple(new)))


@dataclasses.dataclass
class PipelineSummary:
    """What a pipeline run found; :meth:`format` prints it, :meth:`to_dict` serializes it.

    Attributes:
        num: grasps scored (by this process).
        force_closure: how many are force-closure.
        unconverged: grasps with an LP that did not converge (counted as not force-closure).
        quality_percentiles: ``{p: Q}`` among force-closure grasps (from a histogram with
            resolution ``sqrt(1 + mu^2) / 65536``), NaN when there is none.
        quality_mean, quality_max: among force-closure grasps (exact).
        seconds: wall time from the first sample to the closed output file.
        first_chunk_seconds: of which the first chunk (includes JAX compilation).
        first_chunk: grasps in the first chunk.
        epsilon_positive: grasps with Ferrari-Canny epsilon > :data:`grasp_jax.pipeline.EPSILON_ZERO` (``None``
            without epsilon).
        epsilon_disagree: grasps where ``epsilon > EPSILON_ZERO`` and ``force_closure`` disagree.
        epsilon_max: the largest epsilon.
        agree: with :func:`score_file` on a file with stored verdicts, how many match.
        critical_percentiles: percentiles of the critical friction over all grasps (those above
            the cap count as the cap), where it was computed.
        best: the best force-closure grasps (indices count from the start of the whole stream, also
            in a multi-process run).
        output: the file written, if any.
        metadata: the run's settings (as stored in the output).
        devices: devices each chunk was sharded over.
        robust: with robust labels (``--robust N``): samples, noise, the mean P(force-closure)
            over all grasps and over the nominally force-closure ones, the mean expected Q, the
            seconds spent on them and perturbed grasps per second; ``None`` without.
    """

    num: int
    force_closure: int
    unconverged: int
    quality_percentiles: dict
    quality_mean: float
    quality_max: float
    seconds: float
    first_chunk_seconds: float
    first_chunk: int
    best: BestGrasps | None
    output: Path | None
    metadata: dict
    devices: int
    epsilon_positive: int | None = None
    epsilon_disagree: int | None = None
    epsilon_max: float | None = None
    agree: int | None = None
    critical_percentiles: dict | None = None
    robust: dict | None = None

    @property
    def force_closure_rate(self) -> float:
        return self.force_closure / self.num if self.num else math.nan

    @property
    def grasps_per_second(self) -> float:
        """End to end, including sampling, compilation, the baseline and writing."""
        return self.num / self.seconds if self.seconds > 0 else math.nan

    @property
    def steady_grasps_per_second(self) -> float | None:
        """After the first chunk (so without compilation); ``None`` with a single chunk."""
        rest = self.seconds - self.first_chunk_seconds
        if self.num <= self.first_chunk or rest <= 0:
            return None
        return (self.num - self.first_chunk) / rest

    def to_dict(self) -> dict:
        d = {k: v for k, v in dataclasses.asdict(self).items() if k not in ("best", "output")}
        d["quality_percentiles"] = {str(k): v for k, v in self.quality_percentiles.items()}
        d["output"] = None if self.output is None else str(self.output)
        d["force_closure_rate"] = self.force_closure_rate
        d["grasps_per_second"] = self.grasps_per_second
        d["steady_grasps_per_second"] = self.steady_grasps_per_second
        if self.best is not None and len(self.best):
            d["best"] = {"index": self.best.index.tolist(), "quality": self.best.quality.tolist()}
        return d

    def format(self, best: int = 1) -> str:
        """The summary as aligned lines; ``best``: how many of the best grasps to list."""
        m = self.metadata
        lines = []
        what = m.get("object_name") or m.get("object") or m.get("source", "grasps")
        lines.append(
            f"object         {what} ({m.get('dim', '?')}D), {m.get('fingers', '?')} fingers, "
            f"mu {m.get('mu')}, {m.get('edges')} cone edges, torque test {m.get('torque_test')}{contact_text(m)}"
        )
        if "slice" in m:
            s = m["slice"]
            lines.append(f"process        {m['process_index']} of {m['process_count']}: grasps "
                         f"{s[0]:,} to {s[1]:,} of {s[2]:,}")
        steady = self.steady_grasps_per_second
        timing = f"{self.num:,} grasps in {self.seconds:.1f} s: {self.grasps_per_second:,.0f} grasps/s"
        extra = f"first chunk {self.first_chunk_seconds:.1f} s incl. compile"
        if steady is not None:
            extra += f", then {steady:,.0f} grasps/s"
        lines.append(f"scored         {timing} ({extra}; {self.devices} device{'s' * (self.devices > 1)})")
        fc = f"{self.force_closure:,} of {self.num:,} ({100 * self.force_closure_rate:.1f}%)"
        if self.unconverged:
            fc += f"; {self.unconverged:,} with an unconverged LP, counted as not force-closure"
        lines.append(f"force-closure  {fc}")
        if self.agree is not None:
            lines.append(f"stored verdict {self.agree:,} of {self.num:,} agree")
        if self.force_closure:
            pct = "  ".join(f"p{p} {q:.3f}" for p, q in self.quality_percentiles.items())
            lines.append(f"Q (FC grasps)  {pct}  mean {self.quality_mean:.3f}  max {self.quality_max:.4f}")
        if self.best is not None and len(self.best):
            k = max(1, min(int(best), len(self.best)))
            listed = ", ".join(f"#{int(i)} Q {float(q):.4f}" for i, q in
                               zip(self.best.index[:k], self.best.quality[:k]))
            lines.append(f"best grasp{'s' if k > 1 else ' '}    {listed}")
        if self.critical_percentiles is not None:
            pct = "  ".join(f"p{p} {q:.3f}" for p, q in self.critical_percentiles.items())
            lines.append(f"critical mu    {pct}  (all grasps; above the cap {m.get('critical_friction_cap', 4):g} "
                         "counted at it)")
        if self.robust is not None:
            r = self.robust
            lines.append(
                f"robust         {r['samples']} perturbations ({r['noise']}): P(FC) mean {r['p_fc_mean']:.3f}, "
                f"{r['p_fc_mean_nominal_fc']:.3f} over the FC grasps; E[Q] mean {r['q_mean_mean']:.4f}; "
                f"{r['perturbed_per_second']:,.0f} perturbed grasps/s")
        if self.epsilon_positive is not None:
            origin = ", ".join(f"{0.0 if abs(v) < 1e-12 else v:.3g}" for v in m.get("epsilon_origin", ()))
            lines.append(
                f"epsilon        > 0 for {self.epsilon_positive:,} grasps ({self.epsilon_disagree:,} disagree "
                f"with force-closure), max {self.epsilon_max:.4f} (torques about ({origin}) divided by "
                f"{m.get('epsilon_torque_scale'):.4g})"
            )
        if self.output is not None:
            lines.append(f"output         {self.output}")
        return "\n".join(lines)


def best_in_file(path, top: int = DEFAULT_TOP, chunk: int = 65536) -> tuple[BestGrasps | None, dict]:
    """The ``top`` best force-closure grasps of a result file (streamed) and its metadata."""
    src = storage.ResultFile(path)
    missing = [c for c in ("quality", "force_closure") if c not in src.fields]
    if missing:
        raise ValueError(f"{str(path)!r} has no {' or '.join(repr(m) for m in missing)} column: "
                         "score it first (grasp-jax score)")
    keep = _TopK(top)
    offset = 0
    for c in src.iter_chunks(("points", "normals", "quality", "force_closure"), chunk):
        keep.add(offset, c["points"], c["normals"], np.asarray(c["quality"], float),
                 np.asarray(c["force_closure"], bool))
        offset += len(c["points"])
    return keep.best, dict(src.metadata)


def best_starts(path, k: int, chunk: int = 65536) -> tuple[BestGrasps, dict]:
    """The ``k`` best grasps of a file, to start an optimization from (``grasp-jax optimize
    --from``), streamed, and the file's metadata.

    Force-closure grasps come first, by decreasing Q, then the others by decreasing Q (ties: file
    order); all grasps when the file holds ``k`` or fewer. A file without ``quality`` and
    ``force_closure`` columns (plain ``points`` and ``normals``) gives its first ``k`` grasps.
    """
    src = storage.ResultFile(path)
    k = int(k)
    if k < 1:
        raise ValueError(f"k must be a positive integer; got {k}")
    scored = "quality" in src.fields and "force_closure" in src.fields
    columns = ("points", "normals") + (("quality", "force_closure") if scored else ())
    held = None  # (index, points, normals, quality, force_closure) of the best so far
    offset = 0
    for c in src.iter_chunks(columns, chunk):
        rows = len(c["points"])
        q = np.asarray(c["quality"], float) if scored else np.zeros(rows)
        fc = np.asarray(c["force_closure"], bool) if scored else np.zeros(rows, bool)
        new = (np.arange(offset, offset + rows), c["points"], c["normals"], q, fc)
        offset += rows
        if held is not None:
            new = tuple(np.concatenate([a, b]) for a, b in zip(held, new))
        if len(new[0]) > k:
            order = np.lexsort((new[0], -new[3], ~new[4]))[:k]
            new = tuple(a[order] for a in new)
        held = new
        if not scored and offset >= k:
            break
    if held is None or not len(held[0]):
        raise ValueError(f"{str(path)!r} holds no grasps")
    order = np.lexsort((held[0], -held[3], ~held[4]))
    index, points, normals, q, _ = (a[order] for a in held)
    return BestGrasps(index, np.asarray(points, float), np.asarray(normals, float), q), dict(src.metadata)


def optimize_summary(result, metadata: dict, *, best: BestGrasps | None = None, output=None,
                     sampled=None) -> dict:
    """What ``grasp-jax optimize`` prints, as a dictionary (JSON-ready).

    Args:
        result: a :class:`grasp_jax.OptimizeResult`.
        metadata: the run's settings (as stored in the output file).
        best: the best distinct force-closure grasps (listed).
        output: the file written, if any.
        sampled: ``(S * steps,)`` Q of as many random grasps (the figure's comparison), if drawn.
    """
    fc = np.asarray(result.force_closure, bool)
    q = np.asarray(result.quality, float)
    reasons = np.asarray(result.reason)
    starts, steps = len(fc), int(result.steps)
    seconds = float(result.seconds)
    d = {
        "starts": starts,
        "steps": steps,
        "force_closure": int(fc.sum()),
        "force_closure_rate": float(fc.mean()) if starts else math.nan,
        "quality_percentiles": {str(p): float(np.percentile(q[fc], p)) if fc.any() else math.nan
                                for p in PERCENTILES},
        "quality_mean": float(q[fc].mean()) if fc.any() else math.nan,
        "quality_max": float(q[fc].max()) if fc.any() else math.nan,
        "distinct_force_closure": int(result.num_distinct_force_closure),
        "reasons": {r.name.lower(): int((reasons == r).sum()) for r in EndReason},
        "seconds": seconds,
        "start_steps_per_second": starts * steps / seconds if seconds > 0 else math.nan,
        "unconverged": int((~np.asarray(result.evaluation.converged, bool)).sum()),
        "output": None if output is None else str(output),
        "metadata": dict(metadata),
    }
    if best is not None and len(best):
        d["best"] = {"index": best.index.tolist(), "quality": best.quality.tolist()}
    if sampled is not None:
        sampled = np.asarray(sampled, float)
        d["sampled"] = {"num": int(sampled.size), "force_closure_rate": float((sampled > 0).mean()),
                        "quality_median": float(np.median(sampled)), "quality_max": float(sampled.max())}
    return d


def format_optimize(summary: dict, best: int = 5) -> str:
    """:func:`optimize_summary` as aligned lines, in the style of :meth:`PipelineSummary.format`;
    ``best``: how many of the best grasps to list."""
    m = summary["metadata"]
    starts, steps = summary["starts"], summary["steps"]
    what = m.get("object_name") or m.get("object", "?")
    lines = [
        f"object         {what} ({m.get('dim', '?')}D), {m.get('fingers', '?')} fingers, mu {m.get('mu')}, "
        f"{m.get('edges')} cone edges{contact_text(m)}, objective {m.get('objective')}, {m.get('normals')} normals",
        f"optimized      {starts:,} starts x {steps:,} steps in {summary['seconds']:.1f} s: "
        f"{summary['start_steps_per_second']:,.0f} start-steps/s (incl. compile; lr {m.get('learning_rate')}, "
        f"starts {m.get('init', 'random')})",
    ]
    fc = f"{summary['force_closure']:,} of {starts:,} ({100 * summary['force_closure_rate']:.1f}%)"
    if summary["unconverged"]:
        fc += f"; {summary['unconverged']:,} with an unconverged LP, counted as not force-closure"
    lines.append(f"force-closure  {fc}; {summary['distinct_force_closure']:,} distinct")
    if summary["force_closure"]:
        pct = "  ".join(f"p{p} {q:.3f}" for p, q in summary["quality_percentiles"].items())
        lines.append(f"Q (FC grasps)  {pct}  mean {summary['quality_mean']:.3f}  max {summary['quality_max']:.4f}")
    reasons = ", ".join(f"{EndReason[name.upper()].message} {count:,}" for name, count in summary["reasons"].items())
    lines.append(f"end reasons    {reasons}")
    if "sampled" in summary:
        s = summary["sampled"]
        lines.append(f"random grasps  {s['num']:,} (as many as starts x steps): force-closure "
                     f"{100 * s['force_closure_rate']:.1f}%, Q median {s['quality_median']:.3f}, "
                     f"max {s['quality_max']:.4f}")
    if "best" in summary:
        k = max(1, min(int(best), len(summary["best"]["index"])))
        listed = ", ".join(f"#{int(i)} Q {float(q):.4f}" for i, q in
                           zip(summary["best"]["index"][:k], summary["best"]["quality"][:k]))
        lines.append(f"best grasp{'s' if k > 1 else ' '}    {listed}")
    if summary["output"] is not None:
        lines.append(f"output         {summary['output']}")
    return "\n".join(lines)


def summary_json(summary: PipelineSummary | dict) -> str:
    """The summary (a :class:`PipelineSummary` or a dictionary) as one JSON line."""
    def default(o):
        if isinstance(o, (np.integer, np.floating)):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
        return str(o)

    d = summary if isinstance(summary, dict) else summary.to_dict()
    return json.dumps(d, default=default)


__all__ = [
    "DEFAULT_TOP",
    "PERCENTILES",
    "BestGrasps",
    "PipelineSummary",
    "best_in_file",
    "best_starts",
    "format_optimize",
    "optimize_summary",
    "summary_json",
]
