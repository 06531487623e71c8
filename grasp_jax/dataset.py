"""Grasp datasets over many objects: one configuration, one Parquet dataset partitioned by object.

:func:`build` runs the sampling pipeline (:func:`grasp_jax.pipeline.run`, with robust labels
where asked), or a hand's synthesis (:func:`grasp_jax.hands.synthesize`), on every object of a
folder of meshes or of a manifest file, into ``DIR/object=<name>/part.parquet`` beside
``DIR/_manifest.json`` and the records ``DIR/_objects/<name>.json`` (``grasp_jax._dataset_folder``).

``DIR`` is a hive-partitioned Parquet dataset that pyarrow, pandas, polars and DuckDB read
(entries starting with ``_`` or ``.`` are not data). An object is done when its part and a
``done`` record exist; a run again on ``DIR`` skips the done objects, and a run with another
configuration stops with an error. ``shard=(i, N)`` does objects ``i, i + N, ...`` of the sorted
list (:func:`shard_from_environment` reads SLURM's array variables); shards write into one ``DIR``
and each rewrites ``_manifest.json`` from all records, under a lock, every :data:`MANIFEST_EVERY` s.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import time
from pathlib import Path

import numpy as np

from . import _dataset_folder as folder
from . import hands, objects, pipeline, storage
from ._dataset_folder import (  # noqa: F401 - public here
    FIGURE,
    MANIFEST,
    MANIFEST_EVERY,
    PART,
    RECORDS,
    DatasetError,
    part_path,
    versions,
)

#: Mesh files a folder of objects is made of (any format trimesh reads; by suffix, lower case).
MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".glb", ".gltf", ".dae", ".3mf")
#: Settings that must match for a run to add to an existing dataset (the last three only where set:
#: a dataset of free contacts written before they existed reads the same).
CONFIG_KEYS = ("fingers", "num", "seed", "scheme", "mu", "edges", "torque_test", "contact", "torsion", "robust",
               "gripper", "collision", "critical")


@dataclasses.dataclass(frozen=True)
class ObjectEntry:
    """One object of a dataset: its partition ``name``, where it comes from and its scale."""

    name: str
    spec: str
    scale: float = 1.0


def _partition_name(text: str) -> str:
    """A folder-safe partition value: letters, digits, ``_ - .``; others become ``_``."""
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", text).strip(".") or "object"
    return name if not name.startswith("_") else "o" + name


def list_objects(source) -> list[ObjectEntry]:
    """The objects of a folder of mesh files (sorted by name) or of a manifest text file.

    A manifest has one object per line: a mesh path (relative to the manifest's folder) or a
    built-in name, optionally followed by a scale factor (``meshes/mug.obj 0.001``); blank lines
    and ``#`` comments are skipped. Objects are named by the file's stem (a built-in by its name).

    Raises:
        DatasetError: a missing source, an empty folder or manifest, a bad line, two objects of
            one name.
    """
    source = Path(source)
    entries = []
    if source.is_dir():
        files = sorted(f for f in source.iterdir() if f.is_file() and f.suffix.lower() in MESH_SUFFIXES)
        if not files:
            raise DatasetError(f"{str(source)!r} holds no mesh files ({', '.join(MESH_SUFFIXES)}); give a folder "
                               "of meshes or a manifest file")
        entries = [ObjectEntry(_partition_name(f.stem), str(f.resolve())) for f in files]
    elif source.is_file():
        for number, line in enumerate(source.read_text().splitlines(), 1):
            text = line.split("#", 1)[0].strip()
            if not text:
                continue
            parts = text.rsplit(None, 1)
            scale = 1.0
            if len(parts) == 2:
                try:
                    scale = float(parts[1])
                except ValueError:
                    parts = [text]  # a path with a space in it
                else:
                    if not (math.isfinite(scale) and scale > 0):
                        raise DatasetError(f"{source}:{number}: the scale must be a number > 0; got {parts[1]!r}")
            spec = parts[0]
            if spec.lower() in objects.BUILTIN_NAMES and not (source.parent / spec).exists():
                entries.append(ObjectEntry(_partition_name(spec.lower()), spec.lower(), scale))
                continue
            path = Path(spec).expanduser()
            path = path if path.is_absolute() else source.parent / path
            entries.append(ObjectEntry(_partition_name(path.stem), str(path.resolve()), scale))
        if not entries:
            raise DatasetError(f"manifest {str(source)!r} lists no objects")
    else:
        raise DatasetError(f"{str(source)!r} is neither a folder of meshes nor a manifest file")
    seen = {}
    for e in entries:
        if e.name in seen:
            raise DatasetError(f"two objects would be named {e.name!r}: {seen[e.name]} and {e.spec}; rename one")
        seen[e.name] = e.spec
    return entries


def parse_shard(text: str) -> tuple[int, int]:
    """``"i/N"`` -> ``(i, N)`` with ``0 <= i < N``."""
    match = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", str(text))
    if not match or not int(match[2]) or int(match[1]) >= int(match[2]):
        raise DatasetError(f"shard must be i/N with 0 <= i < N (for example 0/4); got {text!r}")
    return int(match[1]), int(match[2])


def shard_from_environment(environ=None) -> tuple[int, int] | None:
    """The shard of a SLURM array task: ``(SLURM_ARRAY_TASK_ID - SLURM_ARRAY_TASK_MIN,
    SLURM_ARRAY_TASK_COUNT)``; ``None`` outside an array."""
    env = os.environ if environ is None else environ
    if "SLURM_ARRAY_TASK_ID" not in env:
        return None
    try:
        task = int(env["SLURM_ARRAY_TASK_ID"]) - int(env.get("SLURM_ARRAY_TASK_MIN", 0))
        count = int(env.get("SLURM_ARRAY_TASK_COUNT", 0))
    except ValueError:
        raise DatasetError("SLURM_ARRAY_TASK_ID, SLURM_ARRAY_TASK_MIN and SLURM_ARRAY_TASK_COUNT must be "
                           "integers") from None
    if count < 1 or not 0 <= task < count:
        raise DatasetError(f"SLURM array task {task} of {count}: run a contiguous array (--array=0-{max(count, 1) - 1}) "
                           "or pass --shard i/N")
    return task, count


# ---------------------------------------------------------------------------------------------
# Building


@dataclasses.dataclass
class DatasetSummary:
    """What one :func:`build` call did.

    Attributes:
        out: the dataset folder.
        shard: ``(i, N)`` of this process.
        done: names of the objects done by this call.
        skipped: names already done before it (resumed).
        failed: ``{name: reason}`` of the objects that failed in this call.
        rows: ``{name: record}`` of every object of this shard that is done (grasps, force-closure
            rate, Q, P(force-closure) ...).
        seconds: wall time.
    """

    out: Path
    shard: tuple[int, int]
    done: list
    skipped: list
    failed: dict
    rows: dict
    seconds: float

    def format(self) -> str:
        """A table of the shard's objects and a one-line total."""
        if any("valid_rate" in r for r in self.rows.values()):
            return "\n".join(self._hand_lines() + [self._total()])
        critical = any("critical_mu_p50" in r for r in self.rows.values())
        lines = [f"{'object':<28} {'status':<7} {'grasps':>8} {'FC %':>6} {'Q p50':>7} {'P(FC)':>6}"
                 + (f" {'mu* p50':>7}" if critical else "")]
        for name, r in sorted(self.rows.items()):
            if r.get("status") == "done":
                p, m = r.get("p_fc_mean"), r.get("critical_mu_p50")
                lines.append(f"{name[:28]:<28} {'done':<7} {r['num']:>8,} {100 * r['force_closure_rate']:>6.1f} "
                             f"{r.get('quality_p50') or math.nan:>7.3f} {'' if p is None else format(p, '6.3f'):>6}"
                             + (f" {'' if m is None else format(m, '7.3f'):>7}" if critical else ""))
            else:
                lines.append(f"{name[:28]:<28} {'failed':<7} {r.get('reason', '')}")
        lines.append(self._total())
        return "\n".join(lines)

    def _hand_lines(self) -> list[str]:
        """The table of a dataset of hand grasps: starts, valid grasps, median Q of the valid ones, seconds."""
        lines = [f"{'object':<28} {'status':<7} {'starts':>7} {'valid':>6} {'valid %':>7} {'Q p50':>7} {'s':>7}"]
        for name, r in sorted(self.rows.items()):
            if r.get("status") == "done":
                lines.append(f"{name[:28]:<28} {'done':<7} {r['num']:>7,} {r['valid']:>6,} {100 * r['valid_rate']:>7.1f} "
                             f"{r.get('quality_p50') or math.nan:>7.3f} {r.get('seconds', math.nan):>7.1f}")
            else:
                lines.append(f"{name[:28]:<28} {'failed':<7} {r.get('reason', '')}")
        return lines

    def _total(self) -> str:
        i, n = self.shard
        return (f"dataset        {self.out}: {len(self.done)} objects done, {len(self.skipped)} already done, "
                f"{len(self.failed)} failed (shard {i}/{n}) in {self.seconds:.1f} s")


def config_of(*, fingers: int, num: int, seed: int, scheme: str, mu: float, num_edges: int, torque_test: str,
              contact: str, torsion, robust, gripper=None, collision: bool = False, critical: bool = False) -> dict:
    """The dataset's configuration (:data:`CONFIG_KEYS`), as stored in the manifest."""
    config = {"fingers": int(fingers), "num": int(num), "seed": int(seed), "scheme": scheme, "mu": float(mu),
              "edges": int(num_edges), "torque_test": torque_test, "contact": contact,
              "torsion": None if torsion is None else float(torsion),
              "robust": None if robust is None else robust.to_dict()}
    if gripper is not None:
        config.update(gripper=gripper.to_dict(), collision=bool(collision), scheme="antipodal")
    if critical:
        config["critical"] = True
    return json.loads(json.dumps(config))  # as the manifest reads back


def load_entry(entry: ObjectEntry):
    """The object of one dataset entry, scaled as its manifest says."""
    obj = objects.load(entry.spec)
    if entry.scale != 1.0:
        mesh = getattr(obj, "mesh", None)
        if mesh is None:
            raise DatasetError(f"{entry.spec}: only meshes can be scaled")
        obj = objects.Mesh.from_trimesh(mesh.copy().apply_scale(entry.scale), name=obj.name, where=entry.spec)
    if obj.dim != 3:
        raise DatasetError(f"{entry.spec}: a {obj.dim}D object; a dataset's objects are 3D meshes or shapes")
    return obj


def parts(out) -> list[tuple[ObjectEntry, Path]]:
    """The done objects of the dataset at ``out`` (every shard's), each as its entry and its part."""
    out = Path(out)
    if not (out / MANIFEST).is_file() and not (out / RECORDS).is_dir():
        raise DatasetError(f"{str(out)!r} is not a grasp_jax dataset (no {MANIFEST})")
    found = []
    for name, record in sorted(folder.records(out).items()):
        if record.get("status") == "done" and record.get("part"):
            entry = ObjectEntry(name, record["spec"], float(record.get("scale", 1.0)))
            found.append((entry, out / record["part"]))
    return found


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if isinstance(exc, ValueError) else f"{type(exc).__name__}: {text}"


def build(
    source,
    out,
    *,
    num: int = 10_000,
    fingers: int | None = None,
    mu: float | None = None,
    num_edges: int = 8,
    seed: int = 0,
    scheme: str = "uniform",
    torque_test: str = "exact",
    contact: str | None = None,
    torsion: float | None = None,
    robust=None,
    gripper=None,
    collision: bool = False,
    critical: bool | None = None,
    chunk: int | None = None,
    shard: tuple[int, int] | None = None,
    progress: bool = False,
    hand=None,
    starts: int = 256,
    steps: int = 200,
) -> DatasetSummary:
    """Sample and score ``num`` grasps of every object of ``source`` into the dataset ``out``, or
    synthesize the grasps of a ``hand``.

    Args:
        source: a folder of mesh files or a manifest file (:func:`list_objects`).
        out: the dataset folder (created; an existing one is resumed if its configuration is this).
        num, fingers, mu, num_edges, seed, scheme, torque_test, contact, torsion, chunk: as
            :func:`grasp_jax.pipeline.run`, the same for every object (``fingers``: 4 by default,
            2 with a gripper; ``mu`` 0.364 and ``contact`` ``"hard"`` by default).
        robust: :class:`grasp_jax.pipeline.RobustLabels` to add robust labels (its ``obj`` is
            set per object). With a gripper and noise that moves contacts, the jaws are cast again
            at every perturbed pose (:func:`grasp_jax.grippers.robust_jaws`).
        gripper: a :class:`grasp_jax.grippers.ParallelJaw`: every object gets ``num`` antipodal
            parallel-jaw grasps of this one gripper (widths in the objects' units, as scaled by
            the manifest), ``fingers`` 2, with the jaw pose columns (``center``, ``axis``,
            ``approach``, ``width``, ``jaw_status``); ``collision``: reject grasps whose gripper
            body meets the object (needs python-fcl). As ``grasp-jax sample --gripper``.
        critical: also the critical friction of each grasp (columns ``critical_mu``,
            ``critical_status``, ``friction_label``); default: with a gripper only.
        shard: ``(i, N)``: this process does objects ``i::N`` (default: from the SLURM array
            variables, else all).
        progress: a progress bar over the objects.
        hand: a :class:`grasp_jax.hands.Hand`, a URDF file or ``"default"``: each object's part is
            :func:`grasp_jax.hands.synthesize` of this hand (``starts``, ``steps``, ``mu``,
            ``contact``, ``num_edges``, ``seed``; ``mu`` 0.5 and soft contacts by default), one row
            per start (:meth:`grasp_jax.hands.HandGraspResult.save`); its record has the valid
            count and rate, the median Q of the valid grasps and the seconds. The manifest records
            the hand's name and URDF file. ``num``, ``torque_test`` and ``chunk`` do not apply;
            ``gripper``, ``robust``, ``critical``, ``fingers``, ``scheme`` and ``torsion`` are errors.

    Returns:
        :class:`DatasetSummary`. An object that cannot be read or scored is recorded as failed
        with its reason, and the others are done.

    Raises:
        DatasetError: no objects, a bad shard, a dataset of another configuration at ``out``.
    """
    t0 = time.perf_counter()
    if hand is not None:
        config, build_one = _hand_settings(hand, starts=starts, steps=steps, mu=mu, contact=contact, torsion=torsion,
                                           num_edges=num_edges, seed=seed, fingers=fingers, scheme=scheme,
                                           robust=robust, gripper=gripper, collision=collision, critical=critical)
        entries, shard = list_objects(source), _check_shard(shard)
    else:
        config, build_one, entries, shard = _sampling_settings(
            source, shard, num=num, fingers=fingers, mu=mu, num_edges=num_edges, seed=seed, scheme=scheme,
            torque_test=torque_test, contact=contact, torsion=torsion, robust=robust, gripper=gripper,
            collision=collision, critical=critical, chunk=chunk)
    out = Path(out)
    folder.start(out, config)
    summary = DatasetSummary(out, shard, [], [], {}, {}, 0.0)
    _build_objects(entries[shard[0]::shard[1]], summary, config, progress, lambda entry: build_one(entry, out))
    summary.seconds = time.perf_counter() - t0
    return summary


def _sampling_settings(source, shard, *, num, fingers, mu, num_edges, seed, scheme, torque_test, contact, torsion,
                       robust, gripper, collision, critical, chunk):
    """``(config, build_one, entries, shard)`` of sampled and scored grasps (free contacts or a
    gripper's), checked in this order: the grasps' settings, the objects, the shard, the labels."""
    mu = 0.364 if mu is None else mu
    contact = "hard" if contact is None else contact
    fingers, critical = _grasp_settings(fingers=fingers, scheme=scheme, gripper=gripper, collision=collision,
                                        critical=critical)
    entries = list_objects(source)
    shard = _check_shard(shard)
    config = config_of(fingers=fingers, num=num, seed=seed, scheme=scheme, mu=mu, num_edges=num_edges,
                       torque_test=torque_test, contact=contact, torsion=torsion, robust=robust, gripper=gripper,
                       collision=collision, critical=critical)
    if robust is not None and robust.obj is not None:
        raise DatasetError("the robust labels of a dataset take each object in turn: leave RobustLabels.obj unset")
    settings = dict(num=num, fingers=fingers, mu=mu, num_edges=num_edges, seed=seed, scheme=scheme,
                    torque_test=torque_test, contact=contact, torsion=torsion, chunk=chunk, gripper=gripper,
                    collision=collision, critical=critical)
    return config, lambda entry, out: _build_one(entry, out, robust=robust, **settings), entries, shard


def _grasp_settings(*, fingers, scheme: str, gripper, collision: bool, critical) -> tuple[int | None, bool]:
    """``(fingers, critical)`` of :func:`build`: 4 free contacts by default, 2 with a gripper (which
    also turns the critical friction on by default)."""
    critical = gripper is not None if critical is None else bool(critical)
    fingers = 4 if fingers is None and gripper is None else fingers
    if gripper is not None:
        if fingers not in (None, 2) or scheme != "uniform":
            raise DatasetError("parallel-jaw grasps have 2 contacts, sampled antipodally: leave fingers and "
                               "scheme at their defaults")
        fingers = 2
    elif collision:
        raise DatasetError("collision checks the body of a gripper: give a gripper too")
    return fingers, critical


def _check_shard(shard) -> tuple[int, int]:
    """``shard``, else the SLURM array's, else ``(0, 1)``; checked."""
    shard = shard if shard is not None else shard_from_environment() or (0, 1)
    i, n = shard
    if not (isinstance(i, int) and isinstance(n, int) and 0 <= i < n):
        raise DatasetError(f"shard must be (i, N) with 0 <= i < N; got {shard!r}")
    return shard


def _build_objects(mine: list, summary: DatasetSummary, config: dict, progress: bool, build_one) -> None:
    """``build_one(entry) -> record`` for every object of ``mine`` not done yet, each record written
    after its part (the object is then done) and into ``summary``; the manifest rewritten every
    :data:`MANIFEST_EVERY` s and at the end."""
    out = summary.out
    i, n = summary.shard
    items = mine
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = items = tqdm(mine, unit="object", desc=f"dataset {out.name}" + (f" {i}/{n}" if n > 1 else ""),
                           dynamic_ncols=True)
    written = time.monotonic()
    try:
        for entry in items:
            if bar is not None:
                bar.set_postfix_str(entry.name[:24], refresh=True)
            if folder.is_done(out, entry.name):
                summary.skipped.append(entry.name)
                summary.rows[entry.name] = folder.read_json(out / RECORDS / f"{entry.name}.json")
                continue
            record = build_one(entry)
            folder.write_json(out / RECORDS / f"{entry.name}.json", record)  # after the part: the object is done
            summary.rows[entry.name] = record
            if record["status"] == "done":
                summary.done.append(entry.name)
            else:
                summary.failed[entry.name] = record["reason"]
            if time.monotonic() - written > MANIFEST_EVERY:
                folder.write_manifest(out, config)
                written = time.monotonic()
    finally:
        if bar is not None:
            bar.close()
        folder.write_manifest(out, config)


def _build_one(entry: ObjectEntry, out: Path, *, robust, **settings) -> dict:
    """Sample, score and write one object; its record (``done`` or ``failed`` with the reason)."""
    t0 = time.perf_counter()
    record = {"name": entry.name, "spec": entry.spec, "scale": entry.scale}
    path = part_path(out, entry.name)
    try:
        obj = load_entry(entry)
        path.parent.mkdir(parents=True, exist_ok=True)
        folder.clean_temporaries(path.parent)
        labels = None if robust is None else dataclasses.replace(robust, obj=obj)
        result = pipeline.run(obj, out=path, object_spec=entry.spec, robust=labels, **settings)
    except (KeyboardInterrupt, SystemExit):
        raise
    except Exception as exc:  # noqa: BLE001 - any failure of one object is recorded, the others go on
        record.update(status="failed", reason=_one_line(exc), seconds=time.perf_counter() - t0)
        return record
    record.update(
        status="done", part=str(path.relative_to(out)), num=int(result.num), force_closure=int(result.force_closure),
        force_closure_rate=float(result.force_closure_rate), unconverged=int(result.unconverged),
        quality_p50=_finite(result.quality_percentiles.get(50)), quality_mean=_finite(result.quality_mean),
        radius=float(obj.radius), seconds=time.perf_counter() - t0,
    )
    if result.critical_percentiles:
        record["critical_mu_p50"] = _finite(result.critical_percentiles.get(50))
    if result.robust is not None:
        record.update(p_fc_mean=_finite(result.robust["p_fc_mean"]),
                      p_fc_mean_nominal_fc=_finite(result.robust["p_fc_mean_nominal_fc"]),
                      q_mean_mean=_finite(result.robust["q_mean_mean"]))
    return record


# ---------------------------------------------------------------------------------------------
# Hand grasps


def _hand_settings(hand, *, starts, steps, mu, contact, torsion, num_edges, seed, fingers, scheme, robust, gripper,
                   collision, critical):
    """``(config, build_one)`` of a dataset of ``hand``'s grasps (:func:`grasp_jax.hands.synthesize`);
    ``hand`` loaded where it is a file or ``"default"``."""
    given = [what for what, set_ in (("a gripper", gripper is not None or collision),
                                     ("robust labels", robust is not None), ("the critical friction", critical),
                                     ("fingers", fingers is not None), ("a sampling scheme", scheme != "uniform"),
                                     ("a torsion", torsion is not None)) if set_]
    if given:
        raise DatasetError(f"hand grasps and {given[0]} do not go together (the hand's fingertips are the contacts, "
                           "soft ones with the torsion of a fingertip patch): leave it out")
    mu = 0.5 if mu is None else mu
    contact = "soft" if contact is None else contact
    if contact not in ("soft", "hard"):
        raise DatasetError(f"a hand's contacts are 'soft' or 'hard'; got {contact!r}")
    for name, value in (("starts", starts), ("steps", steps)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise DatasetError(f"{name} must be an integer >= 1; got {value!r}")
    hand = hand if isinstance(hand, hands.Hand) else hands.load(hand)
    config = json.loads(json.dumps({
        "hand": {"name": hand.name, "urdf": os.path.abspath(hand.path) if hand.path else None},
        "starts": int(starts), "steps": int(steps), "mu": float(mu), "contact": contact, "edges": int(num_edges),
        "seed": int(seed), "objective": "closure"}))
    settings = dict(starts=int(starts), steps=int(steps), mu=float(mu), contact=contact, num_edges=int(num_edges),
                    seed=int(seed))
    return config, lambda entry, out: _build_one_hand(entry, out, hand, **settings)


def _build_one_hand(entry: ObjectEntry, out: Path, hand, **settings) -> dict:
    """Synthesize and write one object's hand grasps; its record (``done`` with the valid count and
    rate, the median Q of the valid grasps, or ``failed`` with the reason)."""
    t0 = time.perf_counter()
    record = {"name": entry.name, "spec": entry.spec, "scale": entry.scale}
    path = part_path(out, entry.name)
    try:
        obj = load_entry(entry)
        path.parent.mkdir(parents=True, exist_ok=True)
        folder.clean_temporaries(path.parent)
        result = hands.synthesize(hand, obj, **settings)
        result.save(path)
    except (KeyboardInterrupt, SystemExit):
        raise
    except Exception as exc:  # noqa: BLE001 - any failure of one object is recorded, the others go on
        record.update(status="failed", reason=_one_line(exc), seconds=time.perf_counter() - t0)
        return record
    valid = np.asarray(result.valid, bool)
    record.update(
        status="done", part=str(path.relative_to(out)), num=len(result), valid=int(valid.sum()),
        valid_rate=float(valid.mean()), force_closure=int(np.sum(result.force_closure)),
        force_closure_rate=float(np.mean(result.force_closure)),
        quality_p50=_finite(np.median(result.quality[valid])) if valid.any() else None,
        penetration_p50_mm=_finite(1e3 * np.median(result.penetration)), radius=float(obj.radius),
        synthesis_seconds=float(result.seconds), seconds=time.perf_counter() - t0,
    )
    return record


def plot_summary(out, path=None) -> Path | None:
    """A figure of every object done in the dataset at ``out`` (all shards' records): its
    force-closure rate, median Q of its force-closure grasps and, with robust labels, mean
    P(force-closure), one row per object. Written atomically to ``path`` (default
    ``out/_summary.png``); ``None`` where no object is done yet."""
    from . import viz

    out = Path(out)
    rows = {k: r for k, r in sorted(folder.records(out).items()) if r.get("status") == "done"}
    if not rows:
        return None
    path = Path(path) if path is not None else out / FIGURE
    names = list(rows)
    panels = [("force-closure %", [100 * rows[k]["force_closure_rate"] for k in names]),
              ("median Q (force-closure grasps)", [rows[k].get("quality_p50") or 0.0 for k in names])]
    if all("valid_rate" in rows[k] for k in names):  # hand grasps
        panels = [("valid %", [100 * rows[k]["valid_rate"] for k in names]), panels[0],
                  ("median Q (valid grasps)", panels[1][1])]
    if any(rows[k].get("p_fc_mean") is not None for k in names):
        panels.append(("mean P(force-closure) under noise", [rows[k].get("p_fc_mean") or 0.0 for k in names]))
    plt = viz.pyplot()
    fig, axes = plt.subplots(1, len(panels), figsize=(3.6 * len(panels) + 2.0, 0.28 * len(names) + 1.4),
                             sharey=True, dpi=100)
    try:
        y = np.arange(len(names))
        for ax, (label, values) in zip(np.atleast_1d(axes), panels):
            ax.barh(y, values, color="tab:blue")
            ax.set_xlabel(label, fontsize=9)
            ax.grid(axis="x", alpha=0.3)
        first = np.atleast_1d(axes)[0]
        first.set_yticks(y, [n[:32] for n in names], fontsize=8)
        first.invert_yaxis()
        total = sum(rows[k]["num"] for k in names)
        fig.suptitle(f"{out.name}: {len(names)} objects, {total:,} grasps", fontsize=10)
        fig.tight_layout()
        storage.write_atomically(path, lambda fh: fig.savefig(fh, format="png", dpi=fig.dpi, bbox_inches="tight"),
                                 mode="wb", what="figure")
    finally:
        plt.close(fig)
    return path


def _finite(x) -> float | None:
    x = float(x) if x is not None else math.nan
    return x if math.isfinite(x) else None


def read(out, columns=None):
    """The dataset as one ``pyarrow.Table`` with an ``object`` column (hive partitioning), rows
    in object order then grasp order."""
    import pyarrow as pa
    import pyarrow.dataset as ds

    parts = sorted(Path(out).glob(f"object=*/{PART}"))
    if not parts:
        raise DatasetError(f"{str(out)!r} holds no object parts")
    tables = []
    for part in parts:
        table = ds.dataset(part, format="parquet").to_table(columns=columns)
        name = part.parent.name.split("=", 1)[1]
        tables.append(table.append_column("object", pa.array(np.full(len(table), name))))
    return pa.concat_tables(tables)


__all__ = [
    "MESH_SUFFIXES",
    "DatasetError",
    "DatasetSummary",
    "ObjectEntry",
    "build",
    "config_of",
    "list_objects",
    "parse_shard",
    "part_path",
    "read",
    "shard_from_environment",
    "versions",
]
