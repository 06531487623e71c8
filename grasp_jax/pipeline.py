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
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from . import devices as _devices
from . import grippers, storage
from ._api import check_contact
from ._labels import RobustLabels
from ._labels import recast_jaws as _recast_jaws  # noqa: F401 - the name this module had
from ._labels import with_object as _with_object
from ._stream import (  # noqa: F401 - the names this module had
    CRITICAL_FIELDS,
    EPSILON_ZERO,
    MIN_ROWS,
    Scoring,
    _evaluate_chunk,
    _mask_failed_jaws,
    _pad,
    _Prefetch,
    _slice_chunks,
)
from ._stream import CRITICAL_RANGE as _CRITICAL_RANGE
from ._stream import score as _score
from .devices import part_path, slice_bounds
from .sampling import iter_grasps
from .summary import DEFAULT_TOP, PipelineSummary

#: The paper's friction coefficient, tan(20 deg).
DEFAULT_MU = 0.364
#: Grasps per pipeline chunk: sampled, scored and written together.
DEFAULT_CHUNK = 65536


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
    scoring = Scoring(mu=float(mu), num_edges=num_edges, torque_test=torque_test, contact=contact, torsion=torsion,
                      epsilon=epsilon, origin=origin, torque_scale=torque_scale, critical=critical, robust=robust)
    return _score(chunks, scoring, num=num, fingers=fingers, dim=dim, metadata=metadata, out=out, progress=progress,
                  top=top, desc=desc, index_offset=index_offset, extra_fields=tuple(extra_fields))


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


def _check_frame(origin, torque_scale, dim: int) -> tuple[np.ndarray, float]:
    """The baseline's frame validated: ``origin`` ``(dim,)`` and a finite ``torque_scale`` > 0."""
    origin = np.asarray(origin, float)
    if origin.shape != (dim,):
        raise ValueError(f"origin must have {dim} coordinates; got {origin.tolist()}")
    torque_scale = float(torque_scale)
    if not (math.isfinite(torque_scale) and torque_scale > 0):
        raise ValueError(f"torque_scale must be a finite number > 0; got {torque_scale}")
    return origin, torque_scale


def _check_contact(contact, torsion, dim: int) -> tuple[str, float | None]:
    """``(contact, torsion)`` validated (``grasp_jax._api.check_contact``); torsion ``None`` for
    hard contacts, as :func:`grasp_jax.evaluate` takes it."""
    contact, value = check_contact(contact, torsion, dim)
    return contact, (None if contact == "hard" else float(value))


def _contact_metadata(contact: str, torsion) -> dict:
    """The contact model in a result file's metadata: ``contact``, and ``torsion`` where soft."""
    return {"contact": contact} if contact == "hard" else {"contact": contact, "torsion": float(torsion)}


@dataclasses.dataclass(frozen=True)
class _Sampling:
    """How :func:`run` draws its grasps: ``num`` of them (this process's rows ``[start, stop)``),
    ``fingers`` contacts each, as :func:`grasp_jax.sampling.iter_grasps` or, with a ``gripper``,
    :func:`grasp_jax.grippers.antipodal_grasps`."""

    num: int
    fingers: int
    seed: int
    scheme: str
    chunk: int
    first_contact: int | None
    gripper: object
    collision: bool
    start: int
    stop: int


