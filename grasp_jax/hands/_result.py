"""What :func:`grasp_jax.hands.synthesize` returns: one row per start, a status each, a file."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from .. import storage
from .._status import StatusEnum

#: Tolerances of the ``valid`` flag (m): the largest penetration of the hand into the object and
#: the largest distance of a contact to the surface.
MAX_PENETRATION = 1e-3
MAX_DISTANCE = 2e-3


class HandStatus(StatusEnum):
    """Why a grasp is or is not valid (``int8`` per start; the first failed check)."""

    VALID = 0, "valid: the fingers within 2 mm of the surface are force-closure, penetration <= 1 mm"
    NOT_FORCE_CLOSURE = 1, "the fingers within 2 mm of the surface are not force-closure (gj.evaluate)"
    PENETRATION = 2, "the hand penetrates the object by more than 1 mm"
    CONTACT_FAR = 3, "fewer than two fingers are within 2 mm of the surface"
    NON_FINITE = 4, "the optimization produced non-finite values"


@dataclasses.dataclass(frozen=True)
class HandGraspResult:
    """Grasps of a hand on an object: ``S`` starts, ``J`` joints, ``F`` fingers (one contact each).

    Attributes:
        position: ``(S, 3)`` wrist (root link) position (m); ``quaternion: (S, 4)`` its
            orientation, unit, **wxyz** (scalar first).
        joints: ``(S, J)`` the grasp's joint values, ``joint_names`` order; ``pregrasp`` and
            ``squeeze``: ``(S, J)`` the opened and the squeezed configurations (as BODex gives them:
            the joints moved away from / into the object along the contacts' distance gradient).
        points, normals: ``(S, F, 3)`` contacts on the mesh (closest points to the fingers' chosen
            candidates) and the mesh's outward normals there.
        distance: ``(S, F)`` each chosen candidate's distance to the mesh (m, negative inside).
        active: ``(S, F)`` the fingers that touch: ``|distance| <=`` :data:`MAX_DISTANCE`.
        penetration: ``(S,)`` the deepest point of the hand's collision surface inside the mesh (m).
        force_closure, quality: ``(S,)`` from ``gj.evaluate`` (``contact``, ``mu``) on the active
            contacts (a finger that does not touch is no contact).
        valid: ``(S,)`` at least two active contacts, force-closure, and penetration <=
            :data:`MAX_PENETRATION`; ``status: (S,) int8`` :class:`HandStatus`.
        closed: ``(S,)`` the grasp is the optimized one with its fingers closed onto the object
            (kept because it is valid); else the optimized one as it is.
        energy: ``(S, steps)`` the energy of each step's iterate (the grasp is the iterate of the
            lowest).
        initial_position, initial_quaternion, initial_joints: the starts.
        joint_names, hand, object_name, objective_name, contact, mu, steps, seconds: static;
        object_path: the mesh file the object was read from (``""`` if none).
    """

    position: np.ndarray
    quaternion: np.ndarray
    joints: np.ndarray
    pregrasp: np.ndarray
    squeeze: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    distance: np.ndarray
    active: np.ndarray
    penetration: np.ndarray
    force_closure: np.ndarray
    quality: np.ndarray
    valid: np.ndarray
    status: np.ndarray
    closed: np.ndarray
    energy: np.ndarray
    initial_position: np.ndarray
    initial_quaternion: np.ndarray
    initial_joints: np.ndarray
    joint_names: tuple = ()
    hand: str = ""
    object_name: str = ""
    objective_name: str = "closure"
    contact: str = "soft"
    mu: float = 0.5
    steps: int = 0
    seconds: float = 0.0
    object_path: str = ""

    def __len__(self) -> int:
        return len(self.valid)

    def joints_by_name(self, index: int) -> dict[str, float]:
        """``{joint name: value}`` of grasp ``index``."""
        return dict(zip(self.joint_names, map(float, self.joints[index])))

    def messages(self) -> list[str]:
        """The status message of every grasp."""
        return [HandStatus(int(s)).message for s in self.status]

    def best(self, count: int = 1) -> np.ndarray:
        """Indices of up to ``count`` valid grasps, highest Q first."""
        index = np.flatnonzero(self.valid)
        return index[np.argsort(-self.quality[index], kind="stable")][:count]

    def distinct(self, position: float = 0.01, angle: float = 15.0) -> np.ndarray:
        """Indices of valid grasps of which none is a copy of another, highest Q first: a grasp
        is a copy of a kept one when its wrist lies within ``position`` (m) and its orientation
        within ``angle`` (degrees) of it."""
        kept: list[int] = []
        cos_half = np.cos(np.radians(angle) / 2)
        for i in self.best(len(self)):
            if kept:
                near = np.linalg.norm(self.position[kept] - self.position[i], axis=1) <= position
                turned = np.abs(self.quaternion[kept] @ self.quaternion[i]) >= cos_half
                if (near & turned).any():
                    continue
            kept.append(int(i))
        return np.asarray(kept, dtype=np.int64)

    def summary(self) -> dict:
        """Numbers a person looks at first."""
        valid = self.valid.astype(bool)
        return {
            "starts": len(self), "steps": self.steps, "objective": self.objective_name,
            "valid_fraction": float(valid.mean()) if len(self) else 0.0,
            "force_closure_fraction": float(self.force_closure.mean()) if len(self) else 0.0,
            "quality_median_valid": float(np.median(self.quality[valid])) if valid.any() else 0.0,
            "distinct_valid": len(self.distinct()),
            "penetration_median_mm": float(1e3 * np.median(self.penetration)) if len(self) else 0.0,
            "status": {s.name.lower(): c for s, c in HandStatus.counts(self.status).items()},
            "seconds": self.seconds,
            "valid_per_second": float(valid.sum() / self.seconds) if self.seconds else 0.0,
        }

    def __repr__(self) -> str:
        s = self.summary()
        return (f"HandGraspResult({self.hand!r} on {self.object_name!r}: {s['starts']} starts x {self.steps} steps, "
                f"valid {100 * s['valid_fraction']:.1f}%, force-closure {100 * s['force_closure_fraction']:.1f}%, "
                f"{self.seconds:.1f} s)")

    def columns(self) -> dict[str, np.ndarray]:
        """Every per-grasp array by name."""
        skip = {f.name for f in dataclasses.fields(self) if not isinstance(getattr(self, f.name), np.ndarray)}
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in skip}

    def metadata(self) -> dict:
        return storage.metadata(hand=self.hand, object=self.object_name, object_path=self.object_path,
                                joint_names=list(self.joint_names),
                                objective=self.objective_name, contact=self.contact, mu=self.mu, steps=self.steps,
                                seconds=self.seconds, quaternion="wxyz",
                                status={s.name: s.message for s in HandStatus},
                                max_penetration=MAX_PENETRATION, max_distance=MAX_DISTANCE)

    def save(self, path) -> Path:
        """Write to ``.npz`` (one array per field, metadata as JSON under ``metadata``) or
        ``.parquet`` (one row per grasp, the metadata under the schema key ``grasp_jax``),
        atomically: nothing is published unless the whole file is written."""
        path = storage.check_output_path(path)
        meta = json.dumps(self.metadata())
        cols = self.columns()
        if path.suffix.lower() == ".npz":
            return storage.write_atomically(path, lambda f: np.savez(f, metadata=np.asarray(meta), **cols), mode="wb")
        table = pa.table({name: _column(a) for name, a in cols.items()})
        table = table.replace_schema_metadata({"grasp_jax": meta})
        return storage.write_atomically(path, lambda f: pq.write_table(table, f), mode="wb")


def _column(a: np.ndarray) -> pa.Array:
    """A parquet column: nested fixed-size lists for array-valued rows."""
    a = np.ascontiguousarray(a)
    if a.ndim == 1:
        return pa.array(a)
    arr = pa.array(a.reshape(-1))
    for size in reversed(a.shape[1:]):
        arr = pa.FixedSizeListArray.from_arrays(arr, size)
    return arr


def load(path) -> HandGraspResult:
    """A result written by :meth:`HandGraspResult.save` (``.npz`` or ``.parquet``)."""
    path = storage.check_input_path(path)
    if path.suffix.lower() == ".npz":
        with np.load(path) as f:
            meta = json.loads(str(f["metadata"]))
            cols = {k: f[k] for k in f.files if k != "metadata"}
    else:
        table = pq.read_table(path)
        meta = json.loads(table.schema.metadata[b"grasp_jax"])
        cols = {}
        for name in table.column_names:
            col = table.column(name).combine_chunks()
            shape = []
            while pa.types.is_fixed_size_list(col.type):
                shape.append(col.type.list_size)
                col = col.flatten()
            cols[name] = np.asarray(col.to_numpy(zero_copy_only=False)).reshape((table.num_rows, *shape))
    if "active" not in cols:  # written before results had the field
        cols["active"] = np.abs(cols["distance"]) <= meta.get("max_distance", MAX_DISTANCE)
    if "closed" not in cols:  # written before the fingers were closed
        cols["closed"] = np.zeros(len(cols["valid"]), bool)
    return HandGraspResult(**cols, joint_names=tuple(meta["joint_names"]), hand=meta["hand"],
                           object_name=meta["object"], objective_name=meta["objective"], contact=meta["contact"],
                           mu=meta["mu"], steps=meta["steps"], seconds=meta["seconds"],
                           object_path=meta.get("object_path", ""))
