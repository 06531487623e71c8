"""grasp_jax.hands: loading (URDF, MJCF), forward kinematics against yourdfpy and MuJoCo, candidates, SDF,
synthesis."""

from __future__ import annotations

import io
import json
import os
import re
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import yourdfpy
from _jit import jit

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
        ours = np.asarray(jit(jax.vmap(hands.forward, in_axes=(None, 0, 0)))(hand, pose, joints))
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
        gp, gj = jit(jax.grad(f, argnums=(0, 1)))(pose, joints)  # op by op: 148 programs
        f = jit(f)
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
    forward = jit(hands.forward)  # op by op, the loop and the vmap compiled 112 programs
    with float64_scope():
        batched = np.asarray(jit(jax.vmap(hands.forward, in_axes=(None, 0, 0)))(default_hand, pose, joints))
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
# MJCF hands, read through MuJoCo's compiler and checked against its own kinematics.

TOY_MJCF = """<mujoco model="toy">
  <compiler angle="degree"/>
  <default><default class="visual"><geom contype="0" conaffinity="0"/></default></default>
  <asset><mesh name="block" scale="1 1 2" vertex="0 0 0  0.016 0 0  0 0.012 0  0.016 0.012 0  0 0 0.01
    0.016 0 0.01  0 0.012 0.01  0.016 0.012 0.01"/></asset>
  <worldbody>
    <geom type="plane" size="1 1 0.1"/>
    <body name="palm" pos="0.1 0.2 0.3" quat="0.9 0.1 0.2 0.3">
      <freejoint name="float"/>
      <geom type="box" size="0.04 0.04 0.01"/>
      <geom class="visual" type="sphere" size="0.1"/>
      <body name="f0" pos="0.03 0 0.01" euler="10 20 30">
        <joint name="f0_yaw" axis="1 0 0" range="-20 20" pos="0 0.002 0"/>
        <joint name="f0_pitch" axis="0 1 1" range="0 90" pos="0.001 0 0.003" ref="10"/>
        <geom type="capsule" fromto="0 0 0 0 0.01 0.04" size="0.008"/>
        <body name="f0_tip" pos="0 0 0.04">
          <joint name="f0_tip" axis="0 1 0" range="0 90" pos="0 0 -0.002"/>
          <geom type="cylinder" size="0.007 0.01" pos="0 0 0.01"/>
          <geom type="mesh" mesh="block" pos="0.003 -0.004 0.02" euler="0 30 0"/>
        </body>
      </body>
      <body name="f1" pos="-0.03 0 0.01">
        <joint name="f1_slide" type="slide" axis="0 0 1" range="0 0.02" ref="0.005"/>
        <joint name="f1_pitch" axis="0 1 0" range="-90 0"/>
        <geom type="box" size="0.008 0.008 0.02" pos="0 0 0.02"/>
        <body name="f1_tip" pos="0 0 0.04">
          <joint name="f1_tip" axis="0 1 0" range="-90 0"/>
          <geom type="sphere" size="0.009" pos="0 0 0.01"/>
        </body>
      </body>
    </body>
  </worldbody>
  <equality>
    <joint joint1="f0_tip" joint2="f0_pitch" polycoef="0.1 0.5 0 0 0"/>
    <joint joint1="f1_pitch" joint2="f1_slide" polycoef="-0.2 -30 0 0 0"/>
    <joint joint1="f1_tip" joint2="f1_pitch" polycoef="0.05 0.7 0 0 0"/>
  </equality>
</mujoco>
"""


