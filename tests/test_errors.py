"""Bad input raises ValueError naming the argument, before anything is traced or compiled."""

from __future__ import annotations

import numpy as np
import pytest

import grasp_jax as gj
import grasp_jax._api as api
import grasp_jax._baseline as baseline

P3 = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
N3 = P3.copy()
P2 = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0]])
N2 = P2.copy()


@pytest.fixture(autouse=True)
def no_tracing(monkeypatch):
    """Fail loudly if validation lets bad input reach the batching/compilation stage."""

    def forbidden(*args, **kwargs):
        raise AssertionError("bad input reached map_grasps (tracing) before being rejected")

    monkeypatch.setattr(api, "map_grasps", forbidden)
    monkeypatch.setattr(baseline.reference, "wrenches", forbidden)


def _evaluate(p, n, **kw):
    return gj.evaluate(p, n, **{"mu": 0.5, **kw})


def _force_closure(p, n, **kw):
    return gj.force_closure(p, n, **{"mu": 0.5, **kw})


def _quality(p, n, **kw):
    return gj.quality(p, n, **{"mu": 0.5, **kw})


def _min_weight(p, n, **kw):
    return gj.min_weight(p, n, **{"mu": 0.5, **kw})


def _ferrari_canny(p, n, **kw):
    return gj.ferrari_canny(p, n, **{"mu": 0.5, **kw})


ALL = [_evaluate, _force_closure, _quality, _min_weight, _ferrari_canny]
IDS = ["evaluate", "force_closure", "quality", "min_weight", "ferrari_canny"]


def _with(arr, index, value):
    arr = np.array(arr, dtype=float)
    arr[index] = value
    return arr


BAD_GRASPS = {
    "mismatched shapes": (P3, N3[:2], "normals"),
    "mismatched d": (P3, np.ones((3, 2)), "normals"),
    "points ndim 1": (P3[0], N3[0], "points"),
    "points ndim 0": (np.float64(1.0), np.float64(1.0), "points"),
    "d = 4": (np.ones((3, 4)), np.ones((3, 4)), "points"),
    "d = 1": (np.ones((3, 1)), np.ones((3, 1)), "points"),
    "one contact": (P3[:1], N3[:1], "contacts"),
    "zero contacts": (np.ones((0, 3)), np.ones((0, 3)), "contacts"),
    "nan point": (_with(P3, (1, 2), np.nan), N3, "points"),
    "inf point": (_with(P3, (0, 0), np.inf), N3, "points"),
    "nan normal": (P3, _with(N3, (2, 1), np.nan), "normals"),
    "-inf normal": (P3, _with(N3, (2, 1), -np.inf), "normals"),
    "zero normal": (P3, _with(N3, 1, 0.0), "normals"),
    "zero normal 2d": (P2, _with(N2, 0, 0.0), "normals"),
    "zero normal in batch": (np.stack([P3, P3]), np.stack([N3, _with(N3, 2, 0.0)]), "normals"),
    "nan in batch": (np.stack([P3, _with(P3, (0, 1), np.nan)]), np.stack([N3, N3]), "points"),
    "strings": (np.array([["a", "b", "c"]] * 3), N3, "points"),
    "objects": (np.array([[None, 1, 2]] * 3, dtype=object), N3, "points"),
    "complex": (P3 + 1j, N3, "points"),
}


@pytest.mark.parametrize("func", ALL, ids=IDS)
@pytest.mark.parametrize("case", list(BAD_GRASPS), ids=list(BAD_GRASPS))
def test_bad_grasps(func, case):
    p, n, name = BAD_GRASPS[case]
    with pytest.raises(ValueError, match=name):
        func(p, n)


BAD_MU = [0.0, -0.3, np.nan, np.inf, -np.inf, [0.3, 0.4], np.array([0.5]), "abc", None, 1e-320 * 0]


@pytest.mark.parametrize("func", ALL, ids=IDS)
@pytest.mark.parametrize("mu", BAD_MU, ids=[repr(m) for m in BAD_MU])
def test_bad_mu(func, mu):
    with pytest.raises(ValueError, match="mu"):
        func(P3, N3, mu=mu)


