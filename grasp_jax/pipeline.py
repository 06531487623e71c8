"""Score millions of candidate grasps with flat memory: sample, evaluate, (baseline), stream out.

:func:`run` draws ``num`` random grasps of an object chunk by chunk
(:func:`grasp_jax.sampling.iter_grasps`, the next chunk sampled in a background thread), scores
each with :func:`grasp_jax.evaluate` (sharded over every local device), optionally adds the qhull
Ferrari-Canny baseline, and streams the results to a ``.npz`` or ``.parquet`` file
(:mod:`grasp_jax.storage`). One chunk is in memory at a time; the summary keeps running counts, a
histogram of Q and the best few grasps (:mod:`grasp_jax.summary`). :func:`score_file` does the
same for grasps stored in a file.

With ``distributed=True`` (:func:`grasp_jax.devices.initialize_distributed` first), every process
samples the same seeded stream, scores its contiguous slice ``[num * i // P, num * (i + 1) // P)``
and writes ``<stem>.<i>-of-<P><suffix>``; the files in process order concatenate to the
single-process result. No collective is used.
"""

from __future__ import annotations

import dataclasses
import math
import queue
import threading
import time
import warnings
from pathlib import Path
from typing import ClassVar, Iterable, Iterator, Mapping

import numpy as np

from . import devices as _devices
from .devices import part_path, slice_bounds
from .summary import DEFAULT_TOP, PERCENTILES, PipelineSummary, _QualityHistogram, _TopK

#: The paper's friction coefficient, tan(20 deg).
DEFAULT_MU = 0.364
#: Grasps per pipeline chunk: sampled, scored and written together.
DEFAULT_CHUNK = 65536
#: Fewest grasps per device in one compiled call (four blocks of ``grasp_jax._batch.BLOCK``).
MIN_ROWS = 1024
#: Ferrari-Canny epsilon (scale free: torques are divided by the torque scale) at or below which
#: the summary counts a grasp as not force-closure by the baseline; qhull leaves round-off of about
#: 1e-17 on grasps exactly on the boundary (contacts on parallel faces).
EPSILON_ZERO = 1e-9


# ---------------------------------------------------------------------------------------------
# Robust labels


@dataclasses.dataclass(frozen=True)
class RobustLabels:
    """Robust labels written beside the nominal scores (``grasp-jax sample / score --robust N``):
    :func:`grasp_jax.robust` of every chunk, with the same draws for every chunk (one key), so the
    labels do not depend on the chunk size. Parallel-jaw grasps (chunks with jaw poses) under noise
    that moves contacts are labelled by :func:`grasp_jax.grippers.robust_jaws` instead: the closing
    line cast again at every perturbed pose (the metadata's ``robust`` says ``"jaws": "recast"``).

    Attributes:
        noise: a :class:`grasp_jax.Noise`.
        samples: perturbations per grasp (>= 2).
        seed: the key's seed (``jax.random.key(seed)``).
        quantile: of ``q_low`` and ``margin_low``.
        margin: also the min-weight margin columns.
        obj: the object, where the noise moves contacts.
    """

    noise: object
    samples: int = 100
    seed: int = 0
    quantile: float = 0.1
    margin: bool = True
    obj: object = None

    #: RobustResult field -> result file column.
    COLUMNS: ClassVar[dict] = {"p_fc": "p_fc", "p_fc_se": "p_fc_se", "q_mean": "q_mean", "q_mean_se": "q_mean_se",
               "q_low": "q_low", "margin_mean": "margin_mean", "margin_mean_se": "margin_mean_se",
               "margin_low": "margin_low", "unconverged": "robust_unconverged"}

    def fields(self) -> tuple[str, ...]:
        """The result file columns this adds."""
        return tuple(c for f, c in self.COLUMNS.items() if self.margin or not f.startswith("margin"))

    def to_dict(self) -> dict:
        """The settings, for a result file's metadata (``robust``)."""
        return {"samples": int(self.samples), "seed": int(self.seed), "quantile": float(self.quantile),
                "margin": bool(self.margin), "noise": dataclasses.asdict(self.noise)}

    def columns(self, points, normals, *, mu, num_edges, torque_test, contact, torsion) -> dict:
        """``{column: (N,) array}`` of the grasps ``points``, ``normals`` ``(N, n, d)``."""
        import jax

        import grasp_jax as gj

        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r".*did not converge", category=RuntimeWarning)
            res = gj.robust(self.obj, points, normals, mu=mu, noise=self.noise, key=jax.random.key(self.seed),
                            samples=self.samples, quantile=self.quantile, num_edges=num_edges,
                            torque_test=torque_test, contact=contact, torsion=torsion, margin=self.margin)
        return {self.COLUMNS[f]: v for f, v in res.columns().items()}

    def jaw_columns(self, chunk: Mapping, *, gripper, collision: bool, mu, num_edges, torque_test, contact,
                    torsion) -> dict:
        """``{column: (N,) array}`` of the parallel-jaw grasps of ``chunk`` (``center``, ``axis``,
        ``width``[, ``approach``]) by :func:`grasp_jax.grippers.robust_jaws` on ``obj``'s mesh."""
        import jax

        from .grippers import robust_jaws

        approaches = chunk.get("approach") if collision else None
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r".*did not converge", category=RuntimeWarning)
            res = robust_jaws(self.obj, chunk["center"], chunk["axis"], chunk["width"], approaches, mu=mu,
                              noise=self.noise, key=jax.random.key(self.seed), samples=self.samples,
                              gripper=gripper, collision=collision, quantile=self.quantile, num_edges=num_edges,
                              torque_test=torque_test, contact=contact, torsion=torsion, margin=self.margin)
        return {self.COLUMNS[f]: v for f, v in res.columns().items()}


