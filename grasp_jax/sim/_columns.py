"""The simulated outcome as columns of a result file, written atomically beside its labels.

Columns: ``sim_success`` (bool), ``sim_status`` (int8, :class:`SimStatus`) and one bool column
per force direction (:data:`DIRECTION_COLUMNS`, in the order of :data:`DIRECTIONS`). The file is
rewritten whole to a temporary file and renamed into place; an error leaves the file as it was.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from ..grippers import ParallelJaw
from ..storage import PARQUET_KEY, ResultFile, check_output_path, write_atomically
from ..storage import metadata as stamp
from ._hands import simulate_hand
from ._jaws import DEFAULT_GRIPPER, body_gripper, simulate_jaws
from ._protocol import DIRECTIONS, Protocol, SimResult

#: The per-direction columns, in the order of :data:`DIRECTIONS`.
DIRECTION_COLUMNS = tuple(f"sim_{'pos' if d[0] == '+' else 'neg'}_{d[1]}" for d in DIRECTIONS)
#: Every column :func:`add_sim_columns` writes.
SIM_COLUMNS = ("sim_success", "sim_status") + DIRECTION_COLUMNS
#: The columns a result file needs for a jaw simulation.
JAW_COLUMNS = ("center", "axis", "approach", "width")
#: The columns a result file needs for a hand simulation.
HAND_COLUMNS = ("position", "quaternion", "joints", "pregrasp", "squeeze")


def sim_columns(result: SimResult) -> dict[str, np.ndarray]:
    """The columns of :data:`SIM_COLUMNS` of a :class:`SimResult`."""
    cols = {"sim_success": np.asarray(result.success, bool), "sim_status": np.asarray(result.status, np.int8)}
    for j, name in enumerate(DIRECTION_COLUMNS):
        cols[name] = np.asarray(result.directions[:, j], bool)
    return cols


def _write_npz(path: Path, arrays: dict, meta: dict) -> None:
    payload = {name: a for name, a in arrays.items()}
    payload["metadata"] = np.array(json.dumps(meta))
    write_atomically(path, lambda f: np.savez(f, **payload), mode="wb", what="result file")


def _write_parquet(source: Path, path: Path, columns: dict, meta: dict) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pq.read_table(source)
    for name, values in columns.items():
        if name in table.column_names:
            table = table.drop_columns([name])
        table = table.append_column(name, pa.array(values))
    schema_meta = dict(table.schema.metadata or {})
    schema_meta[PARQUET_KEY] = json.dumps(meta).encode()
    table = table.replace_schema_metadata(schema_meta)
    write_atomically(path, lambda f: pq.write_table(table, f), mode="wb", what="result file")


def add_sim_columns(path, mesh, *, out=None, gripper=None, protocol: Protocol | None = None, seed: int = 0,
                    workers: int | None = None, progress: bool = False, mesh_name: str | None = None) -> Path:
    """Simulate the jaw grasps of a result file and add :data:`SIM_COLUMNS` to it, atomically.

    Args:
        path: a ``.npz`` or ``.parquet`` result file with the jaw pose columns ``center``,
            ``axis``, ``approach`` ``(N, 3)`` and ``width`` ``(N,)`` (``grasp-jax sample
            --gripper parallel-jaw``).
        mesh: the object the grasps were sampled on (``trimesh.Trimesh`` or
            :class:`grasp_jax.objects.Mesh`).
        out: where to write (default: replace ``path``); same format as ``path``.
        gripper: the :class:`~grasp_jax.grippers.ParallelJaw`; default: the file's metadata
            ``gripper``, else :data:`grasp_jax.sim.DEFAULT_GRIPPER`.
        protocol, seed, workers, progress: as :func:`grasp_jax.sim.simulate_jaws`.
        mesh_name: what to record as the object in the metadata's ``sim`` entry.

    Returns:
        The path written. Columns of the same names already in the file are replaced.

    Raises:
        ValueError: the file lacks a needed column (one sentence naming them), or as
            :func:`~grasp_jax.sim.simulate_jaws`; nothing is written then.
    """
    source = _opened(path, JAW_COLUMNS, "jaw", "grasp-jax sample --gripper parallel-jaw")
    target = _target(source, out)
    if gripper is None and isinstance(source.metadata.get("gripper"), dict):
        gripper = ParallelJaw.from_dict(source.metadata["gripper"])
    gripper = DEFAULT_GRIPPER if gripper is None else gripper
    protocol = Protocol() if protocol is None else protocol
    arrays = source.read()
    result = simulate_jaws(mesh, arrays["center"], arrays["axis"], arrays["approach"], arrays["width"],
                           gripper=gripper, protocol=protocol, seed=seed, workers=workers, progress=progress)
    sim_meta = stamp(protocol=asdict(protocol), seed=int(seed), object=mesh_name,
                     gripper=body_gripper(gripper).to_dict(), directions=list(DIRECTIONS))
    return _publish(source, target, arrays, sim_columns(result), sim_meta)


def add_hand_sim_columns(path, hand, mesh, *, out=None, protocol: Protocol | None = None, seed: int = 0,
                         workers: int | None = None, progress: bool = False, mesh_name: str | None = None) -> Path:
    """Simulate the hand grasps of a result file of :func:`grasp_jax.hands.synthesize` (its
    ``save``, or ``grasp-jax hand --out``) and add :data:`SIM_COLUMNS` to it, atomically.

    Args:
        path: the ``.npz`` or ``.parquet`` file, with ``position``, ``quaternion``, ``joints``,
            ``pregrasp`` and ``squeeze`` per grasp.
        hand: the :class:`grasp_jax.hands.Hand` the grasps are of (the file names it only).
        mesh, out, protocol, seed, workers, progress, mesh_name: as :func:`add_sim_columns`.

    Raises:
        ValueError: the file lacks a needed column or its joints do not match ``hand``; nothing is
            written then.
    """
    source = _opened(path, HAND_COLUMNS, "hand", "grasp-jax hand --out")
    target = _target(source, out)
    protocol = Protocol() if protocol is None else protocol
    arrays = source.read()
    result = simulate_hand(hand, mesh, SimpleNamespace(**{c: arrays[c] for c in HAND_COLUMNS}), protocol=protocol,
                           seed=seed, workers=workers, progress=progress)
    sim_meta = stamp(protocol=asdict(protocol), seed=int(seed), object=mesh_name, hand=hand.name,
                     directions=list(DIRECTIONS))
    return _publish(source, target, arrays, sim_columns(result), sim_meta)


def _opened(path, columns: tuple, kind: str, writer: str) -> ResultFile:
    """The result file at ``path``, with a ``ValueError`` naming the ``columns`` it lacks."""
    source = ResultFile(path)
    missing = [c for c in columns if c not in source.fields]
    if missing:
        raise ValueError(f"{str(source.path)!r} has no {missing}: simulating {kind} grasps needs the columns "
                         f"{list(columns)} ({writer} writes them)")
    return source


def _target(source: ResultFile, out) -> Path:
    target = source.path if out is None else check_output_path(out)
    if target.suffix.lower() != source.path.suffix.lower():
        raise ValueError(f"out must have the format of {str(source.path)!r}; got {str(target)!r}")
    return target


def _publish(source: ResultFile, target: Path, arrays: dict, cols: dict, sim_meta: dict) -> Path:
    """The source's rows with ``cols`` added (replacing columns of the same names) and its
    metadata with ``sim_meta`` under ``"sim"``, written to ``target`` atomically."""
    meta = dict(source.metadata)
    meta["sim"] = sim_meta
    if source.format == "npz":
        arrays.update(cols)
        _write_npz(target, arrays, meta)
    else:
        _write_parquet(source.path, target, cols, meta)
    return target