def _mujoco_frames(model, hand, pose, joints):
    """``(N, L, 4, 4)`` MuJoCo's body frames (``mj_kinematics``, joint couplings applied by hand)
    relative to the root body's, placed by the pose; for each body, the link named after it
    (whose frame is at its last joint's anchor) and that anchor."""
    import mujoco

    data = mujoco.MjData(model)
    root = model.body(hand.link_names[0]).id
    adr = model.jnt_qposadr[[model.joint(n).id for n in hand.joint_names]]
    coupled = [(model.jnt_qposadr[model.eq_obj1id[e]], model.jnt_qposadr[model.eq_obj2id[e]], model.eq_data[e, :2])
               for e in range(model.neq)]
    bodies = [b for b in range(model.nbody) if model.body(b).name in hand.link_names]
    links = [hand.link_index(model.body(b).name) for b in bodies]
    anchor = np.tile(np.eye(4), (len(bodies), 1, 1))
    for k, b in enumerate(bodies):
        if model.body_jntnum[b]:
            anchor[k, :3, 3] = -model.jnt_pos[model.body_jntadr[b] + model.body_jntnum[b] - 1]
    out = np.empty((len(pose), len(bodies), 4, 4))
    for k in range(len(pose)):
        data.qpos[:] = model.qpos0
        data.qpos[adr] = joints[k]
        for y, x, (a0, a1) in coupled:  # in the file's order: a chain's first link first
            data.qpos[y] = model.qpos0[y] + a0 + a1 * (data.qpos[x] - model.qpos0[x])
        mujoco.mj_kinematics(model, data)
        frames = np.tile(np.eye(4), (model.nbody, 1, 1))
        frames[:, :3, :3], frames[:, :3, 3] = data.xmat.reshape(-1, 3, 3), data.xpos
        with float64_scope():
            base = np.asarray(hands._kinematics.pose_matrix(jnp.asarray(pose[k])))
        out[k] = base @ np.linalg.inv(frames[root]) @ frames[bodies]
    return out, links, anchor


def _check_against_mujoco(hand, model, count):
    pose, joints = _random_configs(hand, count, seed=4)
    with float64_scope():
        ours = np.asarray(jit(jax.vmap(hands.forward, in_axes=(None, 0, 0)))(hand, pose, joints))
    theirs, links, anchor = _mujoco_frames(model, hand, pose, joints)
    ours = ours[:, links] @ anchor  # each body's frame, from its link's (at the anchor)
    assert np.abs(ours[..., :3, 3] - theirs[..., :3, 3]).max() < 1e-9
    assert np.abs(ours[..., :3, :3] - theirs[..., :3, :3]).max() < 1e-9


