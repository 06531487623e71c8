"""A URDF or MJCF hand in MuJoCo, and :func:`simulate_hand` for the grasps of :mod:`grasp_jax.hands`.

A URDF is read by MuJoCo with a compiler block (balanced inertias, mesh paths kept, visual
elements dropped); an MJCF file as it is, its root body moved to the origin without its free
joint and its floor planes dropped (the root as :mod:`grasp_jax.hands` reads it). The root is
fixed at the world's origin, and each grasp places the object at the inverse of the grasp's wrist
pose instead. Every actuated joint gets a position
actuator of gain ``Protocol.hand_kp`` and damping ``Protocol.hand_kv``; the controls move from the
pre-grasp to the grasp to the squeeze configuration, then the forces pull along the object's axes.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..hands._builtin import default_urdf
from ._episode import Scene, run_episode
from ._object import sim_object
from ._pool import run_batched
from ._protocol import Protocol, SimResult


def _urdf(hand) -> tuple[str, str]:
    """The hand's URDF text and its folder (meshes are relative to it)."""
    path = getattr(hand, "path", "")
    if path:
        return Path(path).read_text(), str(Path(path).resolve().parent)
    return default_urdf(), "."


def _with_compiler(text: str, folder: str) -> str:
    block = (f'<mujoco><compiler balanceinertia="true" strippath="false" discardvisual="true" '
             f'meshdir="{folder}"/></mujoco>')
    out, count = re.subn(r"(<robot[^>]*>)", lambda m: m.group(1) + block, text, count=1)
    if count != 1:
        raise ValueError("the hand's URDF has no <robot> element")
    return out


def _hand_spec(hand):
    """The hand's ``MjSpec``: its URDF with the compiler block, or its MJCF file with the root at
    the origin."""
    import mujoco

    path = getattr(hand, "path", "")
    if not path.lower().endswith(".xml"):
        text, folder = _urdf(hand)
        return mujoco.MjSpec.from_string(_with_compiler(text, folder))
    spec = mujoco.MjSpec.from_file(path)
    for geom in list(spec.geoms):  # visual geoms and floors
        if (geom.contype == 0 and geom.conaffinity == 0) or geom.type in (mujoco.mjtGeom.mjGEOM_PLANE,
                                                                          mujoco.mjtGeom.mjGEOM_HFIELD):
            spec.delete(geom)
    children = list(spec.worldbody.bodies)
    if len(children) == 1 and not list(spec.worldbody.geoms):  # that body is the wrist
        root = children[0]
        root.pos, root.quat = [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]
        for joint in list(root.joints):
            spec.delete(joint)
    return spec


def _contact(geom, protocol: Protocol, bits: tuple[int, int]) -> None:
    geom.friction = [protocol.friction, protocol.torsion, 1e-4]
    geom.condim = 4
    geom.solref = list(protocol.solref)
    solimp = np.array(geom.solimp, float)
    solimp[:3] = protocol.solimp
    geom.solimp = solimp
    geom.contype, geom.conaffinity = bits


def hand_xml(hand, obj, protocol: Protocol) -> tuple[str, list[str]]:
    """The MJCF of the hand (root at the origin) and the object: ``(xml, names of the hand's
    bodies)``."""
    import mujoco

    spec = _hand_spec(hand)
    spec.option.timestep = protocol.timestep
    spec.option.gravity = [0.0, 0.0, 0.0]
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = 10.0
    spec.option.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_MULTICCD)  # several contacts per pair
    for geom in spec.geoms:
        _contact(geom, protocol, (2, 1))
    bodies = [b.name for b in spec.bodies]
    known = {j.name for j in spec.joints}
    for name in hand.joint_names:
        if name not in known:
            raise ValueError(f"the hand's description has no joint {name!r}")
        act = spec.add_actuator()
        act.name, act.target, act.trntype = f"drive_{name}", name, mujoco.mjtTrn.mjTRN_JOINT
        act.set_to_position(kp=protocol.hand_kp, kv=protocol.hand_kv)
    body = spec.worldbody.add_body()
    body.name = "object"
    body.add_freejoint()
    body.explicitinertial = True
    body.mass, body.ipos = obj.mass, obj.com
    i = obj.inertia
    body.fullinertia = [i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2]]
    for k, (v, f) in enumerate(obj.parts):
        mesh = spec.add_mesh()
        mesh.name, mesh.uservert, mesh.userface = f"part{k}", v.ravel().tolist(), f.ravel().tolist()
        geom = body.add_geom()
        geom.type, geom.meshname = mujoco.mjtGeom.mjGEOM_MESH, f"part{k}"
        _contact(geom, protocol, (1, 2))
    return spec.to_xml(), bodies


