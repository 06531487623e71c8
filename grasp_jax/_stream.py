"""The streaming core of :mod:`grasp_jax.pipeline`: score a stream of chunks and write them out.

:func:`score` takes chunks ``{"points", "normals" (N, n, d)[, "force_closure", jaw poses]}`` one
at a time: the nominal verdict and Q (:func:`grasp_jax.evaluate`, every chunk padded to one
compiled size), then the optional columns (critical friction, the qhull baseline, robust labels),
then the jaw poses, and streams each chunk to an atomic writer while :class:`_Tally` keeps the
running counts of the summary. :class:`Scoring` holds how every chunk is scored.
"""

from __future__ import annotations

import dataclasses
import math
import queue
import threading
import time
import warnings
from collections.abc import Iterable, Iterator, Mapping

import numpy as np

from . import storage
from ._api import critical_friction, evaluate, friction_label
from ._baseline import ferrari_canny
from ._batch import _sizes, pad_rows
from ._labels import RobustLabels, recast_jaws
from .grippers._score import mask_failed
from .summary import DEFAULT_TOP, PERCENTILES, PipelineSummary, _QualityHistogram, _TopK

#: Fewest grasps per device in one compiled call (four blocks of ``grasp_jax._batch.BLOCK``).
MIN_ROWS = 1024
#: Ferrari-Canny epsilon (scale free: torques are divided by the torque scale) at or below which
#: the summary counts a grasp as not force-closure by the baseline; qhull leaves round-off of about
#: 1e-17 on grasps exactly on the boundary (contacts on parallel faces).
EPSILON_ZERO = 1e-9
#: Columns of the critical friction (``critical=True``): ``mu*`` (``inf`` above the cap), its
#: :class:`grasp_jax.FrictionStatus` and GraspNet-1Billion's label (:func:`grasp_jax.friction_label`).
CRITICAL_FIELDS = ("critical_mu", "critical_status", "friction_label")
#: The summary's histogram of ``mu*`` spans ``[0, cap]``; grasps above the cap count at its end.
CRITICAL_RANGE = 4.0
#: Grasps per call of the qhull baseline (and per step of the progress bar while it runs).
_EPSILON_STEP = 512


@dataclasses.dataclass(frozen=True)
class Scoring:
    """How every chunk of a stream is scored.

    Attributes:
        mu, num_edges, torque_test, contact, torsion: as :func:`grasp_jax.evaluate`.
        epsilon, origin, torque_scale: the qhull Ferrari-Canny baseline and its frame.
        critical: also the critical friction (columns :data:`CRITICAL_FIELDS`).
        robust: also robust labels (:class:`grasp_jax.pipeline.RobustLabels`).
    """

    mu: float
    num_edges: int
    torque_test: str
    contact: str = "hard"
    torsion: float | None = None
    epsilon: bool = False
    origin: object = None
    torque_scale: float = 1.0
    critical: bool = False
    robust: RobustLabels | None = None

    @property
    def model(self) -> dict:
        """The friction pyramid and contact model, as keyword arguments of the metrics."""
        return dict(num_edges=self.num_edges, contact=self.contact, torsion=self.torsion)


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


def _jsonable(x):
    if x is None:
        return None
    return np.asarray(x, float).tolist()


def _pad(a: np.ndarray, size: int) -> np.ndarray:
    return pad_rows(a, size)


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


def _evaluate_chunk() -> int:
    """Grasps per compiled call of :func:`grasp_jax.evaluate` on the local devices: a chunk at
    least this large never compiles another size."""
    import jax

    try:
        return int(_sizes(tuple(jax.local_devices()), None)[1])
    except (AttributeError, TypeError, IndexError):  # internals changed: pad fully
        return 1 << 62


# ---------------------------------------------------------------------------------------------
# Before the stream: the file's columns and metadata


