"""Shared fixtures of the grasp_jax test suite.

Importing grasp_jax turns on JAX's 64-bit mode; it is imported here first so that every test
module runs in float64 unless it asks for float32.
"""

from __future__ import annotations

import os
from pathlib import Path

import hypothesis
import jax
import numpy as np
import pytest

import grasp_jax  # noqa: F401  (enables jax_enable_x64)

assert jax.config.jax_enable_x64, "importing grasp_jax must enable 64-bit mode"

#: ``<repo root>/../shared/data``: the real meshes and polygons shared by the project.
SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"

hypothesis.settings.register_profile(
    "grasp_jax",
    deadline=None,
    max_examples=25,
    derandomize=True,
    suppress_health_check=[hypothesis.HealthCheck.too_slow],
)
# Longer runs: HYPOTHESIS_PROFILE=grasp_jax_long (same examples every run, more of them) or
# grasp_jax_explore (fresh random examples).
hypothesis.settings.register_profile(
    "grasp_jax_long", parent=hypothesis.settings.get_profile("grasp_jax"), max_examples=200
)
hypothesis.settings.register_profile(
    "grasp_jax_explore", parent=hypothesis.settings.get_profile("grasp_jax"), max_examples=200,
    derandomize=False,
)
hypothesis.settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "grasp_jax"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path of the shared data folder; skips the test when it is not there."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data not found at {SHARED_DATA}")
    return SHARED_DATA


@pytest.fixture(scope="session")
def mesh_dir(shared_data) -> Path:
    path = shared_data / "meshes"
    if not path.is_dir():
        pytest.skip(f"shared meshes not found at {path}")
    return path


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded generator, fresh for every test."""
    return np.random.default_rng(20240611)
