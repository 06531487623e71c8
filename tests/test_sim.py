"""The MuJoCo check of jaw grasps (grasp_jax.sim): sanity cases on boxes, determinism, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("mujoco")
pytest.importorskip("coacd")

import trimesh  # noqa: E402

from grasp_jax import grippers, sim, storage  # noqa: E402

GRIPPER = grippers.ParallelJaw.scaled(0.1)


@pytest.fixture(scope="module", autouse=True)
def convex_cache(tmp_path_factory):
    with pytest.MonkeyPatch.context() as mp:
        where = tmp_path_factory.mktemp("convex")
        mp.setenv("GRASP_JAX_CONVEX_CACHE", str(where))
        yield where


@pytest.fixture(scope="module")
def box():
    return trimesh.creation.box(extents=(0.05, 0.05, 0.05))


def _poses(centers, axes, approaches, widths):
    k = len(centers)
    return (np.asarray(centers, float).reshape(k, 3), np.broadcast_to(np.asarray(axes, float), (k, 3)),
            np.broadcast_to(np.asarray(approaches, float), (k, 3)),
            np.broadcast_to(np.asarray(widths, float), (k,)))


def test_centred_grasp_holds_and_beside_fails(box):
    c, a, p, w = _poses([[0, 0, 0], [0, 0.09, 0]], [1, 0, 0], [0, 0, 1], 0.07)
    r = sim.simulate_jaws(box, c, a, p, w, gripper=GRIPPER, workers=1)
    assert r.success.tolist() == [True, False]
    assert r.directions[0].all() and not r.directions[1].any()
    assert r.status.tolist() == [sim.SimStatus.OK, sim.SimStatus.NO_CONTACT]
    assert r.status.dtype == np.int8 and r.directions.shape == (2, 6)
    assert np.all(r.displacement[0] < 0.005)


def test_grasp_at_the_edge_of_a_long_face_fails():
    """Jaws on the far edge of a 40 cm bar's face: the load turns the bar about the closing axis."""
    bar = trimesh.creation.box(extents=(0.04, 0.4, 0.04))
    c, a, p, w = _poses([[0, 0, 0], [0, 0.18, 0]], [1, 0, 0], [0, 0, 1], 0.06)
    r = sim.simulate_jaws(bar, c, a, p, w, gripper=GRIPPER, workers=1)
    assert r.success.tolist() == [True, False]
    assert r.status.tolist() == [sim.SimStatus.OK, sim.SimStatus.OK]
    assert not r.directions[1, 4:].any()   # +-z: the bar swings about the closing axis (x)


def test_gripper_inside_the_object_gets_a_status(box):
    c, a, p, w = _poses([[0.03, 0, 0], [0, 0, 0.03]], [1, 0, 0], [0, 0, 1], 0.07)
    r = sim.simulate_jaws(box, c, a, p, w, gripper=GRIPPER, workers=1)
    assert r.status.tolist() == [sim.SimStatus.PENETRATION] * 2   # a jaw inside; the palm inside
    assert not r.success.any() and np.isnan(r.displacement).all()
    assert "inside" in sim.SimStatus(r.status[0]).message