def _layout(scoring: Scoring, metadata: Mapping, extra_fields: tuple, recast, dim: int) -> tuple[list, dict]:
    """``(fields, metadata)`` of the result file: the scored columns, the written-through ones and
    the settings of the optional columns."""
    fields = list(storage.RESULT_FIELDS) + list(extra_fields)
    if scoring.epsilon:
        fields += ["epsilon", "volume"]
    if scoring.critical:
        fields += list(CRITICAL_FIELDS)
    robust = scoring.robust
    if robust is not None:
        if robust.noise.moves_contacts and robust.obj is None:
            raise ValueError(f"robust labels under {robust.noise} move contacts over the object: give the object")
        fields += list(robust.fields())
    meta = dict(metadata)
    if robust is not None:
        meta["robust"] = robust.to_dict()
        if recast is not None:
            meta["robust"]["jaws"] = "recast"
    if scoring.epsilon:
        meta["epsilon_origin"] = _jsonable(scoring.origin) if scoring.origin is not None else [0.0] * dim
        meta["epsilon_torque_scale"] = float(scoring.torque_scale)
    return fields, meta


def _progress_bar(progress: bool, num: int, desc: str):
    if not progress:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=num, unit="grasp", unit_scale=True, desc=desc, dynamic_ncols=True, smoothing=0.1)


def _pad_size(rows: int, devices: int) -> int:
    """The one size every chunk is padded to, from the first chunk's ``rows``.

    Every chunk is scored by one compiled program: a later, smaller chunk is padded to the first
    one's size, and no program is compiled for fewer than MIN_ROWS grasps per device (XLA compiles
    a loop of one to three blocks differently, and Q changes in the last bits). So results do not
    depend on the chunk size."""
    return max(min(rows, _evaluate_chunk()), MIN_ROWS * devices)


# ---------------------------------------------------------------------------------------------
# One chunk's columns


def _nominal(scoring: Scoring, points, normals, pad_to: int) -> dict:
    """``points``, ``normals`` and their ``force_closure``, ``quality``, ``converged`` ``(N,)``."""
    rows = len(points)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r".*did not converge", category=RuntimeWarning)
        res = evaluate(_pad(points, pad_to), _pad(normals, pad_to), mu=scoring.mu,
                       torque_test=scoring.torque_test, **scoring.model)
    return dict(points=points, normals=normals, force_closure=np.asarray(res.force_closure)[:rows],
                quality=np.asarray(res.quality)[:rows], converged=np.asarray(res.converged)[:rows])


def _critical(scoring: Scoring, points, normals, pad_to: int) -> dict:
    """``critical_mu``, ``critical_status`` ``(N,)`` (:func:`grasp_jax.critical_friction`)."""
    rows = len(points)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r".*did not converge", category=RuntimeWarning)
        need, status = critical_friction(_pad(points, pad_to), _pad(normals, pad_to), **scoring.model)
    return dict(critical_mu=np.asarray(need, np.float64)[:rows], critical_status=np.asarray(status, np.int8)[:rows])


def _epsilon(scoring: Scoring, points, normals, bar) -> dict:
    """``epsilon``, ``volume`` ``(N,)`` by qhull (:func:`grasp_jax.ferrari_canny`), in steps of
    :data:`_EPSILON_STEP` grasps that move the progress bar."""
    rows = len(points)
    eps = np.empty(rows)
    vol = np.empty(rows)
    step = _EPSILON_STEP
    for s in range(0, rows, step):
        eps[s:s + step], vol[s:s + step] = ferrari_canny(
            points[s:s + step], normals[s:s + step], mu=scoring.mu, origin=scoring.origin,
            torque_scale=scoring.torque_scale, **scoring.model)
        if bar is not None:
            bar.update(min(step, rows - s))
    return dict(epsilon=eps, volume=vol)


def _robust(scoring: Scoring, chunk: Mapping, points, normals, recast) -> dict:
    """The robust label columns of the chunk (parallel-jaw grasps re-cast where ``recast``)."""
    settings = dict(mu=scoring.mu, num_edges=scoring.num_edges, torque_test=scoring.torque_test,
                    contact=scoring.contact, torsion=scoring.torsion)
    if recast is not None:  # parallel-jaw grasps: the closing lines cast again under noise
        return scoring.robust.jaw_columns(chunk, gripper=recast[0], collision=recast[1], **settings)
    return scoring.robust.columns(points, normals, **settings)