BAD_EDGES = [2, 0, -8, 8.0, 8.5, "8", True, None]


@pytest.mark.parametrize("func", ALL, ids=IDS)
@pytest.mark.parametrize("num_edges", BAD_EDGES, ids=[repr(m) for m in BAD_EDGES])
def test_bad_num_edges(func, num_edges):
    with pytest.raises(ValueError, match="num_edges"):
        func(P3, N3, num_edges=num_edges)


@pytest.mark.parametrize("torque_test", ["Exact", "eq15", "", None, 1])
def test_bad_torque_test(torque_test):
    with pytest.raises(ValueError, match="torque_test"):
        _evaluate(P3, N3, torque_test=torque_test)
    with pytest.raises(ValueError, match="torque_test"):
        _force_closure(P3, N3, torque_test=torque_test)


@pytest.mark.parametrize("func", [_min_weight, _ferrari_canny], ids=["min_weight", "ferrari_canny"])
@pytest.mark.parametrize("origin", [np.zeros(2), np.zeros(4), np.zeros((1, 3)), np.float64(0.0)])
def test_bad_origin(func, origin):
    with pytest.raises(ValueError, match="origin"):
        func(P3, N3, origin=origin)
    with pytest.raises(ValueError, match="origin"):
        func(P2, N2, origin=np.zeros(3))


@pytest.mark.parametrize("func", [_min_weight, _ferrari_canny], ids=["min_weight", "ferrari_canny"])
@pytest.mark.parametrize("torque_scale", [0.0, -1.0, np.nan, np.inf, [1.0, 2.0]])
def test_bad_torque_scale(func, torque_scale):
    with pytest.raises(ValueError, match="torque_scale"):
        func(P3, N3, torque_scale=torque_scale)


BAD_TANGENTS = {
    "2d grasp": (P2, N2, np.ones((3, 3))),
    "2d grasp, 2d tangents": (P2, N2, np.ones((3, 2))),
    "wrong shape": (P3, N3, np.ones((2, 3))),
    "batch shape": (P3, N3, np.ones((2, 3, 3))),
    "nan": (P3, N3, _with(np.ones((3, 3)), (1, 1), np.nan)),
    "inf": (P3, N3, _with(np.ones((3, 3)), (0, 2), np.inf)),
}


@pytest.mark.parametrize("func", ALL, ids=IDS)
@pytest.mark.parametrize("case", list(BAD_TANGENTS), ids=list(BAD_TANGENTS))
def test_bad_tangents(func, case):
    p, n, t = BAD_TANGENTS[case]
    with pytest.raises(ValueError, match="tangents"):
        func(p, n, tangents=t)


@pytest.mark.parametrize("func", ALL, ids=IDS)
@pytest.mark.parametrize("kind", ["zero", "parallel"])
def test_degenerate_tangents(func, kind):
    t = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    t[1] = 0.0 if kind == "zero" else 3.0 * N3[1]
    with pytest.raises(ValueError, match="tangents"):
        func(P3, N3, tangents=t)


@pytest.mark.parametrize("shape", [(), (4,), (2, 5), (3, 7), (6, 2)])
def test_central_axis_bad_shape(shape):
    with pytest.raises(ValueError, match="wrench"):
        gj.central_axis(np.ones(shape))


def test_error_messages_are_specific():
    with pytest.raises(ValueError, match=r"normals must have the same shape as points \(3, 3\)"):
        _evaluate(P3, N3[:2])
    with pytest.raises(ValueError, match=r"d = 4"):
        _quality(np.ones((3, 4)), np.ones((3, 4)))
    with pytest.raises(ValueError, match=r"n = 1"):
        _quality(P3[:1], N3[:1])
    with pytest.raises(ValueError, match=r"index \((np\.int64\()?1\)?,\)"):
        _evaluate(P3, _with(N3, 1, 0.0))
    with pytest.raises(ValueError, match=r"> 0"):
        _evaluate(P3, N3, mu=-1.0)
