"""Robust labels of parallel-jaw grasps: the closing line cast again under noise.

A jaw grasp is a pose of the hand: under noise the jaws close on the line they are on.
:func:`robust_jaws` draws ``samples`` perturbations of every grasp (a :class:`grasp_jax.Noise`,
with the units and draws of :func:`grasp_jax.robust`), casts each perturbed closing line onto the
mesh (:func:`jaw_contacts`) and scores the contacts through the scoring path of
:func:`grasp_jax.robust`. Per grasp and sample (object centre ``o``, radius ``r``):

* ``position``: the jaw centre moves by ``r * position * (g_1 x + g_2 y)`` across the closing axis;
* ``rotation``, ``translation``: the object moves by ``x -> R (x - o) + o + r t`` under the hand;
* ``normal``, ``friction``: as :func:`grasp_jax.robust` draws them per contact slot (jaw 0, jaw 1).

A perturbation whose jaws do not close on two contacts (any :class:`JawStatus` but ``OK``) counts
as not force-closure, Q 0, margin 0. The draws are :func:`grasp_jax._noise.draws` for ``n = 2``
contacts in 3D, the same for every grasp and those :func:`grasp_jax.robust` gives the same key.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .. import _noise, _robust
from .._api import _check_common, check_contact
from .._batch import pad_rows
from .._contact import ContactModel
from .._validate import check_key, check_scalar, is_traced
from ..objects._mesh import center_radius
from ._antipodal import _frame
from ._contacts import as_trimesh, check_poses, jaw_contacts
from ._gripper import JawStatus, ParallelJaw


def _center_radius(mesh, tm) -> tuple[np.ndarray, float]:
    """The object's centre and radius: a grasp_jax object's own, else :class:`grasp_jax.objects.Mesh`'s
    rule for the trimesh (centre of mass of a closed volume, else the area centroid; the largest
    distance from it to a vertex)."""
    center, radius = getattr(mesh, "center", None), getattr(mesh, "radius", None)
    if center is not None and radius is not None and not hasattr(mesh, "faces"):
        return np.asarray(center, float).reshape(3), float(radius)

    return center_radius(tm, tm.is_volume)


class _JawPerturber:
    """The perturbations of one :func:`robust_jaws` call, in the protocol of
    ``grasp_jax._robust.label``: slices of grasps re-cast under noise, with an ``ok`` mask."""

    def __init__(self, mesh, centers, axes, widths, approaches, mu, noise, key, samples, gripper, collision,
                 num_edges, torsion):


        if not isinstance(noise, _noise.Noise):
            raise TypeError(f"noise must be a grasp_jax.Noise; got {type(noise).__name__}")
        key = check_key(key, "robust_jaws")
        self.tm = as_trimesh(mesh)
        # the nominal contacts, of the poses as given (this validates them, and the collision check's
        # needs); they set the dtype, the LP budgets and the precision, and zero noise gives them back
        self.nominal = jaw_contacts(self.tm, centers, axes, widths, approaches=approaches, gripper=gripper,
                                    collision=collision)
        centers, axes, widths, approaches = check_poses(centers, axes, widths, approaches, gripper)
        self.centers, self.axes, self.widths, self.approaches = centers, axes, widths, approaches
        self.gripper, self.collision, self.noise, self.samples = gripper, bool(collision), noise, samples
        self.origin, self.scale = _center_radius(mesh, self.tm)
        points, normals, _, batch, mu, num_edges, scope = _check_common(
            self.nominal.points, self.nominal.normals, mu, num_edges, None, torsion)
        if is_traced(mu, torsion):
            raise ValueError("robust_jaws runs on concrete arrays (outside jit, grad and vmap)")
        self.points, self.normals, self.batch = points, normals, batch
        self.mu, self.num_edges, self.scope = mu, num_edges, scope
        self.dtype = points.dtype
        self.total = len(points)
        self.per = max(1, _robust.ROWS // samples)
        self.draw = _noise.draws(key, samples, 2, 3, np.float64)
        self.sigmas = np.array([0.0, noise.normal, noise.friction[0], noise.friction[1], noise.friction_sigma,
                                0.0, 0.0], np.float64)
        # the hand's steps (S, 2: coordinates in each axis's tangent frame) and the object's poses
        self.step = noise.position * self.scale * self.draw.tangent[:, 0, :]  # (S, 2)
        self.pose = noise.rotation > 0 or noise.translation > 0
        self.rotations = self.shift = None
        if self.pose:

            with jax.enable_x64(True):
                self.rotations = np.asarray(jax.vmap(_noise.rotation)(
                    jnp.asarray(noise.rotation * self.draw.rotation, jnp.float64)))  # (S, 3, 3)
            self.shift = noise.translation * self.scale * self.draw.translation  # (S, 3)

    @property
    def center(self):
        return self.origin

    def start(self) -> None:
        pass

    def poses(self, start: int, stop: int):
        """The perturbed poses of grasps ``start..stop`` in the object's frame: ``(g, S, 3)``
        centres, axes and approaches (``None`` without them)."""

        c, u = self.centers[start:stop], self.axes[start:stop]
        a = None if self.approaches is None else self.approaches[start:stop]
        g, S = len(c), self.samples
        x, y = _frame(u)
        centers = c[:, None] + self.step[None, :, :1] * x[:, None] + self.step[None, :, 1:] * y[:, None]
        axes = np.broadcast_to(u[:, None], (g, S, 3))
        approaches = None if a is None else np.broadcast_to(a[:, None], (g, S, 3))
        if self.pose:
            # the object moved by x -> R (x - o) + o + t: the hand in its frame, x -> R^T (x - o - t) + o
            R = self.rotations
            centers = np.einsum("gsi,sij->gsj", centers - self.origin - self.shift[None], R) + self.origin
            axes = np.einsum("gi,sij->gsj", u, R)
            approaches = None if a is None else np.einsum("gi,sij->gsj", a, R)
        return centers, axes, approaches

    def slice(self, start: int, stop: int):
        """``(points (g, S, 2, 3), normals (g, S, 2, 3), mu (g, S, 2), ok (g, S))`` of grasps
        ``start..stop``. Call inside ``self.scope``."""


        g, S = stop - start, self.samples
        if self.noise.moves_contacts:
            centers, axes, approaches = self.poses(start, stop)
            found = jaw_contacts(self.tm, centers.reshape(-1, 3), axes.reshape(-1, 3),
                                 np.repeat(self.widths[start:stop], S),
                                 approaches=None if approaches is None else approaches.reshape(-1, 3),
                                 gripper=self.gripper, collision=self.collision)
            points, normals = found.points.reshape(g, S, 2, 3), found.normals.reshape(g, S, 2, 3)
            ok = (found.status == JawStatus.OK).reshape(g, S)
        else:  # every sample has the nominal contacts, bit for bit
            points = np.broadcast_to(self.points[start:stop, None], (g, S, 2, 3))
            normals = np.broadcast_to(self.normals[start:stop, None], (g, S, 2, 3))
            ok = np.broadcast_to((self.nominal.status[start:stop] == JawStatus.OK)[:, None], (g, S))
        _, _, tilt, friction = self.noise._flags()
        if not tilt and friction is None:  # every jaw has the nominal friction
            return points, normals, np.full((g, S, 2), self.mu, self.dtype), ok
        # tilt and friction by gj.robust's own code, in pieces of one padded size (one program)
        pieces = []
        for lo in range(0, g, self.per):
            hi = min(lo + self.per, g)
            out = _noise.perturb_moved(pad_rows(points[lo:hi], self.per), pad_rows(normals[lo:hi], self.per),
                                         self.draw, self.sigmas, jnp.asarray(self.mu, self.dtype),
                                         flags=self.noise._flags())
            pieces.append(tuple(np.asarray(a)[:hi - lo] for a in out))
        _, normals, mu = (np.concatenate(a) if len(pieces) > 1 else a[0] for a in zip(*pieces))
        return points, normals, mu, ok


def robust_jaws(
    mesh,
    centers,
    axes,
    widths,
    approaches=None,
    *,
    mu,
    noise,
    key,
    samples: int = 100,
    gripper: ParallelJaw | None = None,
    collision: bool = False,
    contact: str = "soft",
    torsion=None,
    quantile: float = 0.1,
    num_edges: int = 8,
    torque_test: str = "exact",
    margin: bool = True,
    torque_scale: float | None = None,
    progress: bool = False,
):
    """Robust labels of parallel-jaw grasps: P(force-closure), mean and low quantile of Q and of
    the min-weight margin when the object's pose, the hand's position, the normals and the friction
    differ from the nominal ones, the contacts found again by casting each perturbed closing line.

    The noise model is in this module's docstring (and the guide, ``docs/guides/grippers.md``):
    ``noise.position`` moves the jaw centre across the closing axis (object radii), the pose noise
    moves the object under the fixed hand (radians, object radii), normal and friction noise apply
    to the new contacts as in :func:`grasp_jax.robust`. Every grasp meets the same ``samples``
    draws of ``key`` (common random numbers; the labels do not depend on the batch). A draw whose
    jaws do not close on two contacts counts as not force-closure, Q 0. The perturbed contacts are
    scored by :func:`grasp_jax.robust`'s path, ``ROWS`` perturbed grasps at a time (one ray query
    for each such slice). With zero noise every sample is the nominal grasp: ``p_fc`` is the
    verdict of :func:`jaw_contacts` + :func:`grasp_jax.evaluate` (0 where the jaws fail) and
    ``q_mean == q_low`` its Q, exactly.

    Args:
        mesh: a :class:`grasp_jax.objects.Mesh` (or any grasp_jax 3D object with a ``.mesh``) or
            a ``trimesh.Trimesh`` (face normals outward). The object's centre and radius are its
            ``center`` and ``radius``; a bare trimesh gets :class:`grasp_jax.objects.Mesh`'s
            (centre of mass of a closed volume, else area centroid; the largest vertex distance).
        centers: ``(k, 3)`` jaw centres, in the mesh's units.
        axes: ``(k, 3)`` closing axes (normalized here).
        widths: ``(k,)`` openings (or one number), in the mesh's units.
        approaches: ``(k, 3)`` approach directions orthogonal to the axes (needed for
            ``collision`` only; rotated with the pose noise).
        mu: nominal friction coefficient > 0.
        noise: a :class:`grasp_jax.Noise`.
        key: a ``jax.random.key`` (or an integer seed).
        samples: perturbations per grasp (>= 2).
        gripper: a :class:`ParallelJaw` (widths in its range; contacts closer than its
            ``min_width`` fail as ``TOO_NARROW``).
        collision: check the gripper body at every perturbed pose (python-fcl; slow: one FCL
            query per perturbed grasp).
        contact, torsion: the contact model, as :func:`grasp_jax.evaluate` (``"soft"`` by
            default, as :func:`score_grasps`; ``torsion`` a length, :func:`grasp_jax.patch_torsion`;
            held fixed while friction varies).
        quantile, num_edges, torque_test, margin, progress: as :func:`grasp_jax.robust`.
        torque_scale: the margin's torque length (default the object's radius).

    Returns:
        :class:`grasp_jax.RobustResult` of ``k`` grasps (NumPy arrays).

    Raises:
        ValueError: bad poses (as :func:`jaw_contacts`), a bad ``mu``, ``samples``, ``quantile``,
            contact model or key, or a negative sigma (:class:`grasp_jax.Noise`).
        TypeError: ``noise`` that is not a :class:`grasp_jax.Noise`.
    """

    samples, quantile = _robust.check_labels(samples, quantile, torque_test)
    contact, torsion = check_contact(contact, torsion, 3)
    perturber = _JawPerturber(mesh, centers, axes, widths, approaches, mu, noise, key, samples, gripper, collision,
                              num_edges, torsion)
    model = ContactModel(contact, perturber.num_edges, torsion)
    torque_scale = check_scalar("torque_scale", perturber.scale if torque_scale is None else torque_scale)
    result, stuck = _robust.label(perturber, quantile=quantile, torque_test=torque_test, model=model, margin=margin,
                                  torque_scale=torque_scale, progress=progress)
    _robust.warn_unconverged(result, stuck, "robust_jaws")
    return result
