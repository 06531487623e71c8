"""The parallel-jaw gripper of :mod:`grasp_jax.grippers` in MuJoCo, and :func:`simulate_jaws`.

The gripper is a mocap body (the palm) placed at each grasp's pose, with two fingers on slide joints
along the closing axis, each driven by a position actuator whose force saturates at
``Protocol.jaw_force``; an equality constraint couples the two jaws (as the linkage of a Franka or
Robotiq gripper does), so the object is held centred between them. The bodies are the boxes of
:func:`grasp_jax.grippers.gripper_boxes` (``ParallelJaw.scaled`` where the gripper has none). Each
grasp starts with the jaws at its opening ``width``; the targets then move to the closed position
(the jaws stop on the object and squeeze).
"""

from __future__ import annotations

import numpy as np

from ..grippers._contacts import check_poses
from ..grippers._gripper import ParallelJaw
from ._episode import Scene, run_episode
from ._object import sim_object
from ._pool import run_batched
from ._protocol import Protocol, SimResult
from ._scene import gripper_geom_defaults, object_assets, object_body, option

#: The gripper simulated where none is given: the proportions of ``ParallelJaw.scaled(0.1)``.
DEFAULT_GRIPPER = ParallelJaw.scaled(0.1)


def body_gripper(gripper: ParallelJaw) -> ParallelJaw:
    """The gripper as simulated: ``gripper``, or ``ParallelJaw.scaled`` where it has no body."""
    return gripper if gripper.has_body else ParallelJaw.scaled(gripper.max_width, gripper.min_width)


def jaw_xml(obj, gripper: ParallelJaw, protocol: Protocol) -> str:
    """The MJCF of the object and the jaw gripper (fingers open at ``max_width``)."""
    g = body_gripper(gripper)
    t, b, length = g.finger_size
    z = g.tip_depth - 0.5 * length
    half = 0.5 * g.max_width
    travel = half - 0.5 * g.min_width
    kp, force, fm = protocol.jaw_kp, protocol.jaw_force, protocol.finger_mass
    damping = 2.0 * np.sqrt(kp * fm)
    fingers = []
    for i, sign in ((0, -1.0), (1, 1.0)):
        fingers.append(
            f'<body name="finger{i}" pos="{sign * (half + 0.5 * t):.9g} 0 {z:.9g}">'
            f'<joint name="jaw{i}" type="slide" axis="{-sign:g} 0 0" range="0 {travel:.9g}" '
            f'damping="{damping:.9g}"/>'
            f'<geom class="gripper" type="box" size="{0.5 * t:.9g} {0.5 * b:.9g} {0.5 * length:.9g}" '
            f'mass="{fm:.9g}"/></body>')
    palm = ""
    if g.palm_size is not None:
        pz = g.tip_depth - length - 0.5 * g.palm_size[2]
        palm = (f'<geom class="gripper" type="box" pos="0 0 {pz:.9g}" size="{0.5 * g.palm_size[0]:.9g} '
                f'{0.5 * g.palm_size[1]:.9g} {0.5 * g.palm_size[2]:.9g}"/>')
    actuators = "".join(f'<position joint="jaw{i}" kp="{kp:.9g}" ctrlrange="0 {travel:.9g}" '
                        f'forcelimited="true" forcerange="{-force:.9g} {force:.9g}"/>' for i in range(2))
    return (f'<mujoco model="jaws">{option(protocol)}<default>{gripper_geom_defaults(protocol)}</default>'
            f'<asset>{object_assets(obj)}</asset><worldbody>{object_body(obj, protocol)}'
            f'<body name="hand" mocap="true">{palm}{"".join(fingers)}</body></worldbody>'
            f'<equality><joint joint1="jaw0" joint2="jaw1"/></equality>'
            f'<actuator>{actuators}</actuator></mujoco>')


def _quat(rot: np.ndarray) -> np.ndarray:
    """The unit quaternion (w, x, y, z) of a rotation matrix."""
    import mujoco

    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(rot).ravel())
    return q