def _mask_failed_jaws(batch: dict, jaw_status, robust: bool = True) -> None:
    """Grasps whose jaw status is not ``OK``: not force-closure, Q 0, critical friction ``inf``
    (``grasp_jax.grippers.score_grasps``'s rule), in place; ``robust``: their robust labels 0 too
    (their fill contacts perturbed as free contacts mean nothing; re-cast jaws keep their labels:
    a perturbed pose may close where the nominal one does not)."""
    fc, q, mu, st = mask_failed(jaw_status, batch["force_closure"], batch["quality"], batch.get("critical_mu"),
                                batch.get("critical_status"))
    batch.update(force_closure=fc, quality=q)
    failed = np.asarray(jaw_status) != 0
    for name in RobustLabels.COLUMNS.values() if robust else ():
        if name in batch and name != "robust_unconverged":
            batch[name] = np.where(failed, 0.0, batch[name])
    if mu is not None:
        batch["critical_mu"] = mu
    if st is not None:
        batch["critical_status"] = st


def _jaw_columns(batch: dict, chunk: Mapping, extra_fields: tuple, recast) -> None:
    """The chunk's written-through columns (parallel-jaw poses) into ``batch``; where it has
    ``jaw_status``, failed jaws never hold (:func:`_mask_failed_jaws`)."""
    if not extra_fields:
        return
    batch.update({name: chunk[name] for name in extra_fields})
    if "jaw_status" in chunk:
        _mask_failed_jaws(batch, chunk["jaw_status"], robust=recast is None)


# ---------------------------------------------------------------------------------------------
# The running summary


class _Tally:
    """The running counts of a stream: grasps, force-closure, a histogram of Q (and of ``mu*``),
    the best grasps, the baseline's and the robust labels' sums."""

    def __init__(self, scoring: Scoring, top: int):
        self.scoring = scoring
        self.hist = _QualityHistogram(math.sqrt(1 + scoring.mu * scoring.mu) * (1 + 1e-9))
        self.best = _TopK(top)
        self.counts = dict(num=0, fc=0, unconverged=0, eps_pos=0, eps_dis=0, agree=0)
        self.critical_mu = _QualityHistogram(CRITICAL_RANGE) if scoring.critical else None
        self.rob = dict(p_sum=0.0, p_fc_sum=0.0, q_sum=0.0, seconds=0.0)
        self.eps_max = 0.0
        self.have_ref = False
        self.first_seconds = 0.0
        self.first_size = 0

    def add_epsilon(self, eps: np.ndarray, fc: np.ndarray) -> None:
        """The baseline's verdicts ``eps > EPSILON_ZERO`` against the nominal ones ``fc``."""
        pos = eps > EPSILON_ZERO
        self.counts["eps_pos"] += int(pos.sum())
        self.counts["eps_dis"] += int((pos != fc).sum())
        self.eps_max = max(self.eps_max, float(eps.max()))

    def compare(self, chunk: Mapping, fc: np.ndarray) -> None:
        """A stored ``force_closure`` of the chunk against the new verdicts ``fc``."""
        if "force_closure" in chunk:
            self.have_ref = True
            self.counts["agree"] += int((np.asarray(chunk["force_closure"], bool) == fc).sum())

    def add(self, batch: Mapping, index_offset: int, seconds: float) -> None:
        """A written chunk; ``seconds`` since the stream started (the first chunk's time)."""
        fc, q, conv = batch["force_closure"], batch["quality"], batch["converged"]
        if self.scoring.robust is not None:
            self.rob["p_sum"] += float(batch["p_fc"].sum())
            self.rob["p_fc_sum"] += float(batch["p_fc"][fc].sum())
            self.rob["q_sum"] += float(batch["q_mean"].sum())
        self.hist.add(q[fc])
        self.best.add(index_offset + self.counts["num"], batch["points"], batch["normals"], q, fc)
        self.counts["num"] += len(fc)
        self.counts["fc"] += int(fc.sum())
        self.counts["unconverged"] += int((~conv).sum())
        if not self.first_seconds:
            self.first_seconds = seconds

    def robust_summary(self) -> dict:
        """The robust labels' part of the summary: mean P(force-closure) over all grasps and over
        the nominally force-closure ones, mean expected Q, time."""
        robust, counts, rob = self.scoring.robust, self.counts, self.rob
        num = counts["num"]
        return {
            "samples": int(robust.samples),
            "noise": str(robust.noise),
            "p_fc_mean": rob["p_sum"] / num if num else math.nan,
            "p_fc_mean_nominal_fc": rob["p_fc_sum"] / counts["fc"] if counts["fc"] else math.nan,
            "q_mean_mean": rob["q_sum"] / num if num else math.nan,
            "seconds": rob["seconds"],
            "perturbed_per_second": num * robust.samples / rob["seconds"] if rob["seconds"] > 0 else math.nan,
        }

    def summary(self, *, seconds: float, path, meta: dict, devices: int) -> PipelineSummary:
        counts, hist, epsilon, critical_mu = self.counts, self.hist, self.scoring.epsilon, self.critical_mu
        return PipelineSummary(
            num=counts["num"],
            force_closure=counts["fc"],
            unconverged=counts["unconverged"],
            quality_percentiles={p: hist.percentile(p) for p in PERCENTILES},
            quality_mean=hist.sum / hist.total if hist.total else math.nan,
            quality_max=hist.max if hist.total else math.nan,
            seconds=seconds,
            first_chunk_seconds=self.first_seconds,
            first_chunk=self.first_size,
            best=self.best.best,
            output=path,
            metadata=meta,
            devices=devices,
            epsilon_positive=counts["eps_pos"] if epsilon else None,
            epsilon_disagree=counts["eps_dis"] if epsilon else None,
            epsilon_max=self.eps_max if epsilon else None,
            agree=counts["agree"] if self.have_ref else None,
            critical_percentiles=({p: critical_mu.percentile(p) for p in PERCENTILES}
                                  if critical_mu is not None and critical_mu.total else None),
            robust=None if self.scoring.robust is None else self.robust_summary(),
        )


