"""Result files: streaming, atomic writers and readers for ``.npz`` and ``.parquet``.

A result file holds one row per grasp: ``points``, ``normals`` ``(N, n, d)``, ``force_closure``,
``quality`` (Q) and ``converged`` ``(N,)``, plus the columns of the options that made it (the qhull
baseline, ``grasp-jax optimize``, ``--robust N``, ``--gripper parallel-jaw``; listed in
docs/guides/result-files.md), and a metadata dictionary (object, mu, edges, fingers, seed, ...).

* ``.npz``: one ``.npy`` array per field and the metadata as JSON in a 0-d string array
  ``metadata``: ``json.loads(str(f["metadata"]))``.
* ``.parquet``: one row per grasp, ``points`` and ``normals`` as nested ``fixed_size_list`` of
  double; the metadata as JSON under the key ``grasp_jax`` of the schema metadata.

Writers take the grasps chunk by chunk with flat memory and are atomic: a hidden temporary file in
the destination directory, ``fsync``-ed and moved over the destination with :func:`os.replace`
only when the writer closes without error (paths and atomic writes: ``grasp_jax._atomic``).
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import zipfile
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np

from . import __version__
from ._atomic import (  # noqa: F401 - paths and atomic writes, re-exported where they were
    SUFFIXES,
    _umask,
    cannot_write,
    check_input_path,
    check_output_path,
    fsync_dir,
    publish_mode,
    temp_file,
    write_atomically,
)
from ._atomic import cannot_write as _cannot_write  # noqa: F401 - the names this module had
from ._atomic import fsync_dir as _fsync_dir  # noqa: F401

#: Metadata key in a Parquet schema.
PARQUET_KEY = b"grasp_jax"
#: Per-grasp scalar fields and their dtypes, in file order.
SCALAR_FIELDS = {
    "force_closure": np.dtype(bool),
    "quality": np.dtype(np.float64),
    "converged": np.dtype(bool),
    "epsilon": np.dtype(np.float64),
    "volume": np.dtype(np.float64),
    "objective": np.dtype(np.float64),
    "reason": np.dtype(np.int8),
    "width": np.dtype(np.float64),
    "jaw_status": np.dtype(np.int8),
    "critical_mu": np.dtype(np.float64),
    "critical_status": np.dtype(np.int8),
    "friction_label": np.dtype(np.float64),
    # robust labels (grasp-jax sample / score --robust N; grasp_jax.robust)
    "p_fc": np.dtype(np.float64),
    "p_fc_se": np.dtype(np.float64),
    "q_mean": np.dtype(np.float64),
    "q_mean_se": np.dtype(np.float64),
    "q_low": np.dtype(np.float64),
    "margin_mean": np.dtype(np.float64),
    "margin_mean_se": np.dtype(np.float64),
    "margin_low": np.dtype(np.float64),
    "robust_unconverged": np.dtype(np.int32),
}
#: The fields of a scored result (``grasp-jax sample`` / ``score``), in file order.
RESULT_FIELDS = ("points", "normals", "force_closure", "quality", "converged")
#: Per-grasp fields of shape ``(fingers, d)``.
POINT_FIELDS = ("points", "normals", "initial_points")
#: Per-grasp fields of shape ``(d,)``: parallel-jaw poses (:mod:`grasp_jax.grippers`).
VECTOR_FIELDS = ("center", "axis", "approach")
#: Per-grasp fields of shape ``(frames, fingers, d)``: the optimizer's contact paths.
PATH_FIELDS = ("path",)
#: Per-grasp fields with one value per optimizer step, shape ``(steps,)``.
SERIES_FIELDS = {
    "history": np.dtype(np.float64),
    "quality_history": np.dtype(np.float64),
}
_COPY = 1 << 24  # bytes per copy step when assembling an archive


def metadata(**kwargs) -> dict:
    """A result file's metadata: the grasp_jax version and the date (UTC), then ``kwargs``."""
    import datetime

    meta = {
        "grasp_jax_version": __version__,
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    }
    meta.update(kwargs)
    return meta


def object_spec(obj, spec) -> str:
    """What to store so that ``grasp_jax.objects.load`` finds the object again: ``spec`` (a
    built-in name, or a file made absolute), else ``obj.name``."""
    if spec is None:
        return str(obj.name)
    spec = str(spec)
    return os.path.abspath(spec) if os.path.exists(spec) else spec


