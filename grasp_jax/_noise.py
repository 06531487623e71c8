"""The noise model of robust labels: what may differ from a nominal grasp (:class:`Noise`), its
draws (common random numbers), and the perturbation of one grasp on an object's surface.

Units: ``position`` and ``translation`` in object radii (``surface.scale``), ``normal`` and
``rotation`` in radians, all standard deviations per tangent coordinate or axis; ``friction`` a
``(lo, hi)`` uniform factor or ``friction_sigma`` a lognormal one. A contact moves along the
surface (``Surface.retract``); under pose noise the object moves about its centre under fixed
fingers and each contact goes to the surface point nearest its finger (:data:`PROJECTION_STEPS`
retractions). The grasp is scored in the object's frame.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._cones import safe_normalize, tangent_frame

#: Retractions towards a finger's point that find the nearest surface point under pose noise.
PROJECTION_STEPS = 2


@dataclasses.dataclass(frozen=True)
class Noise:
    """What may differ from the nominal grasp; every field 0 (or ``(1, 1)``) is no noise.

    Attributes:
        position: contact position: standard deviation per tangent axis, in units of the
            object's radius; contacts move along the surface (needs an object).
        normal: normal tilt: standard deviation per tangent axis, radians.
        friction: ``(lo, hi)``, ``0 < lo <= hi``: each contact's friction is ``mu * U[lo, hi]``.
        friction_sigma: instead of ``friction``: ``mu * exp(N(0, friction_sigma^2))`` per contact.
        rotation: object pose: standard deviation of each rotation-vector component, radians
            (needs an object).
        translation: object pose: standard deviation of each translation component, in units of
            the object's radius (needs an object).

    Raises:
        ValueError: a negative or non-finite sigma, or a bad friction range.
    """

    position: float = 0.0
    normal: float = 0.0
    friction: tuple[float, float] = (1.0, 1.0)
    friction_sigma: float = 0.0
    rotation: float = 0.0
    translation: float = 0.0

    def __post_init__(self):
        for name in ("position", "normal", "friction_sigma", "rotation", "translation"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
                    or not math.isfinite(value) or value < 0:
                raise ValueError(f"Noise.{name} must be a finite number >= 0 (a standard deviation); got {value!r}")
            object.__setattr__(self, name, float(value))
        try:
            lo, hi = (float(v) for v in self.friction)
        except (TypeError, ValueError):
            raise ValueError(f"Noise.friction must be a pair (lo, hi) of multipliers; got {self.friction!r}") from None
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
            raise ValueError(f"Noise.friction must be multipliers 0 < lo <= hi; got {self.friction!r}")
        if self.friction_sigma > 0 and (lo, hi) != (1.0, 1.0):
            raise ValueError("Noise: give friction=(lo, hi) (uniform) or friction_sigma (lognormal), not both")
        object.__setattr__(self, "friction", (lo, hi))

    @property
    def moves_contacts(self) -> bool:
        """Whether contacts move on the surface (position or pose noise): needs an object."""
        return self.position > 0 or self.rotation > 0 or self.translation > 0

    @property
    def is_zero(self) -> bool:
        """No noise at all: every sample is the nominal grasp."""
        return not self.moves_contacts and self.normal == 0 and not self._friction_varies

    @property
    def _friction_varies(self) -> bool:
        return self.friction_sigma > 0 or self.friction != (1.0, 1.0)

    def _flags(self) -> tuple:
        """The static structure of the perturbation: which kinds are on."""
        return (self.position > 0, self.rotation > 0 or self.translation > 0, self.normal > 0,
                "lognormal" if self.friction_sigma > 0 else "uniform" if self._friction_varies else None)

    def __str__(self) -> str:
        parts = []
        if self.position:
            parts.append(f"position {self.position:g} R")
        if self.normal:
            parts.append(f"normal {self.normal:g} rad")
        if self.friction != (1.0, 1.0):
            parts.append(f"friction x U[{self.friction[0]:g}, {self.friction[1]:g}]")
        if self.friction_sigma:
            parts.append(f"friction x lognormal({self.friction_sigma:g})")
        if self.rotation:
            parts.append(f"rotation {self.rotation:g} rad")
        if self.translation:
            parts.append(f"translation {self.translation:g} R")
        return "Noise(" + (", ".join(parts) or "none") + ")"


class Draws(NamedTuple):
    """Standard random numbers of ``S`` samples for grasps of ``n`` contacts in ``d`` dimensions,
    the same for every grasp (common random numbers); each kind from its own key, so turning one
    kind of noise on leaves the others' draws as they were.

    Attributes:
        tangent: ``(S, n, d - 1)`` standard normal: position steps in each contact's tangent frame.
        tilt: ``(S, n, d - 1)`` standard normal: normal tilts.
        uniform: ``(S, n)`` uniform on [0, 1): friction multipliers (uniform range).
        normal: ``(S, n)`` standard normal: friction multipliers (lognormal).
        rotation: ``(S, 3)`` (3D) or ``(S, 1)`` (2D) standard normal: rotation vectors.
        translation: ``(S, d)`` standard normal: translations.
    """

    tangent: np.ndarray
    tilt: np.ndarray
    uniform: np.ndarray
    normal: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray


def draws(key, samples: int, n: int, d: int, dtype=np.float64) -> Draws:
    """The :class:`Draws` of ``key`` (a ``jax.random.key``) as NumPy arrays of ``dtype``."""
    dtype = np.dtype(dtype)
    with jax.enable_x64(dtype == np.float64):
        return Draws(*(np.asarray(a) for a in _draw(key, samples, n, d, dtype)))


@functools.partial(jax.jit, static_argnums=(1, 2, 3, 4))
def _draw(key, samples: int, n: int, d: int, dtype: np.dtype) -> tuple:
    """The six arrays of :func:`draws`, in one compiled program per shape (op by op, each of the six
    draws compiled a program of its own for every new shape); the same numbers as drawn one by one."""
    keys = jax.random.split(key, 6)
    shapes = ((samples, n, d - 1), (samples, n, d - 1), (samples, n), (samples, n),
              (samples, 3 if d == 3 else 1), (samples, d))
    return tuple(jax.random.uniform(k, s, dtype) if i == 2 else jax.random.normal(k, s, dtype)
                 for i, (k, s) in enumerate(zip(keys, shapes)))


# ---------------------------------------------------------------------------------------------
# Perturbations (one grasp, one sample; vmapped over both).


def _tangents(normal):
    """``(d - 1, d)`` unit tangents of a unit ``normal: (d,)`` (``_cones.tangent_frame`` in 3D)."""
    if normal.shape[-1] == 2:
        return jnp.stack([-normal[1], normal[0]])[None]
    return jnp.stack(tangent_frame(normal))


def rotation(w):
    """The rotation matrix of a rotation vector ``w: (3,)`` (Rodrigues; the angle ``w[0]`` in 2D:
    ``w: (1,)``), exact and smooth at 0."""
    if w.shape[-1] == 1:
        c, s = jnp.cos(w[0]), jnp.sin(w[0])
        return jnp.stack([jnp.stack([c, -s]), jnp.stack([s, c])])
    sq = jnp.sum(w * w)
    small = sq < 1e-12
    theta = jnp.sqrt(jnp.where(small, 1.0, sq))
    a = jnp.where(small, 1.0 - sq / 6.0, jnp.sin(theta) / theta)
    b = jnp.where(small, 0.5 - sq / 24.0, (1.0 - jnp.cos(theta)) / (theta * theta))
    K = jnp.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]], w.dtype)
    return jnp.eye(3, dtype=w.dtype) + a * K + b * (K @ K)


def _tilt(normal, g):
    """``normal: (d,)`` tilted by the tangent-frame vector ``g: (d - 1,)`` (radians): by the
    angle ``|g|`` towards ``g``."""
    normal = safe_normalize(normal)
    t = g @ _tangents(normal)  # (d,)
    theta = jnp.sqrt(jnp.sum(g * g))
    ok = theta > 0
    safe = jnp.where(ok, theta, 1.0)
    return safe_normalize(jnp.cos(theta) * normal + jnp.where(ok, jnp.sin(theta) / safe, 1.0) * t)


def _moved(surface, contacts, draw, sigmas, position: bool, pose: bool):
    """The contacts of one sample moved over the surface by its position noise (a step in each
    contact's tangent frame, walked across edges by ``surface.retract``) and pose noise (each finger
    held in place while the object moves, the contact taken to the surface point under it by
    :data:`PROJECTION_STEPS` retractions). ``contacts``: leading ``(n,)``; returns the same."""
    s_pos, _, _, _, _, s_rot, s_trans = sigmas
    embed = jax.vmap(surface.embed)
    retract = jax.vmap(surface.retract)
    c = contacts
    if position:
        _, n0 = embed(c)
        steps = jnp.einsum("nk,nkd->nd", s_pos * draw.tangent, jax.vmap(_tangents)(n0))
        c = retract(c, steps)
    if pose:
        fingers, _ = embed(c)
        center = jnp.asarray(surface.center, fingers.dtype)
        R = rotation(s_rot * draw.rotation)
        # the object moved by x -> R (x - center) + center + t: fingers in its frame
        target = (fingers - center - s_trans * draw.translation) @ R + center
        for _ in range(PROJECTION_STEPS):
            here, _ = embed(c)
            c = retract(c, target - here)
    return c


def _perturb_one(surface, contacts, points, normals, draw, sigmas, mu, *, flags):
    """One sample of one grasp: ``(points (n, d), normals (n, d), mu (n,))``.

    ``contacts``: the grasp's :class:`~grasp_jax.surfaces.Contact` (leading ``(n,)``, or ``None``
    when contacts do not move); ``draw``: one sample of :class:`Draws`; ``sigmas``: ``(position,
    normal, friction lo, friction hi, friction sigma, rotation, translation)`` (scaled by the
    object's radius where they are lengths); ``flags``: :meth:`Noise._flags`.
    """
    position, pose, tilt, friction = flags
    s_pos, s_normal, lo, hi, s_mu, s_rot, s_trans = sigmas
    if position or pose:
        points, normals = jax.vmap(surface.embed)(_moved(surface, contacts, draw, sigmas, position, pose))
    if tilt:
        normals = jax.vmap(_tilt)(normals, s_normal * draw.tilt)
    n = points.shape[0]
    if friction == "uniform":
        mu = mu * (lo + (hi - lo) * draw.uniform)
    elif friction == "lognormal":
        mu = mu * jnp.exp(s_mu * draw.normal)
    else:
        mu = jnp.full((n,), mu, points.dtype)
    return points, normals, mu


@functools.partial(jax.jit, static_argnames=("flags",))
def perturb_all(surface, contacts, points, normals, draw, sigmas, mu, *, flags):
    """:func:`_perturb_one` for ``(g,)`` grasps x ``(S,)`` samples: ``(g, S, n, d)``, ``(g, S, n, d)``,
    ``(g, S, n)``."""
    one = functools.partial(_perturb_one, surface, flags=flags)
    over_samples = jax.vmap(one, in_axes=(None, None, None, 0, None, None))
    return jax.vmap(over_samples, in_axes=(0, 0, 0, None, None, None))(contacts, points, normals, draw, sigmas, mu)


@functools.partial(jax.jit, static_argnames=("flags",))
def perturb_moved(points, normals, draw, sigmas, mu, *, flags):
    """The normal tilt and friction of :func:`_perturb_one` (``flags``' last two) on contacts that
    already moved, one set per sample (parallel-jaw contacts cast again under noise:
    :func:`grasp_jax.grippers.robust_jaws`): ``(g, S, n, d)`` points and normals, sample ``s``
    with draw ``s``; returns as :func:`_perturb` (points unchanged)."""
    one = functools.partial(_perturb_one, None, None, flags=(False, False) + tuple(flags[2:]))
    over_samples = jax.vmap(one, in_axes=(0, 0, 0, None, None))
    return jax.vmap(over_samples, in_axes=(0, 0, None, None, None))(points, normals, draw, sigmas, mu)


# ---------------------------------------------------------------------------------------------
# A differentiable robust objective for the optimizer (objective="robust" of gj.optimize).

#: Perturbations per step of ``gj.optimize(objective="robust")`` (a fixed sample: the same draws
#: at every step, so the objective is a smooth function of the contacts).
OPTIMIZE_SAMPLES = 8


class Reparameterized(NamedTuple):
    """The fixed draws of ``objective="robust"``: :class:`Draws` of ``K`` samples and the sigmas
    (``_perturb_one``'s order, lengths in object radii times the radius); static flags apart."""

    draw: Draws
    sigmas: jax.Array


def reparameterized(noise: Noise, key, samples: int, n: int, d: int, scale: float, dtype) -> Reparameterized:
    """The draws and sigmas of ``objective="robust"`` (a pytree for the optimizer's program)."""
    draw = draws(key, samples, n, d, dtype)
    sigmas = np.array([noise.position * scale, noise.normal, noise.friction[0], noise.friction[1],
                       noise.friction_sigma, noise.rotation, noise.translation * scale], dtype)
    return Reparameterized(draw, sigmas)


def robust_value(surface, contacts, v, mu, noise: Reparameterized, objective, *, flags):
    """The mean of ``objective(points, normals, mu (n,))`` over the fixed perturbations of one
    grasp, differentiable in the ambient displacement ``v: (n, d)`` (in object radii; the
    optimizer's chart variable, 0 where the gradient is taken).

    Each perturbed contact is the one :func:`grasp_jax.robust` scores (:func:`_moved`: the
    position step walked over the surface, across edges; the pose noise's finger projected back)
    and ``v`` moves it in its own chart, ``surface.chart(moved, v)``: the derivative is that of
    the objective at the perturbed grasp when every contact moves by ``v``, carried along with it
    (where the perturbation stays on one face, exactly the derivative of moving the unperturbed
    contact first). Normals tilted, friction per contact. (A chart of the unperturbed contact,
    ``chart(c, v + step)``, kept a contact in its face's plane on a mesh: the objective never saw
    a slip across an edge, which is what loses a grasp near one.) Returns ``(mean value, value of
    each perturbation (K,))``."""
    position, pose, tilt, friction = flags
    _, s_normal, lo, hi, s_mu, _, _ = noise.sigmas

    def one(draw):
        moved = contacts
        if position or pose:
            moved = jax.lax.stop_gradient(_moved(surface, contacts, draw, noise.sigmas, position, pose))
        points, normals = jax.vmap(surface.chart)(moved, v * surface.scale)
        if tilt:
            normals = jax.vmap(_tilt)(normals, s_normal * draw.tilt)
        if friction == "uniform":
            m = mu * (lo + (hi - lo) * draw.uniform)
        elif friction == "lognormal":
            m = mu * jnp.exp(s_mu * draw.normal)
        else:
            m = jnp.full((points.shape[0],), mu, points.dtype)
        return objective(points, normals, m)

    values = jax.vmap(one)(noise.draw)
    return jnp.mean(values), values
