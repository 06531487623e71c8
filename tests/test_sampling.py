"""Random grasps: shapes, reproducibility, chunking, the paper scheme, argument errors."""

from __future__ import annotations

import numpy as np
import pytest

from grasp_jax import objects
from grasp_jax.sampling import BLOCK, default_first_contact, iter_grasps, sample_grasps


@pytest.fixture(scope="module")
def glass():
    return objects.glass()


@pytest.mark.parametrize("name", ["glass", "star", "ellipsoid"])
@pytest.mark.parametrize("scheme", ["uniform", "paper"])
def test_shapes_and_reproducibility(name, scheme):
    obj = objects.load(name)
    points, normals = sample_grasps(obj, 500, 4, seed=3, scheme=scheme)
    assert points.shape == normals.shape == (500, 4, obj.dim)
    assert points.dtype == normals.dtype == np.float64
    assert np.allclose(np.linalg.norm(normals, axis=-1), 1.0)
    again = sample_grasps(obj, 500, 4, seed=3, scheme=scheme)
    assert np.array_equal(points, again[0]) and np.array_equal(normals, again[1])
    other = sample_grasps(obj, 500, 4, seed=4, scheme=scheme)[0]
    assert not np.array_equal(points[:, 1:], other[:, 1:])


def test_uniform_contacts_lie_on_the_surface():
    sphere = objects.Sphere(2.0)
    points, normals = sample_grasps(sphere, 1000, 3, seed=1)
    assert np.allclose(points, 2.0 * normals)
    # independent contacts: the mean of the normals is near zero in every finger
    assert np.all(np.abs(normals.mean(0)) < 0.1)


@pytest.mark.parametrize("scheme", ["uniform", "paper"])
@pytest.mark.parametrize("chunk", [1000, 7919, BLOCK, 3 * BLOCK])
def test_iter_grasps_equals_sample_grasps(glass, scheme, chunk):
    num = BLOCK + 1234  # crosses a block boundary
    points, normals = sample_grasps(glass, num, 3, seed=7, scheme=scheme)
    chunks = list(iter_grasps(glass, num, 3, seed=7, scheme=scheme, chunk=chunk))
    assert all(len(p) == chunk for p, _ in chunks[:-1]) and 0 < len(chunks[-1][0]) <= chunk
    assert np.array_equal(points, np.concatenate([p for p, _ in chunks]))
    assert np.array_equal(normals, np.concatenate([n for _, n in chunks]))


def test_paper_scheme(glass):
    centroids, facet_normals = glass.facets()
    points, normals = sample_grasps(glass, 20_000, 4, seed=2, scheme="paper", first_contact=17)
    assert np.array_equal(points[:, 0], np.broadcast_to(centroids[17], (20_000, 3)))
    assert np.array_equal(normals[:, 0], np.broadcast_to(facet_normals[17], (20_000, 3)))
    # every other contact is a facet centroid with its normal, facets drawn uniformly
    lookup = {tuple(c): k for k, c in enumerate(centroids)}
    index = np.array([lookup[tuple(p)] for p in points[:, 1:].reshape(-1, 3)])
    assert np.array_equal(facet_normals[index], normals[:, 1:].reshape(-1, 3))
    counts = np.bincount(index, minlength=len(centroids))
    assert abs(counts.mean() - 60_000 / len(centroids)) < 1e-9
    assert counts.std() < 1.5 * np.sqrt(counts.mean())  # Poisson-like spread, not area-weighted
    default = sample_grasps(glass, 10, 4, seed=2, scheme="paper")[0]
    assert np.array_equal(default[:, 0], np.broadcast_to(centroids[default_first_contact(glass, 2)], (10, 3)))


def test_paper_scheme_2d():
    star = objects.star()
    centroids, _ = star.facets()
    points, _ = sample_grasps(star, 100, 3, scheme="paper", first_contact=4)
    assert np.array_equal(points[:, 0], np.broadcast_to(centroids[4], (100, 2)))


@pytest.mark.parametrize("kwargs, message", [
    (dict(num=0), "num must be a positive integer"),
    (dict(num=2.5), "num must be a positive integer"),
    (dict(fingers=1), "fingers must be an integer >= 2"),
    (dict(scheme="grid"), "scheme must be one of"),
    (dict(seed=-1), "seed must be a non-negative integer"),
    (dict(first_contact=3), "scheme='paper' only"),
    (dict(scheme="paper", first_contact=10**9), r"facet index in \[0, "),
])
def test_errors(kwargs, message):
    args = dict(num=10, fingers=3) | kwargs
    with pytest.raises(ValueError, match=message):
        sample_grasps(objects.quad(), args.pop("num"), args.pop("fingers"), **args)


def test_iter_grasps_chunk_error():
    with pytest.raises(ValueError, match="chunk must be a positive integer"):
        iter_grasps(objects.quad(), 10, 3, chunk=0)
