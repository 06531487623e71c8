"""What every object offers (:class:`GraspObject`) and the one error type for user mistakes."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


class ObjectError(ValueError):
    """A file or shape that cannot be used as an object, said in one sentence: which file or
    shape, what is wrong, what to do."""


@runtime_checkable
class GraspObject(Protocol):
    """A 2D polygon or a 3D surface that grasps are sampled on.

    Attributes:
        name: short name (a built-in name or the file's stem).
        dim: 2 or 3.
        center: ``(d,) float`` centre of mass (area centroid of a polygon; centroid of the surface
            when a mesh is not watertight).
        radius: largest distance from ``center`` to the surface (GraspIt's torque scale).
        warnings: reasons results may be unreliable (open surface, several bodies, ...).
    """

    name: str
    dim: int
    center: np.ndarray
    radius: float
    warnings: tuple[str, ...]

    def sample_surface(self, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """``count`` points uniform by area (3D) or length (2D) on the surface.

        Returns:
            points: ``(count, d) float``.
            normals: ``(count, d) float``, unit, outward.
        """
        ...

    def facets(self) -> tuple[np.ndarray, np.ndarray]:
        """Facet centroids and outward unit normals (triangles in 3D, edges in 2D).

        Returns:
            centroids: ``(F, d) float``.
            normals: ``(F, d) float``.
        """
        ...


class Picker:
    """Draws indices with probability proportional to ``weights: (k,) float`` in O(1) each
    (Walker's alias method, Vose's construction; the table is built once in O(k))."""

    def __init__(self, weights):
        weights = np.asarray(weights, dtype=float)
        prob = weights * (len(weights) / weights.sum())
        alias = np.arange(len(weights))
        small, large = list(np.flatnonzero(prob < 1.0)), list(np.flatnonzero(prob >= 1.0))
        while small and large:
            s, g = small.pop(), large[-1]
            alias[s] = g
            prob[g] -= 1.0 - prob[s]
            if prob[g] < 1.0:
                small.append(large.pop())
        prob[small + large] = 1.0  # left over from rounding: keep itself
        self.prob, self.alias = prob, alias

    def __call__(self, count: int, rng: np.random.Generator) -> np.ndarray:
        """``(count,) int`` indices."""
        index = rng.integers(len(self.prob), size=count)
        return np.where(rng.random(count) < self.prob[index], index, self.alias[index])


def check_count(count) -> int:
    """A non-negative integer number of samples."""
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 0:
        raise ValueError(f"count must be an integer >= 0; got {count!r}")
    return int(count)


def unit(v: np.ndarray) -> np.ndarray:
    """Rows of ``v: (..., d)`` scaled to unit length."""
    return v / np.linalg.norm(v, axis=-1, keepdims=True)
