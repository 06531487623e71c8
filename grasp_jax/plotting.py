"""Figures of grasps and of their central axes: the names of :mod:`grasp_jax.viz`, where they live."""

from .viz import *  # noqa: F403
from .viz import __all__ as __all__  # noqa: F401
