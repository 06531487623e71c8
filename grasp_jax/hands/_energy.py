"""What the hand optimizer minimizes, for **one** hand configuration on one object.

* contacts: per finger, the candidate closest to the object (smallest signed distance), projected
  to the surface along the SDF gradient, with the gradient as its outward normal;
* ``-closure``: grasp_jax's own objective on those contacts (``_objectives.objective_one``, the
  same LPs as ``gj.optimize``; or DexGraspNet's energy with ``kind="dfc"``);
* distance: the contacts' distances to the surface (less a small gap);
* penetration: the hand's surface samples into the object (SDF) and the object's surface points
  into the hand's collision spheres;
* self-collision: spheres of different fingers that overlap.

Lengths are in units of the object's radius. Joint limits are kept by projection (the optimizer
clips), not by an energy.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from .._contact import ContactModel
from .._objectives import objective_one
from ._geometry import PATCH, farthest
from ._hand import Hand
from ._kinematics import forward, transform_points
from ._sdf import ObjectGeometry, distance, distance_and_normal


@dataclasses.dataclass(frozen=True)
class Weights:
    """Weights of the energy terms (static; hashable)."""

    closure: float = 12.0
    distance: float = 300.0
    penetration: float = 100.0
    self_collision: float = 10.0
    #: Clearance (m) the hand's surface keeps from the object: samples closer than this are
    #: penalized, which covers the signed-distance grid's rounding of edges and corners.
    clearance: float = 1e-3
    #: Distance (m) the contacts are pulled to: just beyond the clearance (the squeeze
    #: configuration closes it).
    gap: float = 1.2e-3


def contacts(hand: Hand, geom: ObjectGeometry, frames):
    """``(points (F, 3), normals (F, 3), distances (F,), candidate (F,))``: each finger's closest
    candidate projected to the surface, its SDF normal, its signed distance, its index."""
    pts = transform_points(frames, jnp.asarray(hand.finger_link)[:, None], hand.candidate_point)  # (F, K, 3)
    d = jax.vmap(jax.vmap(lambda x: distance(geom, x)))(pts)
    k = jnp.argmin(d, axis=1)
    chosen = jnp.take_along_axis(pts, k[:, None, None], axis=1)[:, 0]
    dist, normal = jax.vmap(lambda x: distance_and_normal(geom, x))(chosen)
    return chosen - dist[:, None] * normal, normal, dist, k


def spheres(hand: Hand, frames):
    """``(centers (S, 3), radii (S,))`` of the collision spheres in the world."""
    return transform_points(frames, hand.sphere_link, hand.sphere_center), hand.sphere_radius


#: The hand's surface patches and collision spheres that the penetration term reads per step: those
#: nearest the object. Farther ones are far enough out that they add nothing (the grid's distance
#: changes by at most LIPSCHITZ times the distance moved).
NEAR_PATCHES, NEAR_SPHERES, LIPSCHITZ = 48, 64, math.sqrt(3.0)
#: Balls are ranked in two rounds: groups of GROUP consecutive balls by a ball around each group,
#: then the balls of the nearest groups (four times as many as ``count`` needs).
GROUP = 8


def _reach(geom: ObjectGeometry, centers, radii):
    """A lower bound ``(n,)`` of the object's signed distance over each ball."""
    return jax.vmap(lambda x: distance(geom, x))(centers) - LIPSCHITZ * radii