def run(
    obj, num: int, fingers: int, *, mu: float = DEFAULT_MU, num_edges: int = 8, seed: int = 0, scheme: str = "uniform",
    torque_test: str = "exact", chunk: int | None = None, epsilon: bool = False, origin=None,
    torque_scale: float | None = None, out=None, progress: bool = False, top: int = DEFAULT_TOP,
    first_contact: int | None = None, distributed: bool = False, object_spec: str | None = None, object_holes=None,
    contact: str = "hard", torsion: float | None = None, gripper=None, collision: bool = False,
    critical: bool | None = None, robust: RobustLabels | None = None,
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
    critical = gripper is not None if critical is None else bool(critical)
    num, fingers, chunk = _check_run(num, fingers, chunk, mu, num_edges, torque_test, top)
    contact, torsion = _check_contact(contact, torsion, int(obj.dim))
    index, count = _devices.process_slot() if distributed else (0, 1)
    start, stop = slice_bounds(num, index, count)
    if out is not None:
        out = part_path(storage.check_output_path(out), index, count)
    if epsilon:
        origin, torque_scale = _check_frame(obj.center if origin is None else origin,
                                            obj.radius if torque_scale is None else torque_scale, obj.dim)
    sampling = _Sampling(num=num, fingers=fingers, seed=int(seed), scheme=scheme, chunk=chunk,
                         first_contact=first_contact, gripper=gripper, collision=collision, start=start, stop=stop)
    meta = _run_metadata(obj, sampling, mu=mu, num_edges=num_edges, torque_test=torque_test, contact=contact,
                         torsion=torsion, object_spec=object_spec, object_holes=object_holes, critical=critical,
                         slot=(index, count))
    chunks, extra = _run_chunks(obj, sampling, meta, mu=mu)
    scoring = Scoring(mu=float(mu), num_edges=num_edges, torque_test=torque_test, contact=contact, torsion=torsion,
                      epsilon=epsilon, origin=origin, torque_scale=torque_scale if torque_scale is not None else 1.0,
                      critical=critical, robust=_with_object(robust, obj))
    try:
        return _score(chunks, scoring, num=stop - start, fingers=fingers, dim=int(obj.dim), metadata=meta, out=out,
                      progress=progress, top=top, desc=f"{obj.name} x{fingers}", index_offset=start,
                      extra_fields=extra)
    finally:
        chunks.close()


def _check_run(num, fingers, chunk, mu, num_edges, torque_test, top) -> tuple[int, int, int]:
    """``(num, fingers, chunk)`` of :func:`run` validated (``chunk`` ``None``: :func:`default_chunk`)."""
    if isinstance(num, bool) or not isinstance(num, (int, np.integer)) or num < 1:
        raise ValueError(f"num must be a positive integer; got {num!r}")
    if isinstance(fingers, bool) or not isinstance(fingers, (int, np.integer)) or fingers < 2:
        raise ValueError(f"fingers must be an integer >= 2; got {fingers!r}")
    chunk = default_chunk() if chunk is None else chunk
    _check_settings(mu, num_edges, torque_test, chunk, top)
    return int(num), int(fingers), int(chunk)


def _run_metadata(obj, sampling: _Sampling, *, mu, num_edges, torque_test, contact, torsion, object_spec,
                  object_holes, critical: bool, slot: tuple[int, int]) -> dict:
    """The result file's metadata of :func:`run`: the object, the sampling and scoring settings,
    this process's slice."""
    first_contact = sampling.first_contact
    meta = storage.metadata(
        object=storage.object_spec(obj, object_spec),
        object_name=str(obj.name),
        dim=int(obj.dim),
        mu=float(mu),
        edges=int(num_edges),
        fingers=sampling.fingers,
        seed=sampling.seed,
        scheme=sampling.scheme,
        num=sampling.stop - sampling.start,
        torque_test=torque_test,
        first_contact=None if first_contact is None else int(first_contact),
        **_contact_metadata(contact, torsion),
    )
    if object_holes:
        meta["object_holes"] = [storage.object_spec(obj, h) for h in object_holes]
    index, count = slot
    if count > 1:
        meta.update(process_index=index, process_count=count, slice=[sampling.start, sampling.stop, sampling.num])
    if critical:
        meta["critical_friction_cap"] = _CRITICAL_RANGE
    return meta


def _run_chunks(obj, sampling: _Sampling, meta: dict, *, mu) -> tuple[_Prefetch, tuple]:
    """``(chunks, extra fields)``: this process's grasps of ``obj``, prefetched; with a gripper the
    antipodal parallel-jaw grasps and their pose columns (``meta`` records the gripper)."""
    s = sampling
    if s.gripper is None:
        kwargs = {} if s.first_contact is None else {"first_contact": s.first_contact}
        stream = iter_grasps(obj, s.num, s.fingers, seed=s.seed, scheme=s.scheme, chunk=s.chunk, **kwargs)
        return _Prefetch(_slice_chunks(stream, s.start, s.stop, s.chunk)), ()
    if s.fingers != 2 or s.scheme != "uniform" or s.first_contact is not None or obj.dim != 3:
        raise ValueError("parallel-jaw grasps have 2 contacts on a 3D mesh, sampled antipodally: "
                         "leave fingers, scheme and first_contact at their defaults")
    meta.update(scheme="antipodal", gripper=s.gripper.to_dict(), collision=bool(s.collision))
    chunks = _Prefetch(grippers._antipodal.column_chunks(obj, s.num, s.start, s.stop, s.chunk, mu=mu,
                                                         gripper=s.gripper, seed=s.seed, collision=s.collision))
    return chunks, grippers.POSE_FIELDS


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
        origin, torque_scale = _file_frame(obj, origin, torque_scale, src.dim)
    meta = _file_metadata(src, path, obj, mu=mu, num_edges=num_edges, torque_test=torque_test, contact=contact,
                          torsion=torsion)
    columns = ("points", "normals") + (("force_closure",) if "force_closure" in src.fields else ())
    # parallel-jaw poses are carried over, and their failed grasps stay failed
    extra = tuple(f for f in storage.VECTOR_FIELDS + ("width", "jaw_status") if f in src.fields)
    chunks = _Prefetch(src.iter_chunks(columns + extra, chunk))
    scoring = Scoring(mu=float(mu), num_edges=int(num_edges), torque_test=torque_test, contact=contact,
                      torsion=torsion, epsilon=epsilon, origin=origin,
                      torque_scale=torque_scale if torque_scale is not None else 1.0, critical=critical,
                      robust=_with_object(robust, obj))
    try:
        return _score(chunks, scoring, num=src.num, fingers=src.fingers, dim=src.dim, metadata=meta, out=out,
                      progress=progress, top=top, desc=Path(path).name, extra_fields=extra)
    finally:
        chunks.close()


def _file_frame(obj, origin, torque_scale, dim: int) -> tuple[np.ndarray, float]:
    """The baseline's frame of :func:`score_file`: given, else the object's centre and radius."""
    if obj is not None:
        origin = obj.center if origin is None else origin
        torque_scale = obj.radius if torque_scale is None else torque_scale
    if origin is None or torque_scale is None:
        raise ValueError("the epsilon baseline needs the object (--object) or both --origin and --torque-scale")
    return _check_frame(origin, torque_scale, dim)


def _file_metadata(src, path, obj, *, mu, num_edges, torque_test, contact, torsion) -> dict:
    """The stored metadata of ``src`` with this scoring's settings and source."""
    stored = src.metadata
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
    return meta


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
