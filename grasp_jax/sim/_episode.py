"""One simulated grasp in MuJoCo, whatever the gripper: close, squeeze, then the six forces.

A gripper model (jaws or a hand) gives a compiled ``MjModel`` with a free body ``object``, the
geoms of the gripper, position actuators and two control vectors (pre-grasp, then the squeeze
target); :func:`run_episode` plays the protocol on it and returns one row of a
:class:`~grasp_jax.sim.SimResult`.
"""

from __future__ import annotations

import numpy as np

from ._protocol import DIRECTION_VECTORS, Protocol, SimStatus


class Scene:
    """A compiled model, its data and the ids the protocol needs.

    Args:
        xml: the MJCF of the scene: a body named ``object`` with a free joint, the gripper.
        hand_bodies: names of the gripper's bodies whose contacts with the object count as touch
            (each finger or link; two of them must touch after the squeeze).
    """

    def __init__(self, xml: str, hand_bodies):
        import mujoco

        self.mj = mujoco
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.obj = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "object")
        if self.obj < 0:
            raise ValueError("the scene has no body named 'object'")
        self.obj_geoms = np.flatnonzero(m.geom_bodyid == self.obj)
        self.is_obj_geom = np.zeros(m.ngeom, bool)
        self.is_obj_geom[self.obj_geoms] = True
        ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in hand_bodies]
        self.hand_bodies = np.asarray(ids)
        self.obj_qpos = m.jnt_qposadr[m.body_jntadr[self.obj]]
        self.obj_dof = m.jnt_dofadr[m.body_jntadr[self.obj]]
        self.state_spec = mujoco.mjtState.mjSTATE_INTEGRATION
        self.state = np.zeros(mujoco.mj_stateSize(m, self.state_spec))

    def _object_contacts(self):
        """``(depth (n,), body (n,))`` of the contacts between the object and anything else."""
        d = self.data
        n = d.ncon
        if n == 0:
            return np.zeros(0), np.zeros(0, int)
        g1, g2 = d.contact.geom1[:n], d.contact.geom2[:n]
        o1, o2 = self.is_obj_geom[g1], self.is_obj_geom[g2]
        keep = o1 ^ o2
        other = np.where(o1, g2, g1)[keep]
        return -d.contact.dist[:n][keep], self.model.geom_bodyid[other]

    def penetration(self) -> float:
        """The deepest penetration of the gripper into the object now (0 without contact), m."""
        self.mj.mj_forward(self.model, self.data)
        depth, _ = self._object_contacts()
        return float(depth.max()) if len(depth) else 0.0

    def touching(self) -> int:
        """How many of the gripper's ``hand_bodies`` touch the object now."""
        _, bodies = self._object_contacts()
        return int(np.isin(self.hand_bodies, bodies).sum())

    def diverged(self) -> bool:
        d = self.data
        bad = d.warning[self.mj.mjtWarning.mjWARN_BADQACC].number > 0
        return bool(bad or not np.isfinite(d.qpos).all())

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The object's centre of mass (3,) and orientation quaternion (4,) now."""
        return self.data.xipos[self.obj].copy(), self.data.xquat[self.obj].copy()


#: Time steps between two updates of a ramp's controls, and between two checks of the object's motion.
STRIDE = 5


def ramp(scene: Scene, start: np.ndarray, stop: np.ndarray, steps: int) -> None:
    """Move the controls linearly from ``start`` to ``stop`` over ``steps`` steps (in stairs of
    :data:`STRIDE` steps)."""
    mj, m, d = scene.mj, scene.model, scene.data
    done = 0
    while done < steps:
        n = min(STRIDE, steps - done)
        done += n
        d.ctrl[:] = start + (stop - start) * (done / steps)
        mj.mj_step(m, d, n)


def _angle(q: np.ndarray, ref: np.ndarray) -> float:
    return float(2.0 * np.arccos(min(1.0, abs(float(q @ ref)))))


def _resting(qvel: np.ndarray, protocol: Protocol) -> bool:
    """Whether the object's speed (m/s) and spin (rad/s) are both under ``settle_speed``."""
    v, w = qvel[:3], qvel[3:]
    return bool(v @ v < protocol.settle_speed**2 and w @ w < protocol.settle_speed**2)


