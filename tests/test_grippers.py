"""Parallel-jaw grasps (``grasp_jax.grippers``): contacts by line casting against closed forms,
the statuses and errors, the antipodal sampler, its two soft contacts against the classical
closing-line condition, the command line and held-out YCB meshes."""

from __future__ import annotations


import numpy as np
import pytest
import trimesh

import grasp_jax as gj
from grasp_jax import grippers, objects, storage
from grasp_jax._cones import cone_edges
from grasp_jax.grippers import JawStatus, ParallelJaw

SPHERE = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
BOX = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
#: Largest distance of the icosphere's triangles from the unit sphere (their sagitta), and the
#: largest angle between a face normal and the sphere's normal inside that face.
SAGITTA, FACET_ANGLE = 1.3e-3, 0.05


def _units(rng, k):
    v = rng.normal(size=(k, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _orthogonal(rng, axes):
    a = rng.normal(size=axes.shape)
    a -= np.sum(a * axes, 1, keepdims=True) * axes
    return a / np.linalg.norm(a, axis=1, keepdims=True)


# -------------------------------------------------------------------------------------------------
# Contacts against closed forms


def test_sphere_contacts_are_the_chord_ends(rng):
    k = 200
    centers = 0.6 * rng.uniform(-1, 1, (k, 3)) / np.sqrt(3)
    axes = _units(rng, k)
    res = grippers.jaw_contacts(SPHERE, centers, axes, 3.3)  # |c| + 1 < 1.65
    assert res.status.dtype == np.int8 and (res.status == JawStatus.OK).all()
    # the chord of the unit sphere along each line: c + s u with |c + s u| = 1
    b = np.sum(centers * axes, 1)
    disc = np.sqrt(b * b - np.sum(centers * centers, 1) + 1.0)
    expect = np.stack([centers + (-b - disc)[:, None] * axes, centers + (-b + disc)[:, None] * axes], 1)
    assert np.abs(res.points - expect).max() < 5 * SAGITTA
    radial = expect / np.linalg.norm(expect, axis=-1, keepdims=True)
    assert np.degrees(np.arccos(np.clip(np.sum(res.normals * radial, -1), -1, 1))).max() < np.degrees(FACET_ANGLE)
    assert np.allclose(np.linalg.norm(res.normals, axis=-1), 1.0)
    # on the line, jaw 0 on the -axis side
    rel = res.points - centers[:, None]
    assert np.abs(np.cross(rel, axes[:, None])).max() < 1e-12
    assert (np.sum(rel * axes[:, None], -1)[:, 0] < 0).all()


def _slab(centers, axes, half):
    """Entry and exit of the lines ``c + s u`` through the box ``|x_i| <= half_i``, and the outward
    normals of the faces they cross."""
    with np.errstate(divide="ignore"):
        lo, hi = (-half - centers) / axes, (half - centers) / axes
    t0, t1 = np.minimum(lo, hi), np.maximum(lo, hi)
    enter, leave = t0.max(1), t1.min(1)
    i0, i1 = t0.argmax(1), t1.argmin(1)
    k = np.arange(len(centers))
    n0, n1 = np.zeros_like(centers), np.zeros_like(centers)
    n0[k, i0] = -np.sign(axes[k, i0])
    n1[k, i1] = np.sign(axes[k, i1])
    points = np.stack([centers + enter[:, None] * axes, centers + leave[:, None] * axes], 1)
    return points, np.stack([n0, n1], 1)


def test_box_contacts_are_exact(rng):
    k = 300
    half = np.array([1.0, 0.5, 0.25])
    centers = rng.uniform(-0.8, 0.8, (k, 3)) * half
    axes = _units(rng, k)
    res = grippers.jaw_contacts(BOX, centers, axes, np.full(k, 5.0))
    points, normals = _slab(centers, axes, half)
    assert (res.status == JawStatus.OK).all()
    np.testing.assert_allclose(res.points, points, atol=1e-12)
    np.testing.assert_allclose(res.normals, normals, atol=1e-12)


@pytest.mark.parametrize("name", ["icosphere", "ycb_025_mug.obj"])
def test_ray_hits_are_trimeshs(name, request):
    """``grippers._contacts.ray_hits`` (short pieces of each ray through rtree) finds the hits of
    trimesh's own ``intersects_location(..., multiple_hits=True)`` on slanted rays: the same
    locations on the same rays (an edge tie may name the other of two triangles)."""
    from grasp_jax.grippers._contacts import ray_hits

    if name == "icosphere":
        tm = trimesh.creation.icosphere(subdivisions=3, radius=0.04)
    else:
        tm = objects.load(request.getfixturevalue("mesh_dir") / name).mesh
    r = np.random.default_rng(4)
    lo, hi = tm.bounds
    targets = lo + r.random((500, 3)) * (hi - lo)
    direction = r.normal(size=(500, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    origins = targets - 2 * np.linalg.norm(hi - lo) * direction
    ours = ray_hits(tm, origins, direction)
    theirs = tm.ray.intersects_location(origins, direction, multiple_hits=True)
    key = lambda loc, ray: np.round(np.column_stack([ray, loc]), 9)  # noqa: E731
    a, b = key(ours[0], ours[1]), key(np.asarray(theirs[0]), np.asarray(theirs[1]))
    assert len(a) > 500
    np.testing.assert_allclose(a[np.lexsort(a.T[::-1])], b[np.lexsort(b.T[::-1])], atol=1e-9)


def test_statuses_and_fill_values():
    # open square (two triangles) in the plane z = 0: every line through it meets it once
    square = trimesh.Trimesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], [[0, 1, 2], [0, 2, 3]])
    centers = np.array([[0.0, 0, 0], [0, 0, 5], [0, 0, 0], [3, 0, 0], [0.0, 0.0, 0.0]])
    axes = np.array([[1.0, 0, 0], [1, 0, 0], [1, 0, 0], [1, 0, 0], [0, 0, 1]])
    widths = np.array([2.4, 2.4, 1.0, 2.0, 1.0])
    res = grippers.jaw_contacts(BOX, centers[:4], axes[:4], widths[:4])
    assert res.status.tolist() == [JawStatus.OK, JawStatus.MISSED, JawStatus.TOO_WIDE, JawStatus.MISSED]
    # no contacts: the open jaws and the normals of an ideal antipodal pair, never NaN
    for i in (1, 2, 3):
        np.testing.assert_allclose(res.points[i], [centers[i] - widths[i] / 2 * axes[i], centers[i] + widths[i] / 2 * axes[i]])
        np.testing.assert_allclose(res.normals[i], [-axes[i], axes[i]])
    assert np.isfinite(res.points).all() and np.isfinite(res.normals).all()
    once = grippers.jaw_contacts(square, centers[4:], axes[4:], widths[4:])
    assert once.status.tolist() == [JawStatus.MISSED]
    # contacts 2 apart, closer than the gripper's smallest opening
    narrow = grippers.jaw_contacts(BOX, centers[:1], axes[:1], 2.4, gripper=ParallelJaw(3.0, min_width=2.1))
    assert narrow.status.tolist() == [JawStatus.TOO_NARROW]
    assert all(JawStatus(s).message for s in JawStatus)


def test_bad_inputs_raise_one_clear_error():
    c, u = np.zeros((1, 3)), np.array([[1.0, 0, 0]])
    cases = [
        (dict(widths=[0.0]), "widths must be finite and > 0"),
        (dict(widths=[-1.0]), "widths must be finite and > 0"),
        (dict(widths=[np.nan]), "widths must be finite and > 0"),
        (dict(axes=[[0.0, 0, 0]]), "axes must be non-zero"),
        (dict(centers=np.zeros(3)), "centers must have shape"),
        (dict(axes=np.ones((2, 3))), "axes must have shape"),
        (dict(widths=[1.0, 2.0]), "widths must have shape"),
        (dict(approaches=[[1.0, 0.1, 0]]), "orthogonal"),
        (dict(gripper=ParallelJaw(1.0)), "at most the gripper's max_width"),
        (dict(collision=True), "collision=True needs a gripper"),
        (dict(collision=True, gripper=ParallelJaw.scaled(3.0)), "needs the approaches"),
    ]
    for change, message in cases:
        kwargs = dict(centers=c, axes=u, widths=[2.5]) | change
        with pytest.raises(ValueError, match=message):
            grippers.jaw_contacts(BOX, kwargs.pop("centers"), kwargs.pop("axes"), kwargs.pop("widths"), **kwargs)
    with pytest.raises(ValueError, match="grasp_jax.objects.Mesh or a trimesh"):
        grippers.jaw_contacts("box", c, u, 1.0)
    for kwargs, message in [(dict(max_width=0.0), "max_width must be > 0"),
                            (dict(max_width=1.0, min_width=1.0), "min_width must be in"),
                            (dict(max_width=1.0, finger_size=(1, 0, 1)), "finger_size must be three"),
                            (dict(max_width=1.0, palm_size=(1, 1, 1)), "needs a finger_size"),
                            (dict(max_width=1.0, finger_size=(1, 1, 1), tip_depth=2.0), "tip_depth")]:
        with pytest.raises(ValueError, match=message):
            ParallelJaw(**kwargs)
    with pytest.raises(ValueError, match="num must be"):
        grippers.antipodal_grasps(BOX, 0, mu=0.5, gripper=ParallelJaw(3.0))
    with pytest.raises(ValueError, match="mu must be"):
        grippers.antipodal_grasps(BOX, 5, mu=-1.0, gripper=ParallelJaw(3.0))


# -------------------------------------------------------------------------------------------------
# Collision body


def test_collision_check_against_the_palm():
    pytest.importorskip("fcl")
    ball = trimesh.creation.icosphere(3, radius=0.03)
    g = ParallelJaw.scaled(0.085)
    centers = np.array([[0.0, 0, 0], [0, 0, 0.02], [0, 0, 0.02]])
    axes = np.tile([1.0, 0, 0], (3, 1))
    approaches = np.array([[0.0, 0, 1], [0, 0, 1], [0, 0, -1]])
    res = grippers.jaw_contacts(ball, centers, axes, 0.07, approaches=approaches, gripper=g, collision=True)
    # line through the centre: the palm's front face is 0.038 behind it, the ball's radius 0.03;
    # 0.02 above the centre, approaching downwards, the palm is at z = -0.029: inside the ball
    assert res.status.tolist() == [JawStatus.OK, JawStatus.COLLISION, JawStatus.OK]
    extents, transforms = grippers.gripper_boxes(g, centers, axes, approaches, np.full(3, 0.07))
    assert extents.shape == (3, 3) and transforms.shape == (3, 3, 4, 4)
    np.testing.assert_allclose(transforms[0, :2, 0, 3], [-(0.035 + g.finger_size[0] / 2), 0.035 + g.finger_size[0] / 2])


def test_collision_without_fcl_names_the_package(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "fcl", None)
    with pytest.raises(ModuleNotFoundError, match="python-fcl"):
        grippers.jaw_contacts(BOX, np.zeros((1, 3)), [[1.0, 0, 0]], 2.5, approaches=[[0, 0, 1.0]],
                              gripper=ParallelJaw.scaled(3.0), collision=True)


# -------------------------------------------------------------------------------------------------
# The antipodal sampler


def test_antipodal_sampler_is_consistent_and_seeded():
    g = ParallelJaw(2.5)
    a = grippers.antipodal_grasps(SPHERE, 500, mu=0.5, gripper=g, seed=3)
    assert len(a) == 500 and (a.status == JawStatus.OK).all()
    assert np.abs(np.sum(a.approaches * a.axes, 1)).max() < 1e-12
    np.testing.assert_allclose(np.linalg.norm(a.approaches, axis=1), 1.0)
    assert (a.widths <= g.max_width).all()
    # the closing direction lies in the inward friction cone of contact 0 (circular, half-angle atan mu)
    cos = np.sum(a.axes * -a.normals[:, 0], 1)
    assert (np.arccos(np.clip(cos, -1, 1)) <= np.arctan(0.5) + FACET_ANGLE).all()
    again = grippers.jaw_contacts(SPHERE, a.centers, a.axes, a.widths, approaches=a.approaches, gripper=g)
    assert (again.status == a.status).all()
    np.testing.assert_allclose(again.points, a.points, atol=1e-12)
    chunks = list(grippers.iter_antipodal_grasps(SPHERE, 500, mu=0.5, gripper=g, seed=3, chunk=77))
    for got, want in zip(grippers.AntipodalGrasps(*(np.concatenate(f) for f in zip(*chunks))), a):
        np.testing.assert_array_equal(got, want)
    other = grippers.antipodal_grasps(SPHERE, 500, mu=0.5, gripper=g, seed=4)
    assert not np.allclose(other.points, a.points)


def test_too_wide_and_narrow_candidates_keep_a_status():
    # the box is 0.5 thick, 1 deep and 2 long: with a 0.8 opening only the thin side fits
    a = grippers.antipodal_grasps(BOX, 400, mu=0.3, gripper=ParallelJaw(0.8, min_width=0.3), seed=0)
    counts = np.bincount(a.status, minlength=len(JawStatus))
    assert counts[JawStatus.OK] > 0 and counts[JawStatus.TOO_WIDE] > 0
    ok = a.status == JawStatus.OK
    gap = np.linalg.norm(a.points[ok, 1] - a.points[ok, 0], axis=1)
    assert (gap >= 0.3).all() and (gap <= 0.8).all()
    narrow = a.status == JawStatus.TOO_NARROW  # lines that cut a corner off
    assert (np.linalg.norm(a.points[narrow, 1] - a.points[narrow, 0], axis=1) < 0.3).all()


def _pyramid_margin(points, normals, mu, num_edges):
    """Per contact of each pair, how far the closing line is inside the linearized pyramid (the
    smallest of its face inequalities; > 0 inside), and the smallest ``mu`` with it inside."""
    d = points[:, 1] - points[:, 0]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    directions = np.stack([d, -d], 1)  # from each contact towards the other
    margin, need = np.empty(points.shape[:2]), np.empty(points.shape[:2])
    for i in range(len(points)):
        unit_edges = np.asarray(cone_edges(normals[i], 1.0, num_edges)) + normals[i][:, None]  # (2, m, 3) tangential
        for j in range(2):
            z = -normals[i, j]
            along = directions[i, j] @ z
            if along <= 0:
                margin[i, j], need[i, j] = -1.0, np.inf
                continue
            w = directions[i, j] / along - z  # tangential offset of the line at unit height
            faces = unit_edges[j] + np.roll(unit_edges[j], -1, axis=0)
            faces /= np.linalg.norm(faces, axis=1, keepdims=True)
            reach = np.max(faces @ w) / np.cos(np.pi / num_edges)
            need[i, j] = reach
            margin[i, j] = (mu - reach) * np.cos(np.pi / num_edges)
    return margin.min(1), need.max(1)


# only FOUND rows are compared (a pair antipodal to round-off has mu* -> 0, found below 4e-9)
@pytest.mark.parametrize("mesh", [SPHERE, BOX], ids=["sphere", "box"])
def test_two_soft_contacts_follow_the_closing_line_condition(mesh):
    mu, m = 0.4, 8
    a = grippers.antipodal_grasps(mesh, 600, mu=0.6, gripper=ParallelJaw(2.5), seed=11)
    ok = a.status == JawStatus.OK
    points, normals = a.points[ok], a.normals[ok]
    margin, need = _pyramid_margin(points, normals, mu, m)
    # the pairs are about 1 long; a torsion moves the boundary by at most 0.33 torsion / length
    torsion = 1e-4
    clear = np.abs(margin) > 3e-3
    scores = grippers.score_grasps(points, normals, np.zeros(len(points), np.int8), mu=mu, torsion=torsion,
                                   num_edges=m)
    assert clear.sum() > 300 and 0 < (margin > 0).mean() < 1
    np.testing.assert_array_equal(scores.force_closure[clear], margin[clear] > 0)
    # critical friction: the smallest mu with the line inside both pyramids
    finite = np.isfinite(need) & (need < 4.0) & (scores.critical_status == gj.FrictionStatus.FOUND)
    assert finite.sum() > 300
    np.testing.assert_allclose(scores.critical_mu[finite], need[finite], rtol=2e-3)


def test_failed_jaws_score_nothing():
    points = np.array([[[-1.0, 0, 0], [0.98, 0.2, 0]]] * 3)
    normals = points / np.linalg.norm(points, axis=-1, keepdims=True)
    status = np.array([JawStatus.OK, JawStatus.MISSED, JawStatus.COLLISION], np.int8)
    s = grippers.score_grasps(points, normals, status, mu=0.5, torsion=0.01)
    assert s.force_closure.tolist() == [True, False, False]
    assert s.quality[0] > 0 and s.quality[1:].tolist() == [0.0, 0.0]
    assert np.isfinite(s.critical_mu[0]) and np.isinf(s.critical_mu[1:]).all()
    assert (s.critical_status[1:] == gj.FrictionStatus.ABOVE_CAP).all()
    with pytest.raises(ValueError, match=r"shape \(k, 2, 3\)"):
        grippers.score_grasps(points[:, :1], normals[:, :1], status, mu=0.5, torsion=0.01)


def test_the_page_draws_the_jaws():
    from grasp_jax import interactive

    a = grippers.antipodal_grasps(SPHERE, 3, mu=0.5, gripper=ParallelJaw(2.5), seed=0)
    cols = {k: v for k, v in a.columns().items() if k not in ("points", "normals")}
    shown = interactive.ShownGrasps(np.arange(3), a.points, a.normals, cols, num=3)
    vertices, faces = interactive._jaw_meshes(shown, ParallelJaw(2.5).to_dict())
    assert vertices.shape == (3, 24, 3) and faces.shape == (36, 3)
    inner = np.sum((vertices[:, :8] - a.centers[:, None]) * a.axes[:, None], -1).max(1)  # finger 0's box
    np.testing.assert_allclose(inner, -a.widths / 2)


# -------------------------------------------------------------------------------------------------
# The command line


def test_cli_sample_parallel_jaw_writes_the_columns(in_process, tmp_path, capsys):
    rc = in_process(["sample", "sphere", "--gripper", "parallel-jaw", "--max-width", "0.1", "--num", "300",
                     "--mu", "0.5", "--out", "jaw.parquet", "-q"])
    assert rc == 0, capsys.readouterr().err
    arrays, meta = storage.read_results(tmp_path / "jaw.parquet")
    for name, shape in [("points", (2, 3)), ("normals", (2, 3)), ("center", (3,)), ("axis", (3,)),
                        ("approach", (3,)), ("width", ()), ("jaw_status", ()), ("force_closure", ()),
                        ("quality", ())]:
        assert arrays[name].shape == (300,) + shape, name
    assert arrays["jaw_status"].dtype == np.int8
    assert meta["gripper"]["max_width"] == 0.1 and meta["contact"] == "soft" and meta["scheme"] == "antipodal"
    assert arrays["force_closure"].any()
    failed = arrays["jaw_status"] != JawStatus.OK
    assert not arrays["force_closure"][failed].any() and (arrays["quality"][failed] == 0).all()
    # the critical friction, on by default with a gripper: failed jaws need infinite friction, and a
    # grasp holds at the run's mu exactly when it needs less (where clear of it)
    assert np.isinf(arrays["critical_mu"][failed]).all()
    assert (arrays["critical_status"][failed] == gj.FrictionStatus.ABOVE_CAP).all()
    mu_star = arrays["critical_mu"]
    clear = np.abs(mu_star - 0.5) > 1e-4
    np.testing.assert_array_equal(arrays["force_closure"][clear], mu_star[clear] < 0.5)
    np.testing.assert_array_equal(arrays["friction_label"], gj.friction_label(mu_star))
    # the file's poses give its contacts again
    again = grippers.jaw_contacts(objects.load("sphere").mesh, arrays["center"], arrays["axis"], arrays["width"])
    assert (again.status == arrays["jaw_status"]).all()
    np.testing.assert_allclose(again.points, arrays["points"], atol=1e-12)
    assert in_process(["show", "jaw.parquet", "--html", "jaw.html", "--top", "2"]) == 0
    assert "gripper" in (tmp_path / "jaw.html").read_text()


def test_cli_failing_run_writes_no_file(in_process, tmp_path, monkeypatch, capsys):
    from grasp_jax.grippers import _antipodal

    real = _antipodal.column_chunks

    def broken(*args, **kwargs):
        for i, chunk in enumerate(real(*args, **kwargs)):
            if i == 1:
                raise ValueError("disk on fire")
            yield chunk

    monkeypatch.setattr(_antipodal, "column_chunks", broken)
    rc = in_process(["sample", "sphere", "--gripper", "parallel-jaw", "--max-width", "0.1", "--num", "300",
                     "--chunk", "100", "--out", "jaw.npz", "-q"])
    assert rc == 2 and "disk on fire" in capsys.readouterr().err
    rc = in_process(["sample", "sphere", "--gripper", "parallel-jaw", "--num", "10", "--out", "bad.npz"])
    assert rc == 2 and "--max-width" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


# -------------------------------------------------------------------------------------------------
# Held out: real scans


@pytest.mark.parametrize("name", ["ycb_006_mustard_bottle", "ycb_025_mug"])
def test_held_out_ycb(mesh_dir, name):
    path = mesh_dir / f"{name}.obj"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    obj = objects.load(path)
    g = ParallelJaw(0.085)
    a = grippers.antipodal_grasps(obj, 400, mu=0.5, gripper=g, seed=5)
    ok = a.status == JawStatus.OK
    assert ok.sum() > 100
    # each contact is on its line, inside the opening, entering the object the way its jaw moves
    rel = a.points[ok] - a.centers[ok][:, None]
    s = np.sum(rel * a.axes[ok][:, None], -1)
    assert np.abs(rel - s[..., None] * a.axes[ok][:, None]).max() < 1e-9
    assert (s[:, 0] < s[:, 1]).all() and (np.abs(s) <= a.widths[ok][:, None] / 2).all()
    assert (np.sum(a.normals[ok, 0] * a.axes[ok], 1) < 0).all() and (np.sum(a.normals[ok, 1] * a.axes[ok], 1) > 0).all()
    again = grippers.jaw_contacts(obj, a.centers, a.axes, a.widths, gripper=g)
    assert (again.status == a.status).all()
    margin, _ = _pyramid_margin(a.points[ok], a.normals[ok], 0.5, 8)
    clear = np.abs(margin) > 3e-3
    scores = grippers.score_grasps(a.points[ok], a.normals[ok], a.status[ok], mu=0.5, torsion=5e-6, critical=False)
    np.testing.assert_array_equal(scores.force_closure[clear], margin[clear] > 0)
