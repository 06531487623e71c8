"""Helpers shared by the paper-reproduction scripts in ``experiments/`` (not part of the library)."""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
SHARED_MESHES = Path(__file__).resolve().parents[2] / "shared" / "data" / "meshes"


def parser(name: str, doc: str) -> argparse.ArgumentParser:
    """An argument parser with ``--out`` (default ``experiments/results/<name>/``) and ``--seed``."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=RESULTS / name, help="output folder (default: %(default)s)")
    ap.add_argument("--seed", type=int, default=0)
    return ap


def mu_of(degrees: float) -> float:
    """Friction coefficient ``tan(alpha)`` of a friction angle in degrees."""
    return float(np.tan(np.radians(degrees)))


def table(header: list[str], rows: list[list]) -> str:
    """A markdown table; floats are written with 3 significant decimals."""

    def cell(x):
        if isinstance(x, (bool, np.bool_)):
            return "yes" if x else "no"
        if isinstance(x, (float, np.floating)):
            if not np.isfinite(x):
                return "-"
            return f"{x:.3g}" if abs(x) < 1e-2 and x != 0 else f"{x:.3f}"
        return str(x)

    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(cell(x) for x in row) + " |" for row in rows]
    return "\n".join(lines)


class Timer:
    """Wall-clock sections, reported at the end of ``results.md``."""

    def __init__(self):
        self.start = time.perf_counter()
        self.sections: list[tuple[str, float]] = []
        self._t = self.start

    def lap(self, name: str) -> float:
        now = time.perf_counter()
        self.sections.append((name, now - self._t))
        self._t = now
        return now - self.sections[-1][1]

    def report(self) -> str:
        total = time.perf_counter() - self.start
        parts = ", ".join(f"{name} {sec:.1f} s" for name, sec in self.sections)
        where = f"{platform.machine()} / Python {platform.python_version()}"
        return f"Total run time {total:.1f} s ({parts}) on {where}."


def write(out: Path, text: str) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    path = out / "results.md"
    path.write_text(text.rstrip() + "\n")
    return path


def use_cpu_cores(count: int | None = None) -> int:
    """Make each CPU core an XLA device (``--xla_force_host_platform_device_count``), as the
    command line does; call before JAX is imported. Returns the device count asked for."""
    import os

    if count is None:
        try:
            count = len(os.sched_getaffinity(0))
        except AttributeError:
            count = os.cpu_count() or 1
    flags = os.environ.get("XLA_FLAGS", "")
    if count > 1 and "xla_force_host_platform_device_count" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={count}".strip()
    return count


def compilation_cache(enable: bool = True) -> str | None:
    """The folder of grasp_jax's compilation cache (``$GRASP_JAX_CACHE``, default
    ``~/.cache/grasp_jax/xla``), or ``None`` when disabled (then switched off for this process).
    JAX's own persistent cache stays off, as in the command line (see ``grasp_jax._cache``)."""
    import os

    if not enable:
        os.environ["GRASP_JAX_CACHE"] = "off"
        return None
    from grasp_jax import _cache

    where = _cache.directory()
    return None if where is None else str(where)


def write_json(out: Path, data, name: str = "results.json") -> Path:
    """``data`` as JSON in ``out/name`` (written to a temporary file, then renamed)."""
    import json
    import os

    out.mkdir(parents=True, exist_ok=True)
    path = out / name
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, default=_jsonable))
    os.replace(tmp, path)
    return path


def _jsonable(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"not JSON serializable: {type(x).__name__}")