class JawSim:
    """A worker's jaw scene: built once, then one grasp after another (:meth:`run`)."""

    def __init__(self, xml: str, gripper: ParallelJaw, protocol: Protocol, force: float, seed: int):
        self.scene = Scene(xml, ["finger0", "finger1"])
        self.gripper, self.protocol, self.force, self.seed = gripper, protocol, force, seed

    def run(self, index: int, center, axis, approach, width):
        """One grasp: ``(status, held (6,), displacement (6,), rotation (6,))``."""
        scene, p, g = self.scene, self.protocol, self.gripper
        mj, m, d = scene.mj, scene.model, scene.data
        mj.mj_resetData(m, d)
        if p.pose_noise > 0:
            rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(index,)))
            center = center + rng.normal(0.0, p.pose_noise, 3)
        binormal = np.cross(approach, axis)
        d.mocap_pos[0] = center
        d.mocap_quat[0] = _quat(np.stack([axis, binormal, approach], axis=-1))
        start = np.full(2, 0.5 * (g.max_width - width))
        d.qpos[m.jnt_qposadr[m.actuator_trnid[:, 0]]] = start
        closed = np.full(2, 0.5 * (g.max_width - g.min_width))
        return run_episode(scene, p, [start, closed], self.force)


def simulate_jaws(mesh, centers, axes, approaches, widths, *, gripper: ParallelJaw | None = None,
                  protocol: Protocol | None = None, seed: int = 0, workers: int | None = None,
                  progress: bool = False) -> SimResult:
    """Simulate ``k`` parallel-jaw grasps of a mesh in MuJoCo (:class:`Protocol`).

    Args:
        mesh: the object, a ``trimesh.Trimesh`` or :class:`grasp_jax.objects.Mesh` (metres); its
            convex decomposition is cached (:func:`grasp_jax.sim.decompose`).
        centers, axes, approaches: ``(k, 3) float`` jaw poses (:mod:`grasp_jax.grippers`); axes and
            approaches are normalized and must be orthogonal.
        widths: ``(k,) float`` openings at the start (the pre-grasp), within the gripper's range.
        gripper: the :class:`~grasp_jax.grippers.ParallelJaw` (default :data:`DEFAULT_GRIPPER`; one
            without a body gets the boxes of ``ParallelJaw.scaled``).
        protocol: the numbers of the check (default ``Protocol()``).
        seed: draws of ``Protocol.pose_noise`` (grasp ``i`` uses its own stream, so results do not
            depend on ``workers``).
        workers: processes (default: one per available core).
        progress: show a tqdm bar.

    Returns:
        :class:`SimResult` of ``k`` grasps.

    Raises:
        ValueError: bad shapes or widths, or a mesh that cannot be decomposed.
    """
    gripper = DEFAULT_GRIPPER if gripper is None else gripper
    if not isinstance(gripper, ParallelJaw):
        raise ValueError(f"gripper must be a grasp_jax.grippers.ParallelJaw; got {type(gripper).__name__}")
    protocol = Protocol() if protocol is None else protocol
    if not isinstance(protocol, Protocol):
        raise ValueError(f"protocol must be a grasp_jax.sim.Protocol; got {type(protocol).__name__}")
    centers, axes, widths, approaches = check_poses(centers, axes, widths, approaches, gripper)
    if approaches is None:
        raise ValueError("approaches are needed: the gripper's body is simulated")
    obj = sim_object(mesh, mass=protocol.mass, params=protocol.decomposition)
    xml = jaw_xml(obj, gripper, protocol)
    init = (xml, body_gripper(gripper), protocol, protocol.force_magnitude, int(seed))
    rows = run_batched(JawSim, init, (centers, axes, approaches, widths), workers=workers,
                       progress=progress, desc="simulating jaw grasps")
    return SimResult.from_rows(rows)
