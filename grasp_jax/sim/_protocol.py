"""The simulation protocol (every number of it), the status of a simulated grasp, the result.

After DexGraspBench: no gravity; the gripper opens at its pre-grasp pose, closes, squeezes; then an
external force pulls the object along +x, -x, +y, -y, +z, -z (the object's frame) in turn, each
from the state after the squeeze. A direction holds when the object's centre of mass moves less
than ``max_displacement`` and the object turns less than ``max_rotation`` (measured from its pose
before the gripper closed, by default); a grasp succeeds when every direction holds.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, fields
from typing import NamedTuple

import numpy as np

from ._object import MASS, Decomposition

#: The six directions of the external force, in this order (columns of ``SimResult.directions``).
DIRECTIONS = ("+x", "-x", "+y", "-y", "+z", "-z")
#: The unit vectors of :data:`DIRECTIONS`, ``(6, 3)``.
DIRECTION_VECTORS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
#: The fields of :class:`Protocol` that may be 0.
_MAY_BE_ZERO = ("torsion", "pose_noise", "penetration", "squeeze", "settle_speed")
#: Standard gravity, m/s^2 (the default force is the object's weight).
GRAVITY = 9.81


@dataclass(frozen=True)
class Protocol:
    """Every number of a simulated check (SI units: m, kg, s, N, radians).

    Attributes:
        mass: the object's total mass (DexGraspBench: 0.1 kg for every object).
        force: the external force's magnitude; ``None``: ``force_scale`` times the object's weight.
        force_scale: the default force in units of the object's weight ``mass * 9.81``.
        friction: sliding friction coefficient of every contact (MuJoCo takes the larger of the
            two geoms'; both get this one).
        torsion: torsional friction of a contact, m (torque per unit normal force: a contact
            patch of radius r gives about ``2 r mu / 3``).
        solref: MuJoCo's contact ``solref`` (time constant, damping ratio): stiffer than MuJoCo's
            default (0.02, 1), so that a squeezed 100 g object sinks well under a millimetre into a jaw.
        solimp: MuJoCo's contact ``solimp``.
        timestep: MuJoCo's time step.
        close_time: time for the jaws (or joints) to move from the pre-grasp to the grasp target.
        squeeze_time: time the squeeze is held before the forces (the object settles).
        hold_time: time each external force is applied.
        settle_time, settle_speed: a direction holds early when, ``settle_time`` or more after the
            force came on, the object moves slower than ``settle_speed`` (m/s, and rad/s for its
            spin): under a constant force it is then in equilibrium (at that speed it would not
            leave the tolerance within ``hold_time``); ``settle_speed = 0``: always the whole
            ``hold_time``.
        max_displacement: a direction fails once the centre of mass moves this far.
        max_rotation: a direction fails once the object turns this much (15 degrees).
        reference: where motion is measured from: ``"start"``, the object's pose before the gripper
            closes (a grasp that knocks or turns the object while closing fails), or ``"squeeze"``,
            its pose after the squeeze (only the forces' effect counts).
        penetration: a gripper that starts deeper than this inside the object gets
            ``SimStatus.PENETRATION`` and is not simulated.
        jaw_force: the force limit of each jaw (position actuators saturate at it while squeezing):
            5 N, about five times the default load, so that a grip far from the centre of mass
            turns.
        jaw_kp: stiffness of each jaw's position actuator, N/m (the force saturates once the
            target is ``jaw_force / jaw_kp`` past the contact).
        finger_mass: mass of each jaw.
        hand_kp: position gain of a hand's joints, N m/rad (DexGraspBench's main branch: 5).
        hand_kv: damping of a hand's joints, N m s/rad.
        squeeze: how far past the grasp configuration a hand's squeeze target goes, as a fraction of
            the distance from pre-grasp to grasp, when the grasp gives no squeeze configuration.
        pose_noise: standard deviation of a Gaussian offset of the gripper's start position per
            axis (drawn per grasp from the seed); 0: the outcome does not depend on the seed.
        decomposition: the convex decomposition of the object (:class:`Decomposition`).
    """

    mass: float = MASS
    force: float | None = None
    force_scale: float = 1.0
    friction: float = 0.5
    torsion: float = 0.005
    solref: tuple = (0.004, 1.0)
    solimp: tuple = (0.95, 0.99, 0.001)
    timestep: float = 0.002
    close_time: float = 0.2
    squeeze_time: float = 0.1
    hold_time: float = 0.2
    settle_time: float = 0.04
    settle_speed: float = 0.001
    max_displacement: float = 0.02
    max_rotation: float = math.radians(15.0)
    reference: str = "start"
    penetration: float = 0.002
    jaw_force: float = 5.0
    jaw_kp: float = 5000.0
    finger_mass: float = 0.05
    hand_kp: float = 5.0
    hand_kv: float = 0.1
    squeeze: float = 0.5
    pose_noise: float = 0.0
    decomposition: Decomposition = Decomposition()

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in ("solref", "solimp"):
                if not all(isinstance(x, (int, float)) and math.isfinite(x) for x in value):
                    raise ValueError(f"Protocol.{f.name} must be finite numbers; got {value!r}")
                continue
            if f.name in ("decomposition", "reference") or (f.name == "force" and value is None):
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"Protocol.{f.name} must be a finite number; got {value!r}")
            if value < 0 or (value == 0 and f.name not in _MAY_BE_ZERO):
                raise ValueError(f"Protocol.{f.name} must be > 0; got {value!r}")
        if self.reference not in ("start", "squeeze"):
            raise ValueError(f"Protocol.reference must be 'start' or 'squeeze'; got {self.reference!r}")
        if not isinstance(self.decomposition, Decomposition):
            raise ValueError("Protocol.decomposition must be a grasp_jax.sim.Decomposition")

    @property
    def force_magnitude(self) -> float:
        """The external force, N."""
        return float(self.force) if self.force is not None else self.force_scale * self.mass * GRAVITY

    def steps(self, seconds: float) -> int:
        """The number of time steps in ``seconds``."""
        return max(1, int(round(seconds / self.timestep)))


class SimStatus(enum.IntEnum):
    """What happened to a simulated grasp (``int8`` per grasp); only ``OK`` grasps can succeed."""

    #: Simulated to the end: ``success`` and ``directions`` say whether it held.
    OK = 0
    #: The gripper starts inside the object deeper than ``Protocol.penetration``; not simulated.
    PENETRATION = 1
    #: After the squeeze the gripper does not touch the object with two fingers (or links).
    NO_CONTACT = 2
    #: The simulation diverged (MuJoCo reported a bad acceleration or a non-finite state).
    UNSTABLE = 3

    @property
    def message(self) -> str:
        """One sentence saying what the status means."""
        return _MESSAGES[self]


_MESSAGES = {
    SimStatus.OK: "simulated: the grasp held in the directions marked True",
    SimStatus.PENETRATION: "the gripper starts inside the object beyond the protocol's penetration threshold",
    SimStatus.NO_CONTACT: "after the squeeze the gripper does not touch the object with two fingers",
    SimStatus.UNSTABLE: "the simulation diverged",
}


class SimResult(NamedTuple):
    """The simulated check of ``k`` grasps.

    Attributes:
        success: ``(k,) bool``: held in every direction (and status ``OK``).
        directions: ``(k, 6) bool``: held against the force along each of :data:`DIRECTIONS`.
        status: ``(k,) int8`` :class:`SimStatus`.
        displacement: ``(k, 6) float64``: the largest displacement of the centre of mass in each
            direction's test, m (a failed direction stops once past the threshold; NaN where not
            simulated).
        rotation: ``(k, 6) float64``: the largest rotation, radians (likewise).
    """

    success: np.ndarray
    directions: np.ndarray
    status: np.ndarray
    displacement: np.ndarray
    rotation: np.ndarray

    def __len__(self) -> int:
        return len(self.success)

    @staticmethod
    def from_rows(rows) -> SimResult:
        """A result from per-grasp rows ``(status, held (6,), displacement (6,), rotation (6,))``."""
        status = np.array([int(r[0]) for r in rows], np.int8)
        held = np.array([r[1] for r in rows], bool).reshape(-1, 6)
        success = held.all(axis=1) & (status == SimStatus.OK)
        disp = np.array([r[2] for r in rows], float).reshape(-1, 6)
        rot = np.array([r[3] for r in rows], float).reshape(-1, 6)
        return SimResult(success, held, status, disp, rot)

    @staticmethod
    def concatenate(parts) -> SimResult:
        """One result from several, in order."""
        parts = list(parts)
        return SimResult(*(np.concatenate([getattr(p, f) for p in parts]) for f in SimResult._fields))
