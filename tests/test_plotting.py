"""grasp_jax.plotting: every figure is written, and central-axis maps tell force-closure apart."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import trimesh  # noqa: E402

from grasp_jax import plotting, reference  # noqa: E402

MU_10 = float(np.tan(np.radians(10.0)))
MU_20 = float(np.tan(np.radians(20.0)))

# A quadrilateral (counter-clockwise) with a triangular hole.
QUAD = np.array([[0.0, 0.0], [2.0, 0.0], [2.5, 1.5], [0.3, 2.0]])
HOLE = np.array([[0.8, 0.6], [1.4, 0.6], [1.2, 1.1]])


def _on_edge(k: int, t: float):
    a, b = QUAD[k], QUAD[(k + 1) % len(QUAD)]
    d = b - a
    return a + t * d, np.array([d[1], -d[0]]) / np.linalg.norm(d)


def _grasp_2d(spec):
    points, normals = zip(*(_on_edge(k, t) for k, t in spec))
    return np.array(points), np.array(normals)


TWO_FINGER = _grasp_2d([(0, 0.5), (2, 0.5)])  # not force-closure: the edges are not parallel
FOUR_FINGER = _grasp_2d([(0, 0.3), (1, 0.5), (2, 0.5), (3, 0.5)])  # force-closure

# Four contacts on the faces of a box, and three on its top face (not force-closure: no downward push).
BOX = trimesh.creation.box(extents=(2.0, 1.2, 0.8))
BOX_FC = (np.array([[1.0, 0.1, 0.0], [-1.0, -0.1, 0.1], [0.2, 0.6, 0.0], [-0.1, -0.6, -0.1]]),
          np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0]]))
BOX_TOP = (np.array([[0.5, 0.2, 0.4], [-0.5, 0.3, 0.4], [0.0, -0.4, 0.4]]),
           np.array([[0.0, 0.0, 1.0]] * 3))


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


def _png(path):
    assert path.is_file() and path.stat().st_size > 1000
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_labels_of_the_fixtures():
    # the classical definition (min-weight LP by HiGHS): l* > 0 iff force-closure
    assert reference.min_weight_highs(*TWO_FINGER, MU_10) <= 1e-9
    assert reference.min_weight_highs(*FOUR_FINGER, MU_10) > 1e-3
    assert reference.min_weight_highs(*BOX_FC, MU_20, 6) > 1e-3
    assert reference.min_weight_highs(*BOX_TOP, MU_20, 6) <= 1e-9


def test_plot_grasp_2d_with_hole(tmp_path):
    path = tmp_path / "g2.png"
    fig = plotting.plot_grasp_2d([QUAD, HOLE], *FOUR_FINGER, mu=MU_20, quality=0.5, path=path)
    assert isinstance(fig, matplotlib.figure.Figure)
    _png(path)
    # a single vertex array and drawing into given axes work too
    fig, ax = plt.subplots()
    assert plotting.plot_grasp_2d(QUAD, *TWO_FINGER, mu=MU_20, ax=ax) is fig


def test_plot_grasp_3d_decimates(tmp_path):
    sphere = trimesh.creation.icosphere(subdivisions=5)  # 20480 faces
    v, f = plotting.decimate(sphere.vertices, sphere.faces, 3000)
    assert 0 < len(f) <= 3000 and f.max() < len(v)
    points = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    path = tmp_path / "g3.png"
    plotting.plot_grasp_3d(sphere, points, points, mu=MU_20, quality=0.3, path=path, max_faces=3000)
    _png(path)
    path = tmp_path / "g3b.png"
    plotting.plot_grasp_3d((BOX.vertices, BOX.faces), *BOX_FC, mu=MU_20, num_edges=6, path=path)
    _png(path)


def test_central_axes_2d_shapes_and_range():
    t1, t2 = plotting.central_axes_2d(*FOUR_FINGER, mu=MU_10, samples=3000, seed=1)
    assert t1.shape == t2.shape and t1.ndim == 1 and 0.8 * 3000 < len(t1) <= 3000
    assert np.all(t1 <= t2) and t1.min() >= 0 and t2.max() < 2 * np.pi
    # the same seed gives the same axes
    s1, _ = plotting.central_axes_2d(*FOUR_FINGER, mu=MU_10, samples=3000, seed=1)
    np.testing.assert_array_equal(t1, s1)


def test_force_closure_covers_more_of_the_dual_plane():
    cover = {}
    for name, grasp in (("two", TWO_FINGER), ("four", FOUR_FINGER)):
        t1, t2 = plotting.central_axes_2d(*grasp, mu=MU_10, samples=5000)
        reach = plotting.reachable_axes_2d(*grasp, mu=MU_10, bins=24)
        upper = np.triu(np.ones((24, 24), bool))
        cover[name] = plotting.dual_plane_coverage(t1, t2, bins=24), reach[upper].mean()
    assert cover["four"][0] > cover["two"][0] + 0.05
    assert cover["four"][1] == 1.0  # force-closure: every line is a central axis
    assert cover["two"][1] < 0.9


def test_central_axes_3d_shapes_and_coverage():
    entry, exit_ = plotting.central_axes_3d(*BOX_FC, mu=MU_20, num_edges=6, samples=3000)
    assert entry.shape == exit_.shape and entry.shape[1] == 3 and 0 < len(entry) <= 3000
    np.testing.assert_allclose(np.linalg.norm(entry, axis=1), 1.0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(exit_, axis=1), 1.0, atol=1e-9)
    reach_fc = plotting.reachable_axes_3d(*BOX_FC, mu=MU_20, num_edges=6, bands=2)
    reach_top = plotting.reachable_axes_3d(*BOX_TOP, mu=MU_20, num_edges=6, bands=2)
    off = ~np.eye(len(reach_fc), dtype=bool)
    assert reach_fc[off].all()
    assert reach_top[off].mean() < 0.8
    e2, x2 = plotting.central_axes_3d(*BOX_TOP, mu=MU_20, num_edges=6, samples=3000)
    # the top grasp only pushes down: every axis is directed downwards
    assert np.all(x2[:, 2] <= e2[:, 2] + 1e-12)
    assert plotting.sphere_coverage(entry, exit_) > plotting.sphere_coverage(e2, x2)


def test_plot_central_axes(tmp_path):
    p2 = tmp_path / "ca2.png"
    plotting.plot_central_axes_2d(*FOUR_FINGER, mu=MU_10, samples=2000, bins=16, path=p2, title="4 fingers")
    _png(p2)
    p3 = tmp_path / "ca3.png"
    fig = plotting.plot_central_axes_3d(*BOX_TOP, mu=MU_20, num_edges=6, samples=2000, bands=2, path=p3)
    assert len(fig.axes) == 3
    _png(p3)


def test_bad_input():
    with pytest.raises(ValueError, match="one grasp"):
        plotting.central_axes_2d(np.zeros((2, 3, 2)), np.ones((2, 3, 2)), mu=0.3)
    with pytest.raises(ValueError, match="2D grasp"):
        plotting.plot_grasp_2d(QUAD, *BOX_FC, mu=0.3)
    with pytest.raises(ValueError, match="concentration"):
        plotting.central_axes_2d(*TWO_FINGER, mu=0.3, concentration=-1.0)