def _nearest(geom: ObjectGeometry, centers, radii, count: int):
    """Indices ``(min(count, n),)`` of the balls ``centers: (n, 3), radii: (n,)`` that may come
    closest to the object: exact wherever at most ``count`` balls and ``4 ceil(count / GROUP)``
    groups are within reach."""
    n = centers.shape[0]
    centers, radii = jax.lax.stop_gradient(centers), jax.lax.stop_gradient(jnp.asarray(radii))
    groups, chosen = -(-n // GROUP), 4 * -(-count // GROUP)
    if count >= n or chosen >= groups:
        return jax.lax.top_k(-_reach(geom, centers, radii), min(count, n))[1]
    index = np.minimum(np.arange(groups * GROUP), n - 1).reshape(groups, GROUP)  # the last group padded
    real = jnp.asarray((np.arange(groups * GROUP) < n).reshape(groups, GROUP))
    c, r = centers[index], radii[index]
    middle = jnp.sum(c * real[..., None], axis=1) / real.sum(axis=1)[:, None]
    size = jnp.max(jnp.where(real, jnp.sqrt(jnp.sum((c - middle[:, None]) ** 2, axis=-1)) + r, -jnp.inf), axis=1)
    near = jax.lax.top_k(-_reach(geom, middle, size), chosen)[1]
    reach = jnp.where(real[near].reshape(-1), _reach(geom, c[near].reshape(-1, 3), r[near].reshape(-1)), jnp.inf)
    return jnp.asarray(index)[near].reshape(-1)[jax.lax.top_k(-reach, count)[1]]


def nearest_points(geom: ObjectGeometry, frames, local, link, count: int, grow=0.0):
    """``(min(count, G) * P, 3)`` world points of the ``count`` groups ``local: (G, P, 3)`` (on the
    links ``link: (G,)``) whose bounding balls, grown by ``grow``, come nearest the object."""
    local = jnp.asarray(local)
    middle = jnp.mean(local, axis=1)
    size = jnp.max(jnp.sqrt(jnp.sum((local - middle[:, None]) ** 2, axis=-1)), axis=1)
    near = _nearest(geom, transform_points(frames, link, middle), size + grow, count)
    return transform_points(frames, jnp.asarray(link)[near][:, None], local[near]).reshape(-1, 3)


def surface_patches(hand: Hand):
    """``(local (G, PATCH, 3), link (G,))``: the hand's surface samples in their patches."""
    return (jnp.asarray(hand.surface_point).reshape(-1, PATCH, 3),
            jnp.asarray(hand.surface_link).reshape(-1, PATCH)[:, 0])


def penetration(hand: Hand, geom: ObjectGeometry, frames, clearance=0.0) -> tuple[jax.Array, jax.Array]:
    """``(sum of depths, largest depth)`` (m) of the hand's surface samples into the object grown
    by ``clearance`` and of the object's surface points into the hand's collision spheres; read on
    the :data:`NEAR_PATCHES` patches and :data:`NEAR_SPHERES` spheres nearest the object."""
    surface = nearest_points(geom, frames, *surface_patches(hand), NEAR_PATCHES, clearance)
    into_object = jax.nn.relu(clearance - jax.vmap(lambda x: distance(geom, x))(surface))
    centers, radii = spheres(hand, frames)
    near = _nearest(geom, centers, radii, NEAR_SPHERES)
    centers, radii = centers[near], jnp.asarray(radii)[near]
    gap = jnp.sqrt(jnp.sum((geom.points[:, None] - centers[None]) ** 2, axis=-1) + 1e-30)
    into_hand = jax.nn.relu(radii[None] - gap)
    return jnp.sum(into_object) + jnp.sum(into_hand), jnp.maximum(jnp.max(into_object), jnp.max(into_hand))


def self_collision(hand: Hand, frames, pairs) -> jax.Array:
    """Sum of the overlaps (m) of the sphere pairs ``pairs: (2, P)`` (spheres of two fingers)."""
    centers, radii = spheres(hand, frames)
    a, b = pairs
    gap = jnp.sqrt(jnp.sum((centers[a] - centers[b]) ** 2, axis=-1) + 1e-30)
    return jnp.sum(jax.nn.relu(radii[a] + radii[b] - gap))


def energy(pose, joints, hand: Hand, geom: ObjectGeometry, pairs, mu, torsion, *, kind: str, num_edges: int,
           iterations: int, contact: str, weights: Weights):
    """``(energy (), monitors)`` of one configuration (``pose: (7,)`` wxyz, ``joints: (J,)``)."""
    frames = forward(hand, pose, joints)
    points, normals, dist, _ = contacts(hand, geom, frames)
    model = ContactModel(contact, num_edges, torsion)
    value, _ = objective_one(points, normals, mu, model, kind, geom.center, geom.scale, iterations, best_effort=True)
    pen_sum, pen_max = penetration(hand, geom, frames, weights.clearance)
    collide = self_collision(hand, frames, pairs)
    scale = geom.scale
    total = (-weights.closure * value + weights.distance * jnp.sum(jnp.abs(dist - weights.gap)) / scale
             + weights.penetration * pen_sum / scale + weights.self_collision * collide / scale)
    return total, {"objective": value, "distance": jnp.max(jnp.abs(dist)), "penetration": pen_max}


#: Spheres per link that take part in finger-finger collision (spread apart from the largest).
PAIR_SPHERES = 12


def finger_pairs(hand: Hand):
    """``(2, P) int32`` the sphere pairs of different fingers, on the two outer links of each
    finger (its distal link, the links fixed to it, and its parent), where fingers touch; at most
    :data:`PAIR_SPHERES` spheres per link."""
    finger, link = np.asarray(hand.sphere_finger), np.asarray(hand.sphere_link)
    outer = set(hand.finger_link) | {hand.parent[b] for b in hand.finger_link}
    outer |= {i for i in range(hand.num_links) if hand.parent[i] in outer and hand.joint_kind[i] == 0}
    near = np.zeros(len(finger), bool)
    centers, radii = np.asarray(hand.sphere_center), np.asarray(hand.sphere_radius)
    for i in sorted(outer):
        own = np.flatnonzero(link == i)
        if len(own):
            near[own[farthest(centers[own], PAIR_SPHERES, int(np.argmax(radii[own])))]] = True
    a, b = np.triu_indices(len(finger), 1)
    keep = (finger[a] >= 0) & (finger[b] >= 0) & (finger[a] != finger[b]) & near[a] & near[b]
    return np.stack([a[keep], b[keep]]).astype(np.int32)
