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
