"""Paths and atomic publication of files.

:func:`check_output_path` and :func:`check_input_path` validate a path before any work is done
(one ``ValueError`` naming the problem). :func:`temp_file` makes a hidden temporary file beside
its destination, :func:`write_atomically` fills one, ``fsync``-s it and renames it onto the
destination (:func:`os.replace`) only when complete, :func:`fsync_dir` makes the rename durable.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

#: Suffixes of result files.
SUFFIXES = (".npz", ".parquet")


def check_output_path(path, *, suffixes=SUFFIXES, what: str = "output file") -> Path:
    """Validate an output path before any work is done: known suffix, existing directory.

    Raises:
        ValueError: with one sentence naming the problem.
    """
    path = Path(path)
    if path.suffix.lower() not in suffixes:
        raise ValueError(
            f"{what} {str(path)!r} must end in {' or '.join(suffixes)}; got {path.suffix or 'no suffix'!r}"
        )
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise ValueError(f"the directory of {what} {str(path)!r} does not exist: {str(parent)!r}")
    if path.is_dir():
        raise ValueError(f"{what} {str(path)!r} is a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"cannot write {what} {str(path)!r}: its directory {str(parent)!r} is not writable")
    return path


def check_input_path(path, *, what: str = "input file") -> Path:
    """An existing ``.npz`` / ``.parquet`` file, or a ``ValueError`` / ``FileNotFoundError``."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{what} {str(path)!r} does not exist")
    if path.is_dir():
        raise ValueError(f"{what} {str(path)!r} is a directory")
    if path.suffix.lower() not in SUFFIXES:
        raise ValueError(
            f"{what} {str(path)!r} must end in {' or '.join(SUFFIXES)}; got {path.suffix or 'no suffix'!r}"
        )
    return path


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def publish_mode(fd: int) -> None:
    """Give a temporary file made by :func:`tempfile.mkstemp` (mode 0600) the mode a plain
    ``open(path, "w")`` would have (0666 less the umask), before it is renamed into place."""
    try:
        os.fchmod(fd, 0o666 & ~_umask())
    except (OSError, AttributeError):  # no fchmod on this platform / filesystem
        pass


def cannot_write(what: str, path: Path, exc: OSError) -> ValueError:
    """The one-sentence error of a file that cannot be written."""
    return ValueError(f"cannot write {what} {str(path)!r}: {exc.strerror or exc}")


def temp_file(path: Path, *, suffix: str = ".tmp", what: str = "output file") -> tuple[int, Path]:
    """A hidden temporary file beside ``path``, with the mode a plain ``open`` would give, to be
    renamed onto ``path`` once complete (atomic publication). A failure is one ``ValueError``."""
    directory = path.parent if str(path.parent) else Path(".")
    try:
        fd, name = tempfile.mkstemp(dir=directory, prefix=f".{path.name}.", suffix=suffix)
    except OSError as exc:
        raise cannot_write(what, path, exc) from None
    publish_mode(fd)
    return fd, Path(name)


def write_atomically(path: Path, write, *, mode: str = "w", what: str = "output file") -> Path:
    """Publish a small file atomically: ``write(f)`` fills a :func:`temp_file` opened with
    ``mode`` (``"w"``: UTF-8 text, ``"wb"``), which is flushed, ``fsync``-ed and renamed onto
    ``path``; on any exception it is removed and nothing is published."""
    path = Path(path)
    fd, tmp = temp_file(path, what=what)
    try:
        with os.fdopen(fd, mode, **({} if "b" in mode else {"encoding": "utf-8"})) as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def fsync_dir(directory: Path) -> None:
    """``fsync`` a directory, so that a file renamed into it stays after a crash (where supported)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:  # not supported on this platform / filesystem
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


__all__ = ["SUFFIXES", "cannot_write", "check_input_path", "check_output_path", "fsync_dir", "publish_mode", "temp_file",
           "write_atomically"]