def _rotation(q: np.ndarray) -> np.ndarray:
    import mujoco

    r = np.zeros(9)
    mujoco.mju_quat2Mat(r, q / np.linalg.norm(q))
    return r.reshape(3, 3)


class HandSim:
    """A worker's hand scene: built once, then one grasp after another (:meth:`run`)."""

    def __init__(self, xml: str, bodies: list[str], joint_names: tuple, protocol: Protocol, force: float,
                 seed: int):
        self.scene = Scene(xml, bodies)
        self.protocol, self.force, self.seed = protocol, force, seed
        m, mj = self.scene.model, self.scene.mj
        ids = [mj.mj_name2id(m, mj.mjtObj.mjOBJ_JOINT, n) for n in joint_names]
        self.qadr = m.jnt_qposadr[ids]

    def run(self, index: int, position, quaternion, pregrasp, grasp, squeeze):
        """One grasp: ``(status, held (6,), displacement (6,), rotation (6,))``."""
        scene, p = self.scene, self.protocol
        mj, m, d = scene.mj, scene.model, scene.data
        mj.mj_resetData(m, d)
        rot = _rotation(np.asarray(quaternion, float))          # wrist in the object's frame
        place = -rot.T @ np.asarray(position, float)              # the object in the wrist's frame
        if p.pose_noise > 0:
            rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(index,)))
            place = place + rng.normal(0.0, p.pose_noise, 3)
        q = np.asarray(quaternion, float) / np.linalg.norm(quaternion)
        adr = scene.obj_qpos
        d.qpos[adr:adr + 3] = place
        d.qpos[adr + 3:adr + 7] = [q[0], -q[1], -q[2], -q[3]]
        d.qpos[self.qadr] = pregrasp
        return run_episode(scene, p, [pregrasp, grasp, squeeze], self.force, frame=rot.T)


def simulate_hand(hand, mesh, result, *, protocol: Protocol | None = None, seed: int = 0,
                  workers: int | None = None, progress: bool = False, rows=None) -> SimResult:
    """Simulate hand grasps of a mesh in MuJoCo (:class:`Protocol`).

    Args:
        hand: the :class:`grasp_jax.hands.Hand` (its URDF, ``hand.path``, is read by MuJoCo; the
            built-in hand's is generated).
        mesh: the object (``trimesh.Trimesh`` or :class:`grasp_jax.objects.Mesh`), metres.
        result: a :class:`grasp_jax.hands.HandGraspResult`, or anything with ``position (S, 3)``,
            ``quaternion (S, 4)`` (wxyz; the wrist in the object's frame), ``joints``,
            ``pregrasp`` and optionally ``squeeze`` ``(S, J)`` in ``hand.joint_names`` order.
            Without ``squeeze`` the squeeze goes ``Protocol.squeeze`` of the way from pre-grasp to
            grasp past the grasp.
        protocol, seed, workers, progress: as :func:`grasp_jax.sim.simulate_jaws`.
        rows: the rows of ``result`` to simulate (default all).

    Returns:
        :class:`SimResult` of the simulated rows.

    Raises:
        ValueError: shapes that do not match the hand, or a mesh that cannot be decomposed.
    """
    protocol = Protocol() if protocol is None else protocol
    arrays = _arrays(hand, result, protocol)
    if rows is not None:
        arrays = tuple(a[np.asarray(rows)] for a in arrays)
    obj = sim_object(mesh, mass=protocol.mass, params=protocol.decomposition)
    xml, bodies = hand_xml(hand, obj, protocol)
    init = (xml, bodies, tuple(hand.joint_names), protocol, protocol.force_magnitude, int(seed))
    out = run_batched(HandSim, init, arrays, workers=workers, progress=progress,
                      desc="simulating hand grasps")
    return SimResult.from_rows(out)


def _arrays(hand, result, protocol: Protocol) -> tuple:
    j = len(hand.joint_names)
    position = np.asarray(result.position, float)
    s = len(position)
    quaternion = np.asarray(result.quaternion, float)
    grasp, pregrasp = np.asarray(result.joints, float), np.asarray(result.pregrasp, float)
    squeeze = getattr(result, "squeeze", None)
    squeeze = grasp + protocol.squeeze * (grasp - pregrasp) if squeeze is None else np.asarray(squeeze, float)
    for name, a, shape in (("position", position, (s, 3)), ("quaternion", quaternion, (s, 4)),
                           ("joints", grasp, (s, j)), ("pregrasp", pregrasp, (s, j)),
                           ("squeeze", squeeze, (s, j))):
        if a.shape != shape:
            raise ValueError(f"result.{name} must have shape {shape} for hand {hand.name!r}; got {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError(f"result.{name} must be finite")
    if (np.linalg.norm(quaternion, axis=1) < 1e-12).any():
        raise ValueError("result.quaternion must be non-zero")
    return position, quaternion, pregrasp, grasp, squeeze
