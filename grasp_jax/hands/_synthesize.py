"""``synthesize``: wrist poses and joint angles of a hand that grasp an object, by gradient.

Starts: wrist poses around the object, the palm facing it, the joints opened. Each step, for
every start at once (``_batch.map_grasps``, segment after segment): the energy of ``_energy``,
its gradient with respect to the wrist position, quaternion and joints, one Adam update (per-group
rates, cosine decay), the quaternion normalized and the joints clipped to their limits. The best
iterate (lowest energy) of each start is scored on the mesh as it is and with its fingers closed
onto the object (the closed one kept where it is valid): contacts at the closest mesh points of the
chosen candidates, ``gj.evaluate`` (soft contacts by default), the penetration of the hand's
deepest dense samples measured on the mesh.
"""

from __future__ import annotations

import contextlib
import functools
import math
import time

import jax
import jax.numpy as jnp
import numpy as np
import optax
import trimesh
from tqdm.auto import tqdm

from .. import objects as _objects
from .._api import _bind, _lp_columns, evaluate
from .._batch import map_grasps
from .._constants import DEFAULT_NUM_EDGES, first_pass_iterations
from .._contact import patch_torsion
from .._precision import float64_scope
from .._validate import check_int, check_num_edges, check_scalar
from . import _geometry as geo
from ._energy import NEAR_PATCHES, Weights, contacts, energy, finger_pairs, nearest_points, surface_patches
from ._hand import Hand
from ._kinematics import forward, matrix_to_quat, transform_points
from ._result import MAX_DISTANCE, MAX_PENETRATION, HandGraspResult, HandStatus
from ._sdf import distance, geometry

#: Adam's peak rates per step: wrist position in object radii, quaternion components, joints (rad).
RATES = (0.03, 0.03, 0.06)
#: The rates decay (cosine) to this share of their peak.
FINAL_RATE = 0.05
#: Segments of the step loop (one compiled call each; the progress bar advances per segment).
SEGMENTS = 10
#: Starts: joints jittered from the opened configuration towards closing by up to this share of
#: their range; the hand's surface this far (m) from the object, moved back along its approach
#: direction in at most CLEARING_ROUNDS rounds.
OPEN_JITTER, STANDOFF, CLEARING_ROUNDS = 0.1, (0.005, 0.02), 8
#: Pre-grasp and squeeze: joints moved (rad, largest joint) away from / into the object.
PREGRASP, SQUEEZE = 0.3, 0.1
#: The best iterate's fingers are closed onto the object (to the energy's contact gap) in this many
#: Gauss-Newton rounds of at most CLOSING_STEP rad per joint.
CLOSING_ROUNDS, CLOSING_STEP = 3, 0.1
#: Hand surface samples per collision element for the final penetration check, the patches of them
#: nearest the object read by the grid per grasp, and the deepest samples there checked against
#: the mesh.
PENETRATION_SAMPLES, NEAR_DENSE, DEEPEST = 2000, 256, 128
OBJECTIVES = ("closure", "dfc")
#: Vmapped block sizes of the step and final programs (``map_grasps(block=)``): the largest that
#: a batch fills, so that 64 starts do not run a block of 256.
BLOCKS = (256, 128, 64, 32, 16, 8)
#: Radius (m) of a fingertip's contact patch: soft contacts resist a moment about the normal of
#: ``grasp_jax.patch_torsion(PATCH_RADIUS, mu)``.
PATCH_RADIUS = 0.005


def _torsion(contact: str, mu: float) -> float:
    return 0.0 if contact == "hard" else float(patch_torsion(PATCH_RADIUS, mu))


