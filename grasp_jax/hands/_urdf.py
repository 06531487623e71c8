"""Reading a hand from a URDF file: the kinematic tree, joints, limits, mimic joints, collisions.

Parsed with yourdfpy (pure Python on trimesh, which grasp_jax already uses); an MJCF file
(``.xml``) goes to :mod:`._mjcf`. A description this module cannot use raises one ``ValueError``
naming the file and the element.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
import yourdfpy

from ._builtin import DEFAULT_NAME, default_urdf
from ._hand import FIXED, PRISMATIC, REVOLUTE, Collision, Tree
from ._mjcf import read as read_mjcf

_KINDS = {"fixed": FIXED, "revolute": REVOLUTE, "continuous": REVOLUTE, "prismatic": PRISMATIC}


def read(spec) -> Tree:
    """Parse ``spec``: :data:`DEFAULT_NAME`, a URDF file path, or an MJCF (``.xml``) one."""
    if str(spec) == DEFAULT_NAME:
        where, folder = f"built-in hand {DEFAULT_NAME!r}", Path(".")
        source = io.BytesIO(default_urdf().encode())
    else:
        path = Path(spec).expanduser()
        if not path.is_file():
            raise ValueError(f"{path}: hand description not found; give a URDF or MJCF file or {DEFAULT_NAME!r}")
        if path.suffix.lower() == ".xml":
            return read_mjcf(path)
        if path.suffix.lower() != ".urdf":
            raise ValueError(f"{path}: a hand description is a URDF (.urdf) or MJCF (.xml) file; got {path.suffix!r}")
        where, folder, source = str(path), path.resolve().parent, str(path)
    try:
        urdf = yourdfpy.URDF.load(source, build_scene_graph=False, load_meshes=False,
                                  load_collision_meshes=False)
    except Exception as exc:  # noqa: BLE001 - any parser failure is an unreadable file
        raise ValueError(f"{where}: cannot be read as URDF ({str(exc).splitlines()[0] if str(exc) else exc!r})") from None
    return _tree(urdf.robot, where, folder)


def _order(robot, where: str) -> tuple[list[str], dict]:
    """Links parent first, and the joint that leads to each non-root link."""
    names = [link.name for link in robot.links]
    by_child = {}
    for joint in robot.joints:
        for end in (joint.parent, joint.child):
            if end not in names:
                raise ValueError(f"{where}: joint {joint.name!r} names link {end!r}, which the file does not define")
        if joint.child in by_child:
            raise ValueError(f"{where}: link {joint.child!r} is the child of two joints")
        by_child[joint.child] = joint
    roots = [n for n in names if n not in by_child]
    if len(roots) != 1:
        raise ValueError(f"{where}: the links must form one tree with one root; roots found: {roots}")
    order, children = [roots[0]], {}
    for joint in robot.joints:
        children.setdefault(joint.parent, []).append(joint.child)
    i = 0
    while i < len(order):
        order.extend(children.get(order[i], []))
        i += 1
    if len(order) != len(names):
        raise ValueError(f"{where}: the joints form a cycle; a hand must be a tree")
    return order, by_child


def _limits(joint, where: str) -> tuple[float, float]:
    if joint.type == "continuous":
        return -np.inf, np.inf
    limit = joint.limit
    if limit is None or limit.lower is None or limit.upper is None:
        raise ValueError(f"{where}: joint {joint.name!r} ({joint.type}) has no <limit lower upper>")
    lo, hi = float(limit.lower), float(limit.upper)
    if not lo <= hi:
        raise ValueError(f"{where}: joint {joint.name!r} has lower limit {lo} above its upper limit {hi}")
    return lo, hi


def _tree(robot, where: str, folder: Path) -> Tree:
    order, by_child = _order(robot, where)
    index = {name: i for i, name in enumerate(order)}
    joints = {j.name: j for j in robot.joints}
    for joint in robot.joints:
        if joint.type not in _KINDS:
            raise ValueError(f"{where}: joint {joint.name!r} has type {joint.type!r}; a hand's joints must be "
                             f"one of {', '.join(_KINDS)}")
    actuated = [j.name for j in (by_child[n] for n in order[1:]) if j.type != "fixed" and j.mimic is None]
    act = {name: k for k, name in enumerate(actuated)}
    count = len(order)
    origin = np.tile(np.eye(4), (count, 1, 1))
    axis = np.tile(np.array([0.0, 0.0, 1.0]), (count, 1))
    multiplier, offset = np.ones(count), np.zeros(count)
    parent, kind, source = [-1] * count, [FIXED] * count, [-1] * count
    for name in order[1:]:
        i, joint = index[name], by_child[name]
        parent[i], kind[i] = index[joint.parent], _KINDS[joint.type]
        origin[i] = np.asarray(joint.origin if joint.origin is not None else np.eye(4), dtype=np.float64)
        if kind[i] == FIXED:
            continue
        a = np.asarray(joint.axis if joint.axis is not None else (1.0, 0.0, 0.0), dtype=np.float64)
        if not np.linalg.norm(a) > 0:
            raise ValueError(f"{where}: joint {joint.name!r} has a zero axis")
        axis[i] = a / np.linalg.norm(a)
        if joint.mimic is None:
            source[i] = act[joint.name]
        else:
            source[i], multiplier[i], offset[i] = _mimic(joint, joints, act, where)
    lower, upper = np.array([_limits(joints[n], where) for n in actuated]).reshape(-1, 2).T
    collisions = tuple(_collisions(robot, index, where, folder))
    return Tree(order=order, origin=origin, axis=axis, multiplier=multiplier, offset=offset, parent=tuple(parent),
                kind=tuple(kind), source=tuple(source), joint_names=tuple(actuated), lower=lower, upper=upper,
                collisions=collisions, name=robot.name or "hand", where=where)


def _mimic(joint, joints: dict, act: dict, where: str) -> tuple[int, float, float]:
    """``(actuated source, multiplier, offset)`` of a mimic joint, following chains of mimics."""
    mult, off, seen, current = 1.0, 0.0, {joint.name}, joint
    while current.mimic is not None:
        target = current.mimic.joint
        if target not in joints:
            raise ValueError(f"{where}: joint {current.name!r} mimics joint {target!r}, which the file does not define")
        if target in seen:
            raise ValueError(f"{where}: mimic joints form a cycle through {target!r}")
        m = 1.0 if current.mimic.multiplier is None else float(current.mimic.multiplier)
        o = 0.0 if current.mimic.offset is None else float(current.mimic.offset)
        mult, off = mult * m, off * m + o
        seen.add(target)
        current = joints[target]
    if current.name not in act:
        raise ValueError(f"{where}: mimic joint {joint.name!r} follows {current.name!r}, which is not a moving joint")
    return act[current.name], mult, off


def _mesh_file(filename: str, folder: Path) -> str:
    name = filename
    for prefix in ("file://", "package://"):
        name = name.removeprefix(prefix)
    candidates = [Path(name)] if os.path.isabs(name) else [folder / name]
    if filename.startswith("package://"):  # package://<pkg>/rest: try the rest beside the URDF too
        candidates.append(folder / Path(*Path(name).parts[1:]))
    for c in candidates:
        if c.is_file():
            return str(c.resolve())
    return ""


def _collisions(robot, index: dict, where: str, folder: Path):
    for link in robot.links:
        for k, col in enumerate(link.collisions):
            geom = col.geometry
            what = f"collision element {k} of link {link.name!r}"
            pose = np.asarray(col.origin if col.origin is not None else np.eye(4), dtype=np.float64)
            origin = tuple(float(v) for v in pose.reshape(-1))
            capsule = getattr(geom, "capsule", None)
            if geom.box is not None:
                yield Collision(index[link.name], "box", tuple(float(v) for v in geom.box.size), origin)
            elif geom.cylinder is not None:
                yield Collision(index[link.name], "cylinder",
                                (float(geom.cylinder.radius), float(geom.cylinder.length)), origin)
            elif geom.sphere is not None:
                yield Collision(index[link.name], "sphere", (float(geom.sphere.radius),), origin)
            elif capsule is not None:
                yield Collision(index[link.name], "capsule", (float(capsule.radius), float(capsule.length)), origin)
            elif geom.mesh is not None:
                found = _mesh_file(geom.mesh.filename, folder)
                if not found:
                    raise ValueError(f"{where}: the mesh {geom.mesh.filename!r} of {what} was not found "
                                     f"(looked beside the URDF, in {folder})")
                scale = geom.mesh.scale
                scale = (1.0, 1.0, 1.0) if scale is None else tuple(float(v) for v in np.broadcast_to(scale, (3,)))
                yield Collision(index[link.name], "mesh", scale, origin, found)
            else:
                raise ValueError(f"{where}: {what} has no geometry this reader knows (box, cylinder, sphere, "
                                 "capsule, mesh)")