def _random_poses(k, seed=0):
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(k, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    ref = np.where(np.abs(axes[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    approaches = np.cross(axes, ref)
    approaches /= np.linalg.norm(approaches, axis=1, keepdims=True)
    return rng.uniform(-0.01, 0.01, (k, 3)), axes, approaches, np.full(k, 0.095)


def test_same_seed_same_outcome_and_workers_agree(box):
    poses = _random_poses(20)
    protocol = sim.Protocol(pose_noise=0.003)
    one = sim.simulate_jaws(box, *poses, gripper=GRIPPER, protocol=protocol, seed=3, workers=1)
    again = sim.simulate_jaws(box, *poses, gripper=GRIPPER, protocol=protocol, seed=3, workers=1)
    two = sim.simulate_jaws(box, *poses, gripper=GRIPPER, protocol=protocol, seed=3, workers=2, progress=True)
    for a, b in ((one, again), (one, two)):
        for field in sim.SimResult._fields:
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)
    assert 0 < one.success.sum() < len(one)   # the sample has both outcomes


def test_mesh_that_cannot_be_decomposed():
    flat = trimesh.Trimesh(vertices=[[0, 0, 0], [0.05, 0, 0], [0, 0.05, 0]], faces=[[0, 1, 2]])
    c, a, p, w = _poses([[0, 0, 0]], [1, 0, 0], [0, 0, 1], 0.07)
    with pytest.raises(ValueError, match="cannot be decomposed"):
        sim.simulate_jaws(flat, c, a, p, w, gripper=GRIPPER, workers=1)


def test_bad_arguments(box):
    c, a, p, w = _poses([[0, 0, 0]], [1, 0, 0], [0, 0, 1], 0.07)
    with pytest.raises(ValueError, match="orthogonal"):
        sim.simulate_jaws(box, c, a, a, w, gripper=GRIPPER, workers=1)
    with pytest.raises(ValueError, match="max_width"):
        sim.simulate_jaws(box, c, a, p, [0.2], gripper=GRIPPER, workers=1)
    with pytest.raises(ValueError, match="workers"):
        sim.simulate_jaws(box, c, a, p, w, gripper=GRIPPER, workers=0)
    with pytest.raises(ValueError, match="jaw_force"):
        sim.Protocol(jaw_force=-1.0)
    with pytest.raises(ValueError, match="reference"):
        sim.Protocol(reference="end")


def test_decomposition_is_cached(box, convex_cache):
    parts = sim.decompose(box)
    files = list(convex_cache.glob("*.npz"))
    assert files and all(len(v) >= 4 for v, _ in parts)
    again = sim.decompose(box)
    assert [v.tolist() for v, _ in again] == [v.tolist() for v, _ in parts]
    other = sim.decompose(box, sim.Decomposition(threshold=0.2))   # other parameters, other entry
    assert len(list(convex_cache.glob("*.npz"))) == len(files) + 1 and other


@pytest.mark.parametrize("suffix", [".npz", ".parquet"])
def test_add_sim_columns(tmp_path, box, suffix):
    c, a, p, w = _poses([[0, 0, 0], [0, 0.09, 0]], [1, 0, 0], [0, 0, 1], 0.07)
    path = tmp_path / f"jaws{suffix}"
    fields = ("points", "normals", "center", "axis", "approach", "width")
    with storage.open_writer(path, {"gripper": GRIPPER.to_dict()}, fields, fingers=2, dim=3) as out:
        out.write({"points": np.zeros((2, 2, 3)), "normals": np.zeros((2, 2, 3)), "center": c, "axis": a,
                   "approach": p, "width": w})
    sim.add_sim_columns(path, box, workers=1, mesh_name="box")
    arrays, meta = storage.read_results(path)
    assert arrays["sim_success"].tolist() == [True, False]
    assert arrays["sim_status"].tolist() == [0, sim.SimStatus.NO_CONTACT]
    for name in sim.DIRECTION_COLUMNS:
        assert arrays[name].tolist() == [True, False]
    assert meta["gripper"] == GRIPPER.to_dict() and meta["sim"]["object"] == "box"
    np.testing.assert_array_equal(arrays["center"], c)

    bare = tmp_path / f"bare{suffix}"
    with storage.open_writer(bare, {}, ("points", "normals"), fingers=2, dim=3) as out:
        out.write({"points": np.zeros((2, 2, 3)), "normals": np.zeros((2, 2, 3))})
    before = bare.read_bytes()
    with pytest.raises(ValueError, match="center"):
        sim.add_sim_columns(bare, box, workers=1)
    assert bare.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [path.name, bare.name])


# hands -----------------------------------------------------------------------------------------

def _hand():
    hands = pytest.importorskip("grasp_jax.hands")
    return hands.load("default")


def _hand_grasps(hand, positions, quaternions, closing=(0.0, 0.6)):
    """Grasps of the built-in hand: every first joint at ``closing[0]``, every second at
    ``closing[1]`` (pre-grasp: opened), the squeeze 0.3 rad further."""
    from types import SimpleNamespace

    names = hand.joint_names
    grasp = np.array([closing[0] if n.endswith("_j0") else closing[1] for n in names])
    pregrasp = np.where([n.endswith("_j0") for n in names], -0.25, 0.0)
    k = len(positions)
    return SimpleNamespace(position=np.asarray(positions, float), quaternion=np.asarray(quaternions, float),
                           joints=np.tile(grasp, (k, 1)), pregrasp=np.tile(pregrasp, (k, 1)),
                           squeeze=np.tile(grasp + 0.3, (k, 1)))


def test_hand_grasps():
    """The built-in hand closing on a ball above its palm holds it, also with the wrist turned; the
    same grasp with the hand 0.5 m away never touches the ball and fails."""
    hand = _hand()
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.03)
    turn = np.array([np.cos(np.pi / 4), np.sin(np.pi / 4), 0, 0])          # 90 degrees about x
    below = np.array([0, 0, -0.042])
    turned = np.array([0, 0.042, 0])                                        # R_x(90) @ below
    res = _hand_grasps(hand, [below, turned, [0.5, 0, 0]], [[1, 0, 0, 0], turn, [1, 0, 0, 0]])
    r = sim.simulate_hand(hand, ball, res, workers=1)
    assert r.success.tolist() == [True, True, False]
    assert r.status.tolist() == [sim.SimStatus.OK, sim.SimStatus.OK, sim.SimStatus.NO_CONTACT]
    with pytest.raises(ValueError, match="joints"):
        res.joints = res.joints[:, :-1]
        sim.simulate_hand(hand, ball, res, workers=1)


def test_mjcf_hand_grasps_as_its_urdf(tmp_path):
    """The built-in hand written as MJCF (by MuJoCo, a free root joint and a floor added) holds
    and misses the ball as its URDF does."""
    import mujoco

    from grasp_jax.hands._builtin import default_urdf
    from grasp_jax.sim._hands import _with_compiler

    hand = _hand()
    spec = mujoco.MjSpec.from_string(_with_compiler(default_urdf(), "."))
    spec.compile()
    xml = tmp_path / "default.xml"
    text = spec.to_xml()
    # a floating wrist and a floor: the simulation drops both
    text = text.replace("<worldbody>", '<worldbody><geom type="plane" size="1 1 0.1" pos="0 0 -1"/>'
                        '<body name="wrist"><freejoint/>', 1).replace("</worldbody>", "</body></worldbody>", 1)
    xml.write_text(text)
    from grasp_jax import hands

    mj_hand = hands.load(xml)
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.03)
    res = _hand_grasps(mj_hand, [[0, 0, -0.042], [0.5, 0, 0]], [[1, 0, 0, 0], [1, 0, 0, 0]])
    r = sim.simulate_hand(mj_hand, ball, res, workers=1)
    assert r.success.tolist() == [True, False] and set(mj_hand.joint_names) == set(hand.joint_names)