# ---------------------------------------------------------------------------------------------
# The stream


def _score_chunk(scoring: Scoring, chunk: Mapping, points, normals, pad_to: int, tally: _Tally, bar,
                 extra_fields: tuple, recast) -> dict:
    """Every column of one chunk, the running counts that need the nominal verdicts updated."""
    batch = _nominal(scoring, points, normals, pad_to)
    fc = batch["force_closure"]
    if scoring.critical:
        batch.update(_critical(scoring, points, normals, pad_to))
    if scoring.epsilon:
        batch.update(_epsilon(scoring, points, normals, bar))
        tally.add_epsilon(batch["epsilon"], fc)
    elif bar is not None:
        bar.update(len(points))
    if scoring.robust is not None:
        t_robust = time.perf_counter()
        batch.update(_robust(scoring, chunk, points, normals, recast))
        tally.rob["seconds"] += time.perf_counter() - t_robust
    tally.compare(chunk, fc)
    _jaw_columns(batch, chunk, extra_fields, recast)
    if scoring.critical:
        batch["friction_label"] = friction_label(batch["critical_mu"])
        tally.critical_mu.add(np.minimum(batch["critical_mu"], CRITICAL_RANGE))
    return batch


def score(chunks: Iterable[Mapping], scoring: Scoring, *, num: int, fingers: int, dim: int, metadata: Mapping,
          out=None, progress: bool = False, top: int = DEFAULT_TOP, desc: str = "scoring", index_offset: int = 0,
          extra_fields: tuple = ()) -> PipelineSummary:
    """:func:`grasp_jax.pipeline.score_stream` with its scoring settings in one :class:`Scoring`."""
    import jax

    recast = recast_jaws(scoring.robust, tuple(extra_fields), metadata)
    fields, meta = _layout(scoring, metadata, extra_fields, recast, dim)
    writer = storage.open_writer(out, meta, fields, fingers=fingers, dim=dim) if out is not None else None
    tally = _Tally(scoring, top)
    devices = len(jax.local_devices())
    bar = _progress_bar(progress, num, desc)
    t0 = time.perf_counter()
    pad_to = 0
    try:
        for chunk in chunks:
            points = np.asarray(chunk["points"], np.float64)
            normals = np.asarray(chunk["normals"], np.float64)
            if len(points) == 0:
                continue
            if not tally.first_size:
                tally.first_size = len(points)
                pad_to = _pad_size(len(points), devices)
            batch = _score_chunk(scoring, chunk, points, normals, pad_to, tally, bar, extra_fields, recast)
            if writer is not None:
                writer.write(batch)
            tally.add(batch, index_offset, time.perf_counter() - t0)
            if bar is not None:
                bar.set_postfix_str(f"FC {100 * tally.counts['fc'] / tally.counts['num']:.1f}%", refresh=False)
        path = writer.close() if writer is not None else None
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    finally:
        if bar is not None:
            bar.close()
    seconds = time.perf_counter() - t0
    meta["num"] = tally.counts["num"]
    return tally.summary(seconds=seconds, path=path, meta=meta, devices=devices)