def _field_layout(fields, fingers: int, dim: int, steps: int | None, frames: int | None = None
                  ) -> tuple[dict, dict]:
    """``(dtypes, row shapes)`` of the named fields."""
    dtypes, shapes = {}, {}
    for name in fields:
        if name in POINT_FIELDS:
            dtypes[name], shapes[name] = np.dtype(np.float64), (fingers, dim)
        elif name in PATH_FIELDS:
            if frames is None or frames < 1:
                raise ValueError(f"result field {name!r} needs the number of frames")
            dtypes[name], shapes[name] = np.dtype(np.float64), (int(frames), fingers, dim)
        elif name in SCALAR_FIELDS:
            dtypes[name], shapes[name] = SCALAR_FIELDS[name], ()
        elif name in VECTOR_FIELDS:
            dtypes[name], shapes[name] = np.dtype(np.float64), (dim,)
        elif name in SERIES_FIELDS:
            if steps is None or steps < 1:
                raise ValueError(f"result field {name!r} needs the number of steps")
            dtypes[name], shapes[name] = SERIES_FIELDS[name], (int(steps),)
        else:
            raise ValueError(f"unknown result field {name!r}")
    return dtypes, shapes


class ResultWriter:
    """Base class of the atomic, streaming writers; use :func:`open_writer`.

    Use as a context manager: leaving the block normally publishes the file, leaving it with an
    exception (including ``KeyboardInterrupt``) removes every temporary file and publishes nothing.
    """

    def __init__(self, path, metadata: Mapping, fields, fingers: int, dim: int, steps: int | None = None,
                 frames: int | None = None):
        self.path = check_output_path(path)
        self.directory = self.path.parent if str(self.path.parent) else Path(".")
        self.metadata = dict(metadata)
        self.fingers, self.dim = int(fingers), int(dim)
        self.dtypes, self.shapes = _field_layout(fields, self.fingers, self.dim, steps, frames)
        self.count = 0
        self._done = False

    def _check(self, batch: Mapping) -> tuple[dict, int]:
        missing = set(self.dtypes) - set(batch)
        if missing:
            raise ValueError(f"result chunk is missing {sorted(missing)}")
        arrays = {}
        rows = None
        for name, dtype in self.dtypes.items():
            a = np.ascontiguousarray(np.asarray(batch[name]), dtype=dtype)
            want = self.shapes[name]
            if a.shape[1:] != want or (rows is not None and len(a) != rows):
                raise ValueError(f"result field {name!r} has shape {a.shape}; expected (rows,) + {want}")
            rows = len(a)
            arrays[name] = a
        return arrays, rows

    def write(self, batch: Mapping) -> None:
        """Append one chunk: a mapping of field name to array with the same number of rows."""
        if self._done:
            raise ValueError("writer is closed")
        arrays, rows = self._check(batch)
        if rows == 0:
            return
        self._write(arrays)
        self.count += rows

    def close(self) -> Path:
        """Finish the file and move it into place atomically; returns its path."""
        if self._done:
            return self.path
        try:
            self._finish()
        except BaseException:
            self.abort()
            raise
        self._done = True
        fsync_dir(self.directory)
        return self.path

    def abort(self) -> None:
        """Drop everything written so far (idempotent)."""
        self._done = True
        self._cleanup()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()
        else:
            self.abort()
        return False

    def _temp_file(self, suffix: str = ".tmp") -> tuple[int, Path]:
        return temp_file(self.path, suffix=suffix)

    # subclass hooks
    def _write(self, arrays: dict) -> None:
        raise NotImplementedError

    def _finish(self) -> None:
        raise NotImplementedError

    def _cleanup(self) -> None:
        raise NotImplementedError


