"""Robust labels of parallel-jaw grasps (grasp_jax.grippers.robust_jaws): the closing line cast again
under noise. Zero noise is the nominal jaw verdict and Q bit for bit (margins to rounding); a translation along the closing
axis keeps an antipodal grasp until a jaw starts inside the object (free contacts do not see it); a
translation larger than the object misses; a brute-force loop over the same draws (jaw_contacts one
draw at a time, then gj.evaluate) gives the same labels; reproducibility and batch independence;
bad input; the command line writes the columns (sample, then score).

Every grasp has two soft contacts and 8 cone edges: one compiled program of each kind."""

from __future__ import annotations


import jax
import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

import grasp_jax as gj
from grasp_jax import _noise, grippers, storage
from grasp_jax.grippers import JawStatus, ParallelJaw

MU = 0.5
TORSION = gj.patch_torsion(0.05, MU)
SOFT = dict(contact="soft", torsion=TORSION)
SPHERE = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
BOX = trimesh.creation.box(extents=(2.0, 1.0, 0.5))
GRIPPER = ParallelJaw(3.0)


@pytest.fixture(scope="module")
def sphere_grasps():
    """Antipodal candidates of the sphere (some whose jaws fail), and a few by hand that miss."""
    g = grippers.antipodal_grasps(SPHERE, 200, mu=MU, gripper=GRIPPER, seed=0)
    centers = np.concatenate([g.centers, [[0.0, 5.0, 0.0], [0.0, 0.0, 0.0]]])
    axes = np.concatenate([g.axes, [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]])
    widths = np.concatenate([g.widths, [2.5, 1.0]])  # the line misses; the sphere is wider than the jaws
    return centers, axes, widths


def _nominal(mesh, centers, axes, widths, gripper=None):
    """jaw_contacts + gj.evaluate with score_grasps' rule: failed jaws are not force-closure, Q 0."""
    jc = grippers.jaw_contacts(mesh, centers, axes, widths, gripper=gripper)
    ev = gj.evaluate(jc.points, jc.normals, mu=MU, **SOFT)
    ok = jc.status == JawStatus.OK
    return jc, np.asarray(ev.force_closure) & ok, np.where(ok, np.asarray(ev.quality), 0.0)


