"""Random grasps on an object: seeded, vectorized, streamable.

Schemes:

- ``"uniform"``: every contact uniform by area (3D) or length (2D) on the surface.
- ``"paper"``: the paper's scheme (Section V): the first contact is fixed at the centroid of one
  facet, the other ``fingers - 1`` are centroids of facets drawn uniformly (each facet equally
  likely, whatever its size).

Reproducibility: grasps are drawn in blocks of :data:`BLOCK` grasps; block ``k`` uses
``np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(k,)))``, the ``k``-th child of
``SeedSequence(seed).spawn``. Results therefore depend on the object, ``num``, ``fingers``,
``seed``, ``scheme`` and ``first_contact`` only, not on how :func:`iter_grasps` chunks them:
``sample_grasps`` equals the concatenation of ``iter_grasps`` for every ``chunk``. The paper
scheme's default first facet is :func:`default_first_contact`.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

SCHEMES: tuple[str, ...] = ("uniform", "paper")

#: Grasps drawn from one random stream.
BLOCK = 1 << 16


def default_first_contact(obj, seed: int = 0) -> int:
    """The facet the paper scheme fixes the first contact at when none is given:
    ``np.random.default_rng(seed).integers(F)`` for ``F`` facets."""
    return int(np.random.default_rng(_check_seed(seed)).integers(len(obj.facets()[0])))


def sample_grasps(obj, num: int, fingers: int, *, seed: int = 0, scheme: str = "uniform",
                  first_contact: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``num`` random grasps of ``fingers`` contacts on ``obj``.

    Args:
        obj: an object of :mod:`grasp_jax.objects` (``sample_surface``, ``facets``, ``dim``).
        num: grasps, >= 1.
        fingers: contacts per grasp, >= 2.
        seed: non-negative integer; the same arguments give the same grasps.
        scheme: ``"uniform"`` or ``"paper"`` (see the module docstring).
        first_contact: paper scheme only: index of the facet of the first contact (default
            :func:`default_first_contact`).

    Returns:
        points: ``(num, fingers, d) float64`` contact points.
        normals: ``(num, fingers, d) float64`` outward unit normals there.
    """
    args = _check(obj, num, fingers, seed, scheme, first_contact)
    points = np.empty((num, fingers, obj.dim))
    normals = np.empty((num, fingers, obj.dim))
    start = 0
    for p, n in _blocks(obj, *args):
        points[start:start + len(p)], normals[start:start + len(p)] = p, n
        start += len(p)
    return points, normals


def iter_grasps(obj, num: int, fingers: int, *, seed: int = 0, scheme: str = "uniform",
                chunk: int = 100_000, first_contact: int | None = None,
                ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """The grasps of :func:`sample_grasps` in chunks of ``chunk`` grasps (the last may be
    smaller), without holding them all in memory.

    Yields:
        points: ``(m, fingers, d) float64``, ``m <= chunk``.
        normals: ``(m, fingers, d) float64``.
    """
    args = _check(obj, num, fingers, seed, scheme, first_contact)
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ValueError(f"chunk must be a positive integer; got {chunk!r}")
    return _rechunk(_blocks(obj, *args), int(chunk))


def _rechunk(blocks, chunk: int):
    held, size = [], 0
    for block in blocks:
        held.append(block)
        size += len(block[0])
        while size >= chunk:
            points, normals = (np.concatenate(a) if len(held) > 1 else a[0] for a in zip(*held))
            yield points[:chunk], normals[:chunk]
            held, size = [(points[chunk:], normals[chunk:])], size - chunk
    if size:
        yield tuple(np.concatenate(a) for a in zip(*held))


def _blocks(obj, num: int, fingers: int, seed: int, scheme: str, first_contact: int | None):
    """Blocks of at most :data:`BLOCK` grasps, block ``k`` from its own child seed."""
    if scheme == "paper":
        centroids, facet_normals = (np.asarray(a, dtype=np.float64) for a in obj.facets())
    for k, start in enumerate(range(0, num, BLOCK)):
        count = min(BLOCK, num - start)
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(k,)))
        if scheme == "uniform":
            shape = (count, fingers, obj.dim)
            points, normals = (np.asarray(a, np.float64).reshape(shape)
                               for a in obj.sample_surface(count * fingers, rng))
            yield points, normals
        else:
            index = np.empty((count, fingers), dtype=np.int64)
            index[:, 0] = first_contact
            index[:, 1:] = rng.integers(len(centroids), size=(count, fingers - 1))
            yield centroids[index], facet_normals[index]


def _check_seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer; got {seed!r}")
    return int(seed)


def _check(obj, num, fingers, seed, scheme, first_contact):
    """Validated ``(num, fingers, seed, scheme, first_contact)``; the paper scheme's default first
    facet filled in."""
    if isinstance(num, bool) or not isinstance(num, (int, np.integer)) or num < 1:
        raise ValueError(f"num must be a positive integer; got {num!r}")
    if isinstance(fingers, bool) or not isinstance(fingers, (int, np.integer)) or fingers < 2:
        raise ValueError(f"fingers must be an integer >= 2; got {fingers!r}")
    seed = _check_seed(seed)
    if scheme not in SCHEMES:
        raise ValueError(f"scheme must be one of {', '.join(map(repr, SCHEMES))}; got {scheme!r}")
    if scheme == "uniform":
        if first_contact is not None:
            raise ValueError("first_contact applies to scheme='paper' only; leave it out for 'uniform'")
    else:
        facets = len(obj.facets()[0])
        if first_contact is None:
            first_contact = default_first_contact(obj, seed)
        if (isinstance(first_contact, bool) or not isinstance(first_contact, (int, np.integer))
                or not 0 <= first_contact < facets):
            raise ValueError(f"first_contact must be a facet index in [0, {facets}); got {first_contact!r}")
        first_contact = int(first_contact)
    return int(num), int(fingers), seed, scheme, first_contact