def synthesize(hand: Hand, obj, *, starts: int = 256, steps: int = 200, mu: float = 0.5, contact: str = "soft",
               seed: int = 0, objective: str = "closure", num_edges: int = DEFAULT_NUM_EDGES,
               iterations: int | None = None, weights: Weights | None = None, dtype="float64",
               progress: bool = False) -> HandGraspResult:
    """Optimize ``starts`` grasps of ``hand`` on ``obj``.

    Args:
        hand: a :class:`Hand` (:func:`grasp_jax.hands.load`).
        obj: a 3D mesh object of :mod:`grasp_jax.objects`, or a spec :func:`grasp_jax.objects.load`
            reads (a mesh file, ``"glass"``).
        starts: number of starts (>= 1); steps: optimizer steps (>= 1).
        mu: friction coefficient of the objective and of the final ``gj.evaluate``.
        contact: ``"soft"`` (default; torsion of a patch of :data:`PATCH_RADIUS`) or ``"hard"``, as
            :func:`grasp_jax.evaluate`.
        seed: seed of the starts (the same seed gives the same starts).
        objective: ``"closure"`` (grasp_jax's force-closure objective, the same LPs as
            ``gj.optimize``) or ``"dfc"`` (DexGraspNet's energy, a baseline).
        num_edges, iterations: friction cone edges; interior-point iterations per LP and step.
        weights: :class:`Weights` of the energy terms (default ``Weights()``).
        dtype: ``"float64"`` or ``"float32"``.
        progress: show a progress bar over the steps.

    Returns:
        :class:`HandGraspResult`, one row per start.
    """
    t0 = time.perf_counter()
    weights = Weights() if weights is None else weights
    if not isinstance(hand, Hand):
        raise TypeError(f"hand must be a grasp_jax.hands.Hand (grasp_jax.hands.load(...)); got {type(hand).__name__}")
    obj = obj if hasattr(obj, "dim") else _objects.load(obj)
    starts, steps = check_int("starts", starts), check_int("steps", steps)
    mu, num_edges = check_scalar("mu", mu), check_num_edges(num_edges)
    if objective not in OBJECTIVES:
        raise ValueError(f"objective must be one of {OBJECTIVES}; got {objective!r}")
    if contact not in ("soft", "hard"):
        raise ValueError(f"contact must be 'soft' or 'hard'; got {contact!r}")
    if np.dtype(dtype) not in (np.float32, np.float64):
        raise ValueError(f"dtype must be 'float32' or 'float64'; got {dtype!r}")
    geom = geometry(obj)
    pose, joints = initial_configurations(hand, geom, starts, seed)
    iterations = iterations or first_pass_iterations(_lp_columns(hand.num_fingers, 3, num_edges, contact))
    scope = float64_scope() if np.dtype(dtype) == np.float64 else contextlib.nullcontext()
    with scope:
        cast = functools.partial(jax.tree_util.tree_map, lambda a: jnp.asarray(a, dtype)
                                 if jnp.issubdtype(jnp.asarray(a).dtype, jnp.floating) else jnp.asarray(a))
        hand_d, geom_d = cast(hand), cast(geom)
        best_pose, best_joints, energies = _run(hand_d, geom_d, cast((pose, joints)), mu, objective, num_edges,
                                                iterations, contact, weights, steps, progress)
        result = _score(hand_d, geom_d, obj, best_pose, best_joints, mu, num_edges, contact, objective, iterations,
                        weights.gap)
    return HandGraspResult(
        **result, energy=energies, initial_position=pose[:, :3], initial_quaternion=pose[:, 3:],
        initial_joints=joints, joint_names=hand.joint_names, hand=hand.name, object_name=str(obj.name),
        object_path=getattr(obj, "source", ""),
        objective_name=objective, contact=contact, mu=float(mu), steps=steps, seconds=time.perf_counter() - t0)