def test_zero_noise_is_the_nominal_jaw_verdict(sphere_grasps):
    centers, axes, widths = sphere_grasps
    res = grippers.robust_jaws(SPHERE, centers, axes, widths, mu=MU, noise=gj.Noise(), key=0, samples=3,
                               gripper=GRIPPER, **SOFT)
    jc, fc, q = _nominal(SPHERE, centers, axes, widths, GRIPPER)
    assert 0 < fc.sum() < len(fc) and (jc.status != JawStatus.OK).sum() >= 2
    assert jc.status[-2] == JawStatus.MISSED and jc.status[-1] == JawStatus.TOO_WIDE
    np.testing.assert_array_equal(res.p_fc, fc.astype(float))
    np.testing.assert_array_equal(res.q_mean, q)
    np.testing.assert_array_equal(res.q_low, q)
    np.testing.assert_array_equal(res.p_fc_se, 0.0)
    np.testing.assert_array_equal(res.q_mean_se, 0.0)
    center, radius = grippers._robust._center_radius(SPHERE, SPHERE)  # the margin's origin and length
    margin = np.asarray(gj.min_weight(jc.points, jc.normals, mu=MU, origin=center, torque_scale=radius, **SOFT))
    # the margins come from two compiled programs (friction per contact, a scalar) that may round an
    # ulp apart on some CPUs (as in test_robust.py): equal to rounding
    np.testing.assert_allclose(res.margin_mean, np.where(jc.status == JawStatus.OK, np.maximum(margin, 0.0), 0.0),
                               rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(res.margin_low, res.margin_mean)
    assert res.unconverged.sum() == 0 and res.samples == 3 and len(res) == len(centers)
    # noise that moves no contact: the nominal contacts, their normals tilted
    tilted = grippers.robust_jaws(SPHERE, centers, axes, widths, mu=MU, noise=gj.Noise(normal=0.02), key=0,
                                  samples=4, margin=False, **SOFT)
    assert np.all(tilted.p_fc[jc.status != JawStatus.OK] == 0) and 0 < tilted.p_fc.mean() < 1


def _along_axis(monkeypatch):
    """The draws of every key with translations along x only (a pure shift along a closing axis x)."""
    real = _noise.draws

    def along(*args, **kwargs):
        d = real(*args, **kwargs)
        t = d.translation.copy()
        t[:, 1:] = 0.0
        return d._replace(translation=t)

    monkeypatch.setattr(_noise, "draws", along)


@pytest.mark.parametrize("mesh", [SPHERE, BOX], ids=["sphere", "box"])
def test_a_shift_along_the_closing_axis_is_recast(monkeypatch, mesh):
    """Antipodal grasps on the x axis under shifts of the object along x: the jaws close on the same
    two points (Q the nominal one) while both start outside the object; past the clearance a jaw
    starts inside it (TOO_WIDE) and the draw fails. Free contacts, moved to the nearest surface
    point, hold at every shift."""
    _along_axis(monkeypatch)
    width = 2.6
    centers = np.array([[0.0, 0.0, 0.0], [0.05, 0.1, 0.05]])
    axes = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    _, radius = grippers._robust._center_radius(mesh, mesh)
    sigma = 0.25 / radius  # shifts of 0.25: some past the clearance (0.3 and less)
    noise = gj.Noise(translation=sigma)
    key = jax.random.key(4)
    res = grippers.robust_jaws(mesh, centers, axes, width, mu=MU, noise=noise, key=key, samples=32, **SOFT)
    jc, fc, q = _nominal(mesh, centers, axes, width)
    assert fc.all()
    # where the surface meets each line (s along the axis from the centre), and where it is after a
    # shift d of the object along x: both jaws (at -/+ width / 2) must start outside it
    s = np.einsum("gki,gi->gk", jc.points - centers[:, None], axes)
    d = sigma * radius * _noise.draws(key, 32, 2, 3).translation[:, 0]
    along = d[None] * axes[:, :1]  # (grasps, samples)
    outside = (s[:, :1] + along > -width / 2) & (s[:, 1:] + along < width / 2)
    assert (0.5 < outside.mean(axis=1)).all() and (outside.mean(axis=1) < 1).all()  # both kinds of draws
    np.testing.assert_array_equal(res.p_fc, outside.mean(axis=1))
    np.testing.assert_allclose(res.q_mean, q * outside.mean(axis=1), rtol=1e-9)
    # the same contacts as free contacts under the same draws: force-closure at every shift
    if mesh is SPHERE:
        from grasp_jax import objects

        free = gj.robust(objects.Mesh.from_trimesh(mesh), jc.points, jc.normals, mu=MU, noise=noise, key=key,
                         samples=32, margin=False, **SOFT)
        np.testing.assert_array_equal(free.p_fc, 1.0)


def test_a_translation_larger_than_the_object_misses(sphere_grasps):
    centers, axes, widths = sphere_grasps
    res = grippers.robust_jaws(SPHERE, centers[:40], axes[:40], widths[:40], mu=MU,
                               noise=gj.Noise(translation=1000.0), key=1, samples=8, **SOFT)
    np.testing.assert_array_equal(res.p_fc, 0.0)
    np.testing.assert_array_equal(res.q_mean, 0.0)
    np.testing.assert_array_equal(res.margin_mean, 0.0)
    assert res.unconverged.sum() == 0
    # a batch of lines none of which meets the mesh: all MISSED, their fill contacts the open jaws
    far = grippers.jaw_contacts(SPHERE, centers[:3] + 10.0, axes[:3], widths[:3])
    np.testing.assert_array_equal(far.status, JawStatus.MISSED)
    np.testing.assert_allclose(far.points[:, 1] - far.points[:, 0], widths[:3, None] * axes[:3], atol=1e-12)


def test_equals_a_brute_force_loop_over_the_same_draws():
    """Re-cast with jaw_contacts one draw at a time (the pose composed here with SciPy), tilted
    normals of the same draws (gj.perturb without an object), gj.evaluate."""
    g = grippers.antipodal_grasps(BOX, 8, mu=MU, gripper=GRIPPER, seed=3)
    centers, axes, widths = g.centers, g.axes, g.widths
    samples, key = 12, jax.random.key(9)
    noise = gj.Noise(position=0.05, normal=0.03, friction=(0.8, 0.8), rotation=0.1, translation=0.05)
    res = grippers.robust_jaws(BOX, centers, axes, widths, mu=MU, noise=noise, key=key, samples=samples,
                               gripper=GRIPPER, margin=False, **SOFT)
    radius = float(np.linalg.norm(BOX.vertices, axis=1).max())  # the box's centre is 0
    draw = _noise.draws(key, samples, 2, 3)
    x, y = grippers._antipodal._frame(axes)
    fc = np.zeros((len(centers), samples), bool)
    q = np.zeros((len(centers), samples))
    for s in range(samples):
        R = Rotation.from_rotvec(noise.rotation * draw.rotation[s]).as_matrix()
        step = noise.position * radius * (draw.tangent[s, 0, 0] * x + draw.tangent[s, 0, 1] * y)
        shift = noise.translation * radius * draw.translation[s]
        c = (centers + step - shift) @ R  # the hand in the moved object's frame
        jc = grippers.jaw_contacts(BOX, c, axes @ R, widths, gripper=GRIPPER)
        _, tilted, _ = gj.perturb(None, jc.points, jc.normals, mu=MU, noise=gj.Noise(normal=noise.normal), key=key,
                                  samples=samples)
        ev = gj.evaluate(jc.points, tilted[:, s], mu=MU * 0.8, **SOFT)
        ok = jc.status == JawStatus.OK
        fc[:, s], q[:, s] = np.asarray(ev.force_closure) & ok, np.where(ok, np.asarray(ev.quality), 0.0)
    np.testing.assert_array_equal(res.p_fc, fc.mean(axis=1))
    np.testing.assert_allclose(res.q_mean, q.mean(axis=1), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(res.q_low, np.quantile(q, 0.1, axis=1), rtol=1e-9, atol=1e-12)
    assert 0 < res.p_fc.mean() < 1 and (fc.any(axis=1) != fc.all(axis=1)).any()


def test_reproducible_and_independent_of_the_batch(sphere_grasps):
    centers, axes, widths = (a[:60] for a in sphere_grasps)
    noise = gj.Noise(position=0.03, normal=0.02, friction=(0.7, 1.1), rotation=0.05, translation=0.03)
    call = dict(mu=MU, noise=noise, samples=6, margin=False, **SOFT)
    a = grippers.robust_jaws(SPHERE, centers, axes, widths, key=jax.random.key(5), **call)
    b = grippers.robust_jaws(SPHERE, centers, axes, widths, key=5, **call)  # an integer seed: the same key
    for name in ("p_fc", "q_mean", "q_low", "q_mean_se"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    sub = grippers.robust_jaws(SPHERE, centers[[7, 3]], axes[[7, 3]], widths[[7, 3]], key=5, **call)
    np.testing.assert_array_equal(sub.q_mean, a.q_mean[[7, 3]])
    other = grippers.robust_jaws(SPHERE, centers, axes, widths, key=6, **call)
    assert not np.array_equal(other.q_mean, a.q_mean)


def test_bad_input_raises_one_clear_error(sphere_grasps):
    centers, axes, widths = (a[:5] for a in sphere_grasps)
    call = dict(mu=MU, key=0, **SOFT)
    noise = gj.Noise(translation=0.1)
    with pytest.raises(ValueError, match="Noise.position must be a finite number >= 0"):
        grippers.robust_jaws(SPHERE, centers, axes, widths, noise=gj.Noise(position=-0.01), **call)
    with pytest.raises(TypeError, match="noise must be a grasp_jax.Noise"):
        grippers.robust_jaws(SPHERE, centers, axes, widths, noise={"position": 0.1}, **call)
    with pytest.raises(ValueError, match="samples must be an integer >= 2"):
        grippers.robust_jaws(SPHERE, centers, axes, widths, noise=noise, samples=1, **call)
    with pytest.raises(ValueError, match="needs torsion"):
        grippers.robust_jaws(SPHERE, centers, axes, widths, noise=noise, mu=MU, key=0)
    with pytest.raises(ValueError, match="mu must be a finite number > 0"):
        grippers.robust_jaws(SPHERE, centers, axes, widths, noise=noise, mu=-1.0, key=0, **SOFT)
    with pytest.raises(ValueError, match="widths must be at most the gripper's max_width"):
        grippers.robust_jaws(SPHERE, centers, axes, widths, noise=noise, gripper=ParallelJaw(0.5), **call)
    with pytest.raises(ValueError, match="collision=True needs a gripper with a collision body"):
        grippers.robust_jaws(SPHERE, centers, axes, widths, noise=noise, collision=True, **call)
    with pytest.raises(ValueError, match="key must be"):
        grippers.robust_jaws(SPHERE, centers, axes, widths, noise=noise, mu=MU, key=-1, **SOFT)
    with pytest.raises(ValueError, match="axes must have shape"):
        grippers.robust_jaws(SPHERE, centers, axes[:, :2], widths, noise=noise, **call)


def test_cli_writes_recast_robust_columns(in_process, tmp_path, capsys):
    trimesh.creation.box(extents=(0.06, 0.04, 0.03)).export(tmp_path / "block.stl")
    noise = ["--sigma-pos", "0.02", "--mu-range", "0.8,1.2", "--sigma-pose", "0.05,0.02"]
    # (no critical friction, on by default with a gripper: its columns from the command line are
    # test_grippers.py's test_cli_sample_parallel_jaw_writes_the_columns)
    rc = in_process(["sample", "block.stl", "--gripper", "parallel-jaw", "--max-width", "0.1", "--num", "48",
                     "--mu", "0.5", "--seed", "2", "--robust", "4", *noise, "--no-margin", "--no-critical-friction",
                     "--out", "jaws.parquet", "-q"])
    assert rc == 0, capsys.readouterr().err
    a, meta = storage.read_results(tmp_path / "jaws.parquet")
    for name in ("p_fc", "p_fc_se", "q_mean", "q_mean_se", "q_low", "robust_unconverged"):
        assert a[name].shape == (48,), name
    assert meta["robust"]["jaws"] == "recast" and meta["robust"]["samples"] == 4
    # the labels of gj.grippers.robust_jaws on the file's poses, with the run's settings
    from grasp_jax import objects

    res = grippers.robust_jaws(objects.load(str(tmp_path / "block.stl")), a["center"], a["axis"], a["width"],
                               mu=0.5, key=2, samples=4, gripper=ParallelJaw.from_dict(meta["gripper"]),
                               noise=gj.Noise(position=0.02, friction=(0.8, 1.2), rotation=0.05, translation=0.02),
                               contact="soft", torsion=meta["torsion"], margin=False)
    np.testing.assert_array_equal(a["p_fc"], res.p_fc)
    np.testing.assert_allclose(a["q_mean"], res.q_mean, rtol=1e-9, atol=1e-12)
    assert 0 < a["p_fc"].mean() < 1
    # score the file again: the same labels
    rc = in_process(["score", "jaws.parquet", "--robust", "4", *noise, "--robust-seed", "2", "--no-margin",
                     "--out", "again.parquet", "-q"])
    assert rc == 0, capsys.readouterr().err
    b, meta_b = storage.read_results(tmp_path / "again.parquet")
    for name in ("p_fc", "q_mean", "q_low", "force_closure", "quality"):
        np.testing.assert_array_equal(b[name], a[name], err_msg=name)
    assert meta_b["robust"] == meta["robust"]
