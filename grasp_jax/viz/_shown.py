"""The grasps a page draws: the best ``top`` of a result file, read chunk by chunk."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .. import storage

#: Grasps drawn by default.
DEFAULT_TOP = 10
#: Bins of the page's Q histogram.
HISTOGRAM_BINS = 60
_SERIES = ("history", "quality_history")


@dataclasses.dataclass(frozen=True)
class ShownGrasps:
    """The grasps a page draws, best first, with every column the file has for them.

    Attributes:
        index: ``(k,)`` int, row of each grasp in the file (0-based).
        points, normals: ``(k, n, d)`` float.
        columns: column name -> ``(k, ...)`` array: every field of the file but ``points`` and
            ``normals`` (``quality``, ``force_closure``, ``initial_points``, ``quality_history``, any
            extra column), in file order.
        num: rows in the file; ``num_force_closure``: force-closure rows (``None`` when unscored).
        histogram: ``(counts (B,), edges (B + 1,))`` of Q over the file's force-closure grasps, or
            ``None``.
    """

    index: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    columns: dict
    num: int = 0
    num_force_closure: int | None = None
    histogram: tuple | None = None

    def __len__(self) -> int:
        return len(self.index)


def select_grasps(path, top: int = DEFAULT_TOP, *, chunk: int = 65536) -> tuple[ShownGrasps, dict]:
    """The ``top`` best grasps of a result file and the file's metadata, streamed with flat memory.

    Force-closure grasps come first by decreasing Q, then the others by decreasing Q (ties: file
    order), so that a file with fewer than ``top`` force-closure grasps (an optimizer's) still shows
    its best tries, each with its verdict. A file without ``quality`` gives its first ``top`` grasps.

    Returns:
        ``(ShownGrasps, metadata)``.
    """

    src = storage.ResultFile(path)
    top = int(top)
    if top < 1:
        raise ValueError(f"top must be a positive integer; got {top}")
    scored = "quality" in src.fields
    has_fc = "force_closure" in src.fields
    mu = float(src.metadata.get("mu", 1.0))
    upper = math.sqrt(1.0 + mu * mu)
    edges = np.linspace(0.0, upper, HISTOGRAM_BINS + 1)
    counts = np.zeros(HISTOGRAM_BINS, np.int64)
    num_fc = 0 if has_fc else None
    held = None  # (index, quality, force_closure)
    offset = 0
    if scored:
        columns = ("quality",) + (("force_closure",) if has_fc else ())
        for c in src.iter_chunks(columns, chunk):
            q = np.asarray(c["quality"], float)
            fc = np.asarray(c["force_closure"], bool) if has_fc else np.isfinite(q) & (q > 0)
            rows = len(q)
            if has_fc:
                num_fc += int(fc.sum())
            good = q[fc & np.isfinite(q)]
            counts += np.histogram(np.clip(good, 0.0, upper), edges)[0]
            key = np.where(np.isfinite(q), q, -np.inf)
            new = (np.arange(offset, offset + rows), key, fc)
            offset += rows
            if held is not None:
                new = tuple(np.concatenate([a, b]) for a, b in zip(held, new))
            if len(new[0]) > top:
                order = np.lexsort((new[0], -new[1], ~new[2]))[:top]
                new = tuple(a[order] for a in new)
            held = new
        index = held[0][np.lexsort((held[0], -held[1], ~held[2]))] if held is not None else np.zeros(0, int)
    else:
        index = np.arange(min(top, src.num))
    index = np.asarray(index, np.int64)
    # second pass: every column of the chosen rows, in rank order
    names = tuple(src.fields)
    wanted = np.sort(index)
    picked: dict[str, list] = {n: [] for n in names}
    offset = 0
    if len(wanted):
        for c in src.iter_chunks(names, chunk):
            rows = len(c["points"])
            sel = wanted[(wanted >= offset) & (wanted < offset + rows)] - offset
            if len(sel):
                for n in names:
                    picked[n].append(np.asarray(c[n])[sel])
            offset += rows
            if offset > wanted[-1]:
                break
    order = np.argsort(np.argsort(index))  # position of each ranked row among the sorted rows
    arrays = {}
    for n in names:
        parts = picked[n]
        a = np.concatenate(parts) if parts else np.zeros((0,) + tuple(src.fields[n][1:]))
        arrays[n] = a[order] if len(a) else a
    points = np.asarray(arrays.pop("points"), float)
    normals = np.asarray(arrays.pop("normals"), float)
    histogram = (counts, edges) if scored and counts.sum() else None
    shown = ShownGrasps(index, points, normals, arrays, num=int(src.num), num_force_closure=num_fc,
                        histogram=histogram)
    return shown, dict(src.metadata)
