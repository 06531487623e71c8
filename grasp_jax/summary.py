"""Summaries with flat memory: running counts, a histogram of Q, the best grasps, and how they
are printed (:class:`PipelineSummary` for ``grasp-jax sample`` / ``score``, :func:`format_optimize`
for ``grasp-jax optimize``).

Nothing here imports JAX.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np

#: Best grasps kept for the summary (and ``--plot``).
DEFAULT_TOP = 10
#: Bins of the Q histogram the percentiles are read from (resolution ``sqrt(1 + mu^2) / BINS``).
HISTOGRAM_BINS = 1 << 16
PERCENTILES = (5, 25, 50, 75, 95)


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
        best: the best force-closure grasps (indices count from the start of the whole stream, also
            in a multi-process run).
        output: the file written, if any.
        metadata: the run's settings (as stored in the output).
        devices: devices each chunk was sharded over.
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
            f"mu {m.get('mu')}, {m.get('edges')} cone edges, torque test {m.get('torque_test')}"
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
    from . import storage

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


def summary_json(summary: PipelineSummary) -> str:
    """The summary as one JSON line."""
    def default(o):
        if isinstance(o, (np.integer, np.floating)):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
        return str(o)

    return json.dumps(summary.to_dict(), default=default)


__all__ = [
    "DEFAULT_TOP",
    "PERCENTILES",
    "BestGrasps",
    "PipelineSummary",
    "best_in_file",
    "summary_json",
]