class NpzWriter(ResultWriter):
    """Streams each field to a scratch file; :meth:`close` assembles an uncompressed ``.npz``."""

    def __init__(self, path, metadata, fields, fingers, dim, steps=None, frames=None):
        super().__init__(path, metadata, fields, fingers, dim, steps, frames)
        try:
            self._scratch = Path(tempfile.mkdtemp(dir=self.directory, prefix=f".{self.path.name}.",
                                                  suffix=".tmp"))
        except OSError as exc:
            raise cannot_write("output file", self.path, exc) from None
        self._files = {name: open(self._scratch / f"{name}.raw", "wb") for name in self.dtypes}
        self._archive: Path | None = None

    def _write(self, arrays):
        for name, a in arrays.items():
            self._files[name].write(memoryview(a.reshape(-1)).cast("B"))

    def _finish(self):
        for f in self._files.values():
            f.close()
        fd, self._archive = self._temp_file()
        with os.fdopen(fd, "wb") as raw:
            with zipfile.ZipFile(raw, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
                for name, dtype in self.dtypes.items():
                    shape = (self.count,) + self.shapes[name]
                    with zf.open(f"{name}.npy", "w", force_zip64=True) as entry:
                        header = {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False,
                                  "shape": shape}
                        np.lib.format.write_array_header_2_0(entry, header)
                        with open(self._scratch / f"{name}.raw", "rb") as src:
                            shutil.copyfileobj(src, entry, _COPY)
                with zf.open("metadata.npy", "w") as entry:
                    np.lib.format.write_array(entry, np.array(json.dumps(self.metadata)), allow_pickle=False)
            raw.flush()
            os.fsync(raw.fileno())
        os.replace(self._archive, self.path)
        self._archive = None
        shutil.rmtree(self._scratch, ignore_errors=True)

    def _cleanup(self):
        for f in self._files.values():
            try:
                f.close()
            except OSError:
                pass
        shutil.rmtree(self._scratch, ignore_errors=True)
        if self._archive is not None:
            self._archive.unlink(missing_ok=True)
            self._archive = None


def _fixed_row_shape(typ) -> tuple[int, ...]:
    """The row shape of a (nested) ``fixed_size_list`` Arrow type; ``()`` for anything else."""
    import pyarrow as pa

    shape = []
    while pa.types.is_fixed_size_list(typ):
        shape.append(typ.list_size)
        typ = typ.value_type
    return tuple(shape)


class ParquetWriter(ResultWriter):
    """One row group per chunk, written to a temporary file that :meth:`close` renames."""

    def __init__(self, path, metadata, fields, fingers, dim, steps=None, frames=None):
        import pyarrow as pa
        import pyarrow.parquet as pq

        super().__init__(path, metadata, fields, fingers, dim, steps, frames)
        self._pa = pa
        columns = []
        for name, dtype in self.dtypes.items():
            # a row of shape (a, b, ...) is a fixed-size list of fixed-size lists ...
            typ = pa.from_numpy_dtype(dtype)
            for size in reversed(self.shapes[name]):
                typ = pa.list_(typ, size)
            columns.append(pa.field(name, typ, nullable=False))
        self.schema = pa.schema(columns, metadata={PARQUET_KEY: json.dumps(self.metadata).encode()})
        fd, self._tmp = self._temp_file()
        self._file = os.fdopen(fd, "wb")
        self._writer = pq.ParquetWriter(self._file, self.schema)

    def _write(self, arrays):
        pa = self._pa
        cols = []
        for name in self.dtypes:
            a = arrays[name]
            column = pa.array(a.reshape(-1))
            for size in reversed(self.shapes[name]):
                column = pa.FixedSizeListArray.from_arrays(column, size)
            cols.append(column)
        self._writer.write_batch(pa.RecordBatch.from_arrays(cols, schema=self.schema))

    def _finish(self):
        self._writer.close()
        self._writer = None
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
        os.replace(self._tmp, self.path)
        self._tmp = None

    def _cleanup(self):
        if self._writer is not None:
            try:
                self._writer.close()
            except Exception:  # noqa: BLE001 - best effort while aborting
                pass
            self._writer = None
        try:
            self._file.close()
        except OSError:
            pass
        if self._tmp is not None:
            self._tmp.unlink(missing_ok=True)
            self._tmp = None


def open_writer(path, metadata: Mapping, fields, *, fingers: int, dim: int,
                steps: int | None = None, frames: int | None = None) -> ResultWriter:
    """A streaming, atomic writer chosen by the suffix of ``path`` (``.npz`` or ``.parquet``).

    Args:
        path: destination; its directory must exist.
        metadata: JSON-serializable dictionary stored with the results.
        fields: names of the per-grasp fields to store, e.g. ``("points", "normals",
            "force_closure", "quality")``.
        fingers, dim: the contacts per grasp and the dimension (2 or 3).
        steps: the length of the per-step fields (:data:`SERIES_FIELDS`), if any are stored.
        frames: the frames of a contact path (:data:`PATH_FIELDS`), if one is stored.

    Raises:
        ValueError: unknown suffix, missing directory, unknown field.
    """
    path = check_output_path(path)
    cls = NpzWriter if path.suffix.lower() == ".npz" else ParquetWriter
    return cls(path, metadata, tuple(fields), fingers, dim, steps, frames)


# ---------------------------------------------------------------------------------------------
# Readers


class _NpyStream:
    """Reads rows of one ``.npy`` member of a zip archive sequentially (flat memory)."""

    def __init__(self, zf: zipfile.ZipFile, member: str, path: Path):
        self._f = zf.open(member)
        try:
            version = np.lib.format.read_magic(self._f)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(self._f)
            elif version == (2, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(self._f)
            else:
                raise ValueError(f"unsupported .npy format version {version}")
        except ValueError as e:
            raise ValueError(f"{str(path)!r}: member {member!r} is not a valid .npy array ({e})") from None
        if dtype.hasobject:
            raise ValueError(f"{str(path)!r}: array {member[:-4]!r} holds Python objects; refusing to unpickle")
        if fortran and len(shape) > 1:
            raise ValueError(f"{str(path)!r}: array {member[:-4]!r} is stored in Fortran order; save it C-ordered")
        self.shape, self.dtype = tuple(shape), dtype
        self._row = int(np.prod(shape[1:], dtype=np.int64)) * dtype.itemsize

    def read(self, rows: int) -> np.ndarray:
        data = self._f.read(rows * self._row)
        n = len(data) // self._row if self._row else rows
        return np.frombuffer(data, self.dtype, count=n * (self._row // self.dtype.itemsize)).reshape(
            (n,) + self.shape[1:]
        )

    def close(self):
        self._f.close()


class ResultFile:
    """A result (or grasp) file opened for reading: metadata, shapes, and chunked iteration.

    Any ``.npz`` or ``.parquet`` file with ``points`` and ``normals`` of shape ``(N, n, d)`` can be
    read, not only files written by grasp_jax (their metadata is then empty).
    """

    def __init__(self, path):
        self.path = check_input_path(path)
        self.format = self.path.suffix.lower()[1:]
        try:
            if self.format == "npz":
                self._open_npz()
            else:
                self._open_parquet()
        except (zipfile.BadZipFile, EOFError) as e:
            raise ValueError(f"{str(self.path)!r} is not a readable .npz file ({e})") from None
        if "points" not in self.fields or "normals" not in self.fields:
            raise ValueError(f"{str(self.path)!r} has no 'points' and 'normals' arrays (it has {sorted(self.fields)})")
        pshape = self.fields["points"]
        if len(pshape) != 3 or pshape[2] not in (2, 3) or pshape[1] < 2:
            raise ValueError(
                f"{str(self.path)!r}: 'points' must have shape (N, fingers >= 2, 2 or 3); got {pshape}"
            )
        if self.fields["normals"] != pshape:
            raise ValueError(
                f"{str(self.path)!r}: 'normals' has shape {self.fields['normals']}, 'points' has {pshape}"
            )
        for name, shape in self.fields.items():
            if shape[:1] != pshape[:1]:
                raise ValueError(f"{str(self.path)!r}: {name!r} has {shape[0]} rows, 'points' has {pshape[0]}")
        self.num, self.fingers, self.dim = pshape

    # npz -----------------------------------------------------------------------------------
    def _open_npz(self):
        with zipfile.ZipFile(self.path) as zf:
            members = [m for m in zf.namelist() if m.endswith(".npy")]
            self.metadata = {}
            self.fields = {}
            for m in members:
                name = m[:-4]
                if name == "metadata":
                    with zf.open(m) as f:
                        meta = np.lib.format.read_array(f, allow_pickle=False)
                    try:
                        self.metadata = json.loads(str(meta))
                    except json.JSONDecodeError:
                        raise ValueError(f"{str(self.path)!r}: 'metadata' is not JSON") from None
                    continue
                stream = _NpyStream(zf, m, self.path)
                stream.close()
                self.fields[name] = stream.shape

    def _iter_npz(self, columns, chunk):
        with zipfile.ZipFile(self.path) as zf:
            streams = {c: _NpyStream(zf, f"{c}.npy", self.path) for c in columns}
            try:
                for start in range(0, self.num, chunk):
                    rows = min(chunk, self.num - start)
                    out = {}
                    for c, s in streams.items():
                        a = s.read(rows)
                        if len(a) != rows:
                            raise ValueError(f"{str(self.path)!r}: array {c!r} is truncated")
                        out[c] = a
                    yield out
            finally:
                for s in streams.values():
                    s.close()

    # parquet -------------------------------------------------------------------------------
    def _open_parquet(self):
        import pyarrow.parquet as pq

        try:
            self._pq = pq.ParquetFile(self.path)
        except Exception as e:  # noqa: BLE001 - pyarrow raises several types for a bad file
            raise ValueError(f"{str(self.path)!r} is not a readable .parquet file ({e})") from None
        schema = self._pq.schema_arrow
        raw = (schema.metadata or {}).get(PARQUET_KEY)
        try:
            self.metadata = json.loads(raw) if raw else {}
        except json.JSONDecodeError:
            raise ValueError(f"{str(self.path)!r}: the grasp_jax schema metadata is not JSON") from None
        num = self._pq.metadata.num_rows
        self.fields = {}
        first = None
        for name in schema.names:
            if name in ("points", "normals"):
                if first is None:
                    first = self._first_row_shape(name)
                self.fields[name] = (num,) + first
            else:
                self.fields[name] = (num,) + _fixed_row_shape(schema.field(name).type)

    def _first_row_shape(self, name):
        import pyarrow as pa

        typ = self._pq.schema_arrow.field(name).type
        if pa.types.is_fixed_size_list(typ) and pa.types.is_fixed_size_list(typ.value_type):
            return (typ.list_size, typ.value_type.list_size)
        if self._pq.metadata.num_rows == 0:
            return (0, 0)
        batch = next(self._pq.iter_batches(batch_size=1, columns=[name]))
        row = batch.column(0).to_pylist()[0]
        return (len(row), len(row[0]) if row else 0)

    def _iter_parquet(self, columns, chunk):
        for batch in self._pq.iter_batches(batch_size=chunk, columns=list(columns)):
            out = {}
            for c in columns:
                col = batch.column(c)
                shape = self.fields[c][1:]
                if shape:
                    flat = col
                    for _ in shape:
                        flat = flat.flatten()
                    flat = flat.to_numpy(zero_copy_only=False)
                    if flat.size != len(col) * int(np.prod(shape)):
                        raise ValueError(f"{str(self.path)!r}: rows of {c!r} do not all have shape {shape}")
                    out[c] = flat.reshape((len(col),) + shape)
                else:
                    out[c] = col.to_numpy(zero_copy_only=False)
            yield out

    # public --------------------------------------------------------------------------------
    def iter_chunks(self, columns=("points", "normals"), chunk: int = 65536) -> Iterator[dict]:
        """Yield dictionaries of ``chunk`` rows of the given columns (the last may be shorter)."""
        missing = [c for c in columns if c not in self.fields]
        if missing:
            raise ValueError(f"{str(self.path)!r} has no {missing} (it has {sorted(self.fields)})")
        if self.format == "npz":
            return self._iter_npz(tuple(columns), int(chunk))
        return self._iter_parquet(tuple(columns), int(chunk))

    def read(self, columns=None) -> dict[str, np.ndarray]:
        """Every row of the given columns (default: all) in memory."""
        columns = tuple(self.fields) if columns is None else tuple(columns)
        parts = list(self.iter_chunks(columns, chunk=max(self.num, 1)))
        if not parts:
            return {c: np.zeros((0,) + self.fields[c][1:], float) for c in columns}
        return {c: np.concatenate([p[c] for p in parts]) for c in columns}


def read_results(path) -> tuple[dict[str, np.ndarray], dict]:
    """Read a whole result file: ``(arrays, metadata)``.

    ``arrays`` maps each stored field (``points``, ``normals``, ``force_closure``, ``quality``,
    ...) to a NumPy array with one row per grasp; ``metadata`` is the stored dictionary (empty
    for files not written by grasp_jax).
    """
    f = ResultFile(path)
    return f.read(), dict(f.metadata)


def read_metadata(path) -> dict:
    """Only the metadata dictionary of a result file."""
    return dict(ResultFile(path).metadata)