def initial_configurations(hand: Hand, geom, starts: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``(pose (S, 7), joints (S, J))``: from random directions ``u``, the palm facing the object
    (its normal along ``-u``), the fingers' centre over the object's centre, a random roll, the
    hand :data:`STANDOFF` clear of the object along ``u``; the joints opened and jittered towards
    closing."""
    rng = np.random.default_rng(seed)
    lo = np.where(np.isfinite(hand.lower), hand.lower, -np.pi)
    hi = np.where(np.isfinite(hand.upper), hand.upper, np.pi)
    joints = np.clip(hand.open_joints + hand.closing * (hi - lo) * rng.uniform(0, OPEN_JITTER,
                                                                                 (starts, hand.num_joints)), lo, hi)
    with float64_scope():
        frames = np.asarray(jax.jit(forward)(hand, np.array([0, 0, 0, 1.0, 0, 0, 0]), hand.open_joints))
    cand = np.asarray(transform_points(frames, np.asarray(hand.finger_link)[:, None], hand.candidate_point))
    palm, normal, along = (np.asarray(v) for v in hand.palm)
    # the palm's centre moved along the fingers to the middle of the candidates
    anchor = palm + along * np.dot(cand.reshape(-1, 3).mean(axis=0) - palm, along)
    center, points = np.asarray(geom.center), np.asarray(geom.points)
    u = rng.normal(size=(starts, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    extent = np.max((points - center) @ u.T, axis=0)  # (S,) the object's support along u
    local = np.stack([normal, along, np.cross(normal, along)], axis=1)  # columns
    pose = np.empty((starts, 7))
    for s in range(starts):
        roll = geo._any_perpendicular(u[s])
        angle = rng.uniform(0, 2 * np.pi)
        roll = math.cos(angle) * roll + math.sin(angle) * np.cross(u[s], roll)
        rot = np.stack([-u[s], roll, np.cross(-u[s], roll)], axis=1) @ local.T
        pose[s, :3] = center + u[s] * extent[s] - rot @ anchor
        pose[s, 3:] = np.asarray(matrix_to_quat(rot))
    standoff = rng.uniform(*STANDOFF, starts)
    with float64_scope():
        for _ in range(CLEARING_ROUNDS):  # back along u until the hand clears the object by standoff
            short = standoff - np.asarray(map_grasps(_clearance_one, (pose, joints), (hand, geom), (starts,)))
            if (short <= 1e-4).all():
                break
            pose[:, :3] += u * np.maximum(short, 0.0)[:, None]
    return pose, joints


def _clearance_one(pose, joints, shared):
    """The smallest signed distance ``()`` of the hand's surface samples to the object."""
    hand, geom = shared
    world = nearest_points(geom, forward(hand, pose, joints), *surface_patches(hand), NEAR_PATCHES)
    return jnp.min(jax.vmap(lambda x: distance(geom, x))(world))


def _segment(*args, treedef, kind, num_edges, iterations, contact, weights, length, total):
    """Advance one start ``length`` steps; ``args``: the leaves of ``(params, Adam state, best
    params, best energy)`` then ``shared = (hand, geom, pairs, mu, torsion, offset)``."""
    *leaves, (hand, geom, pairs, mu, torsion, offset) = args
    params, opt_state, best, best_energy = jax.tree_util.tree_unflatten(treedef, leaves)
    adam = optax.scale_by_adam()
    scale, center = geom.scale, geom.center
    rates = tuple(jnp.asarray(r, scale.dtype) for r in RATES)

    def value(p):
        pose = jnp.concatenate([center + scale * p[0], p[1]])
        return energy(pose, p[2], hand, geom, pairs, mu, torsion, kind=kind, num_edges=num_edges,
                      iterations=iterations, contact=contact, weights=weights)

    def step(carry, i):
        params, opt_state, best, best_energy = carry
        (e, _), grad = jax.value_and_grad(value, has_aux=True)(params)
        grad = jax.tree_util.tree_map(lambda g: jnp.where(jnp.isfinite(g), g, 0.0), grad)
        updates, new_state = adam.update(grad, opt_state, params)
        k = offset + i
        decay = FINAL_RATE + (1 - FINAL_RATE) * 0.5 * (1 + jnp.cos(jnp.pi * jnp.minimum(k, total) / total))
        moved = tuple(p - decay * r * u for p, r, u in zip(params, rates, updates))
        quat = moved[1] / jnp.sqrt(jnp.sum(moved[1] ** 2))
        moved = (moved[0], quat, jnp.clip(moved[2], hand.lower, hand.upper))
        active = k < total
        better = (e < best_energy) & jnp.isfinite(e) & active
        best = jax.tree_util.tree_map(lambda b, c: jnp.where(better, c, b), best, params)
        best_energy = jnp.where(better, e, best_energy)
        keep = lambda new, old: jax.tree_util.tree_map(lambda a, b: jnp.where(active, a, b), new, old)
        return (*keep((moved, new_state), (params, opt_state)), best, best_energy), e

    carry, energies = jax.lax.scan(step, (params, opt_state, best, best_energy), jnp.arange(length))
    return tuple(jax.tree_util.tree_leaves(carry)), energies


def _run(hand, geom, init, mu, kind, num_edges, iterations, contact, weights, steps, progress):
    """All starts through ``steps`` steps; ``((S, 7) poses, (S, J) joints, (S, steps) energies)``
    of the best iterates."""
    pose, joints = init
    count = pose.shape[0]
    dtype = pose.dtype
    params = ((pose[:, :3] - geom.center) / geom.scale, pose[:, 3:], joints)
    opt_state = jax.vmap(optax.scale_by_adam().init)(params)
    state = (params, opt_state, params, jnp.full((count,), jnp.inf, dtype))
    leaves, treedef = jax.tree_util.tree_flatten(state)
    length = math.ceil(steps / min(SEGMENTS, steps))
    fn = _bind(_segment, treedef=treedef, kind=kind, num_edges=num_edges, iterations=iterations, contact=contact,
               weights=weights, length=length, total=steps)
    pairs = jnp.asarray(finger_pairs(hand))
    torsion = jnp.asarray(_torsion(contact, mu), dtype)
    bar = tqdm(total=steps, unit="step", desc=f"hand grasps, {count:,} starts") if progress else None
    energies = []
    for offset in range(0, steps, length):
        shared = (hand, geom, pairs, jnp.asarray(mu, dtype), torsion, jnp.asarray(offset, jnp.int32))
        leaves, e = map_grasps(fn, tuple(leaves), shared, (count,), block=BLOCKS)
        leaves = list(leaves)
        energies.append(np.asarray(e))
        if bar is not None:
            bar.update(min(length, steps - offset))
            bar.set_postfix(energy=f"{np.median(np.asarray(leaves[-1])):.3f}")
    if bar is not None:
        bar.close()
    _, _, best, _ = jax.tree_util.tree_unflatten(treedef, leaves)
    pose = jnp.concatenate([geom.center + geom.scale * best[0], best[1]], axis=1)
    return pose, best[2], np.concatenate(energies, axis=1)[:, :steps]




def _close_fingers(hand, geom, pose, joints, target):
    """The joints ``(J,)`` with each finger's contact moved to ``target`` (m) from the surface by
    :data:`CLOSING_ROUNDS` Gauss-Newton steps on its own joints (at most :data:`CLOSING_STEP` rad
    per joint and round), as a hand closes onto an object; a finger nearer than ``target`` stays."""

    def distances(q):
        d = contacts(hand, geom, forward(hand, pose, q))[2]
        return d, d

    for _ in range(CLOSING_ROUNDS):
        jac, d = jax.jacfwd(distances, has_aux=True)(joints)  # (F, J), (F,)
        far = jnp.maximum(d - target, 0.0)
        move = -jnp.sum((far / jnp.maximum(jnp.sum(jac * jac, axis=1), 1e-12))[:, None] * jac, axis=0)
        move = move * jnp.minimum(1.0, CLOSING_STEP / jnp.maximum(jnp.max(jnp.abs(move)), 1e-12))
        joints = jnp.clip(joints + move, hand.lower, hand.upper)
    return joints


def _closed_one(pose, joints, shared):
    hand, geom, target = shared
    return _close_fingers(hand, geom, pose, joints, target)


def _final_one(pose, joints, shared):
    """For one grasp: the chosen candidates, the hand's deepest surface samples, and the pre-grasp
    and squeeze joints."""
    hand, geom, samples, sample_link = shared
    frames = forward(hand, pose, joints)
    _, _, _, k = contacts(hand, geom, frames)
    cand = transform_points(frames, jnp.asarray(hand.finger_link)[:, None], hand.candidate_point)
    chosen = jnp.take_along_axis(cand, k[:, None, None], axis=1)[:, 0]
    world = nearest_points(geom, frames, samples, sample_link, NEAR_DENSE)
    depth = jax.vmap(lambda x: distance(geom, x))(world)
    deepest = world[jax.lax.top_k(-depth, DEEPEST)[1]]

    def reach(q):
        return jnp.sum(contacts(hand, geom, forward(hand, pose, q))[2])

    g = jax.grad(reach)(joints)
    g = g / jnp.maximum(jnp.max(jnp.abs(g)), 1e-12)
    squeeze = jnp.clip(joints - SQUEEZE * g, hand.lower, hand.upper)
    pregrasp = jnp.clip(joints + PREGRASP * g, hand.lower, hand.upper)
    return chosen, deepest, pregrasp, squeeze


def _score(hand, geom, obj, pose, joints, mu, num_edges, contact, kind, iterations, gap) -> dict:
    """The fields of :class:`HandGraspResult` for the grasps ``pose, joints``, scored on the mesh:
    of each grasp as optimized and with its fingers closed onto the object (:func:`_close_fingers`),
    the closed one where it is valid."""
    count = pose.shape[0]
    closed = map_grasps(_closed_one, (pose, joints), (hand, geom, jnp.asarray(gap, pose.dtype)), (count,),
                        block=BLOCKS)
    both = _score_rows(hand, geom, obj, jnp.concatenate([pose, pose]), jnp.concatenate([joints, closed]), mu,
                       num_edges, contact)
    closed_valid = both["valid"][count:]
    pick = np.where(closed_valid, np.arange(count) + count, np.arange(count))
    return {**{key: value[pick] for key, value in both.items()}, "closed": closed_valid}


def _score_rows(hand, geom, obj, pose, joints, mu, num_edges, contact) -> dict:
    """The fields of :class:`HandGraspResult` that describe the grasps ``pose, joints``."""
    count, fingers = pose.shape[0], hand.num_fingers
    samples, links = geo.dense_samples(hand.collisions, PENETRATION_SAMPLES)
    shared = (hand, geom, jnp.asarray(samples, pose.dtype), jnp.asarray(links))
    chosen, deepest, pregrasp, squeeze = map_grasps(_final_one, (pose, joints), shared, (count,), block=BLOCKS)
    chosen = np.asarray(chosen, dtype=np.float64).reshape(-1, 3)
    mesh = obj.mesh
    closest, gap, tri = trimesh.proximity.closest_point(mesh, chosen)
    normals = np.asarray(mesh.face_normals[tri])
    side = np.einsum("ij,ij->i", chosen - closest, normals)
    dist = np.where(side < 0, -gap, gap).reshape(count, fingers)
    points, normals = closest.reshape(count, fingers, 3), normals.reshape(count, fingers, 3)
    active = np.abs(dist) <= MAX_DISTANCE
    # a finger that does not touch is no contact: it is evaluated as a copy of a touching one, which
    # adds no wrench (force-closure and Q unchanged) and keeps one program for every pattern
    first = np.argmax(active, axis=1)
    source = np.where(active, np.arange(fingers)[None], first[:, None])
    rows = np.arange(count)[:, None]
    ev = evaluate(points[rows, source], normals[rows, source], mu=mu, num_edges=num_edges, contact=contact,
                  torsion=None if contact == "hard" else _torsion(contact, mu))
    inside = trimesh.proximity.signed_distance(mesh, np.asarray(deepest, dtype=np.float64).reshape(-1, 3))
    penetration = np.maximum(inside.reshape(count, -1).max(axis=1), 0.0)
    far = active.sum(axis=1) < 2
    fc, q = np.asarray(ev.force_closure) & ~far, np.where(far, 0.0, np.asarray(ev.quality))
    pose, joints = np.asarray(pose, dtype=np.float64), np.asarray(joints, dtype=np.float64)
    finite = np.isfinite(pose).all(axis=1) & np.isfinite(joints).all(axis=1) & np.isfinite(dist).all(axis=1)
    status = np.select([~finite, far, ~fc, penetration > MAX_PENETRATION],
                       [HandStatus.NON_FINITE, HandStatus.CONTACT_FAR, HandStatus.NOT_FORCE_CLOSURE,
                        HandStatus.PENETRATION], HandStatus.VALID).astype(np.int8)
    return {"position": pose[:, :3], "quaternion": pose[:, 3:] / np.linalg.norm(pose[:, 3:], axis=1, keepdims=True),
            "joints": joints, "pregrasp": np.asarray(pregrasp, np.float64), "squeeze": np.asarray(squeeze, np.float64),
            "points": points, "normals": normals, "distance": dist, "active": active, "penetration": penetration,
            "force_closure": fc, "quality": q, "valid": status == HandStatus.VALID, "status": status}
