"""Score millions of candidate grasps with flat memory: sample, evaluate, (baseline), stream out.

:func:`run` draws ``num`` random grasps of an object chunk by chunk
(:func:`grasp_jax.sampling.iter_grasps`), scores each chunk with :func:`grasp_jax.evaluate`
(sharded over every local device), optionally adds the qhull Ferrari-Canny baseline, and streams
the results to a ``.npz`` or ``.parquet`` file (:mod:`grasp_jax.storage`). Only one chunk of
grasps is in memory at a time, so 10^7 grasps need the same memory as 10^5: the summary keeps
running counts, a fixed histogram of Q (for its percentiles) and the best few grasps.

Sampling of the next chunk runs in a background thread while the current one is scored.

:func:`score_file` does the same for grasps stored in a file.

Devices
    On a CPU, XLA makes one device of all cores; :func:`configure_cpu_devices` splits them into
    one device per core (``XLA_FLAGS=--xla_force_host_platform_device_count``), which about
    doubles throughput on two cores. It must run before JAX starts its backend (importing JAX is
    fine; the first computation or ``jax.devices()`` is too late).

Several hosts
    With ``distributed=True`` (``grasp-jax sample --distributed``), or when the standard
    variables ``JAX_COORDINATOR_ADDRESS``, ``JAX_NUM_PROCESSES`` and ``JAX_PROCESS_ID`` are set,
    :func:`initialize_distributed` calls :func:`jax.distributed.initialize` (which also detects
    SLURM, Open MPI and TPU pods by itself). Every process then samples the same seeded stream of
    ``num`` grasps, scores only its contiguous slice ``[num * i // P, num * (i + 1) // P)`` for
    process ``i`` of ``P`` on its own local devices, and writes its own file
    ``<stem>.<i>-of-<P><suffix>`` with the slice in the metadata. Concatenating the files in
    process order gives exactly the single-process result. No collective is used, so processes
    never wait for each other; each prints the summary of its slice. (Tested with two processes
    on one machine; not on several hosts.)
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import math
import os
import queue
import sys
import threading
import time
import warnings
from pathlib import Path
from typing import Iterable, Iterator, Mapping

import numpy as np

#: The paper's friction coefficient, tan(20 deg).
DEFAULT_MU = 0.364
#: Grasps per pipeline chunk: sampled, scored and written together.
DEFAULT_CHUNK = 65536
#: Best grasps kept for the summary (and ``--plot``).
DEFAULT_TOP = 10
#: Bins of the Q histogram the percentiles are read from (resolution ``sqrt(1 + mu^2) / BINS``).
HISTOGRAM_BINS = 1 << 16
#: Fewest grasps per device in one compiled call (four blocks of ``grasp_jax._batch.BLOCK``).
MIN_ROWS = 1024
PERCENTILES = (5, 25, 50, 75, 95)
#: Ferrari-Canny epsilon (scale free: torques are divided by the torque scale) at or below which
#: the summary counts a grasp as not force-closure by the baseline; qhull leaves round-off of about
#: 1e-17 on grasps exactly on the boundary (contacts on parallel faces).
EPSILON_ZERO = 1e-9

_DEVICE_FLAG = "--xla_force_host_platform_device_count"
_DISTRIBUTED_ENV = ("JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES", "JAX_PROCESS_ID")


# ---------------------------------------------------------------------------------------------
# Devices and processes


def available_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def _backend_started() -> bool:
    if "jax" not in sys.modules:
        return False
    try:
        from jax._src import xla_bridge

        return bool(xla_bridge.backends_are_initialized())
    except (ImportError, AttributeError):  # private API moved: assume the worst
        return True


def configure_cpu_devices(count: int | None = None) -> int | None:
    """Split the host CPU into ``count`` XLA devices (default: one per available core).

    Sets ``XLA_FLAGS=--xla_force_host_platform_device_count=<count>`` (keeping other flags) when
    JAX has not started its backend yet and the flag is not already set. Only the CPU platform
    reads it; on a GPU machine it is harmless.

    Returns:
        The device count now requested, or ``None`` when nothing was changed (the backend already
        runs, or ``XLA_FLAGS`` already chooses a count: the user's setting wins).
    """
    count = available_cores() if count is None else int(count)
    if count < 1:
        raise ValueError(f"device count must be >= 1; got {count}")
    flags = os.environ.get("XLA_FLAGS", "")
    if _DEVICE_FLAG in flags or _backend_started():
        return None
    os.environ["XLA_FLAGS"] = f"{flags} {_DEVICE_FLAG}={count}".strip()
    return count


def distributed_requested() -> bool:
    """Whether the standard JAX multi-process variables are all set."""
    return all(os.environ.get(k) for k in _DISTRIBUTED_ENV)


def initialize_distributed(force: bool = False) -> tuple[int, int]:
    """Join a multi-process JAX job when asked (``force``) or when its variables are set.

    Calls :func:`jax.distributed.initialize` with ``JAX_COORDINATOR_ADDRESS``,
    ``JAX_NUM_PROCESSES`` and ``JAX_PROCESS_ID`` when they are set, else with no arguments so that
    JAX detects the cluster (SLURM, Open MPI, Cloud TPU). Must run before any JAX computation.

    Returns:
        ``(process_index, process_count)``; ``(0, 1)`` when not distributed.
    """
    if not (force or distributed_requested()):
        return 0, 1
    import jax

    kwargs = {}
    if distributed_requested():  # jax reads only the address from the environment itself
        try:
            kwargs = dict(coordinator_address=os.environ["JAX_COORDINATOR_ADDRESS"],
                          num_processes=int(os.environ["JAX_NUM_PROCESSES"]),
                          process_id=int(os.environ["JAX_PROCESS_ID"]))
        except ValueError:
            raise ValueError("JAX_NUM_PROCESSES and JAX_PROCESS_ID must be integers") from None
    try:
        jax.distributed.initialize(**kwargs)
    except (RuntimeError, ValueError) as e:
        if "already" not in str(e).lower():
            raise ValueError(f"could not join the distributed JAX job ({e})") from None
    return jax.process_index(), jax.process_count()


def slice_bounds(num: int, index: int, count: int) -> tuple[int, int]:
    """The contiguous slice ``[start, stop)`` of ``num`` grasps scored by process ``index``."""
    return num * index // count, num * (index + 1) // count


def part_path(path, index: int, count: int) -> Path:
    """``results.npz`` -> ``results.3-of-8.npz`` for process 3 of 8 (unchanged for one process)."""
    path = Path(path)
    if count <= 1:
        return path
    return path.with_name(f"{path.stem}.{index}-of-{count}{path.suffix}")


# ---------------------------------------------------------------------------------------------
# Running statistics with flat memory


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
        epsilon_positive: grasps with Ferrari-Canny epsilon > :data:`EPSILON_ZERO` (``None``
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


# ---------------------------------------------------------------------------------------------
# The streaming core


class _Prefetch:
    """Iterate ``iterable`` in a daemon thread, ``depth`` items ahead of the consumer."""

    _END = object()

    def __init__(self, iterable: Iterable, depth: int = 2):
        self._queue: queue.Queue = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(iter(iterable),), daemon=True,
                                        name="grasp_jax-prefetch")
        self._thread.start()

    def _put(self, item) -> bool:
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def _run(self, it):
        try:
            for item in it:
                if not self._put(("item", item)):
                    return
        except BaseException as e:  # noqa: BLE001 - handed to the consumer
            self._put(("error", e))
            return
        self._put(("end", None))

    def __iter__(self):
        try:
            while True:
                kind, item = self._queue.get()
                if kind == "end":
                    return
                if kind == "error":
                    raise item
                yield item
        finally:
            self.close()

    def close(self):
        self._stop.set()
        self._thread.join(timeout=5)


def _metadata_base(**kwargs) -> dict:
    from . import __version__

    meta = {
        "grasp_jax_version": __version__,
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    }
    meta.update(kwargs)
    return meta


def _jsonable(x):
    if x is None:
        return None
    return np.asarray(x, float).tolist()


def _pad(a: np.ndarray, size: int) -> np.ndarray:
    if len(a) >= size:
        return a
    return np.concatenate([a, np.broadcast_to(a[:1], (size - len(a),) + a.shape[1:])])


def score_stream(
    chunks: Iterable[Mapping],
    *,
    num: int,
    fingers: int,
    dim: int,
    mu: float,
    num_edges: int,
    torque_test: str,
    metadata: Mapping,
    epsilon: bool = False,
    origin=None,
    torque_scale: float = 1.0,
    out=None,
    progress: bool = False,
    top: int = DEFAULT_TOP,
    desc: str = "scoring",
    index_offset: int = 0,
) -> PipelineSummary:
    """Score a stream of chunks ``{"points", "normals"[, "force_closure"]}`` and write the results.

    The engine behind :func:`run` and :func:`score_file`; see there. ``num`` is the number of
    grasps the stream holds (for the progress bar); a stored ``force_closure`` in the chunks is
    compared with the new verdicts (``agree``). ``index_offset`` is added to the indices of the
    best grasps (the start of this process's slice).
    """
    import jax

    import grasp_jax as gj

    from . import storage

    mu = float(mu)
    fields = ["points", "normals", "force_closure", "quality", "converged"]
    if epsilon:
        fields += ["epsilon", "volume"]
    meta = dict(metadata)
    if epsilon:
        meta["epsilon_origin"] = _jsonable(origin) if origin is not None else [0.0] * dim
        meta["epsilon_torque_scale"] = float(torque_scale)
    writer = storage.open_writer(out, meta, fields, fingers=fingers, dim=dim) if out is not None else None
    hist = _QualityHistogram(math.sqrt(1 + mu * mu) * (1 + 1e-9))
    best = _TopK(top)
    devices = len(jax.local_devices())
    counts = dict(num=0, fc=0, unconverged=0, eps_pos=0, eps_dis=0, agree=0)
    eps_max = 0.0
    have_ref = False
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=num, unit="grasp", unit_scale=True, desc=desc, dynamic_ncols=True, smoothing=0.1)
    t0 = time.perf_counter()
    first_seconds, first_size, pad_to = 0.0, 0, 0
    try:
        for chunk in chunks:
            points = np.asarray(chunk["points"], np.float64)
            normals = np.asarray(chunk["normals"], np.float64)
            rows = len(points)
            if rows == 0:
                continue
            if not first_size:
                first_size = rows
                # Every chunk is scored by one compiled program: a later, smaller chunk is padded to
                # the first one's size, and no program is compiled for fewer than MIN_ROWS grasps per
                # device (XLA compiles a loop of one to three blocks differently, and Q changes in the
                # last bits). So results do not depend on the chunk size.
                pad_to = max(min(rows, _evaluate_chunk()), MIN_ROWS * devices)
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", message=r".*did not converge", category=RuntimeWarning)
                res = gj.evaluate(_pad(points, pad_to), _pad(normals, pad_to), mu=mu, num_edges=num_edges,
                                  torque_test=torque_test)
            fc = np.asarray(res.force_closure)[:rows]
            q = np.asarray(res.quality)[:rows]
            conv = np.asarray(res.converged)[:rows]
            batch = dict(points=points, normals=normals, force_closure=fc, quality=q, converged=conv)
            if epsilon:
                eps = np.empty(rows)
                vol = np.empty(rows)
                step = 512
                for s in range(0, rows, step):
                    eps[s:s + step], vol[s:s + step] = gj.ferrari_canny(
                        points[s:s + step], normals[s:s + step], mu=mu, num_edges=num_edges, origin=origin,
                        torque_scale=torque_scale)
                    if bar is not None:
                        bar.update(min(step, rows - s))
                batch.update(epsilon=eps, volume=vol)
                pos = eps > EPSILON_ZERO
                counts["eps_pos"] += int(pos.sum())
                counts["eps_dis"] += int((pos != fc).sum())
                eps_max = max(eps_max, float(eps.max()))
            elif bar is not None:
                bar.update(rows)
            if "force_closure" in chunk:
                have_ref = True
                counts["agree"] += int((np.asarray(chunk["force_closure"], bool) == fc).sum())
            if writer is not None:
                writer.write(batch)
            hist.add(q[fc])
            best.add(index_offset + counts["num"], points, normals, q, fc)
            counts["num"] += rows
            counts["fc"] += int(fc.sum())
            counts["unconverged"] += int((~conv).sum())
            if not first_seconds:
                first_seconds = time.perf_counter() - t0
            if bar is not None:
                bar.set_postfix_str(f"FC {100 * counts['fc'] / counts['num']:.1f}%", refresh=False)
        path = writer.close() if writer is not None else None
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    finally:
        if bar is not None:
            bar.close()
    seconds = time.perf_counter() - t0
    meta["num"] = counts["num"]
    return PipelineSummary(
        num=counts["num"],
        force_closure=counts["fc"],
        unconverged=counts["unconverged"],
        quality_percentiles={p: hist.percentile(p) for p in PERCENTILES},
        quality_mean=hist.sum / hist.total if hist.total else math.nan,
        quality_max=hist.max if hist.total else math.nan,
        seconds=seconds,
        first_chunk_seconds=first_seconds,
        first_chunk=first_size,
        best=best.best,
        output=path,
        metadata=meta,
        devices=devices,
        epsilon_positive=counts["eps_pos"] if epsilon else None,
        epsilon_disagree=counts["eps_dis"] if epsilon else None,
        epsilon_max=eps_max if epsilon else None,
        agree=counts["agree"] if have_ref else None,
    )


def _evaluate_chunk() -> int:
    """Grasps per compiled call of :func:`grasp_jax.evaluate` on the local devices: a chunk at
    least this large never compiles another size."""
    import jax

    try:
        from ._batch import _sizes

        return int(_sizes(tuple(jax.local_devices()), None)[1])
    except (ImportError, AttributeError, TypeError, IndexError):  # internals changed: pad fully
        return 1 << 62


def default_chunk() -> int:
    """:data:`DEFAULT_CHUNK` on a CPU; on an accelerator, two of its compiled batches per device."""
    import jax

    devices = jax.local_devices()
    if devices[0].platform == "cpu":
        return DEFAULT_CHUNK
    return max(DEFAULT_CHUNK, 2 * _evaluate_chunk() * len(devices))


def _check_settings(mu, num_edges, torque_test, chunk, top):
    if not (isinstance(mu, (int, float, np.floating)) and math.isfinite(mu) and mu > 0):
        raise ValueError(f"mu must be a finite number > 0; got {mu!r}")
    if isinstance(num_edges, bool) or not isinstance(num_edges, (int, np.integer)) or num_edges < 3:
        raise ValueError(f"num_edges must be an integer >= 3; got {num_edges!r}")
    if torque_test not in ("exact", "paper"):
        raise ValueError(f"torque_test must be 'exact' or 'paper'; got {torque_test!r}")
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ValueError(f"chunk must be a positive integer; got {chunk!r}")
    if isinstance(top, bool) or not isinstance(top, (int, np.integer)) or top < 0:
        raise ValueError(f"top must be an integer >= 0; got {top!r}")


def _slice_chunks(chunks: Iterator, start: int, stop: int, size: int | None = None) -> Iterator[dict]:
    """Rows ``[start, stop)`` of a stream of ``(points, normals)`` chunks, re-cut into chunks of
    ``size`` rows (the last may be shorter; default: as they come)."""
    held, count, pos = [], 0, 0
    for points, normals in chunks:
        end = pos + len(points)
        lo, hi = max(start, pos), min(stop, end)
        if lo < hi:
            held.append((points[lo - pos:hi - pos], normals[lo - pos:hi - pos]))
            count += hi - lo
        pos = end
        while held and (size is None or count >= size):
            p, n = (np.concatenate(a) if len(held) > 1 else a[0] for a in zip(*held))
            take = len(p) if size is None else size
            yield {"points": p[:take], "normals": n[:take]}
            held = [(p[take:], n[take:])] if take < len(p) else []
            count -= take
        if pos >= stop:
            break
    if count:
        p, n = (np.concatenate(a) for a in zip(*held))
        yield {"points": p, "normals": n}


def _object_spec(obj, spec) -> str:
    """What to store so that ``grasp_jax.objects.load`` finds the object again."""
    if spec is None:
        return str(obj.name)
    spec = str(spec)
    return os.path.abspath(spec) if os.path.exists(spec) else spec


def run(
    obj,
    num: int,
    fingers: int,
    *,
    mu: float = DEFAULT_MU,
    num_edges: int = 8,
    seed: int = 0,
    scheme: str = "uniform",
    torque_test: str = "exact",
    chunk: int | None = None,
    epsilon: bool = False,
    origin=None,
    torque_scale: float | None = None,
    out=None,
    progress: bool = False,
    top: int = DEFAULT_TOP,
    first_contact: int | None = None,
    distributed: bool = False,
    object_spec: str | None = None,
    object_holes=None,
) -> PipelineSummary:
    """Sample ``num`` random grasps of ``obj`` and score them, one chunk at a time.

    Args:
        obj: an object of :mod:`grasp_jax.objects` (``grasp_jax.objects.load("glass")``).
        num: grasps to sample and score (any size: memory does not grow with it).
        fingers: contacts per grasp (>= 2).
        mu, num_edges, torque_test: as :func:`grasp_jax.evaluate`.
        seed, scheme, first_contact: as :func:`grasp_jax.sampling.sample_grasps`. The results do
            not depend on ``chunk`` or on the number of devices.
        chunk: grasps sampled, scored and written together (default :func:`default_chunk`).
        epsilon: also compute the Ferrari-Canny epsilon and hull volume with qhull (slow: about
            5 to 30 ms per grasp).
        origin: ``(d,)`` point the baseline's torques are taken about (default ``obj.center``, the
            centre of mass, or the centroid of a mesh that is not watertight, as GraspIt does).
        torque_scale: length the baseline's torques are divided by (default ``obj.radius``, the
            largest distance from the centre to the surface, as GraspIt does).
        out: ``.npz`` or ``.parquet`` path to stream the results to (see :mod:`grasp_jax.storage`);
            written atomically. In a multi-process run each process writes :func:`part_path`.
        progress: show a tqdm progress bar.
        top: best grasps to keep in the summary.
        distributed: score only this process's slice of a multi-process JAX job (call
            :func:`initialize_distributed` first); see the module docstring.
        object_spec: how the object was named (built-in name or file), stored in the metadata
            so that ``grasp-jax show`` can load it again (default ``obj.name``).
        object_holes: the CSV files of a polygon's holes (``grasp-jax sample --hole``), stored
            in the metadata as ``object_holes`` with ``object_spec``.

    Returns:
        :class:`PipelineSummary`.
    """
    from . import sampling, storage

    if isinstance(num, bool) or not isinstance(num, (int, np.integer)) or num < 1:
        raise ValueError(f"num must be a positive integer; got {num!r}")
    if isinstance(fingers, bool) or not isinstance(fingers, (int, np.integer)) or fingers < 2:
        raise ValueError(f"fingers must be an integer >= 2; got {fingers!r}")
    chunk = default_chunk() if chunk is None else chunk
    _check_settings(mu, num_edges, torque_test, chunk, top)
    num, fingers, chunk = int(num), int(fingers), int(chunk)
    index, count = 0, 1
    if distributed:
        import jax

        index, count = jax.process_index(), jax.process_count()
    start, stop = slice_bounds(num, index, count)
    if out is not None:
        out = part_path(storage.check_output_path(out), index, count)
    if epsilon:
        origin = np.asarray(obj.center, float) if origin is None else np.asarray(origin, float)
        torque_scale = float(obj.radius) if torque_scale is None else float(torque_scale)
        if origin.shape != (obj.dim,):
            raise ValueError(f"origin must have {obj.dim} coordinates; got {origin.tolist()}")
        if not (math.isfinite(torque_scale) and torque_scale > 0):
            raise ValueError(f"torque_scale must be a finite number > 0; got {torque_scale}")
    meta = _metadata_base(
        object=_object_spec(obj, object_spec),
        object_name=str(obj.name),
        dim=int(obj.dim),
        mu=float(mu),
        edges=int(num_edges),
        fingers=fingers,
        seed=int(seed),
        scheme=scheme,
        num=stop - start,
        torque_test=torque_test,
        first_contact=None if first_contact is None else int(first_contact),
    )
    if object_holes:
        meta["object_holes"] = [_object_spec(obj, h) for h in object_holes]
    if count > 1:
        meta.update(process_index=index, process_count=count, slice=[start, stop, num])
    kwargs = {} if first_contact is None else {"first_contact": first_contact}
    stream = sampling.iter_grasps(obj, num, fingers, seed=seed, scheme=scheme, chunk=chunk, **kwargs)
    chunks = _Prefetch(_slice_chunks(stream, start, stop, chunk))
    try:
        return score_stream(
            chunks, num=stop - start, fingers=fingers, dim=int(obj.dim), mu=mu, num_edges=num_edges,
            torque_test=torque_test, metadata=meta, epsilon=epsilon, origin=origin,
            torque_scale=torque_scale if torque_scale is not None else 1.0, out=out, progress=progress,
            top=top, desc=f"{obj.name} x{fingers}", index_offset=start,
        )
    finally:
        chunks.close()


def score_file(
    path,
    *,
    mu: float | None = None,
    num_edges: int | None = None,
    torque_test: str | None = None,
    chunk: int | None = None,
    epsilon: bool = False,
    origin=None,
    torque_scale: float | None = None,
    obj=None,
    out=None,
    progress: bool = False,
    top: int = DEFAULT_TOP,
) -> PipelineSummary:
    """Score the grasps stored in a ``.npz`` / ``.parquet`` file (``points``, ``normals``).

    ``mu``, ``num_edges`` and ``torque_test`` default to the file's metadata, else to
    :data:`DEFAULT_MU`, 8 and ``"exact"``. For ``epsilon``, ``origin`` and ``torque_scale``
    default to ``obj.center`` and ``obj.radius`` when an object is given; one of the two is
    required. If the file has a ``force_closure`` column the summary counts how many verdicts
    agree. Other arguments as :func:`run`.
    """
    from . import storage

    src = storage.ResultFile(path)
    stored = src.metadata
    mu = stored.get("mu", DEFAULT_MU) if mu is None else mu
    num_edges = stored.get("edges", 8) if num_edges is None else num_edges
    torque_test = stored.get("torque_test", "exact") if torque_test is None else torque_test
    chunk = default_chunk() if chunk is None else chunk
    _check_settings(mu, num_edges, torque_test, chunk, top)
    if out is not None:
        out = storage.check_output_path(out)
    if epsilon:
        if obj is not None:
            origin = obj.center if origin is None else origin
            torque_scale = obj.radius if torque_scale is None else torque_scale
        if origin is None or torque_scale is None:
            raise ValueError("the epsilon baseline needs the object (--object) or both --origin and --torque-scale")
        origin = np.asarray(origin, float)
        if origin.shape != (src.dim,):
            raise ValueError(f"origin must have {src.dim} coordinates; got {origin.tolist()}")
        torque_scale = float(torque_scale)
        if not (math.isfinite(torque_scale) and torque_scale > 0):
            raise ValueError(f"torque_scale must be a finite number > 0; got {torque_scale}")
    meta = {k: v for k, v in stored.items() if k not in ("epsilon_origin", "epsilon_torque_scale")}
    meta.update(_metadata_base(
        source=str(Path(path).resolve()),
        dim=src.dim,
        fingers=src.fingers,
        mu=float(mu),
        edges=int(num_edges),
        torque_test=torque_test,
        num=src.num,
    ))
    if obj is not None:
        meta.setdefault("object", str(obj.name))
        meta.setdefault("object_name", str(obj.name))
    columns = ("points", "normals") + (("force_closure",) if "force_closure" in src.fields else ())
    chunks = _Prefetch(src.iter_chunks(columns, chunk))
    try:
        return score_stream(
            chunks, num=src.num, fingers=src.fingers, dim=src.dim, mu=mu, num_edges=int(num_edges),
            torque_test=torque_test, metadata=meta, epsilon=epsilon, origin=origin,
            torque_scale=torque_scale if torque_scale is not None else 1.0, out=out, progress=progress,
            top=top, desc=Path(path).name,
        )
    finally:
        chunks.close()


def best_in_file(path, top: int = DEFAULT_TOP, chunk: int = DEFAULT_CHUNK) -> tuple[BestGrasps | None, dict]:
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
    "DEFAULT_MU",
    "DEFAULT_CHUNK",
    "BestGrasps",
    "PipelineSummary",
    "available_cores",
    "best_in_file",
    "configure_cpu_devices",
    "default_chunk",
    "initialize_distributed",
    "part_path",
    "run",
    "score_file",
    "score_stream",
    "slice_bounds",
]