def _recast_jaws(robust: RobustLabels | None, extra_fields: tuple, metadata: Mapping):
    """``(gripper, collision)`` where the robust labels of a stream re-cast its parallel-jaw
    grasps (jaw poses in the chunks, noise that moves contacts), else ``None``."""
    if robust is None or not robust.noise.moves_contacts:
        return None
    if not {"center", "axis", "width", "jaw_status"} <= set(extra_fields):
        return None
    from .grippers import ParallelJaw

    gripper = metadata.get("gripper")
    gripper = ParallelJaw.from_dict(gripper) if isinstance(gripper, Mapping) else None
    collision = bool(metadata.get("collision")) and gripper is not None and gripper.has_body \
        and "approach" in extra_fields
    return gripper, collision


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


def _jsonable(x):
    if x is None:
        return None
    return np.asarray(x, float).tolist()


def _pad(a: np.ndarray, size: int) -> np.ndarray:
    from ._batch import pad_rows

    return pad_rows(a, size)


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
    contact: str = "hard",
    torsion: float | None = None,
    extra_fields: tuple = (),
    critical: bool = False,
    robust: RobustLabels | None = None,
) -> PipelineSummary:
    """Score a stream of chunks ``{"points", "normals"[, "force_closure"]}`` and write the results.

    The engine behind :func:`run` and :func:`score_file`; see there. ``num`` is the number of
    grasps the stream holds (for the progress bar); a stored ``force_closure`` in the chunks is
    compared with the new verdicts (``agree``). ``index_offset`` is added to the indices of the
    best grasps (the start of this process's slice). ``contact``, ``torsion``: the contact model,
    as :func:`grasp_jax.evaluate`. ``extra_fields``: columns of the chunks written as they are
    (the jaw poses of :mod:`grasp_jax.grippers`); where the chunks have ``jaw_status``, grasps
    whose status is not ``OK`` are not force-closure, Q 0 (critical friction ``inf``).
    ``critical``: also the critical friction of each grasp (:func:`grasp_jax.critical_friction`,
    columns :data:`CRITICAL_FIELDS`). ``robust``: also write robust labels (:class:`RobustLabels`).
    Parallel-jaw grasps under noise that moves contacts are re-cast at every perturbed pose
    (:func:`grasp_jax.grippers.robust_jaws`, with the gripper and collision setting of
    ``metadata``; a perturbation whose jaws fail counts as not force-closure); under normal and
    friction noise alone their contacts do not move and are perturbed as free contacts, failed jaws
    P(force-closure) 0.
    """
    import jax

    import grasp_jax as gj

    from . import storage

    mu = float(mu)
    fields = list(storage.RESULT_FIELDS) + list(extra_fields)
    if epsilon:
        fields += ["epsilon", "volume"]
    if critical:
        fields += list(CRITICAL_FIELDS)
    if robust is not None:
        if robust.noise.moves_contacts and robust.obj is None:
            raise ValueError(f"robust labels under {robust.noise} move contacts over the object: give the object")
        fields += list(robust.fields())
    meta = dict(metadata)
    recast = _recast_jaws(robust, tuple(extra_fields), metadata)
    if robust is not None:
        meta["robust"] = robust.to_dict()
        if recast is not None:
            meta["robust"]["jaws"] = "recast"
    if epsilon:
        meta["epsilon_origin"] = _jsonable(origin) if origin is not None else [0.0] * dim
        meta["epsilon_torque_scale"] = float(torque_scale)
    writer = storage.open_writer(out, meta, fields, fingers=fingers, dim=dim) if out is not None else None
    hist = _QualityHistogram(math.sqrt(1 + mu * mu) * (1 + 1e-9))
    best = _TopK(top)
    devices = len(jax.local_devices())
    counts = dict(num=0, fc=0, unconverged=0, eps_pos=0, eps_dis=0, agree=0)
    critical_mu = _QualityHistogram(_CRITICAL_RANGE) if critical else None
    rob = dict(p_sum=0.0, p_fc_sum=0.0, q_sum=0.0, seconds=0.0)
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
                                  torque_test=torque_test, contact=contact, torsion=torsion)
            fc = np.asarray(res.force_closure)[:rows]
            q = np.asarray(res.quality)[:rows]
            conv = np.asarray(res.converged)[:rows]
            batch = dict(points=points, normals=normals, force_closure=fc, quality=q, converged=conv)
            if critical:
                with warnings.catch_warnings():
                    warnings.filterwarnings("ignore", message=r".*did not converge", category=RuntimeWarning)
                    need, status = gj.critical_friction(_pad(points, pad_to), _pad(normals, pad_to), num_edges=num_edges,
                                                        contact=contact, torsion=torsion)
                batch.update(critical_mu=np.asarray(need, np.float64)[:rows],
                             critical_status=np.asarray(status, np.int8)[:rows])
            if epsilon:
                eps = np.empty(rows)
                vol = np.empty(rows)
                step = 512
                for s in range(0, rows, step):
                    eps[s:s + step], vol[s:s + step] = gj.ferrari_canny(
                        points[s:s + step], normals[s:s + step], mu=mu, num_edges=num_edges, origin=origin,
                        torque_scale=torque_scale, contact=contact, torsion=torsion)
                    if bar is not None:
                        bar.update(min(step, rows - s))
                batch.update(epsilon=eps, volume=vol)
                pos = eps > EPSILON_ZERO
                counts["eps_pos"] += int(pos.sum())
                counts["eps_dis"] += int((pos != fc).sum())
                eps_max = max(eps_max, float(eps.max()))
            elif bar is not None:
                bar.update(rows)
            if robust is not None:
                t_robust = time.perf_counter()
                if recast is not None:  # parallel-jaw grasps: the closing lines cast again under noise
                    batch.update(robust.jaw_columns(chunk, gripper=recast[0], collision=recast[1], mu=mu,
                                                    num_edges=num_edges, torque_test=torque_test, contact=contact,
                                                    torsion=torsion))
                else:
                    batch.update(robust.columns(points, normals, mu=mu, num_edges=num_edges,
                                                torque_test=torque_test, contact=contact, torsion=torsion))
                rob["seconds"] += time.perf_counter() - t_robust
            if "force_closure" in chunk:
                have_ref = True
                counts["agree"] += int((np.asarray(chunk["force_closure"], bool) == fc).sum())
            if extra_fields:  # parallel-jaw poses: written as they come; failed jaws never hold
                batch.update({name: chunk[name] for name in extra_fields})
                if "jaw_status" in chunk:
                    _mask_failed_jaws(batch, chunk["jaw_status"], robust=recast is None)
                    fc, q = batch["force_closure"], batch["quality"]
            if critical:
                batch["friction_label"] = gj.friction_label(batch["critical_mu"])
                critical_mu.add(np.minimum(batch["critical_mu"], _CRITICAL_RANGE))
            if writer is not None:
                writer.write(batch)
            if robust is not None:
                rob["p_sum"] += float(batch["p_fc"].sum())
                rob["p_fc_sum"] += float(batch["p_fc"][fc].sum())
                rob["q_sum"] += float(batch["q_mean"].sum())
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
        critical_percentiles=({p: critical_mu.percentile(p) for p in PERCENTILES} if critical and critical_mu.total
                              else None),
        robust=None if robust is None else _robust_summary(robust, counts, rob),
    )


