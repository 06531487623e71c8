"""The folder of a grasp dataset (:mod:`grasp_jax.dataset`): its files, records and manifest.

``DIR/_manifest.json`` (configuration, versions, totals, every record), ``DIR/_objects/<name>.json``
(one object's status record), ``DIR/object=<name>/part.parquet`` (its grasps), ``DIR/.lock`` (the
lock under which shards rewrite the manifest). Every file is written atomically.
"""

from __future__ import annotations

import contextlib
import json
import sys
import time
from pathlib import Path

from . import __version__
from .storage import fsync_dir, write_atomically

MANIFEST = "_manifest.json"  # "_": readers of the Parquet dataset skip it (as Spark's _SUCCESS)
RECORDS = "_objects"
PART = "part.parquet"
FIGURE = "_summary.png"  # "_": beside the parts, skipped by the dataset's readers


class DatasetError(ValueError):
    """A dataset that cannot be built as asked (one sentence)."""


def versions() -> dict:
    """Versions of grasp_jax, Python and the libraries the results depend on."""
    from importlib import metadata

    out = {"grasp_jax": __version__, "python": sys.version.split()[0]}
    for name in ("jax", "jaxlib", "numpy", "trimesh", "pyarrow"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def write_json(path: Path, data: dict) -> None:
    """``data`` to ``path`` atomically (a temporary file renamed into place)."""
    write_atomically(path, lambda f: f.write(json.dumps(data, indent=1, default=str) + "\n"), what="dataset file")
    fsync_dir(path.parent)


def read_json(path: Path) -> dict | None:
    """A JSON file's content; ``None`` where it does not exist."""
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        raise DatasetError(f"cannot read {str(path)!r} ({exc}); remove it to start that part again") from None


@contextlib.contextmanager
def locked(directory: Path):
    """An exclusive lock on ``directory/.lock`` (``fcntl.flock``; none where it is missing)."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    with open(directory / ".lock", "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def part_path(out: Path, name: str) -> Path:
    """Where the grasps of object ``name`` go: ``out/object=<name>/part.parquet``."""
    return Path(out) / f"object={name}" / PART


def records(out: Path) -> dict:
    """``{name: record}`` of every object record of the dataset at ``out`` (all shards)."""
    folder = out / RECORDS
    if not folder.is_dir():
        return {}
    found = {}
    for f in sorted(folder.glob("*.json")):
        record = read_json(f)
        if record is not None:
            found[record.get("name", f.stem)] = record
    return found


def manifest(out: Path, config: dict) -> dict:
    """The manifest of the dataset at ``out``: its configuration, versions, totals, the records."""
    found = records(out)
    done = sum(r.get("status") == "done" for r in found.values())
    return {
        "format": "grasp_jax dataset 1",
        "config": config,
        "versions": versions(),
        "updated": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "objects_done": done,
        "objects_failed": sum(r.get("status") == "failed" for r in found.values()),
        "grasps": int(sum(r.get("num", 0) for r in found.values() if r.get("status") == "done")),
        "objects": found,
    }


def start(out: Path, config: dict) -> None:
    """Create ``out`` (or check that its configuration is ``config``) and write the manifest."""
    try:
        (out / RECORDS).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DatasetError(f"cannot create the dataset folder {str(out)!r}: {exc.strerror or exc}") from None
    with locked(out):
        old = read_json(out / MANIFEST)
        stored = (old or {}).get("config") or {}
        diff = [k for k in sorted(set(stored) | set(config)) if stored.get(k) != config.get(k)]
        if old is not None and diff:
            raise DatasetError(f"{str(out)!r} holds a dataset of another configuration (differs in "
                               f"{', '.join(diff)}); give another --out or the same settings")
        write_json(out / MANIFEST, manifest(out, config))


#: Seconds between rewrites of the manifest while a run goes on (it is rewritten at the end too;
#: the records are what resuming reads).
MANIFEST_EVERY = 30.0


def write_manifest(out: Path, config: dict) -> None:
    """Rewrite the manifest from every record, under the lock."""
    with locked(out):
        write_json(out / MANIFEST, manifest(out, config))


def is_done(out: Path, name: str) -> bool:
    """Whether object ``name`` is done: its ``done`` record and its part exist."""
    record = read_json(out / RECORDS / f"{name}.json")
    return bool(record) and record.get("status") == "done" and part_path(out, name).is_file()


def clean_temporaries(folder: Path) -> None:
    """The hidden temporary files a killed writer of this object left behind."""
    if folder.is_dir():
        for f in folder.glob(f".{PART}.*.tmp"):
            f.unlink(missing_ok=True)


__all__ = ["FIGURE", "MANIFEST", "MANIFEST_EVERY", "PART", "RECORDS", "DatasetError", "clean_temporaries", "is_done",
           "locked", "manifest", "part_path", "read_json", "records", "start", "versions", "write_json",
           "write_manifest"]
