"""Shared fixtures of the grasp_jax test suite.

Importing grasp_jax changes no JAX configuration (checked here, on every run, and in a fresh
process by ``test_dtypes.py``). The suite itself then turns on JAX's 64-bit mode, as lineax's does,
so that its comparisons with the float64 references (HiGHS, qhull, finite differences) run in
float64 under ``jit`` and ``grad`` too; ``test_dtypes.py`` checks float32 programs in
subprocesses without it.
"""

from __future__ import annotations

import os
from pathlib import Path

import hypothesis
import jax
import numpy as np
import pytest

_CONFIG_BEFORE = dict(jax.config.values)
import grasp_jax  # noqa: F401

#: Configuration entries that importing grasp_jax changed (must be none).
IMPORT_CHANGED_CONFIG = {
    key: (_CONFIG_BEFORE.get(key), value)
    for key, value in jax.config.values.items()
    if _CONFIG_BEFORE.get(key, object()) != value
}
assert not IMPORT_CHANGED_CONFIG, f"importing grasp_jax changed JAX's configuration: {IMPORT_CHANGED_CONFIG}"

jax.config.update("jax_enable_x64", True)  # the suite's float64 references; see the docstring

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
