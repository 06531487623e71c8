"""Interactive HTML pages of grasps: the names of :mod:`grasp_jax.viz.pages`, where they live."""

from .reference import balancing_axis as balancing_axis  # noqa: F401
from .viz._grasp_figure import _jaw_meshes as _jaw_meshes  # noqa: F401
from .viz.pages import *  # noqa: F403
from .viz.pages import __all__ as __all__  # noqa: F401