#: Columns of the critical friction (``critical=True``): ``mu*`` (``inf`` above the cap), its
#: :class:`grasp_jax.FrictionStatus` and GraspNet-1Billion's label (:func:`grasp_jax.friction_label`).
CRITICAL_FIELDS = ("critical_mu", "critical_status", "friction_label")
#: The summary's histogram of ``mu*`` spans ``[0, cap]``; grasps above the cap count at its end.
_CRITICAL_RANGE = 4.0


def _robust_summary(robust: RobustLabels, counts: dict, rob: dict) -> dict:
    """The robust labels' part of the summary: mean P(force-closure) over all grasps and over the
    nominally force-closure ones, mean expected Q, time."""
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


def _mask_failed_jaws(batch: dict, jaw_status, robust: bool = True) -> None:
    """Grasps whose jaw status is not ``OK``: not force-closure, Q 0, critical friction ``inf``
    (``grasp_jax.grippers.score_grasps``'s rule), in place; ``robust``: their robust labels 0 too
    (their fill contacts perturbed as free contacts mean nothing; re-cast jaws keep their labels:
    a perturbed pose may close where the nominal one does not)."""
    from .grippers._score import mask_failed

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


def _check_contact(contact, torsion, dim: int) -> tuple[str, float | None]:
    """``(contact, torsion)`` validated (``grasp_jax._api.check_contact``); torsion ``None`` for
    hard contacts, as :func:`grasp_jax.evaluate` takes it."""
    from ._api import check_contact

    contact, value = check_contact(contact, torsion, dim)
    return contact, (None if contact == "hard" else float(value))


