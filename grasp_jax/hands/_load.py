"""``load``: a :class:`Hand` from a URDF or MJCF file or the built-in description, ready for the optimizer."""

from __future__ import annotations

from pathlib import Path

import jax
import numpy as np

from .._precision import float64_scope
from . import _geometry as geo
from ._builtin import DEFAULT_NAME
from ._hand import FIXED, PRISMATIC, Hand
from ._kinematics import forward
from ._urdf import read

_IDENTITY = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])


def builtin() -> Hand:
    """The built-in default hand (:mod:`grasp_jax.hands._builtin`)."""
    return load(DEFAULT_NAME)


def load(spec=DEFAULT_NAME, *, candidates=None, seed: int = 0) -> Hand:
    """A hand from a URDF or MJCF file, or the built-in hand by its name ``"default"``.

    Args:
        spec: path of a ``.urdf`` file (meshes relative to its folder, ``package://`` prefixes
            stripped), of an MJCF ``.xml`` file (compiled by MuJoCo, ``pip install
            'grasp_jax[sim]'``; see :mod:`grasp_jax.hands._mjcf`), or ``"default"``.
        candidates: contact candidates to use instead of the automatic ones: ``(points, normals)``
            of shape ``(F, K, 3)`` each in the frames of the fingers' distal links
            (``hand.finger_link``), or an ``.npz`` file holding ``points`` and ``normals``.
        seed: seed of the surface sampling (spheres and candidates).

    Raises:
        ValueError: a file it cannot use, naming the file and the element (missing mesh, unknown
            joint type, missing limits, no finger found; for MJCF: no MuJoCo, ball joints, free
            joints below the root, nonlinear joint couplings).
    """
    tree = read(spec)
    every, finger = geo.fingers(tree.parent, tree.kind, tree.collisions)
    bodies = {b: geo.body_links(b, tree.parent, tree.kind) for b in every}
    meshes = {b: [geo.element_mesh(c) for c in tree.collisions if c.link in bodies[b]] for b in every}
    distal = [b for b in every if meshes[b]]
    if not distal:
        raise ValueError(f"{tree.where}: no fingertip found: no leaf link reached through a moving joint has "
                         "collision geometry on its last moving link (or links fixed to it)")
    renumber = {f: distal.index(b) for f, b in enumerate(every) if b in distal}
    finger = [renumber.get(f, -1) for f in finger]
    lower, upper = tree.lower, tree.upper
    closing = geo.closing_signs(lower, upper)
    open_joints = geo.opened(lower, upper, closing)
    centers, radii, links = geo.link_spheres(tree.collisions, len(tree.order), seed)
    surface, surface_link = geo.surface_samples(tree.collisions, seed)
    points, normals = [], []
    for b in distal:
        sign = (closing[tree.source[b]] or 1.0) * np.sign(tree.multiplier[b])
        p, n = geo.candidates(_in_body_frame(meshes[b], b, bodies[b], tree), np.zeros(3), sign * tree.axis[b],
                              tree.kind[b] == PRISMATIC, seed)
        points.append(p)
        normals.append(n)
    hand = Hand(
        origin=tree.origin, axis=tree.axis, multiplier=tree.multiplier, offset=tree.offset, lower=lower,
        upper=upper, sphere_center=centers, sphere_radius=radii, sphere_link=links,
        sphere_finger=np.asarray([finger[k] for k in links], dtype=np.int32).reshape(-1),
        surface_point=surface, surface_link=surface_link,
        candidate_point=np.stack(points), candidate_normal=np.stack(normals), palm=np.zeros((3, 3)),
        open_joints=open_joints, closing=closing, parent=tree.parent, joint_kind=tree.kind, source=tree.source,
        finger_link=tuple(distal), link_names=tuple(tree.order), joint_names=tree.joint_names,
        collisions=tree.collisions, name=tree.name, path="" if str(spec) == DEFAULT_NAME else str(Path(spec).resolve()),
    )
    hand = _with_palm(hand, finger)
    if candidates is not None:
        hand = hand.with_candidates(*_read_candidates(candidates))
    return hand


def _in_body_frame(meshes, body: int, links: list, tree):
    """The body's collision meshes are in their own links' frames; links fixed below ``body`` are
    moved into its frame."""
    out = []
    for c, m in zip((c for c in tree.collisions if c.link in links), meshes):
        chain, link = np.eye(4), c.link
        while link != body:
            chain = tree.origin[link] @ chain
            link = tree.parent[link]
        out.append(m.copy().apply_transform(chain) if c.link != body else m)
    return out


def _with_palm(hand: Hand, finger: list) -> Hand:
    """``hand`` with its palm frame, from the fingers at the opened configuration."""
    with float64_scope():
        frames = np.asarray(jax.jit(forward)(hand, _IDENTITY, np.asarray(hand.open_joints)))
    joint_points, tips, closing = [], [], []
    for f, body in enumerate(hand.finger_link):
        chain = [i for i in range(hand.num_links) if finger[i] == f and hand.joint_kind[i] != FIXED]
        t = frames[body]
        tip = (t[:3, :3] @ hand.candidate_point[f].mean(axis=0)) + t[:3, 3]
        joint_points.append(frames[chain[0], :3, 3])
        tips.append(tip)
        move = np.zeros(3)
        for i in chain:
            sign = hand.closing[hand.source[i]] * np.sign(hand.multiplier[i])
            axis = sign * (frames[i, :3, :3] @ hand.axis[i])
            move += axis if hand.joint_kind[i] == PRISMATIC else np.cross(axis, tip - frames[i, :3, 3])
        closing.append(move / max(np.linalg.norm(move), 1e-12))
    palm = geo.palm_frame(np.asarray(joint_points), np.asarray(tips), np.asarray(closing))
    return Hand(**{**hand.__dict__, "palm": palm})


def _read_candidates(spec):
    if isinstance(spec, (str, Path)):
        path = Path(spec)
        if not path.is_file():
            raise ValueError(f"{path}: candidates file not found")
        with np.load(path) as f:
            if "points" not in f or "normals" not in f:
                raise ValueError(f"{path}: a candidates file must hold arrays 'points' and 'normals' (F, K, 3)")
            return f["points"], f["normals"]
    if isinstance(spec, tuple) and len(spec) == 2:
        return spec
    raise ValueError(f"candidates must be (points, normals) or an .npz file; got {type(spec).__name__}")