def test_simulate_command_adds_the_columns(tmp_path, box, capsys):
    """``grasp-jax simulate FILE``: the jaw file gains the columns in place (the centred grasp
    holds, the one beside the box does not); a file without jaw or hand columns is one error line."""
    from grasp_jax.cli import main

    mesh_file = tmp_path / "box.stl"
    box.export(mesh_file)
    c, a, p, w = _poses([[0, 0, 0], [0, 0.09, 0]], [1, 0, 0], [0, 0, 1], 0.07)
    points = np.stack([c - 0.025 * a, c + 0.025 * a], axis=1)
    normals = np.stack([-a, a], axis=1)
    meta = storage.metadata(object=str(mesh_file), gripper=GRIPPER.to_dict())
    f = tmp_path / "jaws.npz"
    np.savez(f, points=points, normals=normals, center=c, axis=a, approach=p, width=w,
             metadata=np.array(json.dumps(meta)))
    assert main(["simulate", str(f), "--workers", "1", "-q"]) == 0
    cols = storage.ResultFile(f).read(["sim_success", "sim_status"])
    np.testing.assert_array_equal(cols["sim_success"], [True, False])
    plain = tmp_path / "plain.npz"
    np.savez(plain, points=points, normals=normals, metadata=np.array(json.dumps(meta)))
    assert main(["simulate", str(plain), "-q"]) == 2
    assert "center" in capsys.readouterr().err