def _contact_metadata(contact: str, torsion) -> dict:
    """The contact model in a result file's metadata: ``contact``, and ``torsion`` where soft."""
    return {"contact": contact} if contact == "hard" else {"contact": contact, "torsion": float(torsion)}


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
    contact: str = "hard",
    torsion: float | None = None,
    gripper=None,
    collision: bool = False,
    critical: bool | None = None,
    robust: RobustLabels | None = None,
) -> PipelineSummary:
    """Sample ``num`` random grasps of ``obj`` and score them, one chunk at a time.

    Args:
        obj: an object of :mod:`grasp_jax.objects` (``grasp_jax.objects.load("glass")``).
        num: grasps to sample and score (any size: memory does not grow with it).
        fingers: contacts per grasp (>= 2).
        mu, num_edges, torque_test, contact, torsion: as :func:`grasp_jax.evaluate` (stored in the
            file's metadata).
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
        gripper: a :class:`grasp_jax.grippers.ParallelJaw`: sample antipodal parallel-jaw grasps
            (:func:`grasp_jax.grippers.antipodal_grasps`, friction cone ``mu``) instead of free
            contacts, ``fingers`` 2, and write their poses (``center``, ``axis``, ``approach``,
            ``width``, ``jaw_status``) too. ``collision``: check the gripper body.
        critical: also the critical friction of each grasp (:func:`grasp_jax.critical_friction`;
            columns :data:`CRITICAL_FIELDS`). Default: with a gripper only (the search runs at
            about 1/10 of scoring's throughput for two soft contacts, 1/16 for four hard ones).
        robust: also write robust labels (:class:`RobustLabels`; its object defaults to ``obj``).

    Returns:
        :class:`PipelineSummary`.
    """
    from . import sampling, storage

    critical = gripper is not None if critical is None else bool(critical)

    if isinstance(num, bool) or not isinstance(num, (int, np.integer)) or num < 1:
        raise ValueError(f"num must be a positive integer; got {num!r}")
    if isinstance(fingers, bool) or not isinstance(fingers, (int, np.integer)) or fingers < 2:
        raise ValueError(f"fingers must be an integer >= 2; got {fingers!r}")
    chunk = default_chunk() if chunk is None else chunk
    _check_settings(mu, num_edges, torque_test, chunk, top)
    contact, torsion = _check_contact(contact, torsion, int(obj.dim))
    num, fingers, chunk = int(num), int(fingers), int(chunk)
    index, count = 0, 1
    if distributed:
        index, count = _devices.process_slot()
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
    meta = storage.metadata(
        object=storage.object_spec(obj, object_spec),
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
        **_contact_metadata(contact, torsion),
    )
    if object_holes:
        meta["object_holes"] = [storage.object_spec(obj, h) for h in object_holes]
    if count > 1:
        meta.update(process_index=index, process_count=count, slice=[start, stop, num])
    if critical:
        meta["critical_friction_cap"] = _CRITICAL_RANGE
    kwargs = {} if first_contact is None else {"first_contact": first_contact}
    extra = ()
    if gripper is not None:  # parallel-jaw grasps: grasp_jax.grippers
        from . import grippers

        if fingers != 2 or scheme != "uniform" or first_contact is not None or obj.dim != 3:
            raise ValueError("parallel-jaw grasps have 2 contacts on a 3D mesh, sampled antipodally: "
                             "leave fingers, scheme and first_contact at their defaults")
        meta.update(scheme="antipodal", gripper=gripper.to_dict(), collision=bool(collision))
        extra = grippers.POSE_FIELDS
        chunks = _Prefetch(grippers._antipodal.column_chunks(obj, num, start, stop, chunk, mu=mu, gripper=gripper,
                                                             seed=seed, collision=collision))
    else:
        stream = sampling.iter_grasps(obj, num, fingers, seed=seed, scheme=scheme, chunk=chunk, **kwargs)
        chunks = _Prefetch(_slice_chunks(stream, start, stop, chunk))
    try:
        return score_stream(
            chunks, num=stop - start, fingers=fingers, dim=int(obj.dim), mu=mu, num_edges=num_edges,
            torque_test=torque_test, metadata=meta, epsilon=epsilon, origin=origin,
            torque_scale=torque_scale if torque_scale is not None else 1.0, out=out, progress=progress,
            top=top, desc=f"{obj.name} x{fingers}", index_offset=start, contact=contact, torsion=torsion,
            extra_fields=extra, critical=critical, robust=_with_object(robust, obj),
        )
    finally:
        chunks.close()


