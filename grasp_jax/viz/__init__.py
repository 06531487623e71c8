"""Pictures: matplotlib figures of grasps (``figures``), the central-axis figures of the paper
(``axes``), and interactive HTML pages (``pages``). Nothing here solves an LP; the balancing axis
comes from :func:`grasp_jax.reference.balancing_axis`."""

from ._draw import decimate as decimate
from ._draw import pyplot as pyplot
from .axes import central_axes_2d as central_axes_2d
from .axes import central_axes_3d as central_axes_3d
from .axes import dual_plane_coverage as dual_plane_coverage
from .axes import dual_plane_hits as dual_plane_hits
from .axes import plot_central_axes_2d as plot_central_axes_2d
from .axes import plot_central_axes_3d as plot_central_axes_3d
from .axes import reachable_axes_2d as reachable_axes_2d
from .axes import reachable_axes_3d as reachable_axes_3d
from .axes import sphere_coverage as sphere_coverage
from .axes import sphere_pair_hits as sphere_pair_hits
from .figures import plot_grasp_2d as plot_grasp_2d
from .figures import plot_grasp_3d as plot_grasp_3d
from .figures import plot_optimization as plot_optimization
from .hand_page import hand_page as hand_page
from .hand_page import posed_hand as posed_hand
from .pages import grasp_page as grasp_page
from .pages import html_page as html_page
from .pages import result_page as result_page

__all__ = ["plot_grasp_2d", "plot_grasp_3d", "plot_optimization", "central_axes_2d", "central_axes_3d",
           "plot_central_axes_2d", "plot_central_axes_3d", "dual_plane_coverage", "dual_plane_hits",
           "sphere_coverage", "sphere_pair_hits", "reachable_axes_2d", "reachable_axes_3d", "decimate",
           "html_page", "grasp_page", "result_page", "pyplot", "hand_page", "posed_hand"]