def hold(scene: Scene, protocol: Protocol, force: float, reference: tuple | None = None,
         frame: np.ndarray | None = None):
    """The six force tests from the state saved in ``scene.state``: ``(held (6,) bool,
    displacement (6,), rotation (6,), diverged bool)``, the object's motion measured from
    ``reference`` (centre of mass, quaternion; default: its pose in the saved state), the forces
    along the columns of ``frame`` (3, 3) (default: the world's axes). A direction stops at the
    first check (every :data:`STRIDE` steps) that finds the object out of the tolerance, and holds
    at the first check after ``Protocol.settle_time`` that finds it at rest (``settle_speed``)."""
    mj, m, d = scene.mj, scene.model, scene.data
    held = np.zeros(6, bool)
    disp, rot = np.zeros(6), np.zeros(6)
    steps = protocol.steps(protocol.hold_time)
    settle = protocol.steps(protocol.settle_time) if protocol.settle_speed > 0 else steps + 1
    directions = DIRECTION_VECTORS if frame is None else DIRECTION_VECTORS @ np.asarray(frame).T
    for k, direction in enumerate(directions):
        mj.mj_setState(m, d, scene.state, scene.state_spec)
        mj.mj_forward(m, d)
        com0, quat0 = scene.pose() if reference is None else reference
        d.xfrc_applied[scene.obj, :3] = force * direction
        ok, done = True, 0
        while done < steps:
            n = min(STRIDE, steps - done)
            done += n
            mj.mj_step(m, d, n)
            delta = d.xipos[scene.obj] - com0
            dx = float(np.sqrt(delta @ delta))
            da = _angle(d.xquat[scene.obj], quat0)
            disp[k], rot[k] = max(disp[k], dx), max(rot[k], da)
            if dx >= protocol.max_displacement or da >= protocol.max_rotation or not np.isfinite(dx):
                ok = False
                break
            if done >= settle and _resting(d.qvel[scene.obj_dof:scene.obj_dof + 6], protocol):
                break
        d.xfrc_applied[scene.obj] = 0.0
        if scene.diverged():
            return held, disp, rot, True
        held[k] = ok
    return held, disp, rot, False


def run_episode(scene: Scene, protocol: Protocol, controls, force: float, frame: np.ndarray | None = None):
    """Play the protocol from the state set in ``scene.data`` (gripper at its pre-grasp, object at
    rest): ``(status, held (6,) bool, displacement (6,), rotation (6,))``.

    ``controls`` are the actuators' controls at the pre-grasp, then at each later waypoint (the
    grasp, the squeeze): they move linearly from the pre-grasp to the next over ``close_time``,
    then to each further one over ``squeeze_time``, and stay at the last for ``squeeze_time``. The
    forces pull along the columns of ``frame`` (the object's axes; default the world's). With
    ``Protocol.reference == "start"`` the object's motion is measured from its pose before the
    gripper closes, so an object that the closing turns or pushes away fails."""
    mj, m, d = scene.mj, scene.model, scene.data
    nan = np.full(6, np.nan)
    controls = [np.asarray(c, float) for c in controls]
    d.ctrl[:] = controls[0]
    if scene.penetration() > protocol.penetration:
        return SimStatus.PENETRATION, np.zeros(6, bool), nan, nan
    start = scene.pose()
    for i in range(1, len(controls)):
        seconds = protocol.close_time if i == 1 else protocol.squeeze_time
        ramp(scene, controls[i - 1], controls[i], protocol.steps(seconds))
    mj.mj_step(m, d, protocol.steps(protocol.squeeze_time))
    if scene.diverged():
        return SimStatus.UNSTABLE, np.zeros(6, bool), nan, nan
    mj.mj_forward(m, d)
    if scene.touching() < 2:
        return SimStatus.NO_CONTACT, np.zeros(6, bool), nan, nan
    mj.mj_getState(m, d, scene.state, scene.state_spec)
    reference = start if protocol.reference == "start" else None
    held, disp, rot, bad = hold(scene, protocol, force, reference, frame)
    if bad:
        return SimStatus.UNSTABLE, np.zeros(6, bool), disp, rot
    return SimStatus.OK, held, disp, rot
