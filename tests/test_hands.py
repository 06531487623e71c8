"""grasp_jax.hands: loading, forward kinematics against yourdfpy, candidates, SDF, synthesis."""

from __future__ import annotations

import io
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import yourdfpy

from grasp_jax import hands
from grasp_jax._precision import float64_scope
from grasp_jax.hands._builtin import default_urdf

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
HANDS = {
    "allegro": SHARED / "hands" / "allegro_hand" / "allegro_hand_right.urdf",
    "leap": SHARED / "hands" / "leap_hand" / "leap_hand_right.urdf",
    "barrett": SHARED / "hands" / "barrett_hand" / "bhand_model.urdf",
}
needs_shared = pytest.mark.skipif(not SHARED.is_dir(), reason="../shared/data (the real hands and YCB meshes) is absent")


@pytest.fixture(scope="module")
def default_hand():
    return hands.load("default")


def _random_configs(hand, count, seed):
    rng = np.random.default_rng(seed)
    lo = np.where(np.isfinite(hand.lower), hand.lower, -np.pi)
    hi = np.where(np.isfinite(hand.upper), hand.upper, np.pi)
    joints = rng.uniform(lo, hi, (count, hand.num_joints))
    quat = rng.normal(size=(count, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    pose = np.concatenate([rng.uniform(-0.3, 0.3, (count, 3)), quat], axis=1)
    return pose, joints


def _yourdfpy_frames(urdf, hand, pose, joints):
    """``(N, L, 4, 4)`` world frames by yourdfpy's own forward kinematics and the pose."""
    base = np.asarray(jax.vmap(hands._kinematics.pose_matrix)(jnp.asarray(pose)))
    out = np.empty((len(pose), hand.num_links, 4, 4))
    for k in range(len(pose)):
        urdf.update_cfg(dict(zip(hand.joint_names, joints[k])))
        for i, name in enumerate(hand.link_names):
            out[k, i] = base[k] @ urdf.get_transform(name, hand.link_names[0])
    return out


def _check_against_yourdfpy(hand, urdf, count):
    pose, joints = _random_configs(hand, count, seed=1)
    with float64_scope():
        ours = np.asarray(jax.jit(jax.vmap(hands.forward, in_axes=(None, 0, 0)))(hand, pose, joints))
    theirs = _yourdfpy_frames(urdf, hand, pose, joints)
    # positions to 1e-9 m and rotations to 1e-9, every link
    assert np.abs(ours[..., :3, 3] - theirs[..., :3, 3]).max() < 1e-9
    assert np.abs(ours[..., :3, :3] - theirs[..., :3, :3]).max() < 1e-9


def test_default_hand_against_yourdfpy(default_hand):
    urdf = yourdfpy.URDF.load(io.BytesIO(default_urdf().encode()), load_meshes=False)
    _check_against_yourdfpy(default_hand, urdf, 200)
    assert default_hand.num_fingers == 3 and default_hand.num_joints == 6
    assert hands.builtin().joint_names == default_hand.joint_names


@needs_shared
@pytest.mark.parametrize("name", list(HANDS))
def test_forward_against_yourdfpy(name):
    hand = hands.load(HANDS[name])
    urdf = yourdfpy.URDF.load(str(HANDS[name]), load_meshes=False)
    _check_against_yourdfpy(hand, urdf, 1000)
    assert hand.num_fingers >= 3


def test_forward_gradient_matches_finite_differences(default_hand):
    pose, joints = _random_configs(default_hand, 1, seed=2)
    tip = default_hand.finger_link[0]

    def f(pose, joints):
        frames = hands.forward(default_hand, pose, joints)
        return jnp.sum(frames[tip, :3, 3] * jnp.array([1.0, -2.0, 0.5])) + jnp.sum(frames[tip, :3, 0])

    with float64_scope():
        pose, joints = jnp.asarray(pose[0]), jnp.asarray(joints[0])
        gp, gj = jax.jit(jax.grad(f, argnums=(0, 1)))(pose, joints)  # op by op: 148 programs
        f = jax.jit(f)
        h = 1e-6
        for args, grad in (((0, pose), gp), ((1, joints), gj)):
            which, x = args
            for k in range(len(x)):
                e = jnp.zeros_like(x).at[k].set(h)
                plus = f(*((x + e, joints) if which == 0 else (pose, x + e)))
                minus = f(*((x - e, joints) if which == 0 else (pose, x - e)))
                assert abs((plus - minus) / (2 * h) - grad[k]) < 1e-6


def test_forward_vmap_equals_loop_and_float32(default_hand):
    pose, joints = _random_configs(default_hand, 5, seed=3)
    forward = jax.jit(hands.forward)  # op by op, the loop and the vmap compiled 112 programs
    with float64_scope():
        batched = np.asarray(jax.jit(jax.vmap(hands.forward, in_axes=(None, 0, 0)))(default_hand, pose, joints))
        loop = np.stack([np.asarray(forward(default_hand, p, q)) for p, q in zip(pose, joints)])
    np.testing.assert_allclose(batched, loop, atol=1e-12)
    single = forward(default_hand, pose[0].astype(np.float32), joints[0].astype(np.float32))
    assert single.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(single), loop[0], atol=1e-5)
    with pytest.raises(ValueError, match="pose must have shape"):
        hands.forward(default_hand, pose, joints[0])


def _write(tmp_path, text, name="hand.urdf"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_errors_name_the_file_and_element(tmp_path):
    text = default_urdf()
    missing = text.replace('<sphere radius="0.009"/>', '<mesh filename="meshes/nowhere.obj"/>', 1)
    with pytest.raises(ValueError, match=r"hand\.urdf.*nowhere\.obj.*f0_tip"):
        hands.load(_write(tmp_path, missing))
    floating = text.replace('type="revolute"', 'type="floating"', 1)
    with pytest.raises(ValueError, match=r"hand\.urdf.*'f0_j0'.*'floating'"):
        hands.load(_write(tmp_path, floating))
    bare = '<robot name="r"><link name="a"/><link name="b"/><joint name="j" type="revolute"><parent link="a"/>' \
           '<child link="b"/><axis xyz="0 0 1"/><limit lower="0" upper="1" effort="1" velocity="1"/></joint></robot>'
    with pytest.raises(ValueError, match=r"hand\.urdf.*no fingertip"):
        hands.load(_write(tmp_path, bare))
    with pytest.raises(ValueError, match="not found"):
        hands.load(tmp_path / "absent.urdf")


def test_mimic_joint_follows_its_source(tmp_path, default_hand):
    text = default_urdf().replace('<joint name="f0_j1" type="revolute">',
                                  '<joint name="f0_j1" type="revolute"><mimic joint="f0_j0" multiplier="0.5" offset="0.1"/>')
    hand = hands.load(_write(tmp_path, text))
    assert hand.num_joints == 5 and "f0_j1" not in hand.joint_names
    urdf = yourdfpy.URDF.load(str(tmp_path / "hand.urdf"), load_meshes=False)
    _check_against_yourdfpy(hand, urdf, 20)


# ---------------------------------------------------------------------------------------------
# Candidates, object geometry, energies, synthesis (the default hand and built-in objects).


@pytest.fixture(scope="module")
def glass():
    from grasp_jax import objects

    return objects.load("glass")


def test_candidates_face_the_palm(default_hand):
    with float64_scope():
        frames = np.asarray(hands.forward(default_hand, np.array([0, 0, 0, 1.0, 0, 0, 0]), default_hand.open_joints))
    f, k = default_hand.candidate_point.shape[:2]
    assert f == 3 and k >= 4
    for i, link in enumerate(default_hand.finger_link):
        normals = default_hand.candidate_normal[i] @ frames[link, :3, :3].T
        points = default_hand.candidate_point[i] @ frames[link, :3, :3].T + frames[link, :3, 3]
        inward = -points[:, :2] / np.linalg.norm(points[:, :2], axis=1, keepdims=True)  # towards the palm's axis
        assert (np.sum(normals[:, :2] * inward, axis=1) > 0.3).all()
    moved = default_hand.with_candidates(default_hand.candidate_point[:, :2], default_hand.candidate_normal[:, :2] * 3)
    np.testing.assert_allclose(np.linalg.norm(moved.candidate_normal, axis=-1), 1.0)
    with pytest.raises(ValueError, match=r"\(3, K, 3\)"):
        default_hand.with_candidates(np.zeros((2, 2, 3)), np.ones((2, 2, 3)))


def test_sdf_against_trimesh(glass):
    import trimesh

    geom = hands.geometry(glass)
    assert geom.grid.shape == (48, 48, 48) and geom.points.shape == (64, 3)
    rng = np.random.default_rng(0)
    x = glass.center + rng.uniform(-1.2, 1.2, (400, 3)) * glass.radius
    with float64_scope():
        ours = np.asarray(jax.jit(jax.vmap(lambda p: hands._sdf.distance(geom, p)))(x))  # op by op: 38 programs
    exact = -trimesh.proximity.signed_distance(glass.mesh, x)
    near = np.abs(exact) < 0.1 * glass.radius
    assert np.abs(ours - exact)[near].max() < 0.5 * float(geom.cell)
    assert (np.sign(ours) == np.sign(exact))[np.abs(exact) > float(geom.cell)].all()
    assert hands.geometry(glass) is geom  # cached


def test_penetration_against_trimesh(default_hand, glass):
    """The sphere penetration is zero when the posed collision geometry is outside the mesh (trimesh)
    and positive when the hand is pushed through it."""
    import trimesh

    from grasp_jax.hands import _energy, _geometry

    geom = hands.geometry(glass)
    far = np.array([*(glass.center + [0, 0, 3 * glass.radius]), 1.0, 0, 0, 0])
    inside = np.array([*(glass.center - [0, 0, 0.01]), 1.0, 0, 0, 0])
    forward, penetration = jax.jit(hands.forward), jax.jit(_energy.penetration)  # op by op: 57 programs
    with float64_scope():
        for pose, expect in ((far, False), (inside, True)):
            frames = np.asarray(forward(default_hand, pose, default_hand.open_joints))
            depth = float(penetration(default_hand, geom, frames)[1])
            meshes = [_geometry.element_mesh(c).apply_transform(frames[c.link]) for c in default_hand.collisions]
            pts = np.concatenate([m.sample(300, return_index=False) for m in meshes])
            exact = trimesh.proximity.signed_distance(glass.mesh, pts).max()
            assert (exact > 0) == expect and (depth > 0) == expect


@pytest.fixture(scope="module")
def synthesized(default_hand, glass):
    # hard contacts and 4 cone edges: the smallest LPs, the least compilation
    return hands.synthesize(default_hand, glass, starts=8, steps=10, seed=3, contact="hard", num_edges=4)


def test_synthesize_result(synthesized, default_hand, glass):
    r = synthesized
    assert len(r) == 8 and r.joints.shape == (8, 6) and r.points.shape == (8, 3, 3)
    np.testing.assert_allclose(np.linalg.norm(r.quaternion, axis=1), 1.0)
    assert (r.joints >= default_hand.lower - 1e-9).all() and (r.joints <= default_hand.upper + 1e-9).all()
    assert (r.squeeze >= default_hand.lower - 1e-9).all() and (r.pregrasp <= default_hand.upper + 1e-9).all()
    from grasp_jax import evaluate

    ev = evaluate(r.points, r.normals, mu=0.5, num_edges=4)
    np.testing.assert_array_equal(np.asarray(ev.force_closure), r.force_closure)
    expect = r.force_closure & (r.penetration <= 1e-3) & (np.abs(r.distance).max(axis=1) <= 2e-3)
    np.testing.assert_array_equal(r.valid, expect)
    assert (r.valid == (r.status == hands.HandStatus.VALID)).all()
    assert len(r.messages()) == 8 and set(r.joints_by_name(0)) == set(default_hand.joint_names)
    assert r.energy.shape == (8, 10) and np.isfinite(r.energy).all()


def test_same_seed_same_starts(default_hand, glass, synthesized):
    from grasp_jax.hands._synthesize import initial_configurations

    pose, joints = initial_configurations(default_hand, hands.geometry(glass), 8, 3)
    np.testing.assert_array_equal(pose, np.concatenate([synthesized.initial_position,
                                                        synthesized.initial_quaternion], axis=1))
    np.testing.assert_array_equal(joints, synthesized.initial_joints)


@pytest.mark.parametrize("suffix", [".npz", ".parquet"])
def test_save_and_load(synthesized, tmp_path, suffix):
    path = synthesized.save(tmp_path / f"grasps{suffix}")
    back = hands.load_result(path)
    for name, value in synthesized.columns().items():
        np.testing.assert_array_equal(getattr(back, name), value)
    assert back.joint_names == synthesized.joint_names and back.hand == synthesized.hand
    assert [p.name for p in tmp_path.iterdir()] == [f"grasps{suffix}"]
    with pytest.raises(ValueError, match="must end in"):
        synthesized.save(tmp_path / "grasps.txt")


def test_second_object_compiles_nothing(default_hand, glass, synthesized):
    """Another mesh runs the programs compiled for the first: the SDF grid is data."""
    from grasp_jax import _batch, objects

    box = objects.Mesh.from_trimesh(__import__("trimesh").creation.box(extents=(0.05, 0.04, 0.06)), name="box")
    before = _batch.STATS["compiled"] + _batch.STATS["loaded"]
    hands.synthesize(default_hand, box, starts=8, steps=10, seed=4, contact="hard", num_edges=4)
    assert _batch.STATS["compiled"] + _batch.STATS["loaded"] == before


def test_bad_arguments(default_hand, glass):
    with pytest.raises(ValueError, match="starts"):
        hands.synthesize(default_hand, glass, starts=0)
    with pytest.raises(ValueError, match="objective"):
        hands.synthesize(default_hand, glass, objective="surrogate")
    with pytest.raises(TypeError, match="Hand"):
        hands.synthesize("default", glass)
    from grasp_jax import objects

    with pytest.raises(ValueError, match="3D mesh"):
        hands.synthesize(default_hand, objects.load("star"))