@pytest.fixture(scope="module")
def mjcf_cache(tmp_path_factory):
    """A cache folder of its own for the meshes MJCF files compile to (``XDG_CACHE_HOME``)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("XDG_CACHE_HOME", str(tmp_path_factory.mktemp("cache")))
        yield Path(os.environ["XDG_CACHE_HOME"]) / "grasp_jax" / "mjcf"


def test_mjcf_toy_hand_against_mujoco(tmp_path, mjcf_cache):
    mujoco = pytest.importorskip("mujoco")
    path = _write(tmp_path, TOY_MJCF, "toy.xml")
    hand = hands.load(path)
    model = mujoco.MjModel.from_xml_path(str(path))
    # the free joint is dropped, f0_tip follows f0_pitch, f1_tip f1_pitch which follows f1_slide,
    # two bodies carry two joints each
    assert hand.joint_names == ("f0_yaw", "f0_pitch", "f1_slide")
    assert hand.link_names == ("palm", "f0/f0_yaw", "f0", "f0_tip", "f1/f1_slide", "f1", "f1_tip")
    assert hand.num_fingers == 2 and len(hand.collisions) == 6  # no plane, no visual sphere
    _check_against_mujoco(hand, model, 100)
    kinds = {}
    for c in hand.collisions:  # the first of each kind: the palm's box, f0's capsule, f0_tip's cylinder and mesh
        kinds.setdefault(c.kind, c)
    assert kinds["box"].size == pytest.approx((0.08, 0.08, 0.02)) and kinds["capsule"].size[1] == pytest.approx(
        np.linalg.norm([0.01, 0.04]))
    assert kinds["cylinder"].size == pytest.approx((0.007, 0.02))
    # the mesh where the file puts it: the scaled block at the geom's pose in its body's frame
    mesh = kinds["mesh"]
    assert Path(mesh.filename).parent == mjcf_cache
    with float64_scope():
        frames = np.asarray(hands.forward(hand, np.array([0, 0, 0, 1.0, 0, 0, 0]), np.zeros(hand.num_joints)))
    tip = hand.link_index("f0_tip")
    placed = hands._geometry.element_mesh(mesh).apply_transform(frames[tip]).vertices  # from the link's frame
    block = np.array([[x, y, z] for z in (0, 0.02) for y in (0, 0.012) for x in (0, 0.016)])
    rot = hands._kinematics.quat_to_matrix(jnp.array([np.cos(np.pi / 12), 0, np.sin(np.pi / 12), 0]))
    body = frames[tip] @ _shift([0, 0, 0.002])  # the link's frame is at the joint's anchor
    expected = (block @ np.asarray(rot).T + [0.003, -0.004, 0.02]) @ body[:3, :3].T + body[:3, 3]
    apart = np.linalg.norm(placed[:, None] - expected[None], axis=2)
    assert len(placed) == 8 and apart.min(axis=0).max() < 1e-6 and apart.min(axis=1).max() < 1e-6


def _shift(p):
    out = np.eye(4)
    out[:3, 3] = p
    return out


def _urdf_to_mjcf(urdf: Path, out: Path) -> Path:
    """The URDF compiled by MuJoCo (with the compiler block ../shared/HANDS.md gives) saved as MJCF."""
    import mujoco

    block = f'<mujoco><compiler balanceinertia="true" strippath="false" meshdir="{urdf.parent}"/></mujoco>'
    text = re.sub(r"(<robot[^>]*>)", lambda m: m.group(1) + block, urdf.read_text(), count=1)
    staged = out.with_suffix(".urdf")
    staged.write_text(text)
    mujoco.mj_saveLastXML(str(out), mujoco.MjModel.from_xml_path(str(staged)))
    return out


def _element_boxes(hand, joints):
    """``(E, 6)`` world bounds of each collision element at ``joints`` (identity wrist)."""
    with float64_scope():
        frames = np.asarray(hands.forward(hand, np.array([0, 0, 0, 1.0, 0, 0, 0]), joints))
    meshes = [hands._geometry.element_mesh(c).apply_transform(frames[c.link]) for c in hand.collisions]
    return np.array([np.r_[m.bounds[0], m.bounds[1]] for m in meshes])


@needs_shared
@pytest.mark.parametrize("name", ["allegro", "leap"])
def test_mjcf_of_a_urdf_hand_against_mujoco(name, tmp_path, mjcf_cache):
    mujoco = pytest.importorskip("mujoco")
    path = _urdf_to_mjcf(HANDS[name], tmp_path / f"{name}.xml")
    hand, urdf_hand = hands.load(path), hands.load(HANDS[name])
    _check_against_mujoco(hand, mujoco.MjModel.from_xml_path(str(path)), 100)
    assert hand.link_names[0] == "world"  # MuJoCo fuses the URDF's root link into the world
    assert (hand.num_fingers, hand.num_joints) == (urdf_hand.num_fingers, urdf_hand.num_joints)
    assert sorted(hand.joint_names) == sorted(urdf_hand.joint_names)  # in MuJoCo's (depth-first) order
    np.testing.assert_allclose(hand.lower, [urdf_hand.lower[urdf_hand.joint_names.index(n)] for n in hand.joint_names])
    # the same collision geometry in the world (sizes, mesh frames), the file's 6 digits apart
    joints = _random_configs(hand, 1, seed=5)[1][0]
    ours = _element_boxes(hand, joints)
    theirs = _element_boxes(urdf_hand, np.array([joints[hand.joint_names.index(n)] for n in urdf_hand.joint_names]))
    assert len(ours) == len(theirs)
    assert np.abs(ours[:, None] - theirs[None]).max(axis=2).min(axis=1).max() < 1e-5


def test_mjcf_errors_name_the_file_and_element(tmp_path, mjcf_cache, monkeypatch):
    pytest.importorskip("mujoco")
    ball = TOY_MJCF.replace('<joint name="f1_tip" axis="0 1 0" range="-90 0"/>', '<joint name="f1_tip" type="ball"/>')
    ball = ball.replace('<joint joint1="f1_tip" joint2="f1_pitch" polycoef="0.05 0.7 0 0 0"/>', "")
    with pytest.raises(ValueError, match=r"toy\.xml.*'f1_tip'.*'f1_tip'.*ball"):
        hands.load(_write(tmp_path, ball, "toy.xml"))
    quadratic = TOY_MJCF.replace('polycoef="0.1 0.5 0 0 0"', 'polycoef="0 0.5 0.2 0 0"')
    with pytest.raises(ValueError, match=r"toy\.xml.*'f0_tip'.*nonlinear"):
        hands.load(_write(tmp_path, quadratic, "toy.xml"))
    with pytest.raises(ValueError, match=r"absent\.xml.*not found"):
        hands.load(tmp_path / "absent.xml")
    with pytest.raises(ValueError, match=r"hand\.obj.*URDF \(\.urdf\) or MJCF \(\.xml\)"):
        hands.load(_write(tmp_path, "", "hand.obj"))
    monkeypatch.setitem(sys.modules, "mujoco", None)  # as where it is not installed
    with pytest.raises(ValueError, match=r"toy\.xml.*pip install 'grasp_jax\[sim\]'"):
        hands.load(tmp_path / "toy.xml")


# ---------------------------------------------------------------------------------------------
# Candidates, object geometry, energies, synthesis (the default hand and built-in objects).


@pytest.fixture(scope="module")
def glass():
    from grasp_jax import objects

    return objects.load("glass")


def test_candidates_face_the_palm(default_hand):
    with float64_scope():
        # jitted: op by op it compiled 57 programs (the tests above compile this one)
        frames = np.asarray(jit(hands.forward)(default_hand, np.array([0, 0, 0, 1.0, 0, 0, 0]),
                                                   default_hand.open_joints))
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
    assert geom.grid.shape == (64, 64, 64) and geom.points.shape == (64, 3)
    rng = np.random.default_rng(0)
    x = glass.center + rng.uniform(-1.2, 1.2, (400, 3)) * glass.radius
    with float64_scope():
        ours = np.asarray(jit(jax.vmap(lambda p: hands._sdf.distance(geom, p)))(x))  # op by op: 38 programs
    exact = -trimesh.proximity.signed_distance(glass.mesh, x)
    near = np.abs(exact) < 0.1 * glass.radius
    assert np.abs(ours - exact)[near].max() < 0.5 * float(geom.cell)
    assert (np.sign(ours) == np.sign(exact))[np.abs(exact) > float(geom.cell)].all()
    assert hands.geometry(glass) is geom  # cached
    # normals: the direction from the mesh's closest point, outside within 3 mm of the surface
    on, face = trimesh.sample.sample_surface(glass.mesh, 400, seed=0)
    x = on + glass.mesh.face_normals[face] * rng.uniform(5e-4, 3e-3, (400, 1))
    closest, gap, _ = trimesh.proximity.closest_point(glass.mesh, x)
    outside = ~glass.mesh.contains(x)
    with float64_scope():
        normal = np.asarray(jit(jax.vmap(lambda p: hands._sdf.distance_and_normal(geom, p)[1]))(x))
    cosine = np.sum(normal * (x - closest) / gap[:, None], axis=1)[outside]
    angle = np.degrees(np.arccos(np.clip(cosine, -1, 1)))  # measured: median 1.0, 90th 2.8, largest 16
    assert outside.sum() >= 200 and np.median(angle) < 2 and np.percentile(angle, 90) < 5 and angle.max() < 25


def test_penetration_against_trimesh(default_hand, glass):
    """The penetration is zero when the posed collision geometry is outside the mesh (trimesh)
    and positive when the hand is pushed through it."""
    import trimesh

    from grasp_jax.hands import _energy, _geometry

    geom = hands.geometry(glass)
    far = np.array([*(glass.center + [0, 0, 3 * glass.radius]), 1.0, 0, 0, 0])
    inside = np.array([*(glass.center - [0, 0, 0.01]), 1.0, 0, 0, 0])
    forward, penetration = jit(hands.forward), jit(_energy.penetration)  # op by op: 57 programs
    with float64_scope():
        for pose, expect in ((far, False), (inside, True)):
            frames = np.asarray(forward(default_hand, pose, default_hand.open_joints))
            depth = float(penetration(default_hand, geom, frames)[1])
            meshes = [_geometry.element_mesh(c).apply_transform(frames[c.link]) for c in default_hand.collisions]
            pts = np.concatenate([m.sample(300, return_index=False) for m in meshes])
            exact = trimesh.proximity.signed_distance(glass.mesh, pts).max()
            assert (exact > 0) == expect and (depth > 0) == expect


def test_penetration_reads_the_nearest_patches_exactly(default_hand, glass, monkeypatch):
    """Reading only the surface patches and spheres nearest the object gives the sum over all of
    them wherever no more than that many can be within reach (here 40 patches and 24 spheres, of
    the default hand's many)."""
    from grasp_jax.hands import _energy, _geometry
    from grasp_jax.hands._kinematics import transform_points

    geom, clearance = hands.geometry(glass), 1e-3
    monkeypatch.setattr(_energy, "NEAR_PATCHES", 40)
    monkeypatch.setattr(_energy, "NEAR_SPHERES", 24)
    hand = default_hand
    dist = jax.vmap(lambda x: hands._sdf.distance(geom, x))

    def both(pose):
        frames = hands.forward(hand, pose, hand.open_joints)
        surface = transform_points(frames, hand.surface_link, hand.surface_point)
        centers, radii = _energy.spheres(hand, frames)
        gap = jnp.sqrt(jnp.sum((geom.points[:, None] - centers[None]) ** 2, axis=-1) + 1e-30)
        full = jnp.sum(jax.nn.relu(clearance - dist(surface))) + jnp.sum(jax.nn.relu(radii[None] - gap))
        local = jnp.asarray(hand.surface_point).reshape(-1, _geometry.PATCH, 3)
        link = jnp.asarray(hand.surface_link).reshape(-1, _geometry.PATCH)[:, 0]
        middle = local.mean(axis=1)
        size = jnp.max(jnp.linalg.norm(local - middle[:, None], axis=-1), axis=1)
        reach = dist(transform_points(frames, link, middle)) - _energy.LIPSCHITZ * size
        sphere_reach = dist(centers) - _energy.LIPSCHITZ * radii
        fits = (jnp.sum(reach < clearance) <= 40) & (jnp.sum(sphere_reach < 0) <= 24)
        return _energy.penetration(hand, geom, frames, clearance)[0], full, fits

    rng = np.random.default_rng(0)
    top = glass.center + np.array([0, 0, 0.95]) * glass.radius
    poses = np.concatenate([top + rng.normal(0, 0.005, (24, 3)), np.tile([1.0, 0, 0, 0], (24, 1))], axis=1)
    with float64_scope():
        culled, full, fits = (np.asarray(a) for a in jit(jax.vmap(both))(poses))
    assert fits.sum() >= 4 and (full[fits] > 0).sum() >= 2
    np.testing.assert_allclose(culled[fits], full[fits], rtol=1e-12, atol=1e-15)
    assert (culled <= full + 1e-15).all()


def test_final_check_reads_the_deepest_sample(default_hand, glass):
    """The final check's patches nearest the object hold the deepest of all the hand's dense
    samples (by the grid) wherever no more than NEAR_DENSE patches can reach that deep."""
    from grasp_jax.hands import _energy, _geometry, _synthesize
    from grasp_jax.hands._kinematics import transform_points

    geom, hand = hands.geometry(glass), default_hand
    samples, links = _geometry.dense_samples(hand.collisions, _synthesize.PENETRATION_SAMPLES)
    dist = jax.vmap(lambda x: hands._sdf.distance(geom, x))

    def both(pose):
        frames = hands.forward(hand, pose, hand.open_joints)
        culled = jnp.min(dist(_energy.nearest_points(geom, frames, samples, links, _synthesize.NEAR_DENSE)))
        full = jnp.min(dist(transform_points(frames, jnp.repeat(links, samples.shape[1]), samples.reshape(-1, 3))))
        middle = samples.mean(axis=1)
        size = jnp.max(jnp.linalg.norm(samples - middle[:, None], axis=-1), axis=1)
        reach = dist(transform_points(frames, links, middle)) - _energy.LIPSCHITZ * size
        return culled, full, jnp.sum(reach <= full) <= _synthesize.NEAR_DENSE

    rng = np.random.default_rng(1)
    top = glass.center + np.array([0, 0, 0.95]) * glass.radius
    poses = np.concatenate([top + rng.normal(0, 0.005, (16, 3)), np.tile([1.0, 0, 0, 0], (16, 1))], axis=1)
    with float64_scope():
        culled, full, fits = (np.asarray(a) for a in jit(jax.vmap(both))(poses))
    assert fits.sum() >= 4 and (full[fits] < 0).sum() >= 2
    np.testing.assert_array_equal(culled[fits], full[fits])
    assert (culled >= full).all()


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

    # force-closure of the fingers that touch, evaluated without the others (one call per count)
    np.testing.assert_array_equal(r.active, np.abs(r.distance) <= 2e-3)
    touching = r.active.sum(axis=1)
    fc = np.zeros(len(r), bool)
    for k in set(touching[touching >= 2].tolist()):
        rows = np.flatnonzero(touching == k)
        ev = evaluate(r.points[rows][r.active[rows]].reshape(-1, k, 3),
                      r.normals[rows][r.active[rows]].reshape(-1, k, 3), mu=0.5, num_edges=4)
        fc[rows] = np.asarray(ev.force_closure)
    np.testing.assert_array_equal(fc, r.force_closure)
    np.testing.assert_array_equal(r.valid, fc & (r.penetration <= 1e-3))
    assert (r.valid == (r.status == hands.HandStatus.VALID)).all()
    assert r.closed.dtype == bool and (r.valid[r.closed]).all()  # a closed grasp is kept only when valid
    assert len(r.messages()) == 8 and set(r.joints_by_name(0)) == set(default_hand.joint_names)
    assert r.energy.shape == (8, 10) and np.isfinite(r.energy).all()


def test_closing_moves_the_fingers_to_the_gap(synthesized, default_hand, glass):
    """Closing the fingers onto the object (the final check's second candidate) brings each finger
    that is farther than the gap nearer, leaves the nearer ones, and keeps the joint limits."""
    from grasp_jax.hands import _energy, _synthesize

    geom, hand, gap = hands.geometry(glass), default_hand, 1.2e-3
    pose = np.concatenate([synthesized.position, synthesized.quaternion], axis=1)

    def one(p, q):
        closed = _synthesize._close_fingers(hand, geom, p, q, gap)
        dist = lambda j: _energy.contacts(hand, geom, hands.forward(hand, p, j))[2]
        return closed, dist(q), dist(closed)

    with float64_scope():
        closed, before, after = (np.asarray(a) for a in jit(jax.vmap(one))(pose, synthesized.joints))
    far = before > gap + 1e-4
    assert far.sum() >= 4 and (after[far] < before[far]).all()
    assert (np.abs(after - gap) < 2e-4).sum() > (np.abs(before - gap) < 2e-4).sum()
    np.testing.assert_allclose(after[before < gap], before[before < gap], rtol=0, atol=1e-15)
    assert (closed >= hand.lower - 1e-12).all() and (closed <= hand.upper + 1e-12).all()


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
    assert back.object_path == synthesized.object_path
    assert [p.name for p in tmp_path.iterdir()] == [f"grasps{suffix}"]
    with pytest.raises(ValueError, match="must end in"):
        synthesized.save(tmp_path / "grasps.txt")


def test_load_a_file_without_active(synthesized, tmp_path):
    """A result written before ``active`` and ``closed`` existed reads back with them (from the
    distances; not closed)."""
    cols = {k: v for k, v in synthesized.columns().items() if k not in ("active", "closed")}
    path = tmp_path / "old.npz"
    np.savez(path, metadata=np.asarray(json.dumps(synthesized.metadata())), **cols)
    back = hands.load_result(path)
    np.testing.assert_array_equal(back.active, np.abs(synthesized.distance) <= 2e-3)
    assert back.closed.shape == (8,) and not back.closed.any()


def test_distinct_drops_copies(synthesized):
    """A grasp within 1 cm and 15 degrees of a better kept one is a copy; a plain loop agrees."""
    import dataclasses

    rng = np.random.default_rng(0)
    position = rng.normal(size=(8, 3)) * 0.05
    position[1] = position[0] + 0.004  # a copy of 0 (7 mm away, same orientation)
    quaternion = np.tile([1.0, 0, 0, 0], (8, 1))
    turn = np.radians(40) / 2
    position[3], quaternion[3] = position[2], [np.cos(turn), np.sin(turn), 0, 0]  # same place, turned 40 degrees
    r = dataclasses.replace(synthesized, position=position, quaternion=quaternion, valid=np.ones(8, bool),
                            quality=np.linspace(1, 0.3, 8))
    kept = r.distinct()
    assert 1 not in kept and {0, 2, 3} <= set(kept) and list(kept) == sorted(kept)
    expect = []
    for i in range(8):
        if not any(np.linalg.norm(position[i] - position[k]) <= 0.01
                   and 2 * np.degrees(np.arccos(min(1.0, abs(quaternion[i] @ quaternion[k])))) <= 15 for k in expect):
            expect.append(i)
    assert list(kept) == expect


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


def test_hand_dataset(tmp_path, usage):
    """``grasp-jax dataset --hand`` (``grasp_jax.dataset``; here beside the hand's other programs):
    hand grasps over a folder of objects: one part per object (``hands.synthesize``'s result, one
    row per start), records with the valid count, the hand in the manifest, resumed only with the
    same hand; ``--hand`` with a gripper or robust labels is one clear error."""
    import dataclasses
    import json

    import trimesh

    from grasp_jax import dataset, pipeline
    from grasp_jax._robust import Noise

    ROBUST = pipeline.RobustLabels(Noise(position=0.02, friction=(0.8, 1.2)), samples=4, margin=False)  # test_dataset's
    folder = tmp_path / "objects"
    folder.mkdir()
    trimesh.creation.box((0.06, 0.05, 0.07)).export(folder / "a_box.stl")
    trimesh.creation.icosphere(2, 0.035).export(folder / "b_ball.obj")
    hand = hands.load("default")
    out = tmp_path / "ds"
    settings = {"hand": hand, "starts": 8, "steps": 10}
    summary = dataset.build(folder, out, **settings)
    assert summary.done == ["a_box", "b_ball"] and not summary.failed
    for name in summary.done:
        result = hands.load_result(dataset.part_path(out, name))
        record = summary.rows[name]
        assert len(result) == 8 and result.steps == 10 and result.contact == "soft" and result.mu == 0.5
        assert record["num"] == 8 and record["valid"] == int(result.valid.sum()) and record["seconds"] > 0
        assert record["valid_rate"] == result.valid.mean() and record["part"] == f"object={name}/part.parquet"
    manifest = json.loads((out / "_manifest.json").read_text())
    assert manifest["config"]["hand"] == {"name": "default", "urdf": None}
    assert manifest["config"]["starts"] == 8 and manifest["config"]["steps"] == 10
    assert manifest["objects_done"] == 2 and manifest["grasps"] == 16
    assert "valid %" in summary.format() and dataset.read(out).num_rows == 16
    again = dataset.build(folder, out, **settings)
    assert again.skipped == ["a_box", "b_ball"] and not again.done
    with pytest.raises(dataset.DatasetError, match="another configuration .*differs in hand"):
        dataset.build(folder, out, **{**settings, "hand": dataclasses.replace(hand, name="other")})
    with pytest.raises(dataset.DatasetError, match="hand grasps and robust labels do not go together"):
        dataset.build(folder, out, robust=ROBUST, **settings)
    for flags, message in ((["--gripper", "parallel-jaw", "--max-width", "0.1"], "--hand and --gripper describe two"),
                           (["--robust", "4", "--sigma-pos", "0.02"], "--robust sets robust labels"),
                           (["--starts", "8"], None)):
        hand_flags = [] if message is None else ["--hand", "default"]
        cli = usage("dataset", folder, "--out", "cli", *hand_flags, *flags)
        message = message or "--starts sets the hand grasps: add --hand"
        assert cli.returncode == 2 and cli.stderr.count("\n") == 1 and message in cli.stderr, cli.stderr
    assert not (tmp_path / "cli").exists()
