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
        gp, gj = jax.grad(f, argnums=(0, 1))(pose, joints)
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
    with float64_scope():
        batched = np.asarray(jax.vmap(hands.forward, in_axes=(None, 0, 0))(default_hand, pose, joints))
        loop = np.stack([np.asarray(hands.forward(default_hand, p, q)) for p, q in zip(pose, joints)])
    np.testing.assert_allclose(batched, loop, atol=1e-12)
    single = hands.forward(default_hand, pose[0].astype(np.float32), joints[0].astype(np.float32))
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