def _with_object(robust: RobustLabels | None, obj) -> RobustLabels | None:
    """``robust`` with its object set to ``obj`` where it has none."""
    if robust is None or robust.obj is not None or obj is None:
        return robust
    return dataclasses.replace(robust, obj=obj)


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
    contact: str | None = None,
    torsion: float | None = None,
    critical: bool = False,
    robust: RobustLabels | None = None,
) -> PipelineSummary:
    """Score the grasps stored in a ``.npz`` / ``.parquet`` file (``points``, ``normals``).

    ``mu``, ``num_edges``, ``torque_test`` and the contact model (``contact``, ``torsion``) default
    to the file's metadata, else to :data:`DEFAULT_MU`, 8, ``"exact"`` and hard contacts. For ``epsilon``, ``origin`` and ``torque_scale``
    default to ``obj.center`` and ``obj.radius`` when an object is given; one of the two is
    required. If the file has a ``force_closure`` column the summary counts how many verdicts
    agree. ``critical``: also the critical friction (columns :data:`CRITICAL_FIELDS`). Other
    arguments as :func:`run` (``robust``: noise that moves contacts needs ``obj``).
    """
    from . import storage

    src = storage.ResultFile(path)
    stored = src.metadata
    mu = stored.get("mu", DEFAULT_MU) if mu is None else mu
    num_edges = stored.get("edges", 8) if num_edges is None else num_edges
    torque_test = stored.get("torque_test", "exact") if torque_test is None else torque_test
    if contact is None:
        contact = stored.get("contact", "hard")
        torsion = stored.get("torsion") if torsion is None else torsion
    chunk = default_chunk() if chunk is None else chunk
    _check_settings(mu, num_edges, torque_test, chunk, top)
    contact, torsion = _check_contact(contact, torsion, src.dim)
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
    meta = {k: v for k, v in stored.items() if k not in ("epsilon_origin", "epsilon_torque_scale", "torsion")}
    meta.update(storage.metadata(
        source=str(Path(path).resolve()),
        dim=src.dim,
        fingers=src.fingers,
        mu=float(mu),
        edges=int(num_edges),
        torque_test=torque_test,
        num=src.num,
        **_contact_metadata(contact, torsion),
    ))
    if obj is not None:
        meta.setdefault("object", str(obj.name))
        meta.setdefault("object_name", str(obj.name))
    columns = ("points", "normals") + (("force_closure",) if "force_closure" in src.fields else ())
    # parallel-jaw poses are carried over, and their failed grasps stay failed
    extra = tuple(f for f in storage.VECTOR_FIELDS + ("width", "jaw_status") if f in src.fields)
    chunks = _Prefetch(src.iter_chunks(columns + extra, chunk))
    try:
        return score_stream(
            chunks, num=src.num, fingers=src.fingers, dim=src.dim, mu=mu, num_edges=int(num_edges),
            torque_test=torque_test, metadata=meta, epsilon=epsilon, origin=origin,
            torque_scale=torque_scale if torque_scale is not None else 1.0, out=out, progress=progress,
            top=top, desc=Path(path).name, contact=contact, torsion=torsion, extra_fields=extra,
            critical=critical, robust=_with_object(robust, obj),
        )
    finally:
        chunks.close()


__all__ = [
    "RobustLabels",
    "DEFAULT_CHUNK",
    "DEFAULT_MU",
    "EPSILON_ZERO",
    "default_chunk",
    "run",
    "score_file",
    "score_stream",
]
